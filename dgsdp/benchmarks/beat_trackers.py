"""The beat trackers against known beats: ``python -m dgsdp.benchmarks.beat_trackers <synthetic dataset> [--songs
DIR ...] [--json FILE]``.

Measures librosa's tracker (the 35-d features' beat column) and the independent one of
:mod:`dgsdp.audio.beat_tracker` against the known beats of a synthetic dataset's songs (``synthetic.json``): the mean
beat F-measure (70 ms window) and how many songs' tempo each finds within 4% (and within 4% of the tempo, its double
or its half); then, for folders of real songs, each song's tempo by both and whether they agree
(:func:`~dgsdp.audio.beat_tracker.trackers_agree`). The tracker that finds the known beats more often is the better
source of the model's beat features (``audio.beat_tracker``)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from dgsdp.audio.beat_tracker import (
    FPS,
    SAMPLE_RATE,
    beat_f_measure,
    librosa_beats,
    tempo_agrees,
    track_beats,
    trackers_agree,
)


def measure_on_synthetic(root: str | Path) -> dict[str, dict[str, float]]:
    """Each tracker's mean beat F-measure (70 ms) and how many songs' tempo it finds within 4% (and within 4% of
    the tempo, its double or its half) against the known beats of a synthetic dataset's songs (``synthetic.json``).
    Trackers: this one (``flux``), librosa's as on real songs (``librosa``: its own tempo estimate) and as on the
    training songs (``librosa_id_prior``: the tempo of the AIST++ music id as its start)."""
    from dgsdp.audio.io import load_audio
    from dgsdp.data.aistpp import music_tempo_bpm
    from dgsdp.data.synthetic import music_beat_times_s, read_manifest

    manifest = read_manifest(root)
    rows: dict[str, list[tuple[float, bool, bool]]] = {"flux": [], "librosa": [], "librosa_id_prior": []}
    for music_id, info in sorted(manifest["music"].items()):
        waveform, rate = load_audio(Path(root) / "wavs" / f"{music_id}.wav", SAMPLE_RATE, mono=True)
        known = music_beat_times_s(manifest, music_id)
        answers = {
            "flux": track_beats(waveform, rate),
            "librosa": librosa_beats(waveform, rate),
            "librosa_id_prior": librosa_beats(waveform, rate, music_tempo_bpm(music_id)),
        }
        for name, beats in answers.items():
            rows[name].append(
                (
                    beat_f_measure(beats.frames / FPS, known),
                    tempo_agrees(beats.bpm, info["bpm"]),
                    tempo_agrees(beats.bpm, info["bpm"], octaves=True),
                )
            )
    return {
        name: {
            "songs": len(r),
            "f_measure": float(np.mean([x[0] for x in r])),
            "tempo_within_4pct": sum(x[1] for x in r),
            "tempo_within_4pct_or_octave": sum(x[2] for x in r),
        }
        for name, r in rows.items()
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m dgsdp.benchmarks.beat_trackers",
        description="Measure the beat trackers against a synthetic dataset's known beats, and their agreement on "
        "real songs.",
    )
    parser.add_argument("synthetic", type=Path, help="a synthetic dataset (with its synthetic.json)")
    parser.add_argument("--songs", type=Path, nargs="*", default=[], help="folders of real songs: agreement")
    parser.add_argument("--json", type=Path, default=None, help="write the figures to this JSON file")
    args = parser.parse_args(argv)
    figures: dict[str, object] = {"synthetic": measure_on_synthetic(args.synthetic)}
    for name, row in figures["synthetic"].items():  # type: ignore[union-attr]
        print(
            f"synthetic {name}: songs={row['songs']} f_measure_70ms={row['f_measure']:.3f} "
            f"tempo_within_4pct={row['tempo_within_4pct']}/{row['songs']} "
            f"tempo_within_4pct_or_octave={row['tempo_within_4pct_or_octave']}/{row['songs']}"
        )
    songs = []
    from dgsdp.audio.io import load_audio
    from dgsdp.generation import find_songs

    for folder in args.songs:
        for song in find_songs(str(folder)):
            waveform, rate = load_audio(song, SAMPLE_RATE, mono=True)
            ours, theirs = track_beats(waveform, rate), librosa_beats(waveform, rate)
            agree, f = trackers_agree(ours, theirs)
            songs.append({"song": str(song), "flux_bpm": ours.bpm, "librosa_bpm": theirs.bpm, "f_measure": f,
                          "agree": agree})  # fmt: skip
            print(f"{song.name}: flux {ours.bpm:.1f} BPM, librosa {theirs.bpm:.1f} BPM, F {f:.2f}, "
                  f"{'agree' if agree else 'DISAGREE'}")  # fmt: skip
    if songs:
        print(f"real songs: the trackers agree on {sum(s['agree'] for s in songs)}/{len(songs)}")
    figures["songs"] = songs
    if args.json is not None:
        args.json.write_text(json.dumps(figures, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
