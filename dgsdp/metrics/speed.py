"""Joint speeds of a dance: the measure behind the genre speed figures (the style benchmark, the real-song
benchmark) and the speed a model is conditioned on (``model.speed_conditioning``)."""

from __future__ import annotations

import numpy as np

from dgsdp.metrics._common import check_joints

SPEED_QUANTILES = 11
"""How many quantiles of each genre's training-window speeds a speed-conditioned run records: 0, 0.1, ..., 1."""


def joint_speeds(joints: np.ndarray, fps: float = 30) -> np.ndarray:
    """Speed of every joint between consecutive frames, (T-1, J) in m/s, of joints (T, J, 3) in metres."""
    positions = check_joints(joints, min_frames=2)
    return np.linalg.norm(np.diff(positions, axis=0), axis=-1) * fps


def frame_speeds(joints: np.ndarray, fps: float = 30) -> np.ndarray:
    """The mean joint speed of each step between consecutive frames, (T-1,) in m/s: a window's mean of these is
    its :func:`mean_joint_speed`."""
    return joint_speeds(joints, fps).mean(axis=-1)


def mean_joint_speed(joints: np.ndarray, fps: float = 30) -> float:
    """Mean joint speed (m/s) over all joints and frames."""
    return float(joint_speeds(joints, fps).mean())
