"""Tempo encoded in AIST++ music ids (e.g. ``mBR0`` is 80 BPM, ``mHO3`` is 125 BPM), and tempo folding: the beats a
model is given moved by octaves (every other beat, or a beat between beats) toward the tempi it was trained on."""

from __future__ import annotations

import math
import re
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np

from dgsdp.errors import ConfigError

GENRE_CODES = ("BR", "PO", "LO", "MH", "LH", "HO", "WA", "KR", "JS", "JB")

# The id as a whole name or as one "_"-separated part of a longer name (e.g. gBR_sBM_cAll_d04_mBR0_ch01).
_MUSIC_ID = re.compile(r"(?:^|[_/\\])m(" + "|".join(GENRE_CODES) + r")(\d)(?=$|[_.])")


def tempo_from_music_id(music_id: str | None) -> float | None:
    """BPM of an AIST++ song from its music id, or None when the name holds no AIST++ music id.

    For every genre but House, ``m<G><d>`` is ``80 + 10 * d`` BPM; for House (``mHO<d>``) it is
    ``110 + 5 * d`` BPM. Accepts a bare id (``"mBR0"``), a file name (``"mBR0.wav"``) or a sequence name.
    """
    if not music_id:
        return None
    match = _MUSIC_ID.search(str(music_id))
    if match is None:
        return None
    genre, digit = match.group(1), int(match.group(2))
    if genre == "HO":
        return 110.0 + 5.0 * digit
    return 80.0 + 10.0 * digit


# At most this many octaves either way (4x faster or slower than the training tempi is as far as a fold reaches).
MAX_FOLD_OCTAVES = 2


def training_tempo_range(
    music_ids: Iterable[str], rates: tuple[float, float] | None = None
) -> tuple[float, float] | None:
    """(lowest, highest) BPM of the songs of a training split, from their AIST++ music ids, widened by the
    ``data.tempo_augment`` rates (a window played 1.25x faster is at 1.25x the tempo); None when no id names a
    tempo."""
    tempi = [bpm for bpm in (tempo_from_music_id(m) for m in music_ids) if bpm is not None]
    if not tempi:
        return None
    lo_rate, hi_rate = rates if rates is not None else (1.0, 1.0)
    return min(tempi) * float(lo_rate), max(tempi) * float(hi_rate)


def check_tempo_range(value: Any, where: str, *, unknown: bool = True) -> tuple[float, float]:
    """A tempo range (lowest, highest BPM, a list or a tensor) as two floats with 0 < lowest <= highest, or one
    ConfigError naming ``where``. With ``unknown``, None or two NaNs (a range not recorded) give (nan, nan)."""
    if value is None and unknown:
        return math.nan, math.nan
    bad = ConfigError(f"{where} must be [lowest, highest] BPM with 0 < lowest <= highest, got {value!r}")
    values = value.tolist() if hasattr(value, "tolist") else value
    try:
        lo, hi = (float(v) for v in values)
    except (TypeError, ValueError):
        raise bad from None
    if unknown and math.isnan(lo) and math.isnan(hi):
        return math.nan, math.nan
    if not (math.isfinite(lo) and math.isfinite(hi) and 0 < lo <= hi):
        raise bad
    return lo, hi


def beats_tempo_bpm(beats: np.ndarray, fps: float) -> float:
    """The tempo of beat frames: the mean of the intervals within 25% of the median one (whole frames make single
    intervals coarse: 160 BPM at 30 FPS is 11 and 12 frames; a missed beat's double interval is left out); NaN with
    fewer than two beats."""
    beats = np.unique(np.asarray(beats, dtype=np.int64))
    if beats.size < 2:
        return math.nan
    gaps = np.diff(beats).astype(np.float64)
    median = float(np.median(gaps))
    return 60.0 * float(fps) / float(gaps[np.abs(gaps - median) <= 0.25 * median].mean())


def fold_octaves(bpm: float, tempo_range: tuple[float, float]) -> int:
    """How many octaves to fold a song's tempo toward ``tempo_range`` (lo, hi) BPM: k > 0 gives the model every
    2**k-th beat (half time for 1), k < 0 puts 2**-k - 1 beats between beats (double time for -1), 0 leaves it.

    The fold that brings the tempo nearest the range (in octaves; 0 inside it) wins, no fold on a tie: with the
    range 80-135 BPM a song is danced in half time above sqrt(2 * 80 * 135) = 147 BPM."""
    lo, hi = (float(v) for v in tempo_range)
    if not (math.isfinite(bpm) and bpm > 0 and 0 < lo <= hi):
        return 0

    def distance(tempo: float) -> float:
        return max(0.0, math.log2(lo / tempo), math.log2(tempo / hi))

    best = 0
    for k in sorted(range(-MAX_FOLD_OCTAVES, MAX_FOLD_OCTAVES + 1), key=abs):  # 0 first, then 1, -1, 2, -2
        if distance(bpm / 2.0**k) < distance(bpm / 2.0**best) - 1e-9:
            best = k
    return best


def fold_beats(beats: np.ndarray, octaves: int, strength: np.ndarray | None = None) -> np.ndarray:
    """Beat frames folded by ``octaves`` (:func:`fold_octaves`). Every 2**k-th beat is kept for k > 0, starting
    from the one of the 2**k offsets whose beats are strongest in ``strength`` (per frame, e.g. the onset envelope;
    the first offset without it): the stronger beats are the likelier downbeats. For k < 0, 2**-k - 1 evenly spaced
    beats are put between every two beats."""
    beats = np.unique(np.asarray(beats, dtype=np.int64))
    if octaves == 0 or beats.size < 2:
        return beats
    if octaves > 0:
        step = 2**octaves
        offset = 0
        if strength is not None:
            strength = np.asarray(strength, dtype=np.float64)
            sums = [float(strength[beats[o::step]].sum()) for o in range(min(step, beats.size))]
            offset = int(np.argmax(sums))
        return beats[offset::step]
    parts = 2**-octaves
    starts, gaps = beats[:-1], np.diff(beats)
    between = [np.rint(starts + gaps * j / parts).astype(np.int64) for j in range(1, parts)]
    return np.unique(np.concatenate([beats, *between]))


@dataclass(frozen=True)
class TempoFold:
    """How a song's beats were given to a model: the song's tempo (``bpm``, NaN where the features give no beats),
    the fold in octaves (:func:`fold_octaves`; 0: as tracked) and the training tempo range it was folded toward
    (None: folding off or no range known)."""

    bpm: float = math.nan
    octaves: int = 0
    range_bpm: tuple[float, float] | None = None

    @property
    def given_bpm(self) -> float:
        """The tempo of the beats the model was given."""
        return self.bpm / 2.0**self.octaves

    def describe(self) -> str:
        if math.isnan(self.bpm):
            return "no beats in the model's music features"
        if self.octaves == 0:
            return f"{self.bpm:.1f} BPM, beats as tracked"
        time = {1: "half time", -1: "double time"}.get(self.octaves, f"{2.0**-self.octaves:g}x time")
        lo, hi = self.range_bpm or (math.nan, math.nan)
        return f"{self.bpm:.1f} BPM, given in {time} ({self.given_bpm:.1f} BPM; trained on {lo:g}-{hi:g} BPM)"
