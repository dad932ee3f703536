"""Training: the LightningModule (a trained model plus loss, optimiser and EMA updates), checkpoints and callbacks."""

from dgsdp.training.module import DanceDiffusion

__all__ = ["DanceDiffusion"]
