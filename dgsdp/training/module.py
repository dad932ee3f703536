"""The LightningModule: a :class:`~dgsdp.trained.TrainedModel` (denoiser, EMA, diffusion, normaliser, floor, style
bank) with the loss, the optimiser, the EMA update and the checkpoint record added for training."""

from __future__ import annotations

import time
from collections.abc import Mapping
from typing import Any

import lightning as L
import torch

from dgsdp.diffusion import dance_loss
from dgsdp.errors import ConfigError
from dgsdp.registry import Source
from dgsdp.trained.model import CHECKPOINT_FORMAT, TrainedModel, plain
from dgsdp.trained.spec import RunSpec
from dgsdp.training.lr_schedule import LRSchedule
from dgsdp.training.optim import ema_steps, ema_update


def step_seed(seed: int, step: int, rank: int = 0, world_size: int = 1) -> int:
    """The RNG seed of training step ``step`` on data-parallel rank ``rank`` of ``world_size``: distinct for every
    (step, rank) pair of a run (torch's CPU generator keeps only the low 32 bits of a seed, so the rank is
    interleaved with the step rather than put in high bits). One process: ``seed * 1_000_003 + step``."""
    return seed * 1_000_003 + step * world_size + rank


def _progress_every(trainer: L.Trainer | None) -> int:
    """Every how many training steps the progress bar's loss is refreshed: the trainer's ``log_every_n_steps``
    (every step without a trainer)."""
    return max(1, int(getattr(trainer, "log_every_n_steps", 1) or 1))


