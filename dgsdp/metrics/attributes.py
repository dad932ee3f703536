"""How a dance moves beyond its genre: the movement attributes a model can be conditioned on (``model.movement_channels``)
and the style benchmark's attribute pairs measure.

Every measure takes joint positions (T, J, 3) of a skeleton (:class:`dgsdp.motion.Skeleton`: SMPL-24, SMPL-X 22
or 52; its joints are found by name), z-up metres as forward kinematics gives them, and returns one value per frame
or per step between frames, so that a window's value is the mean over its frames:

- **speed** (m/s, per step): the mean joint speed over SMPL's 24 joints (:func:`dgsdp.metrics.speed.frame_speeds`).
- **level** (per frame): the pelvis's height above the floor over its height when standing (:func:`standing_height`,
  from the skeleton's rest pose: 1 standing straight, about 0.6 in a deep crouch).
- **arms** (per frame): how high the wrists are against the shoulders, in arm lengths (the mean of both sides of
  wrist height minus shoulder height over shoulder-to-wrist length at rest): -1 arms hanging, 0 at shoulder
  height, +1 straight overhead.
- **travel** (m/s, per step): how fast the pelvis gets across the floor, its horizontal distance over the half
  second around the step (:data:`SPAN_SECONDS`) per second: a walk counts, a sway back and forth within the half
  second hardly does.
- **turning** (rad/s, per step): how fast the body's facing turns, the absolute change over the half second around
  the step, per second, of the yaw of the line between the hips (the pelvis's left-right axis) seen from above.

Travel and turning are read over half a second, not frame to frame: a frame-to-frame rate adds up every
frame's small jitter (a 1000-step model's hips wobble by about a hundredth of a radian a frame, 0.3 rad/s of
"turning" in genres whose training dances never turn), while over half a second a wobble cancels and a turn adds up.

Speed, travel and turning are rates: a window played ``rate`` times faster measures ``rate`` times more
(:data:`RATE_MEASURES`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from dgsdp.metrics._common import MetricError
from dgsdp.metrics.speed import frame_speeds
from dgsdp.motion import Skeleton, smpl24_layout

MEASURES = ("speed", "level", "arms", "travel", "turning")
"""The movement attributes, in the order a model's style vector carries them (:mod:`dgsdp.style.movement`)."""
SPAN_SECONDS = 0.5
"""Travel and turning are read over this span of time around each step (15 steps at 30 FPS)."""
RATE_MEASURES = frozenset({"speed", "travel", "turning"})
"""The measures given per step between frames (T - 1 values) that scale with the tempo; the others are per frame."""


def check_skeleton_joints(joints: np.ndarray, skeleton: Skeleton, min_frames: int = 1) -> np.ndarray:
    """``joints`` as float64 (T, J, 3) of ``skeleton``: a wrong shape is a ValueError (a programming error), too few
    frames or non-finite values a MetricError (bad data, e.g. a diverged sampler)."""
    arr = np.asarray(joints, dtype=np.float64)
    if arr.ndim != 3 or arr.shape[1:] != (skeleton.num_joints, 3):
        raise ValueError(
            f"joints must have shape (T, {skeleton.num_joints}, 3) ({skeleton.name} joints, xyz metres); got {arr.shape}"
        )
    if len(arr) < min_frames:
        raise MetricError(f"joints have {len(arr)} frame(s); this measure needs at least {min_frames}")
    if not np.isfinite(arr).all():
        raise MetricError("joints contain NaN or infinite values; the motion diverged")
    return arr


def _rest_positions(skeleton: Skeleton) -> np.ndarray:
    """Joint positions (J, 3) of the rest pose, y-up metres, the root at the origin."""
    offsets = np.asarray(skeleton.rest_offsets_m, dtype=np.float64)
    out = np.zeros_like(offsets)
    for j, parent in enumerate(skeleton.parents):
        if parent >= 0:
            out[j] = out[parent] + offsets[j]
    return out


def standing_height(skeleton: Skeleton) -> float:
    """The pelvis's height (m) above the lowest foot joint in the rest pose: its height standing on the floor, as
    the floor is measured (:func:`dgsdp.motion.measure_floor_height`: the lowest foot joint)."""
    rest = _rest_positions(skeleton)
    pelvis = rest[skeleton.joint_index("pelvis"), 1]
    return float(pelvis - rest[list(skeleton.foot_joints), 1].min())


def pelvis_levels(joints: np.ndarray, skeleton: Skeleton, floor_m: float = 0.0) -> np.ndarray:
    """Each frame's pelvis height above the floor (``floor_m``, z-up) over :func:`standing_height`, (T,)."""
    arr = check_skeleton_joints(joints, skeleton)
    return (arr[:, skeleton.joint_index("pelvis"), 2] - floor_m) / standing_height(skeleton)


