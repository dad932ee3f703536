"""Batched forward kinematics on a fixed skeleton (SMPL-24 unless another is given)."""

from __future__ import annotations

import torch

from dgsdp.motion.skeleton import SMPL24, Skeleton


def forward_kinematics(
    local_rotmats: torch.Tensor,
    root_trans: torch.Tensor,
    offsets: torch.Tensor | None = None,
    return_global_rotmats: bool = False,
    *,
    skeleton: Skeleton = SMPL24,
) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
    """Joint positions from local joint rotations.

    local_rotmats: (..., J, 3, 3) rotation of each joint relative to its parent (joint 0: the global root
    orientation), J = ``skeleton.num_joints``; root_trans: (..., 3) position of the root joint; offsets: (J, 3) rest
    offsets, default the skeleton's. Returns joints (..., J, 3) in the frame of ``root_trans`` (and the global
    rotations (..., J, 3, 3) if asked). The root position is the translation itself (the root's rest offset is
    ignored).
    """
    n = skeleton.num_joints
    if local_rotmats.shape[-3:] != (n, 3, 3):
        raise ValueError(
            f"local_rotmats must be (..., {n}, 3, 3) for {skeleton.name}, got {tuple(local_rotmats.shape)}"
        )
    if offsets is None:
        offsets = skeleton.rest_offsets(dtype=local_rotmats.dtype, device=local_rotmats.device)
    positions: list[torch.Tensor] = [root_trans]
    rotations: list[torch.Tensor] = [local_rotmats[..., 0, :, :]]
    for j in range(1, n):
        p = skeleton.parents[j]
        positions.append(positions[p] + (rotations[p] @ offsets[j].unsqueeze(-1)).squeeze(-1))
        rotations.append(rotations[p] @ local_rotmats[..., j, :, :])
    joints = torch.stack(positions, dim=-2)
    if return_global_rotmats:
        return joints, torch.stack(rotations, dim=-3)
    return joints
