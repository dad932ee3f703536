"""From generated or real motion to the inputs of the metric suite.

Motion is pose vectors at 30 FPS, z-up (SMPL-24's 151-d, or another skeleton's). The metrics are defined on SMPL's 24
joints, so a motion on another skeleton is measured on SMPL's joint layout (:func:`dgsdp.motion.smpl24_layout`: SMPL-X's
22 body joints are SMPL's first 22; SMPL's hand joints are the middle fingers' first joints where the skeleton has
fingers (SMPL-X 52), else the wrists). The kinetic and geometric features and the beat alignment score are computed y-up
at 60 FPS, as in the reference protocol: joint positions are upsampled from 30 to 60 FPS by linear interpolation between
consecutive frames (T frames -> 2T - 1 frames, frame 2k at 60 FPS is frame k at 30 FPS), rotated to y-up and, when the
protocol says so, anchored at the first frame's root. PFC is computed on the 30 FPS z-up joints as EDGE defines it."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from dgsdp.metrics import anchor_root, geometric_features_batch, kinetic_features_batch, z_up_to_y_up
from dgsdp.motion import SMPL24, Skeleton, pose_to_joints, smpl24_layout

MODEL_FPS = 30
FEATURE_FPS = 60
UPSAMPLE = FEATURE_FPS // MODEL_FPS


def motion_to_joints(motion: np.ndarray | torch.Tensor, skeleton: Skeleton = SMPL24) -> np.ndarray:
    """Unnormalised pose vectors (..., T, D) of ``skeleton`` -> joint positions in SMPL's layout (..., T, 24, 3),
    z-up metres, float64 (the metrics' input)."""
    x = torch.as_tensor(np.asarray(motion), dtype=torch.float64)
    joints = pose_to_joints(x, skeleton).numpy()
    return joints[..., smpl24_layout(skeleton), :]


def upsample_joints(joints: np.ndarray, factor: int = UPSAMPLE) -> np.ndarray:
    """Linear interpolation in time: (T, 24, 3) -> ((T - 1) * factor + 1, 24, 3); input frames are kept exactly."""
    joints = np.asarray(joints, dtype=np.float64)
    if factor == 1 or len(joints) < 2:
        return joints
    t_in = np.arange(len(joints), dtype=np.float64)
    t_out = np.arange((len(joints) - 1) * factor + 1, dtype=np.float64) / factor
    lo = np.minimum(np.floor(t_out).astype(int), len(joints) - 2)
    w = (t_out - t_in[lo])[:, None, None]
    return (1.0 - w) * joints[lo] + w * joints[lo + 1]


def feature_joints(joints_z_up_30fps: np.ndarray, anchor: bool = True, upsample: bool = True) -> np.ndarray:
    """(T, 24, 3) z-up 30 FPS -> (2T - 1, 24, 3) y-up 60 FPS, root-anchored when ``anchor``. ``upsample`` False
    keeps the 30 FPS frames (T, 24, 3), for protocols that pass them to the 60 FPS feature code as LODGE does."""
    y_up = z_up_to_y_up(upsample_joints(joints_z_up_30fps) if upsample else np.asarray(joints_z_up_30fps, np.float64))
    return anchor_root(y_up) if anchor else y_up


def root_relative(joints: np.ndarray) -> np.ndarray:
    """Every joint but the root relative to the root of its frame; the root itself is kept (LODGE's features)."""
    out = np.array(joints, dtype=np.float64)
    out[..., 1:, :] -= out[..., :1, :]
    return out


def dance_features(
    joints_z_up_30fps: Sequence[np.ndarray], *, mode: str = "paper", anchor: bool = True
) -> tuple[np.ndarray, np.ndarray]:
    """Kinetic (N, 72) and geometric (N, 32) features of N dances given as (T_n, 24, 3) z-up 30 FPS joints."""
    prepared = [feature_joints(j, anchor=anchor) for j in joints_z_up_30fps]
    kinetic = kinetic_features_batch(prepared, fps=FEATURE_FPS, up_axis="y", mode=mode)
    geometric = geometric_features_batch(prepared, fps=FEATURE_FPS, up_axis="y", mode=mode)
    return kinetic, geometric


def beats_to_feature_fps(beat_frames_30fps: np.ndarray) -> np.ndarray:
    """Music beat frame indices at 30 FPS -> the same instants as frame indices at 60 FPS."""
    return np.asarray(beat_frames_30fps, dtype=np.int64) * UPSAMPLE
