"""Beat sync: retime a generated dance so that its pauses fall on the music's beats.

A dancer marks a beat by a pause or a turning point of the movement: a dip of the body's speed (a kinematic
beat, :func:`dgsdp.metrics.kinematic_speed`). A model that has learnt to dance in the music's tempo but not yet its
phase pauses at the right rate in the wrong places. :func:`sync_to_beats` warps the dance's time (never its poses)
so that one clear speed dip lands on each music beat:

1. Candidates: the strict local minima of the smoothed mean joint speed (the same curve the beat alignment score
   uses), each scored by its depth, ``1 - v(dip) / max v`` over the half beat on either side (1: a full stop).
2. Each music beat b takes at most one candidate c within ``max_shift_beats`` of a local beat period of it, in
   order, so that the frame mapping b -> c keeps its slope between anchors within ``[1 / max_rate, max_rate]``.
   A dynamic programme picks the anchors with the largest total depth minus ``rate_penalty * (slope - 1)^2`` per
   beat spanned; a beat may stay unanchored (it scores nothing).
3. Output frame t shows the dance at source time s(t): piecewise linear through the anchors, with slope 1 before
   the first and after the last (clamped to the dance). Poses are interpolated linearly between the two nearest
   source frames (the 6-d rotations are re-orthonormalised wherever they are read).

So the timing moves by at most a quarter beat, the length is unchanged, and the dance locally runs at most
``max_rate`` times faster or slower. Frames given by an editing mask would move in time: a dance with a mask is
returned unchanged.

4. The judge: a retime aligned to one tracker's beats can still lose the beat the model had (a pause moved onto a
   beat the tracker got wrong, a clear pause traded for a shallow one). So each dance is judged by its margins: the
   margin of its beat alignment score over its half-beat-shifted copy's (:func:`dgsdp.metrics.beats.beat_scores`,
   both variants) on every beat set it is judged by (the beats it aligned to, and ``check_beats``: another
   tracker's, which it did not align to; :func:`other_tracker_beats`). The judge decides on what the user gets:
   given the ``finish`` that follows the retime (the floor cleanup, which moves pauses too), it compares the
   finished retime with the finished dance in the model's own timing, and the model's raw dance
   (:func:`keep_retime`). The finished retime is kept where no margin falls below the finished own timing's and one
   rises; or where the floor cleanup alone put the finished own timing below the raw dance on some margin and the
   finished retime is below it on none. So the result is never below the raw dance on a judged margin where either
   finished timing avoids it, and otherwise never below the finished own timing; the stats say which timing was kept
   and on how many margins the result is still below the raw dance, and by how much (``below_raw_margins``,
   ``below_raw_by``: the floor cleanup's own doing, which neither timing avoided).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from scipy.signal import argrelextrema

from dgsdp.audio import AudioEncoder, FeatureCache, LibrosaEncoder
from dgsdp.audio.beat_tracker import TrackedBeats, beats_of_song, bpm_of_beats
from dgsdp.errors import DgsdpError
from dgsdp.metrics.beats import BAS_VARIANTS, BEAT_COLUMN, beat_scores, kinematic_speed, music_beats_from_features
from dgsdp.motion import SMPL24, Skeleton, check_pose_dim, pose_to_joints, smpl24_layout


@dataclass(frozen=True)
class BeatSync:
    """Settings of :func:`sync_to_beats` (see the module docstring)."""

    max_shift_beats: float = 0.25  # a dip moves at most this fraction of a beat period
    max_rate: float = 1.25  # local speed-up (and 1 / slow-down) of the dance's time
    rate_penalty: float = 4.0  # cost of (slope - 1)^2 per beat against a dip's depth (0..1)
    max_skip: int = 4  # anchors at most this many beats apart are constrained together
    judge: bool = True  # keep the model's timing where the retime is worse on any beat set (step 4)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.max_shift_beats) and 0.0 < self.max_shift_beats <= 0.5):
            raise ValueError(f"max_shift_beats must lie in (0, 0.5], got {self.max_shift_beats}")
        if not (math.isfinite(self.max_rate) and self.max_rate > 1.0):
            raise ValueError(f"max_rate must be a number > 1, got {self.max_rate}")
        if not (math.isfinite(self.rate_penalty) and self.rate_penalty >= 0.0):
            raise ValueError(f"rate_penalty must be a finite number >= 0, got {self.rate_penalty}")
        if self.max_skip < 1:
            raise ValueError(f"max_skip must be >= 1, got {self.max_skip}")
        # anchors farther apart than max_skip beats are not checked: their offsets alone must keep the rate
        if 2 * self.max_shift_beats / (self.max_skip + 1) > 1 - 1 / self.max_rate:
            raise ValueError(
                f"max_shift_beats={self.max_shift_beats} with max_skip={self.max_skip} could run the dance faster "
                f"than max_rate={self.max_rate} between anchors far apart: raise max_skip or lower max_shift_beats"
            )


def song_beats(song: Path, cache: FeatureCache, encoder: AudioEncoder | None = None) -> np.ndarray:
    """Beat frames (30 FPS) of a song: the beat column of its 35-d librosa features (librosa's beat tracker, the
    beats the beat alignment score is measured against), cached with the features. ``encoder``: the model's own
    audio encoder; its features are used when it is the librosa encoder, else the default librosa features."""
    if encoder is None or encoder.name != "librosa":
        encoder = LibrosaEncoder()
    features = cache.features_for_file(encoder, song, music_id=song.stem)
    if not np.isin(np.asarray(features)[:, BEAT_COLUMN], (0.0, 1.0)).all():
        raise DgsdpError("the librosa features' beat column is not a 0/1 flag; cannot read music beats")
    return music_beats_from_features(features)


def other_tracker_beats(song: Path, cache: FeatureCache, encoder: AudioEncoder | None = None) -> TrackedBeats:
    """The song's beats by the tracker whose beats :func:`song_beats` does not give the model ``encoder``: the
    independent tracker's (:mod:`dgsdp.audio.beat_tracker`), or librosa's for a model fed the independent tracker's
    (``audio.beat_tracker=flux``). What a retime is judged by beside the beats it aligned to."""
    if fed_beat_tracker(encoder) == "flux":
        frames = np.asarray(song_beats(song, cache, None))  # the default librosa features: librosa's tracker
        return TrackedBeats(bpm_of_beats(frames), frames)
    return beats_of_song(song)


def fed_beat_tracker(encoder: AudioEncoder | None) -> str | None:
    """Whose beats the model's librosa features hold ("librosa" or "flux"), or None for other encoders."""
    if encoder is None or encoder.name != "librosa":
        return None
    return str(getattr(encoder, "beat_tracker", "librosa"))


