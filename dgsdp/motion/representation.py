"""The pose vector (per frame, 30 FPS, z-up) and conversions from/to SMPL parameters.

For a skeleton of J joints (``skeleton.pose_dim`` = 7 + 6 J channels; SMPL-24's is 151-d):

| channels   | content |
| 0-3        | foot contacts of the skeleton's foot joints (left ankle, right ankle, left toe, right toe) |
| 4-6        | root translation, z-up, metres |
| 7-(6 J+6)  | J joints x 6D rotation (dgsdp.motion.rotation); joint j at 7 + 6j .. 12 + 6j |

Every function takes the skeleton (default SMPL-24) and checks the vector's size against it.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from dgsdp.motion.axes import points_y_up_to_z_up, root_rotation_y_up_to_z_up
from dgsdp.motion.fk import forward_kinematics
from dgsdp.motion.rotation import axis_angle_to_matrix, matrix_to_6d, sixd_to_matrix
from dgsdp.motion.skeleton import SMPL24, Skeleton

POSE_DIM = SMPL24.pose_dim  # SMPL-24's pose vector: 151
CONTACT_CHANNELS = slice(0, 4)
ROOT_CHANNELS = slice(4, 7)
ROTATION_CHANNELS = slice(7, POSE_DIM)  # SMPL-24's; see rotation_channels
CONTACT_SPEED_THRESHOLD_M_PER_FRAME = 0.01
ROTATION_PROJECTIONS = ("root", "all")  # the joints project_rotations can make valid


def rotation_channels(skeleton: Skeleton = SMPL24) -> slice:
    """The channels of the skeleton's pose vector that hold the joints' 6D rotations."""
    return slice(ROTATION_CHANNELS.start, skeleton.pose_dim)


def check_pose_dim(x: torch.Tensor, skeleton: Skeleton, what: str = "pose vectors") -> None:
    """Raise ValueError unless ``x`` (..., C) has the skeleton's pose size."""
    if x.shape[-1] != skeleton.pose_dim:
        raise ValueError(f"{what} must have {skeleton.pose_dim} channels ({skeleton.name}), got shape {tuple(x.shape)}")


@dataclass
class PoseParts:
    """The unpacked pose vector: contacts (..., T, 4), root_trans (..., T, 3), rotmats (..., T, J, 3, 3)."""

    contacts: torch.Tensor
    root_trans: torch.Tensor
    rotmats: torch.Tensor
    skeleton: Skeleton = SMPL24

    def joints(self) -> torch.Tensor:
        """FK joint positions (..., T, J, 3), z-up metres."""
        return forward_kinematics(self.rotmats, self.root_trans, skeleton=self.skeleton)


def pack_pose(contacts: torch.Tensor, root_trans: torch.Tensor, rotmats: torch.Tensor) -> torch.Tensor:
    """(..., T, 4), (..., T, 3), (..., T, J, 3, 3) -> (..., T, 7 + 6 J)."""
    sixd = matrix_to_6d(rotmats).flatten(-2)
    return torch.cat((contacts.to(sixd), root_trans.to(sixd), sixd), dim=-1)


def unpack_pose(x: torch.Tensor, skeleton: Skeleton = SMPL24) -> PoseParts:
    """(..., T, 7 + 6 J) -> PoseParts (rotations decoded by Gram-Schmidt)."""
    check_pose_dim(x, skeleton)
    sixd = x[..., rotation_channels(skeleton)].reshape(*x.shape[:-1], skeleton.num_joints, 6)
    return PoseParts(x[..., CONTACT_CHANNELS], x[..., ROOT_CHANNELS], sixd_to_matrix(sixd), skeleton)


