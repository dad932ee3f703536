"""The training loss: named terms with weights, summed in one place (EDGE's four terms by default).

- simple: MSE over all channels of the predicted x0 (normalised space; SMPL-24: 151).
- velocity: MSE of first differences over time of the non-contact channels (SMPL-24: 147).
- fk: MSE of FK joint positions (metres, z-up) on the run's skeleton.
- foot: FK velocity of the skeleton's foot joints (SMPL: 7, 8, 10, 11) pushed to zero where the model's own predicted
  contact is above the threshold.
- pause (in neither paper; weight 0 = off): the velocity term's error again, weighted per frame by how still the true
  motion is there, ``relu(1 - speed / window mean speed)`` (speed: the mean absolute first difference of the non-contact
  channels), so that moving where the training dance holds still costs more. Training dances hold still on the beat; the
  term is a recipe choice for teaching a short run where to pause (docs/notes/2026-11-25-the-models-own-timing.md).
- root (in neither paper; weight 0 = off): the velocity term's error on the root translation's 3 channels alone. In
  the velocity term they are 3 of 147 channels, and the min-max normaliser maps the whole stage (metres of travel)
  onto the range it gives a joint's rotation channel, so a small error there is a body that slides (docs/style.md).

FK runs on unnormalised values (the normaliser is passed in), so the FK and foot terms are in metres. EDGE runs
FK on normalised values; its author reported no difference. Unnormalising keeps the joint positions physical.

The skeleton's rest offsets and foot joints are made into tensors once per skeleton, device and dtype and reused
at every step: a tensor made from a list on a GPU is copied from the host and waits for the device first.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F

from dgsdp.motion import SMPL24, MinMaxNormalizer, Skeleton, forward_kinematics, unpack_pose
from dgsdp.motion.representation import CONTACT_CHANNELS, ROOT_CHANNELS, PoseParts

_SKELETON_TENSORS: dict[tuple[Skeleton, torch.device, torch.dtype], tuple[torch.Tensor, torch.Tensor]] = {}


def _skeleton_tensors(
    skeleton: Skeleton, device: torch.device, dtype: torch.dtype
) -> tuple[torch.Tensor, torch.Tensor]:
    """The skeleton's rest offsets (J, 3) in ``dtype`` and its foot joints' indices (4,) on ``device``, made once
    and kept (a training step would otherwise copy them from the host three times). Made as ordinary tensors even
    under inference mode (a validation step), so that later training steps can save them for the backward pass."""
    key = (skeleton, device, dtype)
    cached = _SKELETON_TENSORS.get(key)
    if cached is None:
        with torch.inference_mode(False):
            cached = (
                skeleton.rest_offsets(dtype=dtype, device=device),
                torch.tensor(skeleton.foot_joints, dtype=torch.long, device=device),
            )
        _SKELETON_TENSORS[key] = cached
    return cached


@dataclass
class LossWeights:
    simple: float = 0.636
    velocity: float = 2.964
    fk: float = 0.646
    foot: float = 10.942
    contact_threshold: float = 0.95
    pause: float = 0.0
    root: float = 0.0


def _joints(parts: PoseParts, skeleton: Skeleton) -> torch.Tensor:
    """``parts.joints()`` (FK joint positions, z-up metres) with the skeleton's kept rest offsets."""
    offsets = _skeleton_tensors(skeleton, parts.rotmats.device, parts.rotmats.dtype)[0]
    return forward_kinematics(parts.rotmats, parts.root_trans, offsets, skeleton=skeleton)


def dance_loss(
    pred_x0: torch.Tensor,
    x0: torch.Tensor,
    normalizer: MinMaxNormalizer,
    weights: LossWeights,
    skeleton: Skeleton = SMPL24,
) -> dict[str, torch.Tensor]:
    """Loss terms for predicted and true x0 (B, T, skeleton.pose_dim), normalised. Returns each term and ``loss``
    (weighted sum)."""
    terms: dict[str, torch.Tensor] = {"simple": F.mse_loss(pred_x0, x0)}
    motion = slice(CONTACT_CHANNELS.stop, None)
    pred_vel, true_vel = pred_x0[:, 1:, motion] - pred_x0[:, :-1, motion], x0[:, 1:, motion] - x0[:, :-1, motion]
    terms["velocity"] = F.mse_loss(pred_vel, true_vel)
    if weights.pause:
        speed = true_vel.abs().mean(dim=-1)  # (B, T - 1)
        stillness = (1 - speed / speed.mean(dim=1, keepdim=True).clamp_min(1e-8)).clamp_min(0)
        terms["pause"] = (stillness[..., None] * (pred_vel - true_vel).square()).mean()
    if weights.root:
        root = slice(ROOT_CHANNELS.start - motion.start, ROOT_CHANNELS.stop - motion.start)
        terms["root"] = F.mse_loss(pred_vel[..., root], true_vel[..., root])
    if weights.fk or weights.foot:
        pred_parts = unpack_pose(normalizer.unnormalize(pred_x0), skeleton)
        pred_joints = _joints(pred_parts, skeleton)
        if weights.fk:
            terms["fk"] = F.mse_loss(pred_joints, _joints(unpack_pose(normalizer.unnormalize(x0), skeleton), skeleton))
        if weights.foot:
            contact = (pred_parts.contacts > weights.contact_threshold).to(pred_x0.dtype)  # (B, T, 4)
            foot_joints = _skeleton_tensors(skeleton, pred_joints.device, pred_joints.dtype)[1]
            feet = pred_joints.index_select(2, foot_joints)  # (B, T, 4, 3)
            foot_vel = (feet[:, 1:] - feet[:, :-1]) * contact[:, :-1, :, None]
            terms["foot"] = F.mse_loss(foot_vel, torch.zeros_like(foot_vel))
    terms["loss"] = sum(getattr(weights, name) * value for name, value in terms.items())
    return terms
