"""Physical Foot Contact score (PFC, EDGE): penalises upward root acceleration while both feet slide.

Lower is better. A sequence's score is already multiplied by 10000; EDGE's PFC is the mean of the
per-sequence scores.
"""

from __future__ import annotations

import warnings

import numpy as np

from dgsdp.metrics._common import MetricWarning, check_choice, check_joints, y_up_to_z_up

PFC_SCALE = 10000.0
LEFT_FOOT = (7, 10)  # left ankle, left toe
RIGHT_FOOT = (8, 11)  # right ankle, right toe
# Below this peak (m/s^2) the root acceleration is rounding noise (float32 positions of a root moving at
# constant velocity reach ~1e-4): normalising by it would turn noise into a full-scale signal.
MIN_PEAK_ACCELERATION = 1e-3


def pfc(joints: np.ndarray, fps: float = 30, up_axis: str = "z") -> float:
    """PFC of one sequence (times 10000).

    joints: (T, 24, 3) metres, T >= 3; ``up_axis="y"`` input is rotated to z-up first ((x, y, z) ->
    (x, -z, y)). Root acceleration is the second difference of the root divided by (1/fps)^2, its up
    component clamped at >= 0, its norm divided by the sequence maximum. Foot speed is the horizontal
    per-frame displacement (not divided by the frame time) from frame t-1 to t for t = 2..T-1; each
    foot takes the slower of ankle and toe. Score = mean(left * right * acceleration) * 10000.
    A root whose clamped acceleration never exceeds 1e-3 m/s^2 (e.g. constant velocity) has no
    meaningful normaliser: the score is 0.0 with a MetricWarning (EDGE's code would give NaN, or
    amplified rounding noise).
    """
    check_choice(up_axis, ("y", "z"), "up_axis")
    positions = check_joints(joints, min_frames=3)
    if up_axis == "y":
        positions = y_up_to_z_up(positions)
    dt_s = 1.0 / fps
    root_velocity = np.diff(positions[:, 0], axis=0) / dt_s
    root_acceleration = np.diff(root_velocity, axis=0) / dt_s  # (T-2, 3)
    root_acceleration[:, 2] = np.maximum(root_acceleration[:, 2], 0.0)
    acceleration = np.linalg.norm(root_acceleration, axis=-1)
    peak = acceleration.max()
    if peak <= MIN_PEAK_ACCELERATION:
        warnings.warn(
            f"PFC: the root never accelerates (peak {peak:.2g} m/s^2 <= {MIN_PEAK_ACCELERATION}), so the "
            "normalised acceleration is undefined; score set to 0.0.",
            MetricWarning,
            stacklevel=2,
        )
        return 0.0
    feet = positions[:, list(LEFT_FOOT + RIGHT_FOOT)]
    foot_speed = np.linalg.norm(feet[2:, :, :2] - feet[1:-1, :, :2], axis=-1)  # (T-2, 4)
    left = np.minimum(foot_speed[:, 0], foot_speed[:, 1])
    right = np.minimum(foot_speed[:, 2], foot_speed[:, 3])
    return float(np.mean(left * right * acceleration / peak) * PFC_SCALE)
