"""Checks on a checkpoint before a run resumes from it."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from dgsdp.errors import ConfigError

DEFAULT_MAX_EPOCHS = 1000  # Lightning's max_epochs when neither max_epochs nor max_steps is set


def epochs_done(ckpt: Mapping[str, Any]) -> int:
    """Training epochs a checkpoint has finished (Lightning's ``epoch_progress.current.processed``)."""
    try:
        return int(ckpt["loops"]["fit_loop"]["epoch_progress"]["current"]["processed"])
    except (KeyError, TypeError):
        return int(ckpt.get("epoch", 0))


def check_resume_has_work(trainer_cfg: Mapping[str, Any], ckpt: Mapping[str, Any]) -> None:
    """Raise a ConfigError if resuming ``ckpt`` under ``trainer_cfg`` would train nothing (Lightning would exit
    at once, silently), saying which limit is reached and how to train on."""
    step = int(ckpt.get("global_step", 0))
    max_steps = trainer_cfg.get("max_steps")
    max_steps = -1 if max_steps is None else int(max_steps)
    max_epochs = trainer_cfg.get("max_epochs")
    if max_epochs is None:
        max_epochs = DEFAULT_MAX_EPOCHS if max_steps == -1 else -1
    max_epochs = int(max_epochs)
    if max_steps != -1 and step >= max_steps:
        raise ConfigError(
            f"nothing to do: the checkpoint is at step {step} and trainer.max_steps={max_steps}; raise "
            f"trainer.max_steps (e.g. trainer.max_steps={step + max(max_steps, 1)}) to train on"
        )
    done = epochs_done(ckpt)
    if max_epochs != -1 and done >= max_epochs:
        raise ConfigError(
            f"nothing to do: the checkpoint has finished {done} epochs and trainer.max_epochs={max_epochs}; raise "
            f"trainer.max_epochs (e.g. trainer.max_epochs={done + max(max_epochs, 1)}) to train on"
        )
