"""A trained model, for sampling and evaluation: its run spec, weights, normaliser, floor and style bank, loaded from
a checkpoint as data (no Lightning)."""

from dgsdp.trained.model import CHECKPOINT_FORMAT, TrainedModel, check_weights, load_model, read_checkpoint
from dgsdp.trained.spec import Conditioning, RunSpec

__all__ = [
    "CHECKPOINT_FORMAT",
    "Conditioning",
    "RunSpec",
    "TrainedModel",
    "check_weights",
    "load_model",
    "read_checkpoint",
]
