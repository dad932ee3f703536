"""Write a motion as an AIST++ motion pickle (y-up SMPL parameters), the format AIST++ tools read.

The file holds ``smpl_poses`` (N, 3 J) axis-angle (SMPL-24: (N, 72)), ``smpl_trans`` (N, 3) metres,
``smpl_scaling`` (1,) = 1.0 (so ``smpl_trans / smpl_scaling`` is metres, as AIST++ readers compute), ``smpl_loss``
0.0, plus ``joints3d`` (N, J, 3) y-up joint positions in metres from our fixed-skeleton forward kinematics (not the
licensed SMPL body model), ``fps`` and ``floor_height``. A motion on another skeleton than SMPL-24 (AIST++'s own)
also records ``skeleton`` (its name) and ``joint_names``, the order of the joints in ``smpl_poses``.

Floor: the pickle keeps the model's (the training data's) coordinates, so that it reads back as the same motion
(e.g. as the given motion of an edit); ``floor_height`` records where the run's floor is: the plane y =
``floor_height`` (metres). The files for viewing (BVH, GLB, video) instead show that floor at height 0 or draw it.

Frame rate: the motion is written at its own rate (30 FPS for generated motions), without resampling, and ``fps``
records it. AIST++'s own files are 60 FPS, so a reader that assumes 60 FPS must be told: the project's reader
takes ``process_motion(poses, trans, source_fps=30, fps=30)``.
"""

from __future__ import annotations

import os
import pickle
from pathlib import Path

import numpy as np
import torch

from dgsdp.errors import DataError
from dgsdp.motion import (
    SMPL24,
    Skeleton,
    forward_kinematics,
    matrix_to_axis_angle,
    points_z_up_to_y_up,
    root_rotation_z_up_to_y_up,
)
from dgsdp.utils.io import atomic_path


def as_motion(
    rotmats: torch.Tensor | np.ndarray, root_trans: torch.Tensor | np.ndarray, skeleton: Skeleton = SMPL24
) -> tuple[torch.Tensor, torch.Tensor]:
    """Check and convert a motion to float64 tensors: rotmats (T, J, 3, 3), root_trans (T, 3) metres.

    Raises :class:`DataError` for wrong shapes, an empty motion or non-finite values.
    """
    rot = torch.as_tensor(rotmats).detach().to("cpu", torch.float64)
    trans = torch.as_tensor(root_trans).detach().to("cpu", torch.float64)
    n = skeleton.num_joints
    if rot.ndim != 4 or rot.shape[1:] != (n, 3, 3) or trans.shape != (rot.shape[0], 3):
        raise DataError(
            f"a motion to export on {skeleton.name} needs rotmats (T, {n}, 3, 3) and root_trans (T, 3); got "
            f"{tuple(rot.shape)} and {tuple(trans.shape)} (unpack a batch of pose vectors one sequence at a time "
            "with unpack_pose)"
        )
    if rot.shape[0] == 0:
        raise DataError("the motion to export has no frames")
    if not (torch.isfinite(rot).all() and torch.isfinite(trans).all()):
        raise DataError("the motion to export has NaN or infinite values; check the generated sequence")
    return rot, trans


def skeleton_motion(
    rotmats: torch.Tensor | np.ndarray,
    root_trans: torch.Tensor | np.ndarray,
    fps: float,
    offsets: torch.Tensor | np.ndarray | None = None,
    floor_height: float = 0.0,
    skeleton: Skeleton = SMPL24,
) -> tuple[torch.Tensor, torch.Tensor, np.ndarray]:
    """:func:`as_motion` plus the frame rate and the skeleton's rest offsets (J, 3) metres (default its own), checked
    for the exporters that write a skeleton; the root's offset is 0 (its position is the translation itself, as in
    our forward kinematics). The root translation comes back shifted down by ``floor_height`` (z-up metres), so that
    the run's floor lies at height 0 in the exported file."""
    if not fps > 0:
        raise DataError(f"fps must be positive, got {fps}")
    if not np.isfinite(floor_height):
        raise DataError(f"the floor height must be a finite number of metres, got {floor_height}")
    rot, trans = as_motion(rotmats, root_trans, skeleton)
    trans = trans.clone()
    trans[:, 2] -= float(floor_height)
    if offsets is None:
        offsets = skeleton.rest_offsets(dtype=torch.float64)
    offs = torch.as_tensor(offsets).detach().to("cpu", torch.float64).numpy().copy()
    if offs.shape != (skeleton.num_joints, 3) or not np.isfinite(offs).all():
        raise DataError(f"offsets must be a finite ({skeleton.num_joints}, 3) array in metres, got shape {offs.shape}")
    offs[0] = 0.0
    return rot, trans, offs


def motion_to_aistpp(
    rotmats: torch.Tensor | np.ndarray,
    root_trans: torch.Tensor | np.ndarray,
    fps: float = 30,
    floor_height: float = 0.0,
    skeleton: Skeleton = SMPL24,
) -> dict[str, np.ndarray | float | str | list[str]]:
    """The AIST++ motion dict of a z-up motion (rotmats (T, J, 3, 3), root_trans (T, 3) metres), y-up, in the
    motion's own coordinates; ``floor_height`` (metres) is recorded, not applied."""
    if not np.isfinite(floor_height):
        raise DataError(f"the floor height must be a finite number of metres, got {floor_height}")
    rot, trans = as_motion(rotmats, root_trans, skeleton)
    joints_y_up = points_z_up_to_y_up(forward_kinematics(rot, trans, skeleton=skeleton))
    rot_y_up = rot.clone()
    rot_y_up[:, 0] = root_rotation_z_up_to_y_up(rot[:, 0])
    poses = matrix_to_axis_angle(rot_y_up).reshape(rot.shape[0], skeleton.num_joints * 3)
    extra = {} if skeleton == SMPL24 else {"skeleton": skeleton.name, "joint_names": list(skeleton.joint_names)}
    return {
        "smpl_poses": poses.numpy().astype(np.float32),
        "smpl_trans": points_z_up_to_y_up(trans).numpy().astype(np.float32),
        "smpl_scaling": np.ones(1, dtype=np.float32),
        "smpl_loss": 0.0,
        "joints3d": joints_y_up.numpy().astype(np.float32),
        "fps": float(fps),
        "floor_height": float(floor_height),
        **extra,
    }


def save_aistpp_pkl(
    path: str | os.PathLike,
    rotmats: torch.Tensor | np.ndarray,
    root_trans: torch.Tensor | np.ndarray,
    fps: float = 30,
    floor_height: float = 0.0,
    skeleton: Skeleton = SMPL24,
) -> Path:
    """Write a z-up motion (rotmats (T, J, 3, 3) local rotations on ``skeleton``, root_trans (T, 3) metres, at
    ``fps``) as an AIST++ y-up motion pickle at the same frame rate, recording the run's ``floor_height``; atomic
    (no half-written file). Returns the path."""
    if fps <= 0:
        raise DataError(f"fps must be positive, got {fps}")
    data = motion_to_aistpp(rotmats, root_trans, fps, floor_height, skeleton)
    path = Path(path)
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            pickle.dump(data, f, protocol=4)
            f.flush()
            os.fsync(f.fileno())
    return path
