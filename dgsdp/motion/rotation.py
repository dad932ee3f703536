"""Rotation conversions used across the project (one implementation of each).

Conventions:
- axis-angle: (..., 3) rotation vectors (SMPL's format).
- quaternion: (..., 4) unit quaternions in (x, y, z, w) order, as in ``roma``, which does the conversions.
- matrix: (..., 3, 3), acting on column vectors (p' = R @ p).
- 6D: (..., 6) the first two ROWS of the matrix, flattened (pytorch3d's ``matrix_to_rotation_6d`` and EDGE's
  convention). Decoding is Gram-Schmidt on those rows. Note that ``roma.special_gramschmidt`` works on columns;
  we do not use it for 6D so that the layout matches EDGE's checkpoints and data.
"""

from __future__ import annotations

import math

import roma
import torch
import torch.nn.functional as F


def axis_angle_to_matrix(rotvec: torch.Tensor) -> torch.Tensor:
    """(..., 3) -> (..., 3, 3)."""
    return roma.rotvec_to_rotmat(rotvec)


def matrix_to_axis_angle(matrix: torch.Tensor) -> torch.Tensor:
    """(..., 3, 3) -> (..., 3), angle in [0, pi]."""
    return roma.rotmat_to_rotvec(matrix)


def matrix_to_quaternion(matrix: torch.Tensor) -> torch.Tensor:
    """(..., 3, 3) -> (..., 4) unit quaternion (x, y, z, w)."""
    return roma.rotmat_to_unitquat(matrix)


def quaternion_to_matrix(quat: torch.Tensor) -> torch.Tensor:
    """(..., 4) quaternion (x, y, z, w), normalised first -> (..., 3, 3)."""
    return roma.unitquat_to_rotmat(F.normalize(quat, dim=-1))


def axis_angle_to_quaternion(rotvec: torch.Tensor) -> torch.Tensor:
    return roma.rotvec_to_unitquat(rotvec)


def quaternion_to_axis_angle(quat: torch.Tensor) -> torch.Tensor:
    return roma.unitquat_to_rotvec(F.normalize(quat, dim=-1))


def matrix_to_6d(matrix: torch.Tensor) -> torch.Tensor:
    """(..., 3, 3) -> (..., 6): first two rows, flattened."""
    return matrix[..., :2, :].reshape(*matrix.shape[:-2], 6)


def sixd_to_matrix(sixd: torch.Tensor) -> torch.Tensor:
    """(..., 6) -> (..., 3, 3) by Gram-Schmidt on the two stored rows (any 6D input gives a valid rotation)."""
    a1, a2 = sixd[..., :3], sixd[..., 3:]
    b1 = F.normalize(a1, dim=-1)
    b2 = F.normalize(a2 - (b1 * a2).sum(-1, keepdim=True) * b1, dim=-1)
    b3 = torch.linalg.cross(b1, b2, dim=-1)
    return torch.stack((b1, b2, b3), dim=-2)


def quaternion_slerp(q0: torch.Tensor, q1: torch.Tensor, weight: torch.Tensor | float) -> torch.Tensor:
    """Element-wise spherical interpolation along the shortest arc.

    q0, q1: (..., 4) unit quaternions (x, y, z, w); weight broadcastable to (...), 0 gives q0 and 1 gives q1.
    (``roma.unitquat_slerp`` interpolates every pair at every step; blending needs one weight per element.)
    """
    q0 = F.normalize(q0, dim=-1)
    q1 = F.normalize(q1, dim=-1)
    w = torch.as_tensor(weight, dtype=q0.dtype, device=q0.device)
    w = w.expand(q0.shape[:-1]).unsqueeze(-1)
    dot = (q0 * q1).sum(-1, keepdim=True)
    q1 = torch.where(dot < 0, -q1, q1)
    dot = dot.abs().clamp(max=1.0)
    theta = torch.acos(dot)
    sin_theta = torch.sin(theta)
    near = sin_theta < 1e-6
    safe = torch.where(near, torch.ones_like(sin_theta), sin_theta)
    c0 = torch.where(near, 1 - w, torch.sin((1 - w) * theta) / safe)
    c1 = torch.where(near, w, torch.sin(w * theta) / safe)
    return F.normalize(c0 * q0 + c1 * q1, dim=-1)


def matrix_slerp(r0: torch.Tensor, r1: torch.Tensor, weight: torch.Tensor | float) -> torch.Tensor:
    """Element-wise slerp of rotation matrices (..., 3, 3) with weights broadcastable to (...)."""
    q = quaternion_slerp(matrix_to_quaternion(r0), matrix_to_quaternion(r1), weight)
    return quaternion_to_matrix(q)


def rotation_about_x(angle_rad: float, dtype: torch.dtype = torch.float32) -> torch.Tensor:
    """(3, 3) rotation by ``angle_rad`` about the x axis."""
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    return torch.tensor([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]], dtype=dtype)
