"""y-up <-> z-up conversion.

AIST++ (and SMPL) are y-up; the model, FK, contacts, PFC and rendering work z-up as EDGE does. The conversion is a
+90 degree rotation about x: a point (x, y, z) y-up becomes (x, -z, y) z-up; the root orientation is
pre-multiplied by the same rotation. Exports to y-up tools (BVH, Blender) rotate back.
"""

from __future__ import annotations

import math

import torch

from dgsdp.motion.rotation import rotation_about_x

Y_UP_TO_Z_UP = rotation_about_x(math.pi / 2)  # (3, 3)
Z_UP_TO_Y_UP = Y_UP_TO_Z_UP.T.contiguous()


def _apply(matrix: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    return points @ matrix.to(points).T


def points_y_up_to_z_up(points: torch.Tensor) -> torch.Tensor:
    """(..., 3) y-up -> z-up: (x, y, z) -> (x, -z, y)."""
    return _apply(Y_UP_TO_Z_UP, points)


def points_z_up_to_y_up(points: torch.Tensor) -> torch.Tensor:
    """(..., 3) z-up -> y-up: (x, y, z) -> (x, z, -y)."""
    return _apply(Z_UP_TO_Y_UP, points)


def root_rotation_y_up_to_z_up(root_rotmat: torch.Tensor) -> torch.Tensor:
    """(..., 3, 3) global root orientation in a y-up world -> the same body in a z-up world."""
    return Y_UP_TO_Z_UP.to(root_rotmat) @ root_rotmat


def root_rotation_z_up_to_y_up(root_rotmat: torch.Tensor) -> torch.Tensor:
    return Z_UP_TO_Y_UP.to(root_rotmat) @ root_rotmat
