"""Training: the LightningModule (a trained model plus loss, optimiser and EMA updates), checkpoints and callbacks."""

from dgsdp.training.module import DanceDiffusion
from dgsdp.training.optim import Adan

__all__ = ["Adan", "DanceDiffusion"]
