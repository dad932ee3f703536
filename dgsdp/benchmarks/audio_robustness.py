"""How robust the librosa music features are to gain, mastering and sample rate, and how well the synthetic
training music covers real songs.

``python -m dgsdp.benchmarks.audio_robustness <songs folder> [--synthetic DIR]`` reads every song in the folder
(its first ``--seconds``), makes three variants of each in memory, as a user's files may come:

- ``loud``: +20 dB and hard clipped at full scale (a loud master, as ``ffmpeg -af volume=20dB`` to 16-bit PCM),
- ``8k``: mono at 8 kHz, ``96k``: 96 kHz,

and encodes them with the librosa encoder under several normalisations (``--methods``; each one a
``LibrosaEncoder`` setting, so the figures are those of the code that training and generation run). The
training distribution is the train-split music of a synthetic dataset (``--synthetic``, generated into a
temporary folder when not given), encoded with the same setting. It prints per normalisation:

- invariance: mean absolute difference between a variant's features and the original's, per feature group, in
  units of the training data's per-column standard deviation (0 is perfectly invariant), and for the binary
  columns the F-measure of the variant's beats and onset peaks against the original's (+-2 frames);
- coverage: the fraction of frames with any column of a group more than 4 training standard deviations from
  the training mean (0: every frame looks like something seen in training), for the originals and all variants.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from dgsdp.audio.io import AUDIO_SUFFIXES, load_audio
from dgsdp.audio.librosa_encoder import (
    BEAT_COLUMN,
    CHROMA_COLUMNS,
    ENVELOPE_COLUMN,
    MFCC_COLUMNS,
    PEAK_COLUMN,
    LibrosaEncoder,
)
from dgsdp.audio.numba_cache import librosa

GROUPS = {
    "env": slice(ENVELOPE_COLUMN, ENVELOPE_COLUMN + 1),
    "mfcc0": slice(MFCC_COLUMNS.start, MFCC_COLUMNS.start + 1),
    "mfcc": MFCC_COLUMNS,
    "chroma": CHROMA_COLUMNS,
}
Z_LIMIT = 4.0
# name -> LibrosaEncoder settings
METHODS: dict[str, dict] = {
    "none": {"loudness_lufs": None, "standardize": "none", "mfcc_fmax_hz": None},  # the features before
    "lufs-23": {"loudness_lufs": -23.0, "standardize": "none", "mfcc_fmax_hz": None},
    "lufs-14": {"loudness_lufs": -14.0, "standardize": "none", "mfcc_fmax_hz": None},
    "mean": {"loudness_lufs": None, "standardize": "mean", "mfcc_fmax_hz": None},
    "mean_std": {"loudness_lufs": None, "standardize": "mean_std", "mfcc_fmax_hz": None},
    "lufs-23+mean": {"loudness_lufs": -23.0, "standardize": "mean", "mfcc_fmax_hz": None},
    "lufs-23+mean_std": {"loudness_lufs": -23.0, "standardize": "mean_std", "mfcc_fmax_hz": None},
    "lufs-23+fmax": {"loudness_lufs": -23.0, "standardize": "none", "mfcc_fmax_hz": 3500.0},  # the default
    "lufs-23+mean+fmax": {"loudness_lufs": -23.0, "standardize": "mean", "mfcc_fmax_hz": 3500.0},
    "lufs-23+mean_std+fmax": {"loudness_lufs": -23.0, "standardize": "mean_std", "mfcc_fmax_hz": 3500.0},
}


def variants(waveform: np.ndarray, rate_hz: int) -> dict[str, tuple[np.ndarray, int]]:
    """The original ``(channels, samples)`` audio and its loud, 8 kHz mono and 96 kHz versions."""
    return {
        "orig": (waveform, rate_hz),
        "loud": (np.clip(waveform * 10.0, -1.0, 1.0), rate_hz),
        "8k": (librosa.resample(waveform.mean(axis=0), orig_sr=rate_hz, target_sr=8000, res_type="soxr_hq"), 8000),
        "96k": (librosa.resample(waveform, orig_sr=rate_hz, target_sr=96000, res_type="soxr_hq", axis=-1), 96000),
    }


def beat_f_measure(reference: np.ndarray, estimate: np.ndarray, tolerance: int = 2) -> float:
    """F-measure of the 1-frames of ``estimate`` against those of ``reference`` within ``tolerance`` frames."""
    ref, est = np.flatnonzero(reference), np.flatnonzero(estimate)
    if len(ref) == 0 and len(est) == 0:
        return 1.0
    if len(ref) == 0 or len(est) == 0:
        return 0.0
    precision = np.mean(np.abs(est[:, None] - ref[None, :]).min(axis=1) <= tolerance)
    recall = np.mean(np.abs(ref[:, None] - est[None, :]).min(axis=1) <= tolerance)
    return float(0.0 if precision + recall == 0 else 2 * precision * recall / (precision + recall))


def out_of_range(features: np.ndarray, mean: np.ndarray, std: np.ndarray, columns: slice) -> float:
    """Fraction of frames with any column of ``columns`` more than Z_LIMIT training stds from the mean."""
    z = np.abs(features[:, columns] - mean[columns]) / std[columns]
    return float(np.mean((z > Z_LIMIT).any(axis=1)))


def training_songs(synthetic: Path) -> list[tuple[Path, str]]:
    manifest = json.loads((synthetic / "synthetic.json").read_text())
    ids = sorted({s["music_id"] for s in manifest["sequences"].values() if s["split"] == "train"})
    return [(synthetic / "wavs" / f"{m}.wav", m) for m in ids]


def measure(method: str, train: list[tuple[Path, str]], songs: dict[str, dict]) -> dict:
    encoder = LibrosaEncoder(**METHODS[method])
    train_feats = [encoder.encode(*load_audio(path, None, mono=True), music_id=mid) for path, mid in train]
    stacked = np.concatenate(train_feats)
    mean, std = stacked.mean(axis=0), np.maximum(stacked.std(axis=0), 1e-6)
    rows: dict[str, dict[str, list[float]]] = {}
    mfcc0 = []
    for song in songs.values():
        feats = {name: encoder.encode(y, rate) for name, (y, rate) in song.items()}
        ref = feats["orig"]
        mfcc0.append(float(np.median(ref[:, MFCC_COLUMNS.start])))
        for name, f in feats.items():
            n = min(len(f), len(ref))
            row = rows.setdefault(name, {})
            for group, cols in GROUPS.items():
                if name != "orig":
                    diff = np.abs(f[:n, cols] - ref[:n, cols]) / std[cols]
                    row.setdefault(f"d_{group}", []).append(float(diff.mean()))
                row.setdefault(f"out_{group}", []).append(out_of_range(f, mean, std, cols))
            if name != "orig":
                row.setdefault("beatF", []).append(beat_f_measure(ref[:n, BEAT_COLUMN], f[:n, BEAT_COLUMN]))
                row.setdefault("peakF", []).append(beat_f_measure(ref[:n, PEAK_COLUMN], f[:n, PEAK_COLUMN]))
    train_out = {g: np.mean([out_of_range(f, mean, std, c) for f in train_feats]) for g, c in GROUPS.items()}
    return {
        "rows": {v: {k: float(np.mean(x)) for k, x in r.items()} for v, r in rows.items()},
        "train_out": train_out,
        "mfcc0_train": (float(np.percentile(stacked[:, 1], 1)), float(np.percentile(stacked[:, 1], 99))),
        "mfcc0_songs": (min(mfcc0), max(mfcc0)),
    }


def report(method: str, result: dict) -> None:
    groups = list(GROUPS)
    print(f"\n== {method}: {METHODS[method]}")
    lo, hi = result["mfcc0_train"]
    slo, shi = result["mfcc0_songs"]
    print(f"   MFCC0: training p1..p99 {lo:.1f}..{hi:.1f}; real songs' medians {slo:.1f}..{shi:.1f}")
    head = "".join(f"{'d_' + g:>9}" for g in groups) + f"{'beatF':>7}{'peakF':>7}"
    head += "".join(f"{'out_' + g:>11}" for g in groups)
    print(f"   {'variant':<8}{head}")
    print(f"   {'train':<8}{'':>{9 * len(groups) + 14}}" + "".join(f"{result['train_out'][g]:>11.3f}" for g in groups))
    for variant, row in result["rows"].items():
        line = "".join(f"{row[f'd_{g}']:>9.3f}" if f"d_{g}" in row else f"{'-':>9}" for g in groups)
        line += f"{row['beatF']:>7.2f}{row['peakF']:>7.2f}" if "beatF" in row else f"{'-':>7}{'-':>7}"
        line += "".join(f"{row[f'out_{g}']:>11.3f}" for g in groups)
        print(f"   {variant:<8}{line}")
    rows = [r for v, r in result["rows"].items() if v != "orig"]
    inv = np.mean([[r[f"d_{g}"] for g in ("env", "mfcc", "chroma")] for r in rows])
    cover = np.mean([[r[f"out_{g}"] for g in ("env", "mfcc", "chroma")] for r in result["rows"].values()])
    print(f"   summary: mean invariance distance {inv:.3f} std, mean out-of-range fraction {cover:.3f}")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("songs", type=Path, help="folder of real songs (wav, flac, ogg, mp3)")
    parser.add_argument("--synthetic", type=Path, default=None, help="synthetic dataset (default: generate one)")
    parser.add_argument("--seconds", type=float, default=30.0, help="length of each song used")
    parser.add_argument("--methods", nargs="+", default=list(METHODS), choices=list(METHODS))
    args = parser.parse_args(argv)

    paths = sorted(p for p in args.songs.iterdir() if p.suffix.lower() in AUDIO_SUFFIXES)
    if not paths:
        raise SystemExit(f"no audio files ({', '.join(AUDIO_SUFFIXES)}) in {args.songs}")
    songs = {}
    for path in paths:
        y, rate = load_audio(path, None, mono=False)
        songs[path.stem] = variants(y[:, : int(args.seconds * rate)], rate)
    print(f"{len(songs)} songs x {args.seconds:.0f} s, variants: {', '.join(next(iter(songs.values())))}")
    with tempfile.TemporaryDirectory() as tmp:
        synthetic = args.synthetic
        if synthetic is None:
            from dgsdp.data.synthetic import generate_synthetic_aistpp

            synthetic = generate_synthetic_aistpp(Path(tmp) / "synthetic")
        train = training_songs(synthetic)
        print(f"training distribution: {len(train)} train-split songs of {synthetic}")
        for method in args.methods:
            start = time.perf_counter()
            result = measure(method, train, songs)
            report(method, result)
            print(f"   ({time.perf_counter() - start:.0f} s)")


if __name__ == "__main__":
    main()