def timing_margins(joints: np.ndarray, beat_sets: list[np.ndarray], fps: float) -> np.ndarray:
    """(len(beat_sets) * 2,) the margin of a dance's beat alignment over its half-beat-shifted copy's, per beat set
    and BAS variant (NaN where a beat set has fewer than two beats in the dance)."""
    out = []
    for beats in beat_sets:
        for variant in BAS_VARIANTS:
            scores = beat_scores(joints, beats, fps=fps, variant=variant)
            out.append(scores.bas - scores.shifted)
    return np.asarray(out, dtype=np.float64)


MARGIN_TOLERANCE = 1e-9  # margins closer than this count as equal


def retime_helps(raw: np.ndarray, retimed: np.ndarray) -> bool:
    """Whether retimed margins (:func:`timing_margins`) are no lower than the raw dance's on every beat set and
    variant, and higher on one (margins within :data:`MARGIN_TOLERANCE` count as equal)."""
    ok = np.isfinite(raw) & np.isfinite(retimed)
    if not ok.any():
        return False
    diff = retimed[ok] - raw[ok]
    return bool((diff >= -MARGIN_TOLERANCE).all() and (diff > MARGIN_TOLERANCE).any())


def margins_below(reference: np.ndarray, margins: np.ndarray) -> int:
    """How many margins (:func:`timing_margins`) lie below the reference's (NaN on either side: not counted)."""
    ok = np.isfinite(reference) & np.isfinite(margins)
    return int((margins[ok] < reference[ok] - MARGIN_TOLERANCE).sum())


