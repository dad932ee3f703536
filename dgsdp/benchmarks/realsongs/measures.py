"""The real-song benchmark's measures: plain numpy on joints (T, 24, 3) at 30 FPS, z-up metres (joint speeds,
floor penetration and floating, long-form seams, beat alignment against a half-beat-shifted copy), and the figures
of one dance and of the training data."""

from __future__ import annotations

import json
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from dgsdp.errors import DgsdpError
from dgsdp.metrics._common import check_joints
from dgsdp.metrics.beats import beat_scores
from dgsdp.metrics.speed import joint_speeds, mean_joint_speed
from dgsdp.motion.skeleton import FOOT_JOINTS

FPS = 30
# The targets for a dance a user would keep.
P999_SPEED_MAX_M_S = 8.0  # p99.9 joint speed below this
PENETRATION_MAX_CM = 3.0  # deepest joint at most this far below the floor
FLOATING_MAX_FRACTION = 0.10  # fraction of frames with the lowest foot joint > FLOATING_HEIGHT_M above the floor
FLOATING_HEIGHT_M = 0.10
SEAM_RATIO_MAX = 1.3  # speed around window boundaries / speed around any frame
SPEED_RATIO_RANGE = (0.7, 1.3)  # mean joint speed within 30% of the training data's
STILL_RATIO = 0.5  # a dance slower than this times the training data's mean speed does not move: it fails
MIN_GENRE_SECONDS = 60.0  # a genre with less training data than this is judged against all the training data
P999_CAP_GENRE_FACTOR = 1.1  # a genre's p99.9 limit is at most max(8 m/s, this times its own training p99.9)
# the targets, in the order they are checked; "bas" and "bas_edge": above the half-beat-shifted copy
CHECK_NAMES = ("p999", "penetration", "floating", "seam", "speed", "bas", "bas_edge")
SEAM_HALF_WIDTH_FRAMES = 2


# Where the Debian packages hyperrogue-music, drascula-music and fb-music-high (and frozen-bubble-data, which the
# last one comes with) install their music.
def p999_joint_speed(joints: np.ndarray, fps: float = FPS) -> float:
    """The 99.9th percentile of joint speed (m/s) over all joints and frames."""
    return float(np.percentile(joint_speeds(joints, fps), 99.9))


def penetration_cm(joints: np.ndarray, floor_m: float = 0.0) -> float:
    """How far the lowest joint of the whole dance goes below the floor, in cm (0 if it never does)."""
    positions = check_joints(joints)
    return 100.0 * max(0.0, float(floor_m) - float(positions[..., 2].min()))


def floating_fraction(joints: np.ndarray, floor_m: float = 0.0, height_m: float = FLOATING_HEIGHT_M) -> float:
    """Fraction of frames whose lowest foot joint (ankles and toes, SMPL 7, 8, 10, 11) is more than ``height_m``
    above the floor."""
    positions = check_joints(joints)
    lowest_foot = positions[:, list(FOOT_JOINTS), 2].min(axis=1)
    return float(np.mean(lowest_foot - float(floor_m) > height_m))


def windowed_speed(joints: np.ndarray, fps: float = FPS, half_width: int = SEAM_HALF_WIDTH_FRAMES) -> np.ndarray:
    """Mean joint speed (m/s) within +-``half_width`` frames of every frame, (T,).

    For frame t it averages the joint-mean speeds of the steps between frames t - half_width .. t + half_width
    (2 * half_width steps; fewer at the ends of the dance, where the window is cut)."""
    speed = joint_speeds(joints, fps).mean(axis=1)  # (T-1,), step k is frames k -> k+1
    n_frames = len(speed) + 1
    cumulative = np.concatenate([[0.0], np.cumsum(speed)])
    t = np.arange(n_frames)
    lo = np.maximum(t - half_width, 0)
    hi = np.minimum(t + half_width, n_frames - 1)
    return (cumulative[hi] - cumulative[lo]) / (hi - lo)


def window_boundaries(n_frames: int, window: int, stride: int) -> np.ndarray:
    """Frames inside a dance of ``n_frames`` where a long-form window starts or ends (with the default 150-frame
    windows 75 apart: the multiples of 75)."""
    from dgsdp.generation.longform import WindowLayout

    layout = WindowLayout(n_frames, window, stride)
    edges = {s for s in layout.starts()} | {s + window for s in layout.starts()}
    return np.array(sorted(b for b in edges if 0 < b < n_frames), dtype=np.int64)


