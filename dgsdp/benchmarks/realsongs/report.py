"""The real-song benchmark's plan and report: which style each song gets, and the rows and summary lines."""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from dgsdp.audio.tempo import TempoFold
from dgsdp.benchmarks.realsongs.measures import (
    CHECK_NAMES,
    MIN_GENRE_SECONDS,
    PHASE_BINS,
    Reference,
    SongFigures,
    phase_distance,
)
from dgsdp.benchmarks.realsongs.songs import song_family
from dgsdp.errors import ConfigError
from dgsdp.metrics.beats import BAS_VARIANTS, BeatScores

MODEL_BEAT_FRACTION = 0.9  # the raw model above the shifted copy on at least this fraction of the dances


def styles_for(songs: Sequence[Path], genres: Sequence[str | None], style: str | None) -> list[str | None]:
    """The style of each song: ``style`` for all, or the genres in turn, one per original song (its loud and
    resampled versions get the same genre, so that versions compare)."""
    if style is not None:
        return [style] * len(songs)
    families = sorted({song_family(s) for s in songs})
    return [genres[families.index(song_family(s)) % len(genres)] for s in songs]


def style_plan(
    songs: Sequence[Path], genres: Sequence[str | None], style: str | None, all_styles: bool = False
) -> list[tuple[Path, str | None]]:
    """The dances to make, (song, style) pairs: each song in its style from :func:`styles_for`, then every genre
    that got no song in turn on the original songs (so that every genre dances); or with ``all_styles`` each song
    in every genre of the checkpoint, song by song."""
    if all_styles:
        if style is not None:
            raise ConfigError("--all-styles dances every song in every genre: leave out --style")
        if all(g is None for g in genres):
            raise ConfigError("--all-styles needs a model with a style embedding; this checkpoint has no genres")
        return [(song, genre) for song in songs for genre in genres]
    plan = list(zip(songs, styles_for(songs, genres, style)))
    if style is None:
        originals = [s for s in songs if s.stem == song_family(s)] or list(songs)
        missing = [g for g in genres if g is not None and g not in {g for _, g in plan}]
        plan += [(originals[k % len(originals)], genre) for k, genre in enumerate(missing)]
    return plan


@dataclass(frozen=True)
class Tracking:
    """The song's beat by the two trackers: librosa's (the features' beat column, what the model hears and the
    main BAS columns score against) and the independent one (:mod:`dgsdp.audio.beat_tracker`), and whether they
    agree (:func:`~dgsdp.audio.beat_tracker.trackers_agree`: tempi within 4%, beats matching)."""

    librosa_bpm: float
    independent_bpm: float
    agree: bool
    f_measure: float  # of librosa's beats against the independent ones, 70 ms


@dataclass
class SongResult:
    """One dance of the benchmark: the finished dance's figures (``figures``, what generate.py writes) and the raw
    model's (``raw``, ``cleanup=false``) from the same sample, and what the finishing changed (``finishing``)."""

    name: str
    style: str | None
    figures: SongFigures | None = None
    raw: SongFigures | None = None
    finishing: dict[str, float] = field(default_factory=dict)
    feature_seconds: float = math.nan
    dance_seconds: float = math.nan
    error: str | None = None
    checks: dict[str, bool] = field(default_factory=dict)
    raw_checks: dict[str, bool] = field(default_factory=dict)
    tempo: TempoFold | None = None  # the song's tempo and how its beats were given to the model
    reference: Reference | None = None  # what the speed targets measured it against
    genre: str | None = None  # the genre code the style names (KR for "krump"); None for free text or a schedule
    tracking: Tracking | None = None  # the song's beat by the two trackers
    # BAS against the independent tracker's beats: {"raw"|"final": {"bas"|"bas_edge": BeatScores}}
    independent: dict[str, dict[str, BeatScores]] = field(default_factory=dict)

    def independent_above(self, stage: str, variant: str) -> bool:
        """Whether the stage's dance is above its half-beat-shifted copy on the independent tracker's beats (an
        error, or no such score, is not)."""
        scores = self.independent.get(stage, {}).get(variant)
        return self.error is None and scores is not None and scores.above_shifted

    @property
    def passed(self) -> bool:
        return self.error is None and all(self.checks.values())


def genre_of(style: str | None, vocab: Any) -> str | None:
    """The code of the genre a style names in ``vocab`` (a :class:`~dgsdp.style.vocab.GenreVocab`, or None for a
    model without genres): "KR" for "krump", "KR" or "gKR"; None for free text ("text: krump", a description) or a
    schedule."""
    if vocab is None or style is None or str(style) not in vocab:
        return None
    return vocab.code(str(style))


