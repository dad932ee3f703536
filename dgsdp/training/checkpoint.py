"""Checkpoints written atomically: a killed run never leaves a truncated file that a resume would read, nor a
checkpoint-sized temporary file anywhere.

Lightning's own saving goes through an fsspec transaction that first writes the whole checkpoint to a
``tempfile.mkstemp`` file in the system temp folder (left behind, up to the checkpoint's size, when the process is
killed; and the checkpoint then keeps mkstemp's ``0600`` permissions). :class:`AtomicCheckpointIO` writes next to
the target instead, through :func:`dgsdp.utils.io.atomic_path`, whose leftovers the next run removes.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import lightning as L
import torch
from lightning.fabric.plugins.io.torch_io import TorchCheckpointIO
from lightning.pytorch.callbacks import ModelCheckpoint

from dgsdp.utils.io import atomic_path, remove_stale_temps


class AtomicCheckpointIO(TorchCheckpointIO):
    """``torch.save`` to a temporary file in the checkpoint's folder, fsync, rename into place."""

    def save_checkpoint(self, checkpoint: dict[str, Any], path: Any, storage_options: Any | None = None) -> None:
        if storage_options is not None:
            raise TypeError(f"{type(self).__name__} takes no storage_options, got {storage_options!r}")
        with atomic_path(path) as tmp, open(tmp, "wb") as f:
            torch.save(checkpoint, f)
            f.flush()
            os.fsync(f.fileno())


def use_atomic_checkpoint_io(trainer: L.Trainer) -> None:
    """Make the trainer save through :class:`AtomicCheckpointIO` unless another plugin was chosen on purpose."""
    strategy = trainer.strategy
    if type(strategy.checkpoint_io) is TorchCheckpointIO:
        strategy.checkpoint_io = AtomicCheckpointIO()


class AtomicModelCheckpoint(ModelCheckpoint):
    """Lightning's ModelCheckpoint whose files appear atomically (see the module docstring)."""

    def setup(self, trainer: L.Trainer, pl_module: L.LightningModule, stage: str) -> None:
        super().setup(trainer, pl_module, stage)
        use_atomic_checkpoint_io(trainer)
        if trainer.is_global_zero:
            folders = {Path(self.dirpath)} if self.dirpath else set()
            resumed = getattr(trainer, "ckpt_path", None)
            if resumed and Path(resumed).is_file():
                folders.add(Path(resumed).parent)  # a resumed run cleans up after the killed one
            for folder in folders:
                remove_stale_temps(folder)

    def on_train_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        """Keep the final state too: a run that stops between two periodic checkpoints (``max_steps`` not a
        multiple of ``every_n_train_steps``) writes ``last.ckpt`` at its last step."""
        if self.save_last and not self._should_skip_saving_checkpoint(trainer):
            self._save_last_checkpoint(trainer, self._monitor_candidates(trainer))