class DanceDiffusion(TrainedModel, L.LightningModule):
    """Trains the denoiser on normalised windows of pose vectors; samples with the EMA weights (see
    :class:`TrainedModel`)."""

    def __init__(self, spec: RunSpec | Mapping[str, Any], source: Source = "config") -> None:
        super().__init__(spec, source)
        self.save_hyperparameters(plain(self.spec.to_dict()))
        self.loss_weights = self.spec.build_loss(source)
        self._ema_first: bool | None = None  # whether the next EMA update is its first (read once from the EMA)
        self._train_seconds_before = 0.0  # training time of the run before a resume
        self._train_started: float | None = None

    def train_seconds(self) -> float:
        """Wall-clock seconds this run has trained so far (validation and checkpoints included; a resumed run adds its
        earlier time), which checkpoints record as ``train_seconds``: what a quality curve is drawn against."""
        now = 0.0 if self._train_started is None else time.perf_counter() - self._train_started
        return self._train_seconds_before + now

    def on_train_start(self) -> None:
        self._train_started = time.perf_counter()

    def on_load_checkpoint(self, checkpoint: dict[str, Any]) -> None:
        seconds = checkpoint.get("train_seconds")
        self._train_seconds_before = float(seconds) if isinstance(seconds, int | float) and seconds >= 0 else 0.0

    def on_save_checkpoint(self, checkpoint: dict[str, Any]) -> None:
        checkpoint["hyper_parameters"] = plain(dict(self.hparams))
        checkpoint["dgsdp_format"] = CHECKPOINT_FORMAT
        run_ids = {}
        for logger in self.loggers:
            version = getattr(logger, "version", None)
            if isinstance(version, str | int):
                run_ids[type(logger).__name__] = str(version)
        checkpoint["logger_run_ids"] = run_ids
        checkpoint["train_seconds"] = self.train_seconds()

    def _noised(
        self, batch: dict[str, Any], train: bool, generator=None
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
        """A random diffusion step t (B,) of each training window, the window noised to it, and its style."""
        x0 = batch["motion"]
        t = self.diffusion.sample_timesteps(x0.shape[0], x0.device, generator)
        noise = torch.randn(x0.shape, device=x0.device, generator=generator)
        # genre indices come from the dataset's vocabulary (checked when it was read): no device read-back here
        style = self.style_for(batch["genre"], random=train, check=False, movement=batch.get("movement"))
        return t, self.diffusion.q_sample(x0, t, noise), style

    def _loss(
        self, denoiser: torch.nn.Module, batch: dict[str, Any], train: bool, generator=None
    ) -> dict[str, torch.Tensor]:
        x0 = batch["motion"]
        b = x0.shape[0]
        cond = self.spec.conditioning
        t, x_t, style = self._noised(batch, train, generator)
        if train:
            keep_music = torch.rand(b, device=x0.device) >= cond.music_drop_prob
            keep_style = torch.rand(b, device=x0.device) >= cond.style_drop_prob
        else:
            keep_music = keep_style = torch.ones(b, dtype=torch.bool, device=x0.device)
        pred = denoiser(x_t, t, batch.get("audio"), style, keep_music, keep_style)
        return dance_loss(pred, x0, self.normalizer, self.loss_weights, self.skeleton)

    # --- Lightning hooks ---------------------------------------------------------------------------------
    def training_step(self, batch: dict[str, Any], batch_idx: int) -> torch.Tensor:
        terms = self._loss(self.denoiser, batch, train=True)
        size = batch["motion"].shape[0]
        self.log_dict({f"train/{k}": v for k, v in terms.items()}, prog_bar=False, batch_size=size)
        # Lightning turns every value shown in the progress bar into a number after every batch, which on a GPU waits
        # for the device each step. The bar's loss is a host copy instead, taken once every log_every_n_steps steps
        # and at the start of each epoch; in between the bar keeps the last one. (The train/ terms reach the logger
        # every log_every_n_steps steps.)
        if batch_idx == 0 or self.global_step % _progress_every(self._trainer) == 0:
            self.log("loss", terms["loss"].detach().cpu(), prog_bar=True, logger=False, batch_size=size)
        return terms["loss"]

    def on_fit_start(self) -> None:
        config = self.spec.record
        if self.device.type == "cuda":  # "high": float32 matmuls on TF32 tensor cores
            torch.set_float32_matmul_precision(str(config.get("matmul_precision") or "high"))
        if config.get("compile") and not getattr(self, "_compiled", False):
            self.denoiser.compile()  # in place: parameter names (and checkpoints) unchanged
            self._compiled = True
        _ = self.style_bank  # built once here (on the training device), not in the first training step

    def on_train_batch_start(self, batch: Any, batch_idx: int) -> None:
        # The randomness of a step (timesteps, noise, condition dropout, dropout) depends only on (seed, step,
        # rank): a run resumed from a checkpoint continues exactly as an uninterrupted one would, and each rank of
        # a data-parallel run draws its own noise, timesteps and dropout masks (see step_seed).
        torch.manual_seed(step_seed(self.spec.seed, self.global_step, self.global_rank, self.trainer.world_size))

    def optimizer_step(self, *args: Any, **kwargs: Any) -> None:
        super().optimizer_step(*args, **kwargs)
        # Right after the weights change, so a checkpoint saved at the end of this batch includes this update. Whether
        # it is the EMA's first update is read from the device once (a fresh or a resumed run), not every step.
        if self._ema_first is None:
            self._ema_first = ema_steps(self.ema) == 0
        ema_update(self.ema, self.denoiser, self.spec.ema_decay, first=self._ema_first)
        self._ema_first = False

    def validation_step(self, batch: dict[str, Any], batch_idx: int) -> None:
        gen = torch.Generator(device=batch["motion"].device).manual_seed(batch_idx)
        terms = self._loss(self.ema.module, batch, train=False, generator=gen)
        self.log_dict({f"val/{k}": v for k, v in terms.items()}, batch_size=batch["motion"].shape[0])

    def configure_optimizers(self) -> Any:
        """The run's optimiser, with a per-step learning-rate scheduler when ``optimizer.schedule`` asks for one
        (:mod:`dgsdp.training.lr_schedule`; it spans ``trainer.max_steps``)."""
        optimizer = self.spec.build_optimizer(self._parameter_groups())
        schedule = LRSchedule.from_config(self.spec.optimizer.get("schedule"))
        if schedule.constant:
            return optimizer
        total = self.trainer.max_steps if self._trainer is not None else None
        scheduler = schedule.scheduler(optimizer, total)
        return {"optimizer": optimizer, "lr_scheduler": {"scheduler": scheduler, "interval": "step", "frequency": 1}}

    def _parameter_groups(self) -> Any:
        """The denoiser's parameters, or with ``optimizer.style_lr_scale`` two groups: the style's ways in at that
        multiple of the learning rate, the rest at it. An optimiser's step moves each weight by about the learning
        rate whatever its gradient's size, so a projection of small inputs (a text embedding's channels are about
        0.05 each) changes its output far less per step than the layers around it; the scale makes up for it."""
        scale = style_lr_scale(self.spec.optimizer)
        if scale == 1.0:
            return self.denoiser.parameters()
        style = self.denoiser.style_parameters()
        if not style:
            raise ConfigError("optimizer.style_lr_scale needs a model with style (style=none has no style to train)")
        ids = {id(p) for p in style}
        rest = [p for p in self.denoiser.parameters() if id(p) not in ids]
        return [{"params": rest}, {"params": style, "lr": float(self.spec.optimizer["lr"]) * scale}]


def style_lr_scale(optimizer: Mapping[str, Any]) -> float:
    """``optimizer.style_lr_scale`` (default 1): a positive number, else a ConfigError."""
    value = optimizer.get("style_lr_scale", 1.0)
    value = 1.0 if value is None else value
    if isinstance(value, bool) or not isinstance(value, int | float) or not (0 < float(value) < 1e4):
        raise ConfigError(f"optimizer.style_lr_scale must be a positive number (1: the model's rate), got {value!r}")
    return float(value)


def wandb_run_id(checkpoint: Mapping[str, Any]) -> str | None:
    """The wandb run id a checkpoint's run logged to (to continue that run), if it is a plain id."""
    import re

    run_id = (checkpoint.get("logger_run_ids") or {}).get("WandbLogger")
    if isinstance(run_id, str) and re.fullmatch(r"[A-Za-z0-9_-]{1,64}", run_id):
        return run_id
    return None  # absent, or not an id (the file is data: never used as a path or an override)
