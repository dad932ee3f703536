"""Checkpoints written atomically: a killed run never leaves a truncated file that a resume would read.

Only Lightning's public API is used: :class:`AtomicModelCheckpoint` is Lightning's ``ModelCheckpoint`` that, when
the trainer is set up, wraps the strategy's checkpoint writer (``strategy.checkpoint_io``, a ``CheckpointIO``) in
:class:`AtomicCheckpointIO`, so every checkpoint of the run (periodic, ``last.ckpt``, ``trainer.save_checkpoint``)
is written to a temporary name in the same folder and renamed into place.
"""

from __future__ import annotations

import contextlib
import logging
import os
from pathlib import Path
from typing import Any

import lightning as L
from lightning.fabric.plugins import CheckpointIO, TorchCheckpointIO
from lightning.pytorch.callbacks import ModelCheckpoint

log = logging.getLogger(__name__)


class AtomicCheckpointIO(CheckpointIO):
    """A ``CheckpointIO`` that writes through ``inner`` to ``.<name>.tmp`` beside the target, then renames it over
    the target (``os.replace``: readers see the old file or the new one, never a partial one)."""

    def __init__(self, inner: CheckpointIO | None = None) -> None:
        self.inner = inner if inner is not None else TorchCheckpointIO()

    def save_checkpoint(self, checkpoint: dict[str, Any], path: Any, storage_options: Any | None = None) -> None:
        target = Path(path)
        tmp = target.with_name(f".{target.name}.tmp")
        try:
            self.inner.save_checkpoint(checkpoint, tmp, storage_options=storage_options)
            os.replace(tmp, target)
        finally:
            with contextlib.suppress(FileNotFoundError):
                tmp.unlink()

    def load_checkpoint(self, path: Any, *args: Any, **kwargs: Any) -> dict[str, Any]:
        return self.inner.load_checkpoint(path, *args, **kwargs)

    def remove_checkpoint(self, path: Any) -> None:
        self.inner.remove_checkpoint(path)

    def teardown(self) -> None:
        self.inner.teardown()


class AtomicModelCheckpoint(ModelCheckpoint):
    """Lightning's ModelCheckpoint whose files are written atomically (see :class:`AtomicCheckpointIO`)."""

    def setup(self, trainer: L.Trainer, pl_module: L.LightningModule, stage: str) -> None:
        super().setup(trainer, pl_module, stage)
        strategy = trainer.strategy
        current = strategy.checkpoint_io
        if isinstance(current, AtomicCheckpointIO):
            return
        if type(current) is not TorchCheckpointIO:  # e.g. an asynchronous writer: a rename could race its write
            log.warning("checkpoint writer %s kept as it is: checkpoints are not written atomically", current)
            return
        strategy.checkpoint_io = AtomicCheckpointIO(current)

    def on_train_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        """Keep the final state too: a run that stops between two periodic checkpoints (``max_steps`` not a
        multiple of ``every_n_train_steps``) writes ``last.ckpt`` at its last step."""
        if self.save_last and not self._should_skip_saving_checkpoint(trainer):
            self._save_last_checkpoint(trainer, self._monitor_candidates(trainer))
