"""The real-song benchmark's plan and report: which style each song gets, and the rows and summary lines."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from dgsdp.benchmarks.realsongs.measures import CHECK_NAMES, SongFigures
from dgsdp.benchmarks.realsongs.songs import song_family
from dgsdp.errors import ConfigError


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
    """The dances to make, (song, style) pairs: each song in its style from :func:`styles_for`, or with
    ``all_styles`` each song in every genre of the checkpoint, song by song."""
    if all_styles:
        if style is not None:
            raise ConfigError("--all-styles dances every song in every genre: leave out --style")
        if all(g is None for g in genres):
            raise ConfigError("--all-styles needs a model with a style embedding; this checkpoint has no genres")
        return [(song, genre) for song in songs for genre in genres]
    return list(zip(songs, styles_for(songs, genres, style)))


@dataclass
class SongResult:
    name: str
    style: str | None
    figures: SongFigures | None = None
    feature_seconds: float = math.nan
    dance_seconds: float = math.nan
    error: str | None = None
    checks: dict[str, bool] = field(default_factory=dict)

    @property
    def passed(self) -> bool:
        return self.error is None and all(self.checks.values())


def _fmt(value: float, spec: str) -> str:
    return "n/a" if value is None or (isinstance(value, float) and math.isnan(value)) else format(value, spec)


def header(width: int = 30) -> str:
    return (
        f"{'song':<{width}} {'style':<6} {'sec':>6} {'p999':>6} {'pen_cm':>6} {'float':>6} {'seam':>5} {'speed':>6} "
        f"{'ratio':>5} {'bas':>5} {'bas_sh':>6} {'gen_s':>6}  result"
    )


def format_row(result: SongResult, train_speed: float, width: int = 30) -> str:
    if result.error is not None:
        return f"{result.name:<{width}} {str(result.style):<6} ERROR: {result.error}"
    f = result.figures
    failed = [name for name, ok in result.checks.items() if not ok]
    verdict = "pass" if not failed else "FAIL(" + ",".join(failed) + ")"
    ratio = f.mean_speed_m_s / train_speed if train_speed and not math.isnan(train_speed) else math.nan
    return (
        f"{result.name:<{width}} {str(result.style):<6} {f.seconds:6.1f} {f.p999_speed_m_s:6.2f} {f.penetration_cm:6.1f} "
        f"{f.floating_fraction:6.3f} {_fmt(f.seam_ratio, '5.2f'):>5} {f.mean_speed_m_s:6.3f} {_fmt(ratio, '5.2f'):>5} "
        f"{_fmt(f.bas, '5.3f'):>5} {_fmt(f.bas_shifted, '6.3f'):>6} {result.dance_seconds:6.1f}  {verdict}"
    )


def summary_line(results: Sequence[SongResult], train_speed: float) -> str:
    done = [r for r in results if r.error is None]
    figs = [r.figures for r in done]

    def worst(values: list[float], fn: Any = max) -> str:
        values = [v for v in values if not math.isnan(v)]
        return _fmt(fn(values), ".3f") if values else "n/a"

    ratios = [f.mean_speed_m_s / train_speed for f in figs] if train_speed and not math.isnan(train_speed) else []
    gen = [r.dance_seconds / r.figures.seconds for r in done if r.figures.seconds > 0]
    return (
        f"songs={len(results)} pass={sum(r.passed for r in results)} errors={len(results) - len(done)} "
        f"worst_p999={worst([f.p999_speed_m_s for f in figs])} worst_pen_cm={worst([f.penetration_cm for f in figs])} "
        f"worst_float={worst([f.floating_fraction for f in figs])} worst_seam={worst([f.seam_ratio for f in figs])} "
        f"bas_above_shifted={sum(r.checks.get('bas', False) for r in done)}/{len(done)} "
        f"speed_ratio_mean={_fmt(float(np.mean(ratios)) if ratios else math.nan, '.3f')} "
        f"train_speed={_fmt(train_speed, '.3f')} gen_s_per_dance_s={_fmt(float(np.mean(gen)) if gen else math.nan, '.2f')}"
    )


def style_summary_lines(results: Sequence[SongResult]) -> list[str]:
    """One line per style: how many of its dances pass, each target's misses, and its worst p99.9 speed."""
    lines = []
    for style in dict.fromkeys(r.style for r in results):
        mine = [r for r in results if r.style == style]
        done = [r for r in mine if r.error is None]
        missed = {name: sum(not r.checks.get(name, True) for r in done) for name in CHECK_NAMES}
        p999 = [r.figures.p999_speed_m_s for r in done]
        lines.append(
            f"style={style} dances={len(mine)} pass={sum(r.passed for r in mine)} errors={len(mine) - len(done)} "
            + " ".join(f"{name}_missed={n}" for name, n in missed.items())
            + f" worst_p999={_fmt(max(p999) if p999 else math.nan, '.3f')}"
        )
    return lines
