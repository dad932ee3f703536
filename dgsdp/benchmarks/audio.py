"""Benchmark of audio feature extraction.

``python -m dgsdp.benchmarks.audio`` times the librosa features of one synthetic 3-minute song, then the
throughput of dataset extraction (songs per second, audio seconds per wall-clock second) over a folder of
synthetic songs written to a temporary folder, and a second, fully cached pass over the same folder.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
import soundfile as sf

from dgsdp.audio import LibrosaEncoder, extract_dataset


def synthetic_song(seconds: float, bpm: float, sample_rate: int, seed: int = 0) -> np.ndarray:
    """A click track at ``bpm`` over a chord drone with a little noise, float32 mono."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(seconds * sample_rate)) / sample_rate
    y = 0.05 * sum(np.sin(2 * np.pi * f * t) for f in (220.0, 277.2, 329.6))
    y = y + 0.01 * rng.standard_normal(t.shape)
    beat = (t % (60.0 / bpm)) < 0.03
    y = y + 0.6 * beat * np.sin(2 * np.pi * 1000.0 * t) * np.exp(-(t % (60.0 / bpm)) / 0.008)
    return y.astype(np.float32)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--song-seconds", type=float, default=180.0, help="length of the single song")
    parser.add_argument("--n-songs", type=int, default=8, help="songs in the extraction folder")
    parser.add_argument("--dataset-song-seconds", type=float, default=20.0)
    args = parser.parse_args(argv)

    encoder = LibrosaEncoder()
    song = synthetic_song(args.song_seconds, 120.0, encoder.sample_rate)
    encoder.encode(song[: 2 * encoder.sample_rate], encoder.sample_rate)  # warm-up: numba compiles on first use
    start = time.perf_counter()
    features = encoder.encode(song, encoder.sample_rate, music_id="mBR4")
    seconds = time.perf_counter() - start
    print(
        f"librosa features, {args.song_seconds:.0f} s song -> {features.shape}: {seconds:.2f} s "
        f"({args.song_seconds / seconds:.0f}x real time)"
    )

    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "wavs"
        folder.mkdir()
        paths = []
        for i in range(args.n_songs):
            path = folder / f"m{['BR', 'PO', 'HO', 'JB'][i % 4]}{i % 10}_{i}.wav"
            sf.write(str(path), synthetic_song(args.dataset_song_seconds, 90 + 5 * i, 44100, seed=i), 44100)
            paths.append(path)
        for label in ("extraction", "cached pass"):
            start = time.perf_counter()
            summary = extract_dataset(encoder, paths, Path(tmp) / "cache", progress=False)
            wall = time.perf_counter() - start
            print(
                f"{label}: {summary.n_songs} songs x {args.dataset_song_seconds:.0f} s "
                f"({summary.n_computed} encoded, {summary.n_cached} cached) in {wall:.2f} s: "
                f"{summary.n_songs / wall:.2f} songs/s, {summary.audio_seconds / wall:.0f} audio s/s"
            )


if __name__ == "__main__":
    main()