def _fmt(value: float, spec: str) -> str:
    return "n/a" if value is None or (isinstance(value, float) and math.isnan(value)) else format(value, spec)


def _ratio(speed: float, train_speed: float) -> float:
    return speed / train_speed if train_speed and not math.isnan(train_speed) else math.nan


def low_phase(profile: Sequence[float] | None) -> int | None:
    """The beat-phase bin (0 = on the beat, in eighths) where a speed-by-phase profile is slowest, or None."""
    values = np.asarray([math.nan if v is None else v for v in profile or []], dtype=np.float64)
    return None if values.size == 0 or np.isnan(values).all() else int(np.nanargmin(values))


def header(width: int = 30) -> str:
    return (
        f"{'song':<{width}} {'style':<6} {'stage':<5} {'sec':>6} {'p999':>6} {'pen_cm':>6} {'float':>6} {'seam':>5} "
        f"{'speed':>6} {'ratio':>5} {'bas':>5} {'bas_sh':>6} {'basE':>5} {'basE_sh':>7} {'lowph':>5} {'gen_s':>6}  "
        "result"
    )


def verdict(checks: dict[str, bool]) -> str:
    failed = [k for k, ok in checks.items() if not ok]
    return "pass" if not failed else "FAIL(" + ",".join(failed) + ")"


def _stage_row(name: str, style: str, stage: str, f: SongFigures, train_speed: float, gen_s: str, result: str,
               width: int) -> str:  # fmt: skip
    return (
        f"{name:<{width}} {style:<6} {stage:<5} {f.seconds:6.1f} {f.p999_speed_m_s:6.2f} {f.penetration_cm:6.1f} "
        f"{f.floating_fraction:6.3f} {_fmt(f.seam_ratio, '5.2f'):>5} {f.mean_speed_m_s:6.3f} "
        f"{_fmt(_ratio(f.mean_speed_m_s, train_speed), '5.2f'):>5} {_fmt(f.bas, '5.3f'):>5} "
        f"{_fmt(f.bas_shifted, '6.3f'):>6} {_fmt(f.bas_edge, '5.3f'):>5} {_fmt(f.bas_edge_shifted, '7.3f'):>7} "
        f"{_fmt(low_phase(f.speed_by_phase), 'd'):>5} {gen_s:>6}  {result}"
    )


def format_row(result: SongResult, train_speed: float, width: int = 30) -> str:
    """Three lines: the raw model's figures (its checks in brackets: targets of the finished dance only), the
    finished dance's (the targets), and what the finishing changed."""
    style = str(result.style)
    if result.error is not None:
        return f"{result.name:<{width}} {style:<6} ERROR: {result.error}"
    raw = _stage_row(result.name, style, "raw", result.raw, train_speed, "", f"({verdict(result.raw_checks)})", width)
    final = _stage_row(result.name, style, "final", result.figures, train_speed, f"{result.dance_seconds:.1f}",
                       verdict(result.checks), width)  # fmt: skip
    return f"{raw}\n{final}\n  {finishing_text(result.finishing)}\n  {tracking_text(result)}"


def tracking_text(result: SongResult) -> str:
    """The song's beat by both trackers and the dance's BAS against the independent tracker's beats, in words."""
    t = result.tracking
    if t is None:
        return "beats: n/a"
    verdict_ = "agree" if t.agree else "DISAGREE (not scored for the model's timing)"
    parts = [
        f"beats: librosa {_fmt(t.librosa_bpm, '.1f')} BPM, independent {_fmt(t.independent_bpm, '.1f')} BPM, "
        f"F {t.f_measure:.2f}: {verdict_}"
    ]
    for stage in ("raw", "final"):
        scores = result.independent.get(stage, {})
        cells = [
            f"{variant} {_fmt(sc.bas, '.3f')}/{_fmt(sc.shifted, '.3f')}" for variant, sc in scores.items()
        ]  # fmt: skip
        parts.append(f"{stage} on independent beats (dance/shifted) " + " ".join(cells))

    return "; ".join(parts)


