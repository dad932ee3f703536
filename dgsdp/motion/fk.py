"""Batched forward kinematics on the fixed SMPL skeleton."""

from __future__ import annotations

import torch

from dgsdp.motion.skeleton import NUM_JOINTS, PARENTS, rest_offsets


def forward_kinematics(
    local_rotmats: torch.Tensor,
    root_trans: torch.Tensor,
    offsets: torch.Tensor | None = None,
    return_global_rotmats: bool = False,
) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
    """Joint positions from local joint rotations.

    local_rotmats: (..., 24, 3, 3) rotation of each joint relative to its parent (joint 0: the global root
    orientation); root_trans: (..., 3) position of the root joint; offsets: (24, 3) rest offsets, default the
    SMPL mean body. Returns joints (..., 24, 3) in the frame of ``root_trans`` (and the global rotations
    (..., 24, 3, 3) if asked). The root position is the translation itself (the pelvis rest offset is ignored).
    """
    if local_rotmats.shape[-3:] != (NUM_JOINTS, 3, 3):
        raise ValueError(f"local_rotmats must be (..., 24, 3, 3), got {tuple(local_rotmats.shape)}")
    if offsets is None:
        offsets = rest_offsets(dtype=local_rotmats.dtype, device=local_rotmats.device)
    positions: list[torch.Tensor] = [root_trans]
    rotations: list[torch.Tensor] = [local_rotmats[..., 0, :, :]]
    for j in range(1, NUM_JOINTS):
        p = PARENTS[j]
        positions.append(positions[p] + (rotations[p] @ offsets[j].unsqueeze(-1)).squeeze(-1))
        rotations.append(rotations[p] @ local_rotmats[..., j, :, :])
    joints = torch.stack(positions, dim=-2)
    if return_global_rotmats:
        return joints, torch.stack(rotations, dim=-3)
    return joints
