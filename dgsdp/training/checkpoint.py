"""Checkpoints written atomically: a killed run never leaves a truncated file that a resume would read."""

from __future__ import annotations

import os
from pathlib import Path
from weakref import proxy

import lightning as L
from lightning.pytorch.callbacks import ModelCheckpoint


class AtomicModelCheckpoint(ModelCheckpoint):
    """Lightning's ModelCheckpoint, but each file is written to a temporary name and renamed into place."""

    def _save_checkpoint(self, trainer: L.Trainer, filepath: str) -> None:
        path = Path(filepath)
        tmp = path.with_name(f".{path.name}.tmp")
        trainer.save_checkpoint(str(tmp), self.save_weights_only)
        if trainer.is_global_zero:
            os.replace(tmp, path)
        self._last_global_step_saved = trainer.global_step
        self._last_checkpoint_saved = filepath
        if trainer.is_global_zero:
            for logger in trainer.loggers:
                logger.after_save_checkpoint(proxy(self))

    def on_train_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        """Keep the final state too: a run that stops between two periodic checkpoints (``max_steps`` not a
        multiple of ``every_n_train_steps``) writes ``last.ckpt`` at its last step."""
        if self.save_last and not self._should_skip_saving_checkpoint(trainer):
            self._save_last_checkpoint(trainer, self._monitor_candidates(trainer))