def seam_ratio(
    joints: np.ndarray, boundaries: Sequence[int], fps: float = FPS, half_width: int = SEAM_HALF_WIDTH_FRAMES
) -> float:
    """Mean over the window boundaries of the +-``half_width``-frame speed (:func:`windowed_speed`), divided by the
    same windowed speed averaged over every frame: 1.0 when boundaries look like any other moment. NaN without a
    boundary (a dance of one window) or without motion."""
    speed = windowed_speed(joints, fps, half_width)
    frames = np.asarray(boundaries, dtype=np.int64).reshape(-1)
    frames = frames[(frames >= 0) & (frames < len(speed))]
    overall = float(speed.mean())
    if frames.size == 0 or overall <= 0.0:
        return math.nan
    return float(speed[frames].mean()) / overall


PHASE_BINS = 8  # speed by beat phase, in eighths of a beat from the beat


def phase_bins(n_steps: int, music_beats: Sequence[int], bins: int = PHASE_BINS) -> np.ndarray:
    """The beat-phase bin (0 .. bins - 1) of each of ``n_steps`` steps between frames, (n_steps,): step t (frames
    t -> t + 1, at time t + 0.5) lies k/bins .. (k+1)/bins of the way from one music beat to the next. -1 before
    the first and from the last beat on, and everywhere with fewer than two beats."""
    beats = np.unique(np.asarray(music_beats, dtype=np.float64).reshape(-1))
    out = np.full(int(n_steps), -1, dtype=np.int64)
    if beats.size < 2:
        return out
    t = np.arange(int(n_steps)) + 0.5
    inside = (t >= beats[0]) & (t < beats[-1])
    k = np.searchsorted(beats, t[inside], side="right") - 1
    phase = (t[inside] - beats[k]) / (beats[k + 1] - beats[k])
    out[inside] = np.minimum((phase * bins).astype(np.int64), bins - 1)
    return out


def mean_by_bin(values: np.ndarray, which: np.ndarray, bins: int = PHASE_BINS) -> np.ndarray:
    """Mean of ``values`` per bin index of ``which`` (entries -1 left out), ``(bins,)``; NaN for an empty bin."""
    keep = which >= 0
    sums = np.bincount(which[keep], weights=values[keep], minlength=bins)
    counts = np.bincount(which[keep], minlength=bins)
    return np.where(counts > 0, sums / np.maximum(counts, 1), math.nan)


def speed_by_phase(
    joints: np.ndarray, music_beats: Sequence[int], fps: float = FPS, bins: int = PHASE_BINS
) -> np.ndarray:
    """Mean joint speed (m/s) by phase within the beat (:func:`phase_bins`), ``(bins,)``; NaN for an empty bin."""
    speed = joint_speeds(joints, fps).mean(axis=1)
    return mean_by_bin(speed, phase_bins(len(speed), music_beats, bins), bins)


def phase_distance(a: int, b: int, bins: int = PHASE_BINS) -> int:
    """How many bins apart two phase bins are around the beat (0 .. bins // 2)."""
    d = abs(int(a) - int(b)) % bins
    return min(d, bins - d)


