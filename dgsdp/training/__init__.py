"""Training: the run spec, the LightningModule (denoiser, diffusion, loss, optimiser, EMA) and callbacks."""

from dgsdp.training.module import DanceDiffusion, load_checkpoint, read_checkpoint
from dgsdp.training.spec import Conditioning, RunSpec

__all__ = ["Conditioning", "DanceDiffusion", "RunSpec", "load_checkpoint", "read_checkpoint"]