def largest_drop(reference: np.ndarray, margins: np.ndarray) -> float:
    """How far the margins (:func:`timing_margins`) fall below the reference's at most (0: nowhere)."""
    ok = np.isfinite(reference) & np.isfinite(margins)
    return float(np.max(reference[ok] - margins[ok], initial=0.0))


def keep_retime(raw: np.ndarray, own: np.ndarray, retimed: np.ndarray) -> bool:
    """The judge (step 4 of the module docstring) on the margins (:func:`timing_margins`) of the model's ``raw`` dance,
    of the finished dance in its ``own`` timing and of the finished ``retimed`` dance (without a finishing step,
    ``own`` is ``raw``): keep the retime where it is no lower than the own timing on every margin and higher on one
    (:func:`retime_helps`), or where the own timing fell below the raw dance on a margin (the finishing moved its
    pauses) and the retime falls below it on none."""
    return retime_helps(own, retimed) or (margins_below(raw, own) > 0 and margins_below(raw, retimed) == 0)


def _local_periods(beats: np.ndarray) -> np.ndarray:
    """(B,) beat period around each beat: the median of the (up to four) intervals next to it."""
    gaps = np.diff(beats).astype(np.float64)
    out = np.empty(len(beats))
    for k in range(len(beats)):
        out[k] = np.median(gaps[max(0, k - 2) : k + 2])
    return out


def _dips(speed: np.ndarray, beats: np.ndarray, periods: np.ndarray, s: BeatSync) -> list[list[tuple[int, float]]]:
    """Per beat, the candidate dips (frame, depth) within reach."""
    minima = argrelextrema(speed, np.less)[0]  # the kinematic beats' definition (dgsdp.metrics.motion_beats)
    out = []
    for b, period in zip(beats, periods):
        reach = s.max_shift_beats * period
        near = minima[np.abs(minima - b) <= reach]
        half = max(1, int(round(period / 2)))
        cands = []
        for c in near:
            top = speed[max(0, c - half) : c + half + 1].max()
            cands.append((int(c), float(1.0 - speed[c] / top) if top > 0 else 0.0))
        out.append(cands)
    return out


def beat_anchors(speed: np.ndarray, beats: np.ndarray, settings: BeatSync | None = None) -> tuple[np.ndarray, ...]:
    """Anchors (music beat frames, source frames) of the warp for a speed curve (N,) and music beats (B,), both in
    frames of the dance: step 2 of the module docstring."""
    s = settings or BeatSync()
    beats = np.unique(np.asarray(beats, dtype=np.int64))
    beats = beats[(beats >= 0) & (beats < len(speed))]
    if len(beats) < 2:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    periods = _local_periods(beats)
    cands = _dips(np.asarray(speed, dtype=np.float64), beats, periods, s)
    # best[k][i]: the best total of anchors up to and ending with candidate i of beat k; back: the anchor before.
    # Anchors more than max_skip beats apart are not constrained (their slope is near 1 anyway): a prefix maximum.
    best: list[list[float]] = []
    back: list[list[tuple[int, int] | None]] = []
    prefix: list[tuple[float, tuple[int, int] | None]] = []  # best chain ending at or before beat k
    for k, options in enumerate(cands):
        best.append([])
        back.append([])
        far = k - s.max_skip - 1
        start = prefix[far] if far >= 0 else (0.0, None)
        for c, depth in options:
            value, prev = start[0] + depth, start[1]
            for k0 in range(max(0, k - s.max_skip), k):
                span = beats[k] - beats[k0]
                for i0, (c0, _) in enumerate(cands[k0]):
                    slope = (c - c0) / span
                    if not (1.0 / s.max_rate <= slope <= s.max_rate):
                        continue
                    v = best[k0][i0] + depth - s.rate_penalty * (slope - 1.0) ** 2 * (k - k0)
                    if v > value:
                        value, prev = v, (k0, i0)
            best[k].append(value)
            back[k].append(prev)
        here = max(((v, (k, i)) for i, v in enumerate(best[k])), default=(-np.inf, None))
        before = prefix[-1] if prefix else (0.0, None)
        prefix.append(here if here[0] > before[0] else before)
    node = prefix[-1][1]
    chosen = []
    while node is not None:
        chosen.append((int(beats[node[0]]), cands[node[0]][node[1]][0]))
        node = back[node[0]][node[1]]
    chosen.reverse()
    return np.array([b for b, _ in chosen], np.int64), np.array([c for _, c in chosen], np.int64)


