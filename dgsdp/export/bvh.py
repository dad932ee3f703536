"""Write a motion as a BVH file (y-up), e.g. for Blender's BVH importer with its default axes (Forward -Z, Up Y).

The hierarchy is the motion's skeleton (:class:`~dgsdp.motion.Skeleton`, default SMPL-24: its joint names and
parents); OFFSETs are its rest offsets in the model's y-up rest frame, so the rest pose (all channels zero) is the
T-pose. Leaf joints (feet, head, hands) get an
End Site half as long as their own bone, continuing it, so that every bone has a length in Blender.

Units: metres by default, so that Blender's importer (which takes the file's numbers as Blender units) gives a
life-size body at its default scale 1.0; ``units="cm"`` writes centimetres for tools that expect them.

Channels: the root has ``Xposition Yposition Zposition Zrotation Xrotation Yrotation``, every other joint
``Zrotation Xrotation Yrotation``, in degrees. A BVH channel list means the local rotation is
``R = Rz(z) @ Rx(x) @ Ry(y)`` acting on column vectors in the parent frame (rotations applied in the listed order,
each about the axis of the frame rotated by the previous ones). Angles are unwrapped over time (each may be
shifted by 360 degrees, which leaves the rotation unchanged) so that curves do not jump between frames.

The motion comes in the project's z-up world and is converted to y-up: the root orientation is pre-multiplied by
the z-up -> y-up rotation and the root position mapped (x, y, z) -> (x, z, -y); local joint rotations are unchanged
(the offsets already live in the y-up rest frame).

Floor: the run's floor (``floor_height``, z-up metres, see :mod:`dgsdp.motion.floor`) is put at y = 0, the ground
plane of Blender and other tools: the root position is shifted down by it. Jumps keep their height above it.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import torch

from dgsdp.errors import DataError
from dgsdp.export.aistpp_pkl import skeleton_motion
from dgsdp.motion import SMPL24, Skeleton, points_z_up_to_y_up, root_rotation_z_up_to_y_up
from dgsdp.utils.io import atomic_write_text

ROTATION_CHANNELS = ("Zrotation", "Xrotation", "Yrotation")
POSITION_CHANNELS = ("Xposition", "Yposition", "Zposition")
UNIT_SCALE = {"m": 1.0, "cm": 100.0}
END_SITE_FRACTION = 0.5


def matrix_to_euler_zxy(rotmats: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotations -> (..., 3) angles (z, x, y) in radians with R = Rz(z) @ Rx(x) @ Ry(y).

    x lies in [-pi/2, pi/2]. Near the gimbal configuration (x = +-pi/2) z and y are not separately defined; y is
    solved from what remains after removing Rz(z) Rx(x), so the recomposed rotation stays exact.
    """
    r = np.asarray(rotmats, dtype=np.float64)
    # R = Rz Rx Ry has R[2, 1] = sin x, (R[0, 1], R[1, 1]) = cos x (-sin z, cos z).
    x = np.arctan2(r[..., 2, 1], np.hypot(r[..., 0, 1], r[..., 1, 1]))
    z = np.arctan2(-r[..., 0, 1], r[..., 1, 1])
    cz, sz = np.cos(z), np.sin(z)
    # M = Rx(x)^T Rz(z)^T R = Ry(y): y = atan2(M[0, 2], M[0, 0]); only row 0 of M is needed.
    # Row 0 of Rx^T Rz^T is row 0 of Rz^T = (cz, sz, 0).
    m00 = cz * r[..., 0, 0] + sz * r[..., 1, 0]
    m02 = cz * r[..., 0, 2] + sz * r[..., 1, 2]
    y = np.arctan2(m02, m00)
    return np.stack((z, x, y), axis=-1)