@dataclass(frozen=True)
class Reference:
    """What a dance's two speed targets measure it against: the training data's mean and p99.9 joint speed, and, for
    a dance asked for in one of its genres, those of that genre's training dances (NaN otherwise).

    A dance in a free-text style (or a genre the training data lacks) is judged against all the training data: a
    mean speed within 30% of its mean (:data:`SPEED_RATIO_RANGE`) and a p99.9 below 8 m/s
    (:data:`P999_SPEED_MAX_M_S`). A dance asked for in a genre is judged against that genre's training dances only:
    a mean speed within 30% of the genre's (never below half the mean speed of all, :data:`STILL_RATIO`: such a
    dance does not move), and a p99.9 below 8 m/s times the genre's p99.9 over all the training data's where that
    factor is above 1, capped at ``max(8 m/s, 1.1 x the genre's own p99.9)``. A genre with under
    :data:`MIN_GENRE_SECONDS` of training dances is too thin to judge by: its dances are judged against all the
    training data, and ``thin_genre`` names it so that the report can say so."""

    speed_m_s: float
    p999_m_s: float = math.nan
    genre_speed_m_s: float = math.nan
    genre_p999_m_s: float = math.nan
    thin_genre: str | None = None  # the asked genre, judged against all the data for want of its own dances

    @classmethod
    def for_genre(
        cls,
        figures: dict[str, Any] | None,
        genre: str | None,
        speed_m_s: float | None = None,
        min_seconds: float = MIN_GENRE_SECONDS,
    ) -> Reference:
        """The reference of a dance asked for in ``genre`` (a genre code of the training data, or None for a style
        that names no genre) from :func:`training_figures`' ``figures`` (None without the training data);
        ``speed_m_s`` replaces their mean speed (``--train-speed``); a genre with fewer than ``min_seconds`` of
        training dances (their ``seconds``) is judged against all the data."""
        figures = figures or {}
        own = (figures.get("by_genre") or {}).get(genre) or {} if genre is not None else {}
        overall = cls(
            float(figures.get("mean_speed_m_s", math.nan)) if speed_m_s is None else float(speed_m_s),
            float(figures.get("p999_speed_m_s", math.nan)),
        )
        if not own:
            return overall
        if not float(own.get("seconds", 0.0)) >= min_seconds:
            return replace(overall, thin_genre=genre)
        return replace(
            overall,
            genre_speed_m_s=float(own.get("mean_speed_m_s", math.nan)),
            genre_p999_m_s=float(own.get("p999_speed_m_s", math.nan)),
        )

    @property
    def overall(self) -> Reference:
        """The same without the genre: the targets as set for all the training data."""
        return Reference(self.speed_m_s, self.p999_m_s)

    def speed_range(self) -> tuple[float, float]:
        """The mean joint speeds (m/s) that pass; NaN (nothing passes) without the training data's speed."""
        if not self.genre_speed_m_s > 0:
            return SPEED_RATIO_RANGE[0] * self.speed_m_s, SPEED_RATIO_RANGE[1] * self.speed_m_s
        low, high = (r * self.genre_speed_m_s for r in SPEED_RATIO_RANGE)
        if not math.isnan(self.speed_m_s):
            low = max(low, STILL_RATIO * self.speed_m_s)
        return low, high

    def p999_limit(self) -> float:
        """The p99.9 joint speed (m/s) a dance must stay below."""
        stretch = self.genre_p999_m_s / self.p999_m_s if self.p999_m_s > 0 else math.nan
        if not stretch > 1.0:
            return P999_SPEED_MAX_M_S
        return min(P999_SPEED_MAX_M_S * stretch, max(P999_SPEED_MAX_M_S, P999_CAP_GENRE_FACTOR * self.genre_p999_m_s))

    def passes(self, mean_speed_m_s: float, p999_speed_m_s: float) -> tuple[bool, bool]:
        """Whether a dance of this mean and p99.9 joint speed passes the p99.9 target and the speed target (a NaN
        fails)."""
        low, high = self.speed_range()
        return bool(p999_speed_m_s < self.p999_limit()), bool(low <= mean_speed_m_s <= high)


@dataclass
class SongFigures:
    """The benchmark's figures of one dance."""

    seconds: float
    p999_speed_m_s: float
    penetration_cm: float
    floating_fraction: float
    seam_ratio: float
    mean_speed_m_s: float
    bas: float
    bas_shifted: float
    bas_edge: float
    bas_edge_shifted: float
    bas_shift_frames: int
    n_music_beats: int
    n_boundaries: int
    speed_by_phase: list[float]

    def checks(self, reference: Reference) -> dict[str, bool]:
        """Pass/fail per target (:data:`CHECK_NAMES`), the speed targets against ``reference``. A NaN figure fails
        its check (the seam ratio of a dance of one window, which has no seam, excepted); so does a speed check
        without the training data's speed (NaN)."""
        p999_ok, speed_ok = reference.passes(self.mean_speed_m_s, self.p999_speed_m_s)
        passed = (
            p999_ok,
            self.penetration_cm <= PENETRATION_MAX_CM,
            self.floating_fraction < FLOATING_MAX_FRACTION,
            self.seam_ratio < SEAM_RATIO_MAX or self.n_boundaries == 0,  # one window: no seam to check
            speed_ok,
            bool(self.bas > self.bas_shifted),
            bool(self.bas_edge > self.bas_edge_shifted),
        )  # every comparison with a NaN is False
        return dict(zip(CHECK_NAMES, passed, strict=True))


