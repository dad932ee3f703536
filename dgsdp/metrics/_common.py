"""Shared pieces of the metric suite: the warning and error classes, input checks and axis conversions."""

from __future__ import annotations

import numpy as np

from dgsdp.errors import DgsdpError

N_JOINTS = 24
UP_AXES = ("y", "z")
FEATURE_MODES = ("paper", "corrected")


class MetricWarning(UserWarning):
    """A metric was computed on degenerate input and a documented fallback value was used."""


class MetricError(DgsdpError):
    """A metric cannot be computed from the given input (non-finite joints, too few frames or samples)."""


def check_joints(joints: np.ndarray, name: str = "joints", min_frames: int = 1) -> np.ndarray:
    """Return ``joints`` as float64 (T, 24, 3) after checking shape, length and finiteness.

    Wrong shapes raise ValueError (a programming error); non-finite values or too few frames raise
    MetricError (bad data a user can meet, e.g. a diverged sampler).
    """
    arr = np.asarray(joints, dtype=np.float64)
    if arr.ndim != 3 or arr.shape[1:] != (N_JOINTS, 3):
        raise ValueError(
            f"{name} must have shape (T, {N_JOINTS}, 3) (frames, SMPL joints, xyz metres); got {arr.shape}."
        )
    if arr.shape[0] < min_frames:
        raise MetricError(
            f"{name} has {arr.shape[0]} frame(s) but this metric needs at least {min_frames}; pass a longer motion."
        )
    if not np.isfinite(arr).all():
        bad_frames = np.unique(np.nonzero(~np.isfinite(arr))[0])
        raise MetricError(
            f"{name} contains NaN or infinite values at frame(s) {bad_frames[:10].tolist()}"
            f"{' ...' if bad_frames.size > 10 else ''}; fix or drop this motion before computing metrics."
        )
    return arr


def check_choice(value: str, choices: tuple[str, ...], name: str) -> str:
    """Raise ValueError unless ``value`` is one of ``choices``."""
    if value not in choices:
        raise ValueError(f"{name} must be one of {list(choices)}; got {value!r}.")
    return value


def z_up_to_y_up(points: np.ndarray) -> np.ndarray:
    """Rotate z-up coordinates to y-up: (x, y, z) -> (x, z, -y). Shape (..., 3) kept."""
    points = np.asarray(points, dtype=np.float64)
    return np.stack([points[..., 0], points[..., 2], -points[..., 1]], axis=-1)


def y_up_to_z_up(points: np.ndarray) -> np.ndarray:
    """Rotate y-up coordinates to z-up: (x, y, z) -> (x, -z, y), the inverse of :func:`z_up_to_y_up`."""
    points = np.asarray(points, dtype=np.float64)
    return np.stack([points[..., 0], -points[..., 2], points[..., 1]], axis=-1)


def to_y_up(joints: np.ndarray, up_axis: str) -> np.ndarray:
    """Return (T, 24, 3) joints in y-up coordinates given the axis that points up in the input."""
    check_choice(up_axis, UP_AXES, "up_axis")
    return joints if up_axis == "y" else z_up_to_y_up(joints)


def anchor_root(joints: np.ndarray) -> np.ndarray:
    """Subtract the first frame's root position from every joint of every frame.

    This is the Bailando protocol applied to both real and generated motion before the kinetic and
    geometric features; the paper-mode energy expenditure depends on absolute position, so it matters.
    joints: (T, 24, 3) -> (T, 24, 3).
    """
    arr = check_joints(joints)
    return arr - arr[:1, :1, :]


def stack_by_length(joints_list: list[np.ndarray] | np.ndarray, min_frames: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """Check every (T_n, 24, 3) motion and group equal lengths for batched computation.

    Returns a list of (indices (B,), stacked joints (B, T, 24, 3)) so callers can scatter results back
    into input order. An empty input raises ValueError.
    """
    motions = [check_joints(j, name=f"joints[{n}]", min_frames=min_frames) for n, j in enumerate(joints_list)]
    if not motions:
        raise ValueError("expected at least one motion of shape (T, 24, 3); got an empty list.")
    lengths = np.array([m.shape[0] for m in motions])
    groups = []
    for length in np.unique(lengths):
        idx = np.nonzero(lengths == length)[0]
        groups.append((idx, np.stack([motions[i] for i in idx])))
    return groups


def check_feature_args(fps: float, up_axis: str, mode: str) -> None:
    """Validate the arguments shared by the kinetic and geometric features."""
    check_choice(mode, FEATURE_MODES, "mode")
    check_choice(up_axis, UP_AXES, "up_axis")
    if not fps > 0:
        raise ValueError(f"fps must be positive; got {fps}.")