def _hierarchy(offsets: np.ndarray, order: list[int], skeleton: Skeleton) -> list[str]:
    """HIERARCHY lines; appends joints in depth-first file order to ``order``."""
    lines = ["HIERARCHY"]

    def fmt(v: np.ndarray) -> str:
        return " ".join(f"{c:.6f}" for c in v)

    def visit(j: int, depth: int) -> None:
        pad = "  " * depth
        order.append(j)
        root = skeleton.parents[j] < 0
        lines.append(f"{pad}{'ROOT' if root else 'JOINT'} {skeleton.joint_names[j]}")
        lines.append(f"{pad}{{")
        lines.append(f"{pad}  OFFSET {fmt(offsets[j])}")
        channels = POSITION_CHANNELS + ROTATION_CHANNELS if root else ROTATION_CHANNELS
        lines.append(f"{pad}  CHANNELS {len(channels)} {' '.join(channels)}")
        kids = skeleton.children(j)
        for c in kids:
            visit(c, depth + 1)
        if not kids:
            lines.append(f"{pad}  End Site")
            lines.append(f"{pad}  {{")
            lines.append(f"{pad}    OFFSET {fmt(END_SITE_FRACTION * offsets[j])}")
            lines.append(f"{pad}  }}")
        lines.append(f"{pad}}}")

    visit(0, 0)
    return lines


def bvh_text(
    rotmats: torch.Tensor | np.ndarray,
    root_trans: torch.Tensor | np.ndarray,
    fps: float = 30,
    offsets: torch.Tensor | np.ndarray | None = None,
    units: str = "m",
    floor_height: float = 0.0,
    skeleton: Skeleton = SMPL24,
) -> str:
    """The BVH file contents for a z-up motion (rotmats (T, J, 3, 3), root_trans (T, 3) metres) on ``skeleton``;
    see the module docstring for axes, units, channels and the floor. ``offsets``: (J, 3) rest offsets in metres,
    y-up (default the skeleton's); ``floor_height``: the run's floor (z-up metres), written at y = 0."""
    if units not in UNIT_SCALE:
        raise DataError(f"BVH units must be one of {sorted(UNIT_SCALE)}, got {units!r}")
    rot, trans, offs = skeleton_motion(rotmats, root_trans, fps, offsets, floor_height, skeleton)
    scale = UNIT_SCALE[units]

    rot = rot.clone()
    rot[:, 0] = root_rotation_z_up_to_y_up(rot[:, 0])
    position = points_z_up_to_y_up(trans).numpy() * scale  # (T, 3)
    angles_deg = np.degrees(np.unwrap(matrix_to_euler_zxy(rot.numpy()), axis=0))  # (T, J, 3)

    order: list[int] = []
    lines = _hierarchy(offs * scale, order, skeleton)
    values = np.concatenate((position, angles_deg[:, order].reshape(len(position), -1)), axis=1)
    lines += ["MOTION", f"Frames: {len(values)}", f"Frame Time: {1.0 / fps:.8f}"]
    lines += [" ".join(f"{v:.6f}" for v in row) for row in values]
    return "\n".join(lines) + "\n"


def save_bvh(
    path: str | os.PathLike,
    rotmats: torch.Tensor | np.ndarray,
    root_trans: torch.Tensor | np.ndarray,
    fps: float = 30,
    offsets: torch.Tensor | np.ndarray | None = None,
    units: str = "m",
    floor_height: float = 0.0,
    skeleton: Skeleton = SMPL24,
) -> Path:
    """Write a z-up motion (rotmats (T, J, 3, 3) local rotations on ``skeleton``, root_trans (T, 3) metres, at
    ``fps``) as a y-up BVH file (atomic) with the run's floor (``floor_height``, z-up metres) at y = 0. ``units`` is
    ``"m"`` (Blender at scale 1.0) or ``"cm"``. Returns the path."""
    path = Path(path)
    text = bvh_text(
        rotmats, root_trans, fps=fps, offsets=offsets, units=units, floor_height=floor_height, skeleton=skeleton
    )
    atomic_write_text(path, text)
    return path
