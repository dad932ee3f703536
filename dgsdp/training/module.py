"""The LightningModule: denoiser + diffusion + loss + optimiser + EMA, with style and normaliser state.

Everything the model needs at generation time is in its state dict as plain tensors (normaliser statistics,
style bank) and in ``hparams``, a plain dict (denoiser sizes, diffusion, conditioning, the run's resolved config).
Checkpoints therefore load with ``torch.load(..., weights_only=True)`` and without this package's classes.
"""

from __future__ import annotations

import copy
from typing import Any

import lightning as L
import torch
from torch.optim.swa_utils import AveragedModel, get_ema_multi_avg_fn

from dgsdp.diffusion import GaussianDiffusion, LossWeights, dance_loss
from dgsdp.errors import ConfigError
from dgsdp.model import DanceDenoiser
from dgsdp.motion import POSE_DIM, MinMaxNormalizer
from dgsdp.sampling import Condition, Guidance, Sampler
from dgsdp.style.embeddings import StyleBank

CHECKPOINT_FORMAT = 1
# Sections of hparams that shape the weights; a checkpoint must agree on them to load.
ARCHITECTURE_KEYS = ("model", "conditioning")


def plain(obj: Any) -> Any:
    """Recursively turn mappings/sequences (e.g. Lightning's AttributeDict) into builtin dicts and lists."""
    if isinstance(obj, dict):
        return {str(k): plain(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [plain(v) for v in obj]
    return obj


def step_seed(seed: int, step: int, rank: int = 0, world_size: int = 1) -> int:
    """The RNG seed of training step ``step`` on data-parallel rank ``rank`` of ``world_size``: distinct for every
    (step, rank) pair of a run (torch's CPU generator keeps only the low 32 bits of a seed, so the rank is
    interleaved with the step rather than put in high bits). One process: ``seed * 1_000_003 + step``."""
    return seed * 1_000_003 + step * world_size + rank


class DanceDiffusion(L.LightningModule):
    """Trains the denoiser on normalised 151-d windows; samples with the EMA weights.

    hparams: ``model`` (denoiser sizes and injection), ``conditioning`` (audio_dim, audio settings, style kind and
    dim, style bank size, music/style drop probabilities, text encoder config), ``diffusion``, ``loss``,
    ``optimizer``, ``ema`` and ``config`` (the full resolved run config, for the record).
    """

    def __init__(self, hparams: dict[str, Any]) -> None:
        super().__init__()
        self.save_hyperparameters(plain(hparams))
        cond = self.hparams["conditioning"]
        self.style_dim = int(cond.get("style_dim", 0))
        self.denoiser = DanceDenoiser(
            audio_dim=int(cond.get("audio_dim", 0)), style_dim=self.style_dim, **self.hparams["model"]
        )
        self.diffusion = GaussianDiffusion(**self.hparams.get("diffusion", {}))
        self.loss_weights = LossWeights(**self.hparams.get("loss", {}))
        self.normalizer = MinMaxNormalizer(POSE_DIM)
        bank_size = int(cond.get("style_bank_size", 0))
        self.register_buffer("style_vectors", torch.zeros(bank_size, self.style_dim))
        self.register_buffer("style_genre_index", torch.zeros(bank_size, dtype=torch.long))
        self.n_genres = int(cond.get("n_genres", 0))
        decay = float(self.hparams.get("ema", {}).get("decay", 0.9999))
        self.ema = AveragedModel(self.denoiser, multi_avg_fn=get_ema_multi_avg_fn(decay), use_buffers=True)
        self.ema.requires_grad_(False)

    # --- state -------------------------------------------------------------------------------------------
    def set_style_bank(self, bank: StyleBank | None) -> None:
        if bank is None:
            return
        if bank.vectors.shape != self.style_vectors.shape:
            raise ConfigError(
                f"style bank {tuple(bank.vectors.shape)} does not match {tuple(self.style_vectors.shape)}"
            )
        self.style_vectors.copy_(bank.vectors)
        self.style_genre_index.copy_(bank.genre_index)

    @property
    def style_bank(self) -> StyleBank | None:
        """The style bank of the ``style_vectors``/``style_genre_index`` buffers, built once and rebuilt only when
        those buffers change (new values, device or dtype), so training steps never rebuild or validate it."""
        if not self.style_dim or len(self.style_vectors) == 0:
            return None
        key = tuple((b.data_ptr(), b._version, b.device, b.dtype) for b in (self.style_vectors, self.style_genre_index))
        cached = getattr(self, "_style_bank_cache", None)
        if cached is None or cached[0] != key:
            cached = (key, StyleBank(self.style_vectors, self.style_genre_index, self.n_genres))
            self._style_bank_cache = cached
        return cached[1]

    def on_save_checkpoint(self, checkpoint: dict[str, Any]) -> None:
        checkpoint["hyper_parameters"] = plain(dict(self.hparams))
        checkpoint["dgsdp_format"] = CHECKPOINT_FORMAT
        run_ids = {}
        for logger in self.loggers:
            version = getattr(logger, "version", None)
            if isinstance(version, str | int):
                run_ids[type(logger).__name__] = str(version)
        checkpoint["logger_run_ids"] = run_ids

    # --- conditioning ------------------------------------------------------------------------------------
    def style_for(self, genre: torch.Tensor, random: bool, check: bool = True) -> torch.Tensor | None:
        """Style vectors (B, ds) for genre indices (B,): a random bank row of each genre, or the genre's mean.
        ``check=False`` skips the range checks (they read values back from the device)."""
        bank = self.style_bank
        if bank is None:
            return None
        return bank.sample(genre, check=check) if random else bank.mean_for(genre, check=check)

    def _loss(
        self, denoiser: torch.nn.Module, batch: dict[str, Any], train: bool, generator=None
    ) -> dict[str, torch.Tensor]:
        x0 = batch["motion"]
        b = x0.shape[0]
        cond = self.hparams["conditioning"]
        t = self.diffusion.sample_timesteps(b, x0.device, generator)
        noise = torch.randn(x0.shape, device=x0.device, generator=generator)
        x_t = self.diffusion.q_sample(x0, t, noise)
        # genre indices come from the dataset's vocabulary (checked when it was read): no device read-back here
        style = self.style_for(batch["genre"], random=train, check=False)
        if train:
            keep_music = torch.rand(b, device=x0.device) >= float(cond.get("music_drop_prob", 0.25))
            keep_style = torch.rand(b, device=x0.device) >= float(cond.get("style_drop_prob", 0.0))
        else:
            keep_music = keep_style = torch.ones(b, dtype=torch.bool, device=x0.device)
        pred = denoiser(x_t, t, batch.get("audio"), style, keep_music, keep_style)
        return dance_loss(pred, x0, self.normalizer, self.loss_weights)

    # --- Lightning hooks ---------------------------------------------------------------------------------
    def training_step(self, batch: dict[str, Any], batch_idx: int) -> torch.Tensor:
        terms = self._loss(self.denoiser, batch, train=True)
        self.log_dict({f"train/{k}": v for k, v in terms.items()}, prog_bar=False, batch_size=batch["motion"].shape[0])
        self.log("loss", terms["loss"], prog_bar=True, logger=False, batch_size=batch["motion"].shape[0])
        return terms["loss"]

    def on_fit_start(self) -> None:
        config = self.hparams.get("config", {})
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
        seed = int(self.hparams.get("config", {}).get("seed", 0) or 0)
        torch.manual_seed(step_seed(seed, self.global_step, self.global_rank, self.trainer.world_size))

    def optimizer_step(self, *args: Any, **kwargs: Any) -> None:
        super().optimizer_step(*args, **kwargs)
        # Right after the weights change, so a checkpoint saved at the end of this batch includes this update.
        self.ema.update_parameters(self.denoiser)

    def validation_step(self, batch: dict[str, Any], batch_idx: int) -> None:
        gen = torch.Generator(device=batch["motion"].device).manual_seed(batch_idx)
        terms = self._loss(self.ema.module, batch, train=False, generator=gen)
        self.log_dict({f"val/{k}": v for k, v in terms.items()}, batch_size=batch["motion"].shape[0])

    def configure_optimizers(self) -> torch.optim.Optimizer:
        opt = dict(self.hparams.get("optimizer", {"name": "adan", "lr": 2e-4}))
        name = opt.pop("name", "adan")
        if "betas" in opt:
            opt["betas"] = tuple(opt["betas"])
        params = self.denoiser.parameters()
        if name == "adan":
            from adan_pytorch import Adan

            return Adan(params, **opt)
        if name == "adamw":
            return torch.optim.AdamW(params, **opt)
        raise ConfigError(f"unknown optimizer {name!r}; use 'adan' or 'adamw'")

    # --- sampling ----------------------------------------------------------------------------------------
    def sampler(self, use_ema: bool = True) -> Sampler:
        denoiser = self.ema.module if use_ema else self.denoiser
        style_guidance = float(self.hparams["conditioning"].get("style_drop_prob", 0.0)) > 0
        return Sampler(denoiser, self.diffusion, style_guidance=style_guidance)

    @torch.no_grad()
    def sample_batch(
        self,
        music: torch.Tensor | None,
        style: torch.Tensor | None,
        *,
        n_frames: int,
        batch: int | None = None,
        guidance: Guidance | None = None,
        **sample_kwargs: Any,
    ) -> torch.Tensor:
        """Unnormalised 151-d motion (B, T, 151) for music (B, T, Da) and style (B, ds)."""
        b = batch or (music.shape[0] if music is not None else style.shape[0])
        x = self.sampler().sample(
            (b, n_frames, POSE_DIM),
            Condition(music, style),
            guidance=guidance,
            device=self.device,
            **sample_kwargs,
        )
        return self.normalizer.unnormalize(x)


def check_compatible(saved: dict[str, Any], current: dict[str, Any], source: str) -> None:
    """Raise one clear ConfigError if a checkpoint's architecture differs from the configured one."""
    diffs = []
    for section in ARCHITECTURE_KEYS:
        a, b = saved.get(section, {}), current.get(section, {})
        for key in sorted(set(a) | set(b)):
            if key in ("text_encoder", "audio_settings"):
                continue
            if a.get(key) != b.get(key):
                diffs.append(f"{section}.{key}: checkpoint {a.get(key)!r}, config {b.get(key)!r}")
    if diffs:
        raise ConfigError(
            f"checkpoint {source} was trained with a different model configuration:\n  "
            + "\n  ".join(diffs)
            + "\nUse the same config groups (audio, style, model, ...) as the checkpoint's run, or start a new run."
        )


def load_checkpoint(path: str, map_location: str | torch.device = "cpu") -> DanceDiffusion:
    """Rebuild a trained model from a checkpoint (plain tensors + plain-dict config), EMA weights included."""
    from pathlib import Path

    p = Path(path).expanduser()
    if not p.is_file():
        raise ConfigError(f"checkpoint {p} does not exist; train one with 'python train.py' or check the path")
    try:
        ckpt = torch.load(p, map_location=map_location, weights_only=True)
    except Exception as e:  # noqa: BLE001 - any failure here means the file is not a usable checkpoint
        raise ConfigError(f"cannot read checkpoint {p} ({type(e).__name__}: {e})") from e
    if "hyper_parameters" not in ckpt or "state_dict" not in ckpt:
        raise ConfigError(f"{p} is not a dgsdp checkpoint (no hyper_parameters/state_dict)")
    model = DanceDiffusion(copy.deepcopy(ckpt["hyper_parameters"]))
    try:
        model.load_state_dict(ckpt["state_dict"])
    except RuntimeError as e:
        raise ConfigError(f"checkpoint {p} does not match its own configuration: {e}") from e
    return model.eval()