def project_rotations(x: torch.Tensor, which: str = "all", skeleton: Skeleton = SMPL24) -> torch.Tensor:
    """Unnormalised pose vectors (..., T, 7 + 6 J) with the 6D rotations of ``which`` joints (``all``, or ``root``: the
    body's orientation only) replaced by those of the rotations they decode to (Gram-Schmidt): two orthonormal
    columns. Valid rotations are unchanged (to float precision); a shrunken 6D vector, such as the mean of a turn
    left and a turn right, becomes a unit one. Other channels are unchanged. Returns a new tensor."""
    check_pose_dim(x, skeleton)
    if which not in ROTATION_PROJECTIONS:
        raise ValueError(f"which={which!r}: project the rotations of 'all' joints or of the 'root' only")
    n = skeleton.num_joints if which == "all" else 1
    channels = slice(ROTATION_CHANNELS.start, ROTATION_CHANNELS.start + 6 * n)
    sixd = x[..., channels].reshape(*x.shape[:-1], n, 6)
    out = x.clone()
    out[..., channels] = matrix_to_6d(sixd_to_matrix(sixd)).reshape(*x.shape[:-1], 6 * n)
    return out


def pose_to_joints(x: torch.Tensor, skeleton: Skeleton = SMPL24) -> torch.Tensor:
    """(..., T, 7 + 6 J) unnormalised pose vectors -> joint positions (..., T, J, 3), z-up metres."""
    return unpack_pose(x, skeleton).joints()


def foot_contacts(
    joints: torch.Tensor,
    threshold_m_per_frame: float = CONTACT_SPEED_THRESHOLD_M_PER_FRAME,
    skeleton: Skeleton = SMPL24,
) -> torch.Tensor:
    """Binary foot contacts (..., T, 4) from joints (..., T, J, 3) at 30 FPS.

    Speed of the skeleton's foot joints (SMPL: 7, 8, 10, 11) is the norm of the displacement to the next frame (metres
    per frame); the last frame gets speed 0. Contact where speed < threshold (0.01 m/frame, about 0.3 m/s at 30 FPS).
    """
    feet = joints[..., list(skeleton.foot_joints), :]
    speed = torch.zeros(feet.shape[:-1], dtype=joints.dtype, device=joints.device)
    speed[..., :-1, :] = (feet[..., 1:, :, :] - feet[..., :-1, :, :]).norm(dim=-1)
    return (speed < threshold_m_per_frame).to(joints.dtype)


def smpl_to_pose(
    poses_axis_angle: torch.Tensor, trans_m: torch.Tensor, y_up: bool = True, skeleton: Skeleton = SMPL24
) -> torch.Tensor:
    """SMPL(-X) parameters -> pose vectors (..., T, 7 + 6 J), z-up.

    poses_axis_angle: (..., T, 3 J) axis-angle in the skeleton's joint order (SMPL: 72); trans_m: (..., T, 3) root
    translation in metres (AIST++: smpl_trans / smpl_scaling). ``y_up`` says the input is y-up (AIST++) and is
    converted. Contacts are computed from FK at the input's frame rate (use 30 FPS input).
    """
    n = skeleton.num_joints
    if poses_axis_angle.shape[-1] != 3 * n:
        raise ValueError(f"{skeleton.name} poses need {3 * n} axis-angle values, got {tuple(poses_axis_angle.shape)}")
    rotmats = axis_angle_to_matrix(poses_axis_angle.reshape(*poses_axis_angle.shape[:-1], n, 3))
    if y_up:
        rotmats = rotmats.clone()
        rotmats[..., 0, :, :] = root_rotation_y_up_to_z_up(rotmats[..., 0, :, :])
        trans_m = points_y_up_to_z_up(trans_m)
    joints = forward_kinematics(rotmats, trans_m, skeleton=skeleton)
    return pack_pose(foot_contacts(joints, skeleton=skeleton), trans_m, rotmats)


def channels_for_joints(
    joints: list[int | str] | tuple[int | str, ...], with_root_and_contacts: bool, skeleton: Skeleton = SMPL24
) -> list[int]:
    """Channels of the skeleton's pose vector that hold the rotations of the given joints (by index or name),
    plus the root translation and foot-contact channels if asked (they belong with the lower body)."""
    channels: list[int] = []
    if with_root_and_contacts:
        channels += list(range(CONTACT_CHANNELS.start, ROOT_CHANNELS.stop))
    for j in sorted({skeleton.joint_index(j) for j in joints}):
        start = ROTATION_CHANNELS.start + 6 * j
        channels += list(range(start, start + 6))
    return channels
