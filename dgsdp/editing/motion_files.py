"""Given motions for editing (seed motion, keyframes, a body part to keep) read from files.

Accepted: ``.npy`` holding pose vectors ``(N, D)`` of the model's skeleton (unnormalised, z-up, 30 FPS, as the
project writes them; SMPL-24: D = 151), or ``.pkl`` holding either such an array or, for SMPL-24 models, an AIST++
motion dict (``smpl_poses (N, 72)``, ``smpl_trans (N, 3)``, ``smpl_scaling``; 60 FPS unless the dict says ``fps``,
as our exported pickles do).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import torch

from dgsdp.data.aistpp import motion_from_pkl_data, process_motion
from dgsdp.errors import DataError
from dgsdp.motion import SMPL24, Skeleton
from dgsdp.safety.safe_pickle import load_pickle

MOTION_FILE_SUFFIXES = (".npy", ".pkl")
AISTPP_SOURCE_FPS = 60


def _as_pose_array(data: object, path: Path, skeleton: Skeleton) -> torch.Tensor:
    try:
        arr = np.asarray(data)
    except ValueError:  # ragged nested lists
        arr = np.asarray(data, dtype=object)
    dim = skeleton.pose_dim
    if arr.ndim == 1 and arr.shape[0] == dim:
        arr = arr[None]
    real = np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)
    if arr.ndim != 2 or arr.shape[1] != dim or arr.shape[0] == 0 or not real:
        raise DataError(
            f"motion file {path} holds an array of shape {arr.shape} ({arr.dtype}); expected {dim}-d pose vectors "
            f"(N, {dim}) (contacts, root translation, {skeleton.num_joints} x 6D rotations of {skeleton.name}; "
            "z-up, 30 FPS) or an AIST++ motion pickle with smpl_poses (N, 72) and smpl_trans (N, 3)"
        )
    if not np.isfinite(arr).all():
        raise DataError(f"motion file {path} has NaN or infinite values")
    return torch.from_numpy(arr.astype(np.float32))


def load_motion_file(path: str | os.PathLike, fps: int = 30, skeleton: Skeleton = SMPL24) -> torch.Tensor:
    """Read a motion as unnormalised pose vectors ``(N, D)`` of ``skeleton`` at ``fps``; one DataError for a bad
    file."""
    path = Path(path).expanduser()
    if not path.is_file():
        raise DataError(f"motion file {path} does not exist; check the path")
    suffix = path.suffix.lower()
    if suffix not in MOTION_FILE_SUFFIXES:
        raise DataError(
            f"motion file {path}: unsupported type {suffix!r}; give a .npy of (N, {skeleton.pose_dim}) pose vectors "
            "or an AIST++ .pkl motion"
        )
    if suffix == ".npy":
        try:
            data = np.load(path, allow_pickle=False)
        except Exception as e:  # noqa: BLE001 - any failure here means an unreadable file for the user
            raise DataError(f"cannot read motion file {path} ({type(e).__name__}: {e})") from e
        return _as_pose_array(data, path, skeleton)
    data = load_pickle(path, "motion file")  # plain data and numpy arrays only: never runs code from the file
    if not isinstance(data, dict):
        return _as_pose_array(data, path, skeleton)
    if skeleton != SMPL24:
        raise DataError(
            f"motion file {path}: an AIST++ motion pickle holds SMPL-24 poses; this model's skeleton is "
            f"{skeleton.name}: give a .npy of (N, {skeleton.pose_dim}) pose vectors"
        )
    try:
        source_fps = int(round(float(data.get("fps", AISTPP_SOURCE_FPS))))
    except (TypeError, ValueError, OverflowError) as e:
        raise DataError(f"motion file {path}: 'fps' must be a number, got {data.get('fps')!r}") from e
    poses, trans_m = motion_from_pkl_data(data, path)
    if source_fps <= 0 or source_fps % fps:
        raise DataError(f"motion file {path} is at {source_fps} FPS, which is not a multiple of {fps} FPS")
    return torch.from_numpy(process_motion(poses, trans_m, source_fps=source_fps, fps=fps))
