"""Training: the LightningModule (denoiser, diffusion, loss, optimiser, EMA) and callbacks."""

from dgsdp.training.module import DanceDiffusion, check_compatible, load_checkpoint

__all__ = ["DanceDiffusion", "check_compatible", "load_checkpoint"]