def arm_heights(joints: np.ndarray, skeleton: Skeleton) -> np.ndarray:
    """Each frame's wrist height above the shoulder in arm lengths, the mean of both sides, (T,)."""
    arr = check_skeleton_joints(joints, skeleton)
    offsets = np.asarray(skeleton.rest_offsets_m, dtype=np.float64)
    sides = []
    for side in ("left", "right"):
        shoulder, elbow, wrist = (skeleton.joint_index(f"{side}_{j}") for j in ("shoulder", "elbow", "wrist"))
        length = float(np.linalg.norm(offsets[elbow]) + np.linalg.norm(offsets[wrist]))
        sides.append((arr[:, wrist, 2] - arr[:, shoulder, 2]) / length)
    return np.mean(sides, axis=0)


def _span_rates(values: np.ndarray, fps: float) -> np.ndarray:
    """Per step between frames (T-1,): how far ``values`` (T,) or (T, D) get (the norm of the change) over the
    :data:`SPAN_SECONDS` centred on the step, per second; near the ends the span is cut short (two frames: their
    one step)."""
    n = len(values)
    half = max(1, round(SPAN_SECONDS * fps / 2))
    step = np.arange(n - 1)
    start, end = np.maximum(step + 1 - half, 0), np.minimum(step + half, n - 1)
    change = values[end] - values[start]
    distance = np.linalg.norm(change, axis=-1) if change.ndim > 1 else np.abs(change)
    return distance * fps / (end - start)


def travel_speeds(joints: np.ndarray, skeleton: Skeleton, fps: float = 30) -> np.ndarray:
    """How fast the pelvis gets across the floor (m/s): its horizontal distance over the half second around each
    step between frames (:data:`SPAN_SECONDS`), per second, (T-1,)."""
    arr = check_skeleton_joints(joints, skeleton, min_frames=2)
    return _span_rates(arr[:, skeleton.joint_index("pelvis"), :2], fps)


def facing_yaw(joints: np.ndarray, skeleton: Skeleton) -> np.ndarray:
    """Each frame's yaw (rad, about the z axis) of the line from the right hip to the left hip, (T,)."""
    arr = check_skeleton_joints(joints, skeleton)
    across = arr[:, skeleton.joint_index("left_hip"), :2] - arr[:, skeleton.joint_index("right_hip"), :2]
    return np.arctan2(across[:, 1], across[:, 0])


def turning_rates(joints: np.ndarray, skeleton: Skeleton, fps: float = 30) -> np.ndarray:
    """How fast the facing turns (rad/s): the absolute yaw change over the half second around each step between
    frames (:data:`SPAN_SECONDS`), per second, (T-1,); from one frame to the next the facing turns by at most half
    a turn (a larger change is read the shorter way round)."""
    yaw = facing_yaw(check_skeleton_joints(joints, skeleton, min_frames=2), skeleton)
    return _span_rates(np.unwrap(yaw), fps)


def movement_series(
    joints: np.ndarray,
    skeleton: Skeleton,
    fps: float = 30,
    floor_m: float = 0.0,
    measures: Sequence[str] = MEASURES,
) -> dict[str, np.ndarray]:
    """Each of ``measures`` per frame (T,) or per step (T-1,) (:data:`RATE_MEASURES`), by name."""
    unknown = [m for m in measures if m not in MEASURES]
    if unknown:
        raise ValueError(f"unknown movement measures {unknown}; known: {', '.join(MEASURES)}")
    arr = check_skeleton_joints(joints, skeleton, min_frames=2)
    out: dict[str, np.ndarray] = {}
    for name in measures:
        if name == "speed":
            out[name] = frame_speeds(arr[:, smpl24_layout(skeleton)], fps)
        elif name == "level":
            out[name] = pelvis_levels(arr, skeleton, floor_m)
        elif name == "arms":
            out[name] = arm_heights(arr, skeleton)
        elif name == "travel":
            out[name] = travel_speeds(arr, skeleton, fps)
        else:
            out[name] = turning_rates(arr, skeleton, fps)
    return out


def movement_attributes(
    joints: np.ndarray,
    skeleton: Skeleton,
    fps: float = 30,
    floor_m: float = 0.0,
    measures: Sequence[str] = MEASURES,
) -> dict[str, float]:
    """Each of ``measures`` of a whole dance (the mean of its series), by name."""
    return {k: float(v.mean()) for k, v in movement_series(joints, skeleton, fps, floor_m, measures).items()}
