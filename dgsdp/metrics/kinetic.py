"""Kinetic features (72-d per sequence): per-joint horizontal and vertical kinetic energy and energy
expenditure, the features behind FID_k and Div_k (Bailando / AIST++ definitions).

Everything is vectorised over sequences, frames and joints; the reference computes each value in a
per-frame Python loop. The windowed sums below use the same truncated 5-frame windows.
"""

from __future__ import annotations

import warnings

import numpy as np

from dgsdp.metrics._common import (
    MetricWarning,
    check_feature_args,
    check_joints,
    stack_by_length,
    to_y_up,
)

KINETIC_DIM = 72
WINDOW_HALF_WIDTH = 2  # frames on each side of the centre frame


def _window_sum(values: np.ndarray, n_out: int) -> tuple[np.ndarray, np.ndarray]:
    """Sums over the truncated windows [n - 2, n + 2] along axis 1, for n = 0 .. n_out - 1.

    values: (B, L, ...) -> sums (B, n_out, ...) and counts (n_out,) of the in-range terms (0 <= index < L).
    """
    w = WINDOW_HALF_WIDTH
    length = values.shape[1]
    pad_after = max(n_out + w - length, 0)
    pad = [(0, 0), (w, pad_after)] + [(0, 0)] * (values.ndim - 2)
    padded = np.pad(values, pad)
    sums = sum(padded[:, s : s + n_out] for s in range(2 * w + 1))
    index = np.arange(n_out)
    counts = np.minimum(index + w, length - 1) - np.maximum(index - w, 0) + 1
    return sums, np.maximum(counts, 0)


def _kinetic_core(positions: np.ndarray, fps: float, mode: str) -> np.ndarray:
    """Kinetic features of equal-length y-up motions: (B, T, 24, 3) metres -> (B, 72)."""
    batch, n_frames, n_joints, _ = positions.shape
    frame_time_s = 1.0 / fps
    n_out = n_frames - 1  # features average over frames i = 1 .. T-1

    # Windowed velocity at frame i: displacements p[k] - p[k-1], k in [i-2, i+2] and 1 <= k <= T-1.
    # Displacement k sits at index k-1, so frame i (output index i-1) is a centred window on index i-1.
    displacement = positions[:, 1:] - positions[:, :-1]  # (B, T-1, J, 3)
    vel_sum, vel_count = _window_sum(displacement, n_out)
    velocity = vel_sum / (vel_count[None, :, None, None] * frame_time_s)
    ke_horizontal = np.mean(velocity[..., 0] ** 2 + velocity[..., 2] ** 2, axis=1)  # (B, J)
    ke_vertical = np.mean(velocity[..., 1] ** 2, axis=1)

    # Energy expenditure: accelerations at k = 1 .. T-2 (index k-1), window [i-2, i+2] around frame i,
    # i.e. a window [n-2, n+2] around output index n = i-1.
    if n_frames >= 3:
        v2 = (positions[:, 2:] - positions[:, 1:-1]) / frame_time_s
        if mode == "paper":
            v1 = positions[:, 1:-1] - positions[:, :-2] / frame_time_s  # the reference's missing brackets
        else:
            v1 = (positions[:, 1:-1] - positions[:, :-2]) / frame_time_s
        acceleration = (v2 - v1) / frame_time_s  # (B, T-2, J, 3)
        acc_sum, acc_count = _window_sum(acceleration, n_out)
        acc_mean = acc_sum / acc_count[None, :, None, None]
        energy = np.mean(np.linalg.norm(acc_mean, axis=-1), axis=1)  # (B, J)
    else:
        warnings.warn(
            "energy expenditure needs at least 3 frames; got 2, so those 24 features are set to 0.",
            MetricWarning,
            stacklevel=3,
        )
        energy = np.zeros((batch, n_joints))

    features = np.stack([ke_horizontal, ke_vertical, energy], axis=-1)  # (B, J, 3)
    return features.reshape(batch, n_joints * 3)


def kinetic_features(joints: np.ndarray, fps: float = 60, up_axis: str = "y", mode: str = "paper") -> np.ndarray:
    """72 kinetic features of one motion, ordered (j0 horizontal KE, j0 vertical KE, j0 energy, j1 ...).

    joints: (T, 24, 3) positions in metres, T >= 2; ``up_axis="z"`` input is rotated to y-up first.
    Frame time is 1 / fps. Horizontal KE is the mean over frames 1..T-1 of the squared x-z norm of a
    5-frame windowed velocity, vertical KE the same with y (no 1/2, no mass). Energy expenditure is
    the mean norm of a 5-frame windowed acceleration. Apply :func:`anchor_root` first for the
    Bailando protocol.

    Modes differ in one place only:
      - ``"paper"`` (default, for comparison with published tables) uses the reference's first
        velocity ``v1 = p[k] - p[k-1] / ft`` (brackets missing), so a static joint at position p gets
        energy (1/ft) * (1/ft - 1) * |p| (3540 |p| at 60 FPS).
      - ``"corrected"`` uses ``v1 = (p[k] - p[k-1]) / ft``: a static joint gets 0.

    A 2-frame motion has no acceleration: its energies are 0 with a MetricWarning. Returns (72,) float64
    (the reference stores float32: differences of about 1e-7 relative).
    """
    check_feature_args(fps, up_axis, mode)
    positions = to_y_up(check_joints(joints, min_frames=2), up_axis)
    return _kinetic_core(positions[None], fps, mode)[0]


def kinetic_features_batch(
    joints_list: list[np.ndarray] | np.ndarray, fps: float = 60, up_axis: str = "y", mode: str = "paper"
) -> np.ndarray:
    """:func:`kinetic_features` of N motions (lengths may differ): list of (T_n, 24, 3) -> (N, 72)."""
    check_feature_args(fps, up_axis, mode)
    groups = stack_by_length(joints_list, min_frames=2)
    out = np.empty((sum(len(idx) for idx, _ in groups), KINETIC_DIM))
    for idx, stacked in groups:
        out[idx] = _kinetic_core(to_y_up(stacked, up_axis), fps, mode)
    return out