def finishing_text(n: dict[str, float]) -> str:
    """What the finishing changed, in words (the keys of :meth:`DanceGenerator.finish`'s stats, plus the joint
    displacement ``moved_mean_cm`` / ``moved_max_cm``)."""
    if not n:
        return "finishing: off"
    parts = [f"finishing moved the joints {_fmt(n.get('moved_mean_cm', math.nan), '.1f')} cm on average, "
             f"{_fmt(n.get('moved_max_cm', math.nan), '.1f')} cm at most"]  # fmt: skip
    if "anchored_beats" in n and n.get("retimed", 1.0):
        parts.append(
            f"retimed {n['anchored_beats']:g}/{n['beats']:g} beats (poses moved {n['mean_shift_ms']:.0f} ms on average, "
            f"{n['max_shift_ms']:.0f} ms at most)"
        )
    elif "anchored_beats" in n and n.get("judged_beat_sets"):
        parts.append(f"beat sync kept the model's timing (the retime onto {n['anchored_beats']:g}/{n['beats']:g} "
                     f"beats, finished, was worse on one of {n['judged_beat_sets']:g} trackers' beats)")  # fmt: skip
    if n.get("below_raw_margins"):
        parts.append(f"the floor cleanup left the timing below the raw dance's on {n['below_raw_margins']:g} judged "
                     f"beat scores, by up to {n.get('below_raw_by', math.nan):.3f} (no timing avoided it)")  # fmt: skip
    limits = [f"{k.removesuffix('_frames').replace('_', ' ')} {n[k]:g}" for k in LIMIT_KEYS if k in n]
    if limits:
        parts.append("frames touched: " + ", ".join(limits))
    return "; ".join(parts)


LIMIT_KEYS = ("tilt_limited_frames", "turn_limited_frames", "grounded_air_frames", "foot_locked_frames")


def _profile(profiles: Sequence[Sequence[float]]) -> np.ndarray:
    values = np.asarray([[math.nan if v is None else v for v in p] for p in profiles], dtype=np.float64)
    if values.size == 0:
        return np.full(PHASE_BINS, math.nan)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a bin empty everywhere stays NaN
        return np.nanmean(values, axis=0)


def _count(results: Sequence[SongResult], checks: str, name: str) -> str:
    """How many of the dances pass one check, over every dance: a dance that errored has no checks and counts as a
    failure in every count."""
    return f"{sum(getattr(r, checks).get(name, False) for r in results)}/{len(results)}"


def summary_line(results: Sequence[SongResult], train_speed: float) -> str:
    """The finished dances against the targets (the last-but-one line of the report)."""
    done = [r for r in results if r.error is None]
    figs = [r.figures for r in done]

    def worst(values: list[float], fn: Any = max) -> str:
        values = [v for v in values if not math.isnan(v)]
        return _fmt(fn(values), ".3f") if values else "n/a"

    ratios = [_ratio(f.mean_speed_m_s, train_speed) for f in figs]
    ratios = [r for r in ratios if not math.isnan(r)]
    gen = [r.dance_seconds / r.figures.seconds for r in done if r.figures.seconds > 0]
    return (
        f"songs={len(results)} pass={sum(r.passed for r in results)} "
        f"pass_as_set={sum(all(_as_set(r, r.figures).values()) for r in done)} "
        f"errors={len(results) - len(done)} "
        f"worst_p999={worst([f.p999_speed_m_s for f in figs])} worst_pen_cm={worst([f.penetration_cm for f in figs])} "
        f"worst_float={worst([f.floating_fraction for f in figs])} worst_seam={worst([f.seam_ratio for f in figs])} "
        f"speed_within_30pct={_count(results, 'checks', 'speed')} bas_above_shifted={_count(results, 'checks', 'bas')} "
        f"bas_edge_above_shifted={_count(results, 'checks', 'bas_edge')} "
        f"speed_ratio_mean={_fmt(float(np.mean(ratios)) if ratios else math.nan, '.3f')} "
        f"train_speed={_fmt(train_speed, '.3f')} gen_s_per_dance_s={_fmt(float(np.mean(gen)) if gen else math.nan, '.2f')}"
    )


def _as_set(result: SongResult, figures: SongFigures) -> dict[str, bool]:
    """The checks of one stage of a finished dance against the targets as set for all the training data (the same as
    its own for a free-text style)."""
    return (
        figures.checks(result.reference.overall)
        if result.reference is not None
        else figures.checks(Reference(math.nan))
    )


