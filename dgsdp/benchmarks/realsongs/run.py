"""The real-song benchmark's commands: ``prepare`` a song set, and dance to it and measure (``main``)."""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections.abc import Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from dgsdp.audio.beat_tracker import (
    AGREE_F_MEASURE,
    TEMPO_TOLERANCE,
    TrackedBeats,
    bpm_of_beats,
    trackers_agree,
)
from dgsdp.benchmarks.realsongs.measures import (
    FLOATING_HEIGHT_M,
    FLOATING_MAX_FRACTION,
    MIN_GENRE_SECONDS,
    P999_CAP_GENRE_FACTOR,
    P999_SPEED_MAX_M_S,
    PENETRATION_MAX_CM,
    SEAM_RATIO_MAX,
    SPEED_RATIO_RANGE,
    Reference,
    _no_nan,
    dance_figures,
    training_dances_passing,
    training_figures,
    window_boundaries,
)
from dgsdp.benchmarks.realsongs.report import (
    MODEL_BEAT_FRACTION,
    SongResult,
    Tracking,
    _fmt,
    format_row,
    genre_of,
    genre_speed_line,
    header,
    independent_summary,
    raw_summary,
    style_plan,
    style_summary_lines,
    summary_line,
    tempo_line,
)
from dgsdp.benchmarks.realsongs.songs import DEBIAN_MUSIC_DIRS, MIN_SONG_SECONDS, prepare
from dgsdp.errors import ConfigError, DgsdpError
from dgsdp.metrics.beats import BAS_VARIANTS, beat_scores