def warp_times(n_frames: int, beats: np.ndarray, sources: np.ndarray) -> np.ndarray:
    """Source time (n_frames,) of each output frame: piecewise linear through the anchors, slope 1 outside."""
    t = np.arange(n_frames, dtype=np.float64)
    if len(beats) == 0:
        return t
    src = np.interp(t, beats, sources.astype(np.float64))
    src = np.where(t < beats[0], t + (sources[0] - beats[0]), src)
    src = np.where(t > beats[-1], t + (sources[-1] - beats[-1]), src)
    return np.clip(src, 0.0, n_frames - 1.0)


def resample(motion: torch.Tensor, times: np.ndarray) -> torch.Tensor:
    """Motion (T, C) read at fractional frame ``times`` (T',) by linear interpolation of neighbouring frames."""
    lo = np.clip(np.floor(times).astype(np.int64), 0, len(motion) - 1)
    hi = np.clip(lo + 1, 0, len(motion) - 1)
    w = torch.as_tensor(times - lo, dtype=motion.dtype, device=motion.device)[:, None]
    return motion[lo] * (1 - w) + motion[hi] * w


# what follows the retime (the floor cleanup): motions (S, T, D) and a list for one stats dict each -> finished motions
Finish = Callable[[torch.Tensor, list[dict[str, float]]], torch.Tensor]


def _retime(
    x: torch.Tensor, beats: np.ndarray, fps: float, s: BeatSync, skeleton: Skeleton
) -> tuple[torch.Tensor, np.ndarray, int]:
    """One dance (T, D) retimed onto beat frames (steps 1-3) -> (the retimed dance, each output frame's source time,
    the number of anchored beats; no anchor: the dance itself)."""
    joints = pose_to_joints(x.detach().double().cpu(), skeleton).numpy()[:, smpl24_layout(skeleton)]
    anchors, sources = beat_anchors(kinematic_speed(joints, fps), beats, s)
    times = warp_times(len(x), anchors, sources)
    return (resample(x, times) if len(anchors) else x), times, len(anchors)