def raw_summary(
    results: Sequence[SongResult], train_speed: float, train_profile: Sequence[float] | None
) -> tuple[str, bool]:
    """The raw model's timing (the last line of the report) and whether it meets the model's own beat target: above
    the half-beat-shifted copy on at least :data:`MODEL_BEAT_FRACTION` of the dances in both BAS variants on
    librosa's beats, its speed-by-phase minimum within one eighth of a beat of the training dances', and the same
    fraction above the shifted copy in both variants on the independent tracker's beats, over the dances of songs
    where the two trackers agree (:func:`independent_summary`). A dance that errored counts as one below its
    shifted copy."""
    done = [r for r in results if r.error is None]
    n = len(results)
    above = {k: sum(r.raw_checks.get(k, False) for r in done) for k in ("bas", "bas_edge")}
    profile = _profile([r.raw.speed_by_phase for r in done])
    low, train_low = low_phase(profile.tolist()), low_phase(train_profile)
    phase_ok = low is not None and train_low is not None and phase_distance(low, train_low) <= 1
    librosa_met = bool(done) and all(k >= MODEL_BEAT_FRACTION * n for k in above.values()) and phase_ok
    independent_met = _independent_counts(results, "raw")[2]
    met = librosa_met and independent_met
    ratios = [_ratio(r.raw.mean_speed_m_s, train_speed) for r in done]
    ratios = [x for x in ratios if not math.isnan(x)]
    line = (
        f"raw: bas_above_shifted={above['bas']}/{n} bas_edge_above_shifted={above['bas_edge']}/{n} "
        f"errors={n - len(done)} "
        f"speed_ratio_mean={_fmt(float(np.mean(ratios)) if ratios else math.nan, '.3f')} "
        f"speed_by_phase={_phase_text(profile)} low_phase={_fmt(low, 'd')} "
        f"train_speed_by_phase={_phase_text(train_profile)} train_low_phase={_fmt(train_low, 'd')} "
        f"librosa_beats={'pass' if librosa_met else 'FAIL'} independent_beats={'pass' if independent_met else 'FAIL'} "
        f"model_beat_target={'pass' if met else 'FAIL'}"
    )
    return line, met


def _independent_counts(results: Sequence[SongResult], stage: str) -> tuple[dict[str, int], list[SongResult], bool]:
    """Per BAS variant, how many of the scored dances (those of songs where the two trackers agree, and those that
    errored before their song was tracked) are above their shifted copy on the independent beats; the scored
    dances; and whether at least :data:`MODEL_BEAT_FRACTION` of them are, in both variants."""
    scored = [r for r in results if r.tracking is None or r.tracking.agree]
    above = {v: sum(r.independent_above(stage, v) for r in scored) for v in BAS_VARIANTS}
    met = bool(scored) and all(k >= MODEL_BEAT_FRACTION * len(scored) for k in above.values())
    return above, scored, met


def independent_summary(results: Sequence[SongResult]) -> str:
    """The beat by the two trackers (how many songs they agree on, and the tempi where they do not) and the dances
    above their half-beat-shifted copy on the independent tracker's beats, raw and finished, beside the same
    dances on librosa's beats. Dances of songs where the trackers disagree are not scored: neither beat can be
    trusted there."""
    songs: dict[str, Tracking] = {r.name: r.tracking for r in results if r.tracking is not None}
    disagree = sorted(name for name, t in songs.items() if not t.agree)
    parts = [
        f"independent beats: the trackers agree on {len(songs) - len(disagree)}/{len(songs)} songs"
        + (
            "; disagree (librosa/independent BPM, not scored): "
            + ", ".join(f"{n} {songs[n].librosa_bpm:.0f}/{songs[n].independent_bpm:.0f}" for n in disagree)
            if disagree
            else ""
        )
    ]
    for stage, checks in (("raw", "raw_checks"), ("final", "checks")):
        above, scored, met = _independent_counts(results, stage)
        on_librosa = {v: sum(getattr(r, checks).get(v, False) for r in scored) for v in BAS_VARIANTS}
        parts.append(
            f"{stage}: "
            + " ".join(f"{v}_above_shifted={above[v]}/{len(scored)}" for v in BAS_VARIANTS)
            + " (librosa's beats, same dances: "
            + " ".join(f"{v}={on_librosa[v]}/{len(scored)}" for v in BAS_VARIANTS)
            + ")"
            + (f" target={'pass' if met else 'FAIL'}" if stage == "raw" else "")
        )
    judged = [r for r in results if r.finishing and r.finishing.get("judged_beat_sets")]
    if judged:
        kept = sum(bool(r.finishing.get("retimed")) for r in judged)
        below = sum(bool(r.finishing.get("below_raw_margins")) for r in judged)
        parts.append(
            f"beat sync kept the retime on {kept}/{len(judged)} dances (the model's timing on the others); "
            f"finished below raw on a judged beat score: {below}/{len(judged)} (the floor cleanup's doing: no timing "
            "avoided it)"
        )
    return "; ".join(parts)