def dance_figures(
    joints: np.ndarray,
    *,
    music_beats: Sequence[int],
    boundaries: Sequence[int],
    floor_m: float = 0.0,
    fps: float = FPS,
) -> SongFigures:
    """Every figure of one dance, joints (T, 24, 3) z-up metres."""
    positions = check_joints(joints, min_frames=2)
    beats = beat_scores(positions, music_beats, fps, "bas")
    edge = beat_scores(positions, music_beats, fps, "bas_edge")
    return SongFigures(
        seconds=positions.shape[0] / fps,
        p999_speed_m_s=p999_joint_speed(positions, fps),
        penetration_cm=penetration_cm(positions, floor_m),
        floating_fraction=floating_fraction(positions, floor_m),
        seam_ratio=seam_ratio(positions, boundaries, fps),
        mean_speed_m_s=mean_joint_speed(positions, fps),
        bas=beats.bas,
        bas_shifted=beats.shifted,
        bas_edge=edge.bas,
        bas_edge_shifted=edge.shifted,
        bas_shift_frames=beats.shift_frames,
        n_music_beats=beats.n_music_beats,
        n_boundaries=len(boundaries),
        speed_by_phase=speed_by_phase(positions, music_beats, fps).tolist(),
    )


# --- the run's facts ---------------------------------------------------------------------------------------------
def training_figures(
    spec: Any,
    cache_dir: str | os.PathLike,
    *,
    floor_m: float = 0.0,
    window: int = 150,
    stride: int = 75,
    progress: bool = False,
) -> tuple[dict[str, float] | None, str]:
    """The benchmark's figures on the data a run was trained on (its config's ``data.root``, train split, read with
    the project's loader), the reference for the dances: mean joint speed over every frame of every dance, p99.9
    joint speed, deepest penetration, floating fraction over every frame, and the mean seam ratio of the dances
    with long-form window boundaries laid on them (about 1.0: real dances have no seams), and the mean speed by beat
    phase (:func:`speed_by_phase`, every step of every dance pooled, against its song's beats); per genre
    (``by_genre``: its dances' mean and p99.9 joint speed and seconds), the reference of a dance asked for in that
    genre; and each dance's genre, mean and p99.9 joint speed (``dances``, for :func:`training_dances_passing`).
    Cached in ``cache_dir/realsongs``. Returns (figures, where they came from), or (None, why) without the
    data."""
    from dgsdp.data.aistpp import read_split
    from dgsdp.data.datamodule import load_sequences
    from dgsdp.utils.io import atomic_write_text, stable_hash

    data = (getattr(spec, "record", None) or {}).get("data") or {}
    root = data.get("root")
    if not root or not (Path(root) / "motions").is_dir():
        return None, f"training data not found (data.root={root!r}); give --train-speed"
    root = Path(root)
    split = str(data.get("train_split", "train"))
    fps = int(data.get("fps", FPS))
    try:
        names = read_split(root, split)
    except DgsdpError as e:
        return None, f"training split unreadable: {e}"
    stamps = []  # the cached figures are recomputed when a motion file changes
    for name in names:
        pkl = root / "motions" / f"{name}.pkl"
        stamps.append([name, [pkl.stat().st_size, pkl.stat().st_mtime_ns] if pkl.is_file() else None])
    # "version" of what is measured (2: the genres' figures added, 3: each dance's): an older cache is recomputed
    settings = {"floor_m": float(floor_m), "window": int(window), "stride": int(stride), "fps": fps, "version": 3}
    key = stable_hash({"root": str(root.resolve()), "split": split, "files": stamps, **settings})
    cache_file = Path(cache_dir) / "realsongs" / f"train-figures-{key}.json"
    if cache_file.is_file():
        try:
            return dict(json.loads(cache_file.read_text())["figures"]), f"{root} ({split}, cached)"
        except (ValueError, KeyError, TypeError):
            pass  # a damaged cache file is recomputed
    import torch

    from dgsdp.audio.cache import FeatureCache
    from dgsdp.generation.beatsync import song_beats
    from dgsdp.motion import pose_to_joints

    try:
        sequences = load_sequences(root, split, fps=fps, cache_dir=cache_dir, progress=progress)
    except DgsdpError as e:
        return None, f"training data unreadable: {e}"
    speeds, floating, seams, penetration, frames = [], 0.0, [], 0.0, 0
    genre_speeds: dict[str, list[np.ndarray]] = {}  # each genre's dances: every joint speed, and their frames
    genre_frames: dict[str, int] = {}
    step_speeds, step_bins = [], []  # every step of every dance with a song, for the speed by beat phase
    dances = []  # each dance's genre, mean and p99.9 joint speed
    cache = FeatureCache(cache_dir)
    for seq in sequences:
        if len(seq.motion) < 2:
            continue
        joints = pose_to_joints(torch.from_numpy(np.asarray(seq.motion, dtype=np.float64))).numpy()
        speeds.append(joint_speeds(joints, fps).reshape(-1))
        genre_speeds.setdefault(seq.genre, []).append(speeds[-1])
        dances.append(
            {"genre": seq.genre, "mean_speed_m_s": float(speeds[-1].mean()),
             "p999_speed_m_s": float(np.percentile(speeds[-1], 99.9))}
        )  # fmt: skip
        genre_frames[seq.genre] = genre_frames.get(seq.genre, 0) + len(joints)
        floating += floating_fraction(joints, floor_m) * len(joints)
        frames += len(joints)
        penetration = max(penetration, penetration_cm(joints, floor_m))
        boundaries = window_boundaries(len(joints), window, stride)
        if boundaries.size:
            seams.append(seam_ratio(joints, boundaries, fps))
        wav = root / "wavs" / f"{seq.music_id}.wav"
        if wav.is_file():
            step_speeds.append(speeds[-1].reshape(len(joints) - 1, -1).mean(axis=1))
            step_bins.append(phase_bins(len(joints) - 1, song_beats(wav, cache)))
    if not speeds:
        return None, f"no training dance of two frames or more in {root} ({split})"
    pooled = np.concatenate(speeds)
    figures = {
        "mean_speed_m_s": float(pooled.mean()),
        "p999_speed_m_s": float(np.percentile(pooled, 99.9)),
        "penetration_cm": penetration,
        "floating_fraction": floating / frames,
        "seam_ratio": float(np.nanmean(seams)) if seams else math.nan,
        "speed_by_phase": mean_by_bin(np.concatenate(step_speeds), np.concatenate(step_bins)).tolist()
        if step_speeds
        else None,
        "n_dances": len(speeds),
        "seconds": frames / fps,
        "by_genre": {
            genre: {
                "mean_speed_m_s": float(np.concatenate(v).mean()),
                "p999_speed_m_s": float(np.percentile(np.concatenate(v), 99.9)),
                "seconds": genre_frames[genre] / fps,
            }
            for genre, v in sorted(genre_speeds.items())
        },
        "dances": dances,
    }
    record = {"figures": figures, "root": str(root), "split": split, **settings}
    atomic_write_text(cache_file, json.dumps(_no_nan(record)))
    return figures, f"{root} ({split})"


def training_dances_passing(figures: dict[str, Any]) -> tuple[int, int, int]:
    """How many of the training dances (``figures["dances"]``, from :func:`training_figures`) pass the two speed
    targets (mean and p99.9 joint speed) as set for all the training data, and against their own genre's training
    dances (:class:`Reference`, :data:`MIN_GENRE_SECONDS`), and how many dances there are: what the targets ask of
    real dances."""
    dances = figures.get("dances") or []
    plain = stretched = 0
    for dance in dances:
        reference = Reference.for_genre(figures, dance["genre"])
        speeds = (dance["mean_speed_m_s"], dance["p999_speed_m_s"])
        plain += all(reference.overall.passes(*speeds))
        stretched += all(reference.passes(*speeds))
    return plain, stretched, len(dances)


# --- song set ----------------------------------------------------------------------------------------------------


def _no_nan(value: Any) -> Any:
    """``value`` with every NaN replaced by None (null in JSON)."""
    if isinstance(value, float) and math.isnan(value):
        return None
    if isinstance(value, dict):
        return {k: _no_nan(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_no_nan(v) for v in value]
    return value