def run_benchmark(
    folder: Path,
    checkpoint: str,
    overrides: Sequence[str] = (),
    *,
    style: str | None = None,
    all_styles: bool = False,
    floor_m: float | None = None,
    train_speed: float | None = None,
    json_path: Path | None = None,
    motions_dir: Path | None = None,
    out: Any = None,
) -> list[SongResult]:
    """Dance to every song of ``folder`` as generate.py would and print the table and the summary line (to ``out``,
    default stdout; progress goes to stderr). ``all_styles``: every song in every genre of the checkpoint (a row and
    a dance each), and a summary line per genre after the summary line."""
    import torch

    from dgsdp.cli.config import compose_config
    from dgsdp.cli.generate import generate_settings
    from dgsdp.generation import find_songs, write_motion
    from dgsdp.generation.beatsync import fed_beat_tracker, other_tracker_beats, song_beats
    from dgsdp.generation.songs import SongDancer
    from dgsdp.motion import pose_to_joints, smpl24_layout

    out = sys.stdout if out is None else out
    if not folder.is_dir():
        raise ConfigError(f"{folder} is not a folder of songs (build one with: python -m {__spec__.name} prepare DIR)")
    cfg = compose_config("generate", [f"checkpoint={checkpoint}", *overrides])
    songs = find_songs(str(folder))
    job = SongDancer.from_settings(generate_settings(cfg))
    generator, sampling = job.generator, job.sampling
    settings = job.settings
    finishing_settings = {  # every post-processing setting of the finished dances
        "cleanup": settings.cleanup,
        "beat_sync": settings.cleanup and settings.beat_sync,
        "floor_cleanup": asdict(settings.finishing.floor()) if settings.cleanup else None,
        "beat_sync_settings": asdict(settings.finishing.beat_sync())
        if settings.cleanup and settings.beat_sync
        else None,
    }
    window, stride = generator.window_layout(sampling)
    floor = generator.floor_height if floor_m is None else float(floor_m)
    reference, train_source = training_figures(
        generator.spec, cfg.paths.cache_dir, floor_m=floor, window=window, stride=stride
    )
    given_speed = train_speed  # --train-speed replaces the training data's mean speed
    if given_speed is not None:
        train_source = "--train-speed"
    train_speed = Reference.for_genre(reference, None, given_speed).speed_m_s
    genres: list[str | None] = [None]
    vocab = generator.embedder().vocab if generator.style_dim else None
    if vocab is not None:
        genres = list(vocab.codes)
    dances = style_plan(songs, genres, None if style is None else str(style), all_styles)
    plans: dict[str | None, Any] = {}
    tracked: dict[Path, TrackedBeats] = {}
    # a model fed the independent tracker's beats (audio.beat_tracker=flux) is checked against librosa's instead
    swapped = fed_beat_tracker(generator.audio_encoder) == "flux"
    first: dict[Path, tuple[Path, str | None]] = {}
    for pair in dances:
        first.setdefault(pair[0], pair)
    print(
        f"checkpoint {checkpoint}; {len(songs)} songs in {folder}; sampling {sampling.method}-{sampling.steps} "
        f"guidance music={sampling.guidance.music:g} project_rotations={sampling.project_rotations} "
        f"tempo_fold={_tempo_setting(generator.training_tempi(sampling))}; "
        f"windows {window} frames, stride {stride}; floor z={floor:g} m; "
        f"training mean joint speed {_fmt(train_speed, '.3f')} m/s from {train_source}",
        file=out,
    )
    if swapped:
        print(
            "this model is fed the independent tracker's beats (audio.beat_tracker=flux): below, \"librosa's beats\" "
            "are its own (the independent tracker's) and the \"independent beats\" are librosa's tracker's",
            file=out,
        )
    print(
        "finishing (the final rows; the raw rows are the model's own output from the same sample): "
        + json.dumps(finishing_settings, separators=(",", ":")),
        file=out,
    )
    if reference is not None:
        r = reference
        print(
            f"training data ({r['n_dances']:g} dances, {r['seconds']:.0f} s) on the same measures: "
            f"p999={r['p999_speed_m_s']:.2f} pen_cm={r['penetration_cm']:.1f} float={r['floating_fraction']:.3f} "
            f"seam={_fmt(r['seam_ratio'], '.2f')} speed={r['mean_speed_m_s']:.3f}{_training_passing(r)}",
            file=out,
        )
    width = max([len(s.name) for s in songs] + [4])
    print(header(width), file=out, flush=True)
    results: list[SongResult] = []
    for k, (song, song_style) in enumerate(dances, 1):
        print(f"[{k}/{len(dances)}] {song.name} (style {song_style})", file=sys.stderr, flush=True)
        genre = genre_of(song_style, vocab)
        result = SongResult(
            song.name, song_style, genre=genre, reference=Reference.for_genre(reference, genre, given_speed)
        )
        try:
            if song_style not in plans:
                plans[song_style] = generator.resolve_style(song_style)
            start = time.perf_counter()
            generator.music_features(song, cfg.seconds)  # features first (cached), so that the dance time is sampling
            beats = song_beats(song, generator.cache, generator.audio_encoder)
            result.feature_seconds = time.perf_counter() - start
            start = time.perf_counter()
            dance = job.dance(song, plans[song_style])
            skel = dance.skeleton
            result.dance_seconds = time.perf_counter() - start
            result.tempo = dance.tempo
            if motions_dir is not None:
                # a song's first dance is <song>; its dances in other genres are <song>__<genre>
                name = (
                    song.stem if not all_styles and (song, song_style) == first[song] else f"{song.stem}__{song_style}"
                )
                write_motion(dance.motion[0], motions_dir / name, fps=generator.fps, formats=["npy"], skeleton=skel)
                write_motion(
                    dance.raw[0], motions_dir / "raw" / name, fps=generator.fps, formats=["npy"], skeleton=skel
                )
            # the measures read SMPL's 24 joints: another skeleton's joints in SMPL's layout
            layout = smpl24_layout(skel)
            joints = pose_to_joints(dance.motion[0].double(), skel).numpy()[:, layout]
            raw_joints = pose_to_joints(dance.raw[0].double(), skel).numpy()[:, layout]
            boundaries = window_boundaries(len(joints), window, stride)
            result.figures = dance_figures(joints, music_beats=beats, boundaries=boundaries, floor_m=floor)
            result.raw = dance_figures(raw_joints, music_beats=beats, boundaries=boundaries, floor_m=floor)
            result.checks = result.figures.checks(result.reference)
            result.raw_checks = result.raw.checks(result.reference)
            if song not in tracked:  # the independent tracker's beats, once per song
                tracked[song] = other_tracker_beats(song, generator.cache, generator.audio_encoder)
            independent = tracked[song]
            agree, f = trackers_agree(TrackedBeats(bpm_of_beats(beats), np.asarray(beats)), independent)
            result.tracking = Tracking(bpm_of_beats(beats), independent.bpm, agree, f)
            result.independent = {
                stage: {v: beat_scores(j, independent.frames, variant=v) for v in BAS_VARIANTS}
                for stage, j in (("raw", raw_joints), ("final", joints))
            }
            moved = np.linalg.norm(joints - raw_joints, axis=-1)
            result.finishing = {
                **dance.finishing[0], "moved_mean_cm": 100 * float(moved.mean()), "moved_max_cm": 100 * float(moved.max())
            }  # fmt: skip
        except (DgsdpError, torch.cuda.OutOfMemoryError) as e:
            result.error = str(e).replace("\n", " ")
        results.append(result)
        print(format_row(result, train_speed, width), file=out, flush=True)
    summary = summary_line(results, train_speed)
    print(summary, file=out, flush=True)
    by_genre = None if reference is None else reference.get("by_genre")
    style_lines = style_summary_lines(results, by_genre) if all_styles else []
    if style_lines:
        print("\n".join(style_lines), file=out, flush=True)
    raw_line, _ = raw_summary(results, train_speed, None if reference is None else reference.get("speed_by_phase"))
    print(raw_line, file=out, flush=True)
    independent_line = independent_summary(results)
    print(independent_line, file=out, flush=True)
    genre_line = genre_speed_line(results)
    print(genre_line, file=out, flush=True)
    tempo_summary = tempo_line(results)
    print(tempo_summary, file=out, flush=True)
    if json_path is not None:
        from dgsdp.utils.io import atomic_write_text

        payload = {
            "folder": str(folder),
            "checkpoint": str(checkpoint),
            "overrides": list(overrides),
            "sampling": asdict(sampling),
            "all_styles": all_styles,
            "floor_m": floor,
            "train_speed_m_s": None if math.isnan(train_speed) else train_speed,
            "train_speed_source": train_source,
            "training_data_figures": reference,
            "window_frames": window,
            "stride_frames": stride,
            "thresholds": {
                "p999_speed_m_s_below": P999_SPEED_MAX_M_S,
                "penetration_cm_at_most": PENETRATION_MAX_CM,
                "floating_fraction_below": FLOATING_MAX_FRACTION,
                "floating_height_m": FLOATING_HEIGHT_M,
                "seam_ratio_below": SEAM_RATIO_MAX,
                "speed_ratio_within": list(SPEED_RATIO_RANGE),
                "genre_judgement": "a dance asked for in a genre of the training data is judged against that "
                "genre's training dances: mean speed within 30% of the genre's (never below half the mean speed of "
                "all), p999 below 8 m/s times its genre's p999 over all the training data's where that is above 1, at "
                f"most max(8 m/s, {P999_CAP_GENRE_FACTOR:g} x the genre's p999); a free-text style, a genre the "
                f"data lacks or one with under {MIN_GENRE_SECONDS:g} s of training dances against all the training "
                "data (each song's 'limits'; 'checks_as_set': every dance against all the training data)",
                "bas_variants_sigma_frames": {k: list(v) for k, v in BAS_VARIANTS.items()},
                "independent_beats": "BAS also against the beats of dgsdp.audio.beat_tracker (spectral flux, "
                "comb-filter tempo, grid phase: no code shared with librosa's); the trackers agree on a song when "
                f"their tempi are within {TEMPO_TOLERANCE:.0%} (double or half is a disagreement) and at least "
                f"{AGREE_F_MEASURE:g} F-measure (70 ms) of librosa's beats match; the model's own timing target "
                "needs the same fraction above the shifted copy on the independent beats, over the dances of the "
                "songs where the trackers agree (the others are not scored)",
                "model_beat_fraction_at_least": MODEL_BEAT_FRACTION,
            },
            "finishing": finishing_settings,
            "songs": [
                {
                    "name": r.name,
                    "style": r.style,
                    "genre": r.genre,
                    "error": r.error,
                    "feature_seconds": r.feature_seconds,
                    "dance_seconds": r.dance_seconds,
                    "figures": None if r.figures is None else asdict(r.figures),
                    "raw_figures": None if r.raw is None else asdict(r.raw),
                    "finishing": r.finishing,
                    "speed_ratio": None
                    if r.figures is None or math.isnan(train_speed)
                    else r.figures.mean_speed_m_s / train_speed,
                    "limits": None if r.reference is None else _limits(r.reference),
                    "checks": r.checks,
                    "checks_as_set": None
                    if r.figures is None or r.reference is None
                    else r.figures.checks(r.reference.overall),
                    "raw_checks": r.raw_checks,
                    "tracking": None if r.tracking is None else asdict(r.tracking),
                    "independent_beats": {
                        stage: {v: asdict(sc) for v, sc in scores.items()} for stage, scores in r.independent.items()
                    },
                    "passed": r.passed,
                    "tempo": None if r.tempo is None else {**asdict(r.tempo), "given_bpm": r.tempo.given_bpm},
                }
                for r in results
            ],
            "summary": summary,
            "style_summaries": style_lines,
            "raw_summary": raw_line,
            "independent_beats_summary": independent_line,
            "genre_speed_summary": genre_line,
            "tempo_summary": tempo_summary,
        }
        atomic_write_text(json_path, json.dumps(_no_nan(payload), indent=2, allow_nan=False) + "\n")
    return results