def _phase_text(profile: Sequence[float] | None) -> str:
    if profile is None:
        return "n/a"
    return "[" + ",".join(_fmt(None if v is None else float(v), ".2f") for v in profile) + "]"


def style_summary_lines(
    results: Sequence[SongResult], by_genre: Mapping[str, Mapping[str, float]] | None = None
) -> list[str]:
    """One line per style: how many of its dances pass, each target's misses, and its worst p99.9 speed. With the
    training data's figures per genre (``by_genre``, from :func:`training_figures`), a genre's line also compares
    its dances with that genre's own training dances: their mean and p99.9 joint speed (``genre_train_speed``,
    ``genre_train_p999``) and the mean speed ratio of the finished and the raw dances to it (``speed_ratio_genre``,
    ``raw_speed_ratio_genre``): the speed targets of a genre's dances (:class:`Reference`)."""
    lines = []
    for style in dict.fromkeys(r.style for r in results):
        mine = [r for r in results if r.style == style]
        done = [r for r in mine if r.error is None]
        missed = {name: sum(not r.checks.get(name, False) for r in mine) for name in CHECK_NAMES}  # errors miss all
        p999 = [r.figures.p999_speed_m_s for r in done]
        line = (
            f"style={style} dances={len(mine)} pass={sum(r.passed for r in mine)} errors={len(mine) - len(done)} "
            + " ".join(f"{name}_missed={n}" for name, n in missed.items())
            + f" worst_p999={_fmt(max(p999) if p999 else math.nan, '.3f')}"
        )
        genre = (by_genre or {}).get(str(mine[0].genre))
        if genre is not None:
            speed = float(genre["mean_speed_m_s"])
            final = [_ratio(r.figures.mean_speed_m_s, speed) for r in done]
            raw = [_ratio(r.raw.mean_speed_m_s, speed) for r in done]
            line += (
                f" genre_train_speed={speed:.3f} genre_train_p999={float(genre['p999_speed_m_s']):.2f}"
                f" speed_ratio_genre={_fmt(float(np.mean(final)) if final else math.nan, '.2f')}"
                f" raw_speed_ratio_genre={_fmt(float(np.mean(raw)) if raw else math.nan, '.2f')}"
            )
        lines.append(line)
    return lines


def genre_speed_line(results: Sequence[SongResult]) -> str:
    """The two speed targets (mean speed and p99.9) both ways, finished and raw dances, over every dance (an error
    fails): by genre, the targets (a dance asked for in a genre against that genre's training dances, a free-text
    one against all the data, :class:`Reference`), and as set (every dance against all the training data); and the
    genres judged against all the data because their training dances were too few."""

    def counts(by_genre: bool) -> str:
        parts = []
        for stage in ("figures", "raw"):
            checks = [
                {} if r.error is not None or getattr(r, stage) is None
                else (r.checks if stage == "figures" else r.raw_checks) if by_genre
                else _as_set(r, getattr(r, stage))
                for r in results
            ]  # fmt: skip
            parts.append(
                f"{'finished' if stage == 'figures' else 'raw'} speed={sum(c.get('speed', False) for c in checks)}/"
                f"{len(results)} p999={sum(c.get('p999', False) for c in checks)}/{len(results)}"
            )
        return " ".join(parts)

    thin = sorted({r.reference.thin_genre for r in results if r.reference is not None and r.reference.thin_genre})
    return (
        f"speed targets by genre (the targets: a genre's dances against its own training dances, free text against "
        f"all): {counts(True)}; as set (against all the training data): {counts(False)}; genres judged against all "
        f"the data (under {MIN_GENRE_SECONDS:g} s of training dances): {', '.join(thin) or 'none'}"
    )


def tempo_line(results: Sequence[SongResult]) -> str:
    """Which songs' beats the model was given folded (``sampling.tempo_fold``), and toward which training tempi."""
    tempi = [r.tempo for r in results if r.tempo is not None]
    ranges = sorted({f"{t.range_bpm[0]:g}-{t.range_bpm[1]:g} BPM" for t in tempi if t.range_bpm})
    folded = {r.name: r.tempo for r in results if r.tempo is not None and r.tempo.octaves}
    songs = ", ".join(f"{name} {t.bpm:.1f}->{t.given_bpm:.1f}" for name, t in sorted(folded.items()))
    return (
        f"tempo folds (training tempi {', '.join(ranges) or 'none: folding off'}; song BPM -> BPM given): "
        f"{len(folded)} of {len({r.name for r in results})} songs" + (f": {songs}" if songs else "")
    )
