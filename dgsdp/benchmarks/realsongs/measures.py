"""The real-song benchmark's measures: plain numpy on joints (T, 24, 3) at 30 FPS, z-up metres (joint speeds,
floor penetration and floating, long-form seams, beat alignment against a half-beat-shifted copy), and the figures
of one dance and of the training data."""

from __future__ import annotations

import json
import math
import os
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from dgsdp.errors import DgsdpError
from dgsdp.metrics._common import MetricWarning, check_joints
from dgsdp.metrics.beats import beat_alignment_from_beats, motion_beats
from dgsdp.motion.skeleton import FOOT_JOINTS

FPS = 30
# The targets for a dance a user would keep.
P999_SPEED_MAX_M_S = 8.0  # p99.9 joint speed below this
PENETRATION_MAX_CM = 3.0  # deepest joint at most this far below the floor
FLOATING_MAX_FRACTION = 0.10  # fraction of frames with the lowest foot joint > FLOATING_HEIGHT_M above the floor
FLOATING_HEIGHT_M = 0.10
SEAM_RATIO_MAX = 1.3  # speed around window boundaries / speed around any frame
CHECK_NAMES = ("p999", "penetration", "floating", "seam", "bas")  # the targets, in the order they are checked
SEAM_HALF_WIDTH_FRAMES = 2


# Where the Debian packages hyperrogue-music, drascula-music and fb-music-high (and frozen-bubble-data, which the
# last one comes with) install their music.
def joint_speeds(joints: np.ndarray, fps: float = FPS) -> np.ndarray:
    """Speed of every joint between consecutive frames, (T-1, 24) in m/s."""
    positions = check_joints(joints, min_frames=2)
    return np.linalg.norm(np.diff(positions, axis=0), axis=-1) * fps


def p999_joint_speed(joints: np.ndarray, fps: float = FPS) -> float:
    """The 99.9th percentile of joint speed (m/s) over all joints and frames."""
    return float(np.percentile(joint_speeds(joints, fps), 99.9))


def mean_joint_speed(joints: np.ndarray, fps: float = FPS) -> float:
    """Mean joint speed (m/s) over all joints and frames."""
    return float(joint_speeds(joints, fps).mean())


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


@dataclass
class BeatScores:
    """BAS of a dance and of the same motion shifted later by ``shift_frames`` (half the median beat interval)."""

    bas: float
    shifted: float
    shift_frames: int
    n_music_beats: int

    @property
    def above_shifted(self) -> bool:
        return bool(self.bas > self.shifted)


def beat_scores(joints: np.ndarray, music_beats: Sequence[int], fps: float = FPS) -> BeatScores:
    """Beat alignment score (:mod:`dgsdp.metrics.beats`, Bailando variant) of a dance and of the same motion
    shifted later in time by half the median interval of the music beats (frame indices at ``fps``).

    Shifting the motion by h frames shifts its kinematic beats by h (those that leave the dance are dropped);
    music beats at or after the last speed sample are ignored, as in :func:`dgsdp.metrics.beats.beat_alignment`.
    With fewer than two music beats there is no beat interval: both scores are NaN."""
    positions = check_joints(joints, min_frames=2)
    n_frames = positions.shape[0]
    music = np.asarray(music_beats, dtype=np.int64).reshape(-1)
    music = music[(music >= 0) & (music < n_frames - 1)]
    if music.size < 2:
        return BeatScores(math.nan, math.nan, 0, int(music.size))
    shift = int(round(float(np.median(np.diff(np.sort(music)))) / 2.0))
    beats = motion_beats(positions, fps=fps)
    shifted = beats + shift
    shifted = shifted[shifted < n_frames - 1]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", MetricWarning)  # no motion beat at all: both scores are 0
        bas = beat_alignment_from_beats(beats, music, fps=fps)
        bas_shifted = beat_alignment_from_beats(shifted, music, fps=fps)
    return BeatScores(bas, bas_shifted, shift, int(music.size))


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
    bas_shift_frames: int
    n_music_beats: int
    n_boundaries: int

    def checks(self) -> dict[str, bool]:
        """Pass/fail per target (a dance of one window has no seams: its seam check passes)."""
        passed = (
            self.p999_speed_m_s < P999_SPEED_MAX_M_S,
            self.penetration_cm <= PENETRATION_MAX_CM,
            self.floating_fraction < FLOATING_MAX_FRACTION,
            math.isnan(self.seam_ratio) or self.seam_ratio < SEAM_RATIO_MAX,
            bool(self.bas > self.bas_shifted),
        )
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
    beats = beat_scores(positions, music_beats, fps)
    return SongFigures(
        seconds=positions.shape[0] / fps,
        p999_speed_m_s=p999_joint_speed(positions, fps),
        penetration_cm=penetration_cm(positions, floor_m),
        floating_fraction=floating_fraction(positions, floor_m),
        seam_ratio=seam_ratio(positions, boundaries, fps),
        mean_speed_m_s=mean_joint_speed(positions, fps),
        bas=beats.bas,
        bas_shifted=beats.shifted,
        bas_shift_frames=beats.shift_frames,
        n_music_beats=beats.n_music_beats,
        n_boundaries=len(boundaries),
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
    with long-form window boundaries laid on them (about 1.0: real dances have no seams). Cached in
    ``cache_dir/realsongs``. Returns (figures, where they came from), or (None, why) without the data."""
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
    settings = {"floor_m": float(floor_m), "window": int(window), "stride": int(stride), "fps": fps}
    key = stable_hash({"root": str(root.resolve()), "split": split, "files": stamps, **settings})
    cache_file = Path(cache_dir) / "realsongs" / f"train-figures-{key}.json"
    if cache_file.is_file():
        try:
            return dict(json.loads(cache_file.read_text())["figures"]), f"{root} ({split}, cached)"
        except (ValueError, KeyError, TypeError):
            pass  # a damaged cache file is recomputed
    import torch

    from dgsdp.motion import pose_to_joints

    try:
        sequences = load_sequences(root, split, fps=fps, cache_dir=cache_dir, progress=progress)
    except DgsdpError as e:
        return None, f"training data unreadable: {e}"
    speeds, floating, seams, penetration, frames = [], 0.0, [], 0.0, 0
    for seq in sequences:
        if len(seq.motion) < 2:
            continue
        joints = pose_to_joints(torch.from_numpy(np.asarray(seq.motion, dtype=np.float64))).numpy()
        speeds.append(joint_speeds(joints, fps).reshape(-1))
        floating += floating_fraction(joints, floor_m) * len(joints)
        frames += len(joints)
        penetration = max(penetration, penetration_cm(joints, floor_m))
        boundaries = window_boundaries(len(joints), window, stride)
        if boundaries.size:
            seams.append(seam_ratio(joints, boundaries, fps))
    if not speeds:
        return None, f"no training dance of two frames or more in {root} ({split})"
    pooled = np.concatenate(speeds)
    figures = {
        "mean_speed_m_s": float(pooled.mean()),
        "p999_speed_m_s": float(np.percentile(pooled, 99.9)),
        "penetration_cm": penetration,
        "floating_fraction": floating / frames,
        "seam_ratio": float(np.nanmean(seams)) if seams else math.nan,
        "n_dances": len(speeds),
        "seconds": frames / fps,
    }
    record = {"figures": figures, "root": str(root), "split": split, **settings}
    atomic_write_text(cache_file, json.dumps(_no_nan(record)))
    return figures, f"{root} ({split})"


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