def sync_to_beats(
    motion: torch.Tensor,
    music_beats: np.ndarray,
    fps: float,
    *,
    mask: torch.Tensor | None = None,
    settings: BeatSync | None = None,
    stats: list[dict[str, float]] | None = None,
    skeleton: Skeleton = SMPL24,
    check_beats: list[np.ndarray] | tuple[np.ndarray, ...] = (),
    finish: Finish | None = None,
) -> torch.Tensor:
    """Unnormalised motion (T, D) or (S, T, D) of ``skeleton`` (D its pose size; the speed is that of its joints in
    SMPL's layout, :func:`~dgsdp.motion.smpl24_layout`) at ``fps`` and music beat frames (B,) of the same frame
    rate -> the motion retimed so that its speed dips fall on the beats (see the module docstring), each dance kept
    in its own timing where the judge finds the retime worse on ``music_beats`` or on any of ``check_beats`` (other
    trackers' beat frames; step 4, unless ``settings.judge`` is False). With an editing ``mask`` the motion is
    returned unchanged (finished).

    ``finish``: the step that follows the retime (the floor cleanup): motions (S', T, D) and a list that gets one
    stats dict per motion -> the finished motions. Given, every dance comes back finished, and the judge decides on
    the finished dances (it runs ``finish`` on the dances in their own timing and, for those with anchors, retimed:
    at most twice per dance). ``stats``: a list that gets one dict per motion: ``beats``, ``anchored_beats``, the mean
    and largest retiming offset ``mean_shift_ms``, ``max_shift_ms`` (how far in time a frame's pose moved; 0 where the
    model's timing was kept), ``retimed`` (1 where the retime was kept, 0 where the model's own timing was),
    ``judged_beat_sets``, ``below_raw_margins`` (judged margins on which the result lies below the raw dance: only a
    ``finish`` can leave any) and ``below_raw_by`` (how far at most), and the stats of ``finish`` for the dance
    returned."""
    check_pose_dim(motion, skeleton, "sync_to_beats's motion")
    if motion.ndim not in (2, 3):
        raise ValueError(f"sync_to_beats needs motion (T, D) or (S, T, D), got {tuple(motion.shape)}")
    s = settings or BeatSync()
    batch = motion if motion.ndim == 3 else motion[None]

    def finished(x: torch.Tensor) -> tuple[torch.Tensor, list[dict[str, float]]]:
        if finish is None:
            return x, [{} for _ in x]
        notes: list[dict[str, float]] = []
        return finish(x, notes), notes

    unchanged = {"beats": len(music_beats), "anchored_beats": 0, "mean_shift_ms": 0.0, "max_shift_ms": 0.0,
                 "retimed": 0.0, "judged_beat_sets": 0.0, "below_raw_margins": 0.0,
                 "below_raw_by": 0.0}  # fmt: skip
    if mask is not None or motion.shape[-2] < 3:
        out, notes = finished(batch)
        if stats is not None:
            stats.extend({**unchanged, **n} for n in notes)
        return motion if finish is None else (out if motion.ndim == 3 else out[0])
    layout = smpl24_layout(skeleton)
    beat_sets = [np.asarray(music_beats, dtype=np.int64), *(np.asarray(b, dtype=np.int64) for b in check_beats)]
    retimes = [_retime(x, beat_sets[0], fps, s, skeleton) for x in batch]
    moved = [i for i, (_, _, anchors) in enumerate(retimes) if anchors > 0]
    if s.judge:  # both timings finished, the retime only where it moved something
        own, own_notes = finished(batch)
        new, new_notes = finished(torch.stack([retimes[i][0] for i in moved])) if moved else (own[:0], [])
        row = {i: k for k, i in enumerate(moved)}
    else:  # every retime kept: one finishing per dance
        own, own_notes = finished(torch.stack([r[0] for r in retimes]))
        new, new_notes, row = own, own_notes, {i: i for i in moved}

    def margins(x: torch.Tensor) -> np.ndarray:
        return timing_margins(pose_to_joints(x.detach().double().cpu(), skeleton).numpy()[:, layout], beat_sets, fps)

    out = []
    for i, x in enumerate(batch):
        keep, below, drop = i in row, 0, 0.0
        if s.judge and (keep or finish is not None):
            raw = margins(x)
            own_margins = raw if finish is None else margins(own[i])
            new_margins = margins(new[row[i]]) if keep else own_margins
            keep = keep and keep_retime(raw, own_margins, new_margins)
            kept_margins = new_margins if keep else own_margins
            below = margins_below(raw, kept_margins)
            drop = largest_drop(raw, kept_margins) if below else 0.0
        out.append(new[row[i]] if keep else own[i])
        if stats is not None:
            shift_ms = np.abs(retimes[i][1] - np.arange(len(x))) * 1000.0 / fps if keep else np.zeros(1)
            stats.append({**unchanged, "anchored_beats": retimes[i][2], "mean_shift_ms": float(shift_ms.mean()),
                          "max_shift_ms": float(shift_ms.max()), "retimed": float(keep),
                          "judged_beat_sets": float(len(beat_sets) if s.judge else 0),
                          "below_raw_margins": float(below), "below_raw_by": drop,
                          **(new_notes[row[i]] if keep else own_notes[i])})  # fmt: skip
    result = torch.stack(out)
    return result if motion.ndim == 3 else result[0]