def _limits(reference: Reference) -> dict[str, Any]:
    """A dance's speed limits for the JSON."""
    return {
        "p999_speed_m_s_below": reference.p999_limit(),
        "speed_m_s_within": list(reference.speed_range()),
        "judged_against": "all the training data"
        if reference.thin_genre or not reference.genre_speed_m_s > 0
        else "the genre's training dances",
        "thin_genre": reference.thin_genre,
    }


def _training_passing(figures: dict[str, Any]) -> str:
    """The training data line's count of its own dances within the speed targets (nothing for an older cache)."""
    plain, stretched, n = training_dances_passing(figures)
    if not n:
        return ""
    return (
        f"; its dances within the speed and p999 targets: {plain}/{n} as set, {stretched}/{n} against their own genre's"
    )


def _tempo_setting(tempi: tuple[tuple[float, float] | None, str]) -> str:
    """The header's tempo folding: off, or on with the training tempi it folds toward and where they came from."""
    tempo_range, source = tempi
    if source == "off":
        return "off"
    return f"on({source})" if tempo_range is None else f"on({tempo_range[0]:g}-{tempo_range[1]:g} BPM, {source})"


def _prepare_main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m dgsdp.benchmarks.realsongs prepare",
        description="Build the real-song set: varied originals plus loud (+20 dB, clipped), 8 kHz mono and "
        "96 kHz versions, written with ffmpeg.",
    )
    parser.add_argument("out", type=Path, help="folder to write the song set into")
    parser.add_argument(
        "--sources", nargs="+", default=list(DEBIAN_MUSIC_DIRS),
        help="folders of songs (default: where the Debian packages hyperrogue-music, drascula-music and "
        "fb-music-high install theirs)",
    )  # fmt: skip
    parser.add_argument("--max-songs", type=int, default=8, help="how many originals to pick (default 8)")
    parser.add_argument("--min-seconds", type=float, default=MIN_SONG_SECONDS, help="shortest song to consider")
    parser.add_argument("--exclude", nargs="+", type=Path, default=[], metavar="SET",
                        help="song sets (folders made by prepare) whose songs this one must not share: a report set "
                        "disjoint from the set settings were tuned on")  # fmt: skip
    args = parser.parse_args(argv)
    return prepare(args.out, args.sources, args.max_songs, args.min_seconds, args.exclude)


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        if argv and argv[0] == "prepare":
            return _prepare_main(argv[1:])
        parser = argparse.ArgumentParser(
            prog="python -m dgsdp.benchmarks.realsongs",
            description="Dance to every song of a folder as generate.py does and measure the dances "
            "(build a song set first with the 'prepare' command).",
        )
        parser.add_argument("folder", type=Path, help="folder of songs (wav, mp3, ogg, flac)")
        parser.add_argument("overrides", nargs="*", help="overrides of conf/generate.yaml, e.g. sampling.steps=10")
        parser.add_argument("--checkpoint", required=True, help="a trained model's .ckpt file")
        parser.add_argument("--style", default=None, help="one style for all songs (default: the checkpoint's "
                            "genres in turn, one per original song)")  # fmt: skip
        parser.add_argument("--all-styles", action="store_true", help="dance every song in every genre of the "
                            "checkpoint (a row each) and print a summary line per genre")  # fmt: skip
        parser.add_argument("--floor", type=float, default=None, help="floor height in metres (default: the run's)")
        parser.add_argument(
            "--train-speed",
            type=float,
            default=None,
            help="the training data's mean joint speed in m/s (default: computed from its data)",
        )
        parser.add_argument("--json", type=Path, default=None, help="write every figure to this JSON file")
        parser.add_argument("--motions", type=Path, default=None,
                            help="also write each dance (T, 151) as <folder>/<song>.npy (<song>__<style>.npy with "
                            "--all-styles), e.g. to render it later")  # fmt: skip
        args = parser.parse_intermixed_args(argv)
        run_benchmark(
            args.folder, args.checkpoint, args.overrides, style=args.style, all_styles=args.all_styles,
            floor_m=args.floor, train_speed=args.train_speed, json_path=args.json, motions_dir=args.motions,
        )  # fmt: skip
        return 0
    except DgsdpError as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
