"""Gaussian diffusion (schedule and update rules) and the training loss, apart from any denoiser."""

from dgsdp.diffusion.gaussian import GaussianDiffusion, cosine_betas
from dgsdp.diffusion.losses import LossWeights, dance_loss

__all__ = ["GaussianDiffusion", "LossWeights", "cosine_betas", "dance_loss"]
