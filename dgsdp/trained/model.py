"""A trained model, for sampling: the run spec, the denoiser with its EMA weights, the diffusion process, the
normaliser, the floor height and the style bank, loaded from a checkpoint and checked.

Everything the model needs at generation time is in its state dict as plain tensors (normaliser statistics,
style bank) and in its :class:`~dgsdp.trained.spec.RunSpec`, stored as plain data in ``hyper_parameters``.
Checkpoints therefore load with weights only, after a bounded scan of the file
(:func:`dgsdp.safety.checkpoint_file.load_checkpoint`), without this package's classes, and their configs are data:
parts are built only from the project's registered classes (:mod:`dgsdp.registry`), and only once their sizes
match the stored weights (:func:`check_weights`).
Training (:class:`dgsdp.training.module.DanceDiffusion`, a LightningModule) builds on this class; nothing here
imports Lightning.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import torch
from torch import nn
from torch.optim.swa_utils import AveragedModel, get_ema_multi_avg_fn

from dgsdp.audio.tempo import check_tempo_range
from dgsdp.errors import CheckpointError, ConfigError
from dgsdp.metrics.speed import SPEED_QUANTILES
from dgsdp.motion import MinMaxNormalizer, Skeleton
from dgsdp.registry import Source
from dgsdp.safety.checkpoint_file import load_checkpoint, reading
from dgsdp.sampling import Sampler
from dgsdp.style.embeddings import StyleBank
from dgsdp.style.movement import ATTRIBUTE_REACH, movement_channels
from dgsdp.trained.spec import RunSpec

CHECKPOINT_FORMAT = 2
MAX_FLOOR_M = 10.0  # a stored floor height further from z = 0 is refused as damaged data


def plain(obj: Any) -> Any:
    """Recursively turn mappings/sequences (e.g. Lightning's AttributeDict) into builtin dicts and lists."""
    if isinstance(obj, Mapping):
        return {str(k): plain(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [plain(v) for v in obj]
    return obj


class TrainedModel(nn.Module):
    """The denoiser (and its EMA copy, used for sampling), diffusion, normaliser, floor height and style bank of a
    run. spec: the run's :class:`RunSpec` (or its plain-dict form, as stored in checkpoints); ``source`` says
    whether it came from the user's config or from a checkpoint (then only registered classes are built)."""

    def __init__(self, spec: RunSpec | Mapping[str, Any], source: Source = "config") -> None:
        super().__init__()
        spec = spec if isinstance(spec, RunSpec) else RunSpec.from_dict(spec, "hyper_parameters")
        self.spec = spec
        cond = spec.conditioning
        self.style_dim = cond.style_dim
        self.denoiser = spec.build_denoiser(source)
        self.diffusion = spec.build_diffusion(source)
        self.normalizer = MinMaxNormalizer(spec.skeleton.pose_dim)
        # The training data's floor (z-up metres, dgsdp.motion.floor); checkpoints written before it existed load 0.0.
        self.register_buffer("floor_height", torch.tensor(0.0))
        self.register_load_state_dict_pre_hook(_default_floor_height)
        # The tempi (lowest, highest BPM) of the training songs (dgsdp.audio.tempo.training_tempo_range), toward
        # which generation folds a song's beats (sampling.tempo_fold); NaN: not recorded (older checkpoints).
        self.register_buffer("tempo_range_bpm", torch.full((2,), math.nan))
        self.register_load_state_dict_pre_hook(_default_tempo_range)
        self.register_buffer("style_vectors", torch.zeros(cond.style_bank_size, self.style_dim))
        self.register_buffer("style_genre_index", torch.zeros(cond.style_bank_size, dtype=torch.long))
        self.n_genres = cond.n_genres
        # a model conditioned on movement channels (model.movement_channels; model.speed_conditioning: speed) records
        # its training windows' values of each: per genre, their quantiles 0, 0.1, ..., 1 (``<channel>_quantiles``),
        # the median of all of them (``<channel>_reference``, the channel's zero) and, but for speed (encoded as a
        # log ratio to its median), their 10th-to-90th percentile spread (``<channel>_spread``, the channel's unit)
        self.movement_channels = movement_channels(spec.model.get("movement_channels"),
                                                   bool(spec.model.get("speed_conditioning", False)))  # fmt: skip
        for name in self.movement_channels:
            self.register_buffer(f"{name}_quantiles", torch.full((cond.n_genres, SPEED_QUANTILES), math.nan))
            self.register_buffer(f"{name}_reference", torch.tensor(math.nan))
            if name != "speed":
                self.register_buffer(f"{name}_spread", torch.tensor(math.nan))
        self.ema = AveragedModel(self.denoiser, multi_avg_fn=get_ema_multi_avg_fn(spec.ema_decay), use_buffers=True)
        self.ema.requires_grad_(False)

    # --- state -------------------------------------------------------------------------------------------
    def set_style_bank(self, bank: StyleBank | None) -> None:
        """Copy a style bank (one vector per style, with its genre) into the model; None keeps the current one."""
        if bank is None:
            return
        if bank.vectors.shape != self.style_vectors.shape:
            raise ConfigError(
                f"style bank {tuple(bank.vectors.shape)} does not match {tuple(self.style_vectors.shape)}"
            )
        self.style_vectors.copy_(bank.vectors)
        self.style_genre_index.copy_(bank.genre_index)
        for denoiser in (self.denoiser, self.ema.module):
            denoiser.set_style_statistics(self.style_vectors)

    @property
    def speed_conditioning(self) -> bool:
        """Whether the model takes the dance's mean joint speed as a style channel."""
        return "speed" in self.movement_channels

    def set_movement_statistics(self, quantiles: Any, reference: Any, spread: Any) -> None:
        """Store the training windows' movement values of each of the model's channels, in its channels' order:
        per genre quantiles (C, n_genres, SPEED_QUANTILES), the median of all windows (C,) and the 10th-to-90th
        percentile spread of all windows (C,; not used for speed); a no-op for a model without movement channels."""
        if not self.movement_channels:
            return
        n = len(self.movement_channels)
        quantiles = torch.as_tensor(quantiles, dtype=torch.float32)
        reference = torch.as_tensor(reference, dtype=torch.float32).reshape(-1)
        spread = torch.as_tensor(spread, dtype=torch.float32).reshape(-1)
        want = (n, self.n_genres, SPEED_QUANTILES)
        if tuple(quantiles.shape) != want or reference.shape != (n,) or spread.shape != (n,):
            raise ConfigError(
                f"movement statistics {tuple(quantiles.shape)}, {tuple(reference.shape)}, {tuple(spread.shape)} do "
                f"not match the model's channels ({', '.join(self.movement_channels)}): {want}, ({n},), ({n},)"
            )
        for k, name in enumerate(self.movement_channels):
            value, unit = float(reference[k]), float(spread[k])
            if not math.isfinite(value) or (name == "speed" and value <= 0):
                raise ConfigError(f"the training windows' median {name} must be a finite (for speed positive) number, "
                                  f"got {value}")  # fmt: skip
            if name != "speed" and not (math.isfinite(unit) and unit > 0):
                raise ConfigError(
                    f"the training windows' {name} does not vary (its 10th-to-90th percentile spread is {unit}); "
                    f"leave {name} out of model.movement_channels"
                )
            self.quantile_table(name).copy_(quantiles[k])
            getattr(self, f"{name}_reference").fill_(value)
            if name != "speed":
                getattr(self, f"{name}_spread").fill_(unit)

    def quantile_table(self, name: str) -> torch.Tensor:
        """The recorded quantiles (n_genres, SPEED_QUANTILES) of a movement channel's training windows."""
        if name not in self.movement_channels:
            raise ConfigError(f"this model takes no {name} channel (its channels: {self.movement_channels or 'none'})")
        return getattr(self, f"{name}_quantiles")

    def genre_movement(self, genre: torch.Tensor, quantile: float | torch.Tensor = 0.5) -> torch.Tensor:
        """Movement values (B, C) at ``quantile`` (0-1; scalar, (B,) or (B, C)) of each genre's training windows,
        linear between the recorded quantiles; the median of all windows for a genre the training data lacks."""
        q = torch.as_tensor(quantile, dtype=torch.float32, device=genre.device)
        q = (q[:, None] if q.ndim == 1 else q).expand(*genre.shape, len(self.movement_channels))
        columns = [self._at_quantile(name, genre, q[..., k]) for k, name in enumerate(self.movement_channels)]
        return torch.stack(columns, dim=-1)

    def asked_movement(self, genre: torch.Tensor, scores: torch.Tensor) -> torch.Tensor:
        """Movement values (B, C) a reading's scores (B, C) or (C,), -1 to +1 in the model's channels' order (speed:
        the energy; not finite: 0), ask of each genre (B,): the genre's quantile the score asks
        (:func:`~dgsdp.style.reading.speed_quantile`); for the attributes but speed, at least ``ATTRIBUTE_REACH`` x
        |score| of all windows' spread from the genre's median, toward the score's sign, and within the lowest and
        highest value of any genre's windows."""
        from dgsdp.style.reading import speed_quantile  # the reader's scale (the reader does not import the model)

        scores = torch.as_tensor(scores, dtype=torch.float32, device=genre.device)
        scores = scores.nan_to_num(0.0, posinf=0.0, neginf=0.0).clamp(-1, 1)
        scores = scores.expand(*genre.shape, len(self.movement_channels))
        values = self.genre_movement(genre, speed_quantile(scores))
        medians = self.genre_movement(genre, 0.5)
        for k, name in enumerate(self.movement_channels):
            if name == "speed":
                continue
            score, table = scores[..., k], self.quantile_table(name).to(values)
            reach = ATTRIBUTE_REACH * score.abs() * getattr(self, f"{name}_spread").to(values)
            shift = torch.sign(score) * torch.maximum((values[..., k] - medians[..., k]).abs(), reach)
            low, high = table[:, 0].nan_to_num(math.inf).min(), table[:, -1].nan_to_num(-math.inf).max()
            values[..., k] = torch.minimum(torch.maximum(medians[..., k] + shift, low), high)
        return values

    def _at_quantile(self, name: str, genre: torch.Tensor, quantile: torch.Tensor) -> torch.Tensor:
        table = self.quantile_table(name).to(genre.device)
        position = quantile.to(table.dtype).clamp(0, 1) * (table.shape[1] - 1)
        position = position.expand(genre.shape)
        lo = position.floor().long().clamp(max=table.shape[1] - 2)
        w = position - lo
        rows = table[genre]
        value = rows.gather(1, lo[:, None])[:, 0] * (1 - w) + rows.gather(1, (lo + 1)[:, None])[:, 0] * w
        reference = getattr(self, f"{name}_reference").to(value)
        return torch.where(torch.isfinite(value), value, reference)

    def genre_speed(self, genre: torch.Tensor, quantile: float | torch.Tensor = 0.5) -> torch.Tensor:
        """The speed (m/s, (B,)) at ``quantile`` (scalar or (B,)) of each genre's training windows
        (:meth:`genre_movement`'s speed column)."""
        q = torch.as_tensor(quantile, dtype=torch.float32, device=genre.device)
        return self._at_quantile("speed", genre, q)

    def movement_encoding(self, values: torch.Tensor) -> torch.Tensor:
        """The style vector's movement channels (..., C) for measured values (..., C) in the model's channels'
        order: speed as log2 of its ratio to the training windows' median (one unit: twice or half as fast); the
        others as their distance from the training windows' median in 10th-to-90th percentile spreads."""
        columns = []
        for k, name in enumerate(self.movement_channels):
            value = values[..., k].float()
            reference = getattr(self, f"{name}_reference").to(value.device, torch.float32)
            if name == "speed":
                columns.append(torch.log2(value.clamp_min(1e-3) / reference))
            else:
                spread = getattr(self, f"{name}_spread").to(value.device, torch.float32)
                columns.append((value - reference) / spread)
        return torch.stack(columns, dim=-1)

    def with_movement(self, style: torch.Tensor, values: torch.Tensor) -> torch.Tensor:
        """Style vectors (B, ds) or (ds,) with their movement channels appended, for movement values (B, C) or (C,)
        in the model's channels' order (:meth:`movement_encoding`)."""
        return torch.cat((style, self.movement_encoding(values).to(style.dtype)), dim=-1)

    def set_floor_height(self, metres: float) -> None:
        """Store the floor height of the training data (z-up metres, see dgsdp.motion.floor)."""
        self.floor_height.fill_(check_floor_height(metres, "the floor height"))

    def set_tempo_range(self, bpm: tuple[float, float] | None) -> None:
        """Store the training songs' tempo range (lowest, highest BPM); None: unknown."""
        self.tempo_range_bpm.copy_(torch.tensor(check_tempo_range(bpm, "the tempo range"), dtype=torch.float32))

    @property
    def tempo_range(self) -> tuple[float, float] | None:
        """The training songs' tempo range (lowest, highest BPM), or None where the checkpoint recorded none."""
        lo, hi = (float(v) for v in self.tempo_range_bpm)
        return None if math.isnan(lo) or math.isnan(hi) else (lo, hi)

    @property
    def skeleton(self) -> Skeleton:
        """The skeleton of the run's motion (its pose vectors have ``skeleton.pose_dim`` channels)."""
        return self.spec.skeleton

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

    # --- conditioning ------------------------------------------------------------------------------------
    def style_for(
        self, genre: torch.Tensor, random: bool, check: bool = True, movement: torch.Tensor | None = None
    ) -> torch.Tensor | None:
        """Style vectors (B, ds) for genre indices (B,): a random bank row of each genre, or the genre's mean; for a
        model with movement channels (B, ds + C), with the channels of ``movement`` (B, C) (the training windows'
        measured values; default: each genre's medians). ``check=False`` skips the range checks (they read values
        back from the device)."""
        bank = self.style_bank
        if bank is None:
            return None
        style = bank.sample(genre, check=check) if random else bank.mean_for(genre, check=check)
        if not self.movement_channels:
            return style
        values = self.genre_movement(genre) if movement is None else movement.to(style.device)
        return self.with_movement(style, values)

    # --- sampling ----------------------------------------------------------------------------------------
    def sampler(self, use_ema: bool = True) -> Sampler:
        """A :class:`~dgsdp.sampling.Sampler` over the EMA weights (``use_ema=False``: the trained weights)."""
        denoiser = self.ema.module if use_ema else self.denoiser
        return Sampler(denoiser, self.diffusion, style_guidance=self.spec.conditioning.style_guidance)


def check_floor_height(value: Any, where: str) -> float:
    """A floor height as a float, or a ConfigError: a finite number within MAX_FLOOR_M of zero."""
    if torch.is_tensor(value):
        if value.numel() != 1 or not value.is_floating_point():
            raise ConfigError(f"{where} must be one number, got a {value.dtype} tensor of shape {tuple(value.shape)}")
        value = value.item()
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ConfigError(f"{where} must be a finite number of metres, got {value!r}")
    if abs(value) > MAX_FLOOR_M:
        raise ConfigError(f"{where} is {value} m; a floor more than {MAX_FLOOR_M:g} m from z = 0 is not a dance floor")
    return float(value)


def _default_tempo_range(module: torch.nn.Module, state: dict[str, Any], prefix: str, *args: Any) -> None:
    """Checkpoints written before the training tempo range was stored load with none (NaN)."""
    key = prefix + "tempo_range_bpm"
    if key not in state and isinstance(module, TrainedModel):
        state[key] = torch.full((2,), math.nan)


def _default_floor_height(module: torch.nn.Module, state: dict[str, Any], prefix: str, *args: Any) -> None:
    """Checkpoints written before the floor height was stored load with the model's current one (0.0 when new)."""
    key = prefix + "floor_height"
    if key not in state and isinstance(module, TrainedModel):
        state[key] = module.floor_height.detach().clone()


def read_checkpoint(path: str | Path, map_location: str | torch.device = "cpu") -> dict[str, Any]:
    """A checkpoint file as plain data (tensors and builtins only), or one clear CheckpointError."""
    p = Path(path).expanduser()
    ckpt = load_checkpoint(
        p, what="checkpoint", map_location=map_location,
        hint="Use a checkpoint written by 'python train.py' or by the EDGE import.",
    )  # fmt: skip
    if not isinstance(ckpt, dict) or "hyper_parameters" not in ckpt or "state_dict" not in ckpt:
        raise CheckpointError(f"{p} is not a dgsdp checkpoint (no hyper_parameters/state_dict)")
    return ckpt


def check_weights(spec: RunSpec, state: Any, source: str) -> None:
    """Refuse a checkpoint whose stored config does not describe its stored weights, before any model is built:
    the model is laid out on the meta device (no memory) and each weight's shape compared with the file's. A
    config asking for a far larger model than its weights (a 2 MB file with d_model=8192) stops here, not after
    allocating that model."""
    if not isinstance(state, Mapping) or not all(isinstance(k, str) and torch.is_tensor(v) for k, v in state.items()):
        raise CheckpointError(f"checkpoint {source}: state_dict must map names to tensors")
    with torch.device("meta"):
        layout = TrainedModel(spec, source="checkpoint").state_dict()
    optional = ("floor_height", "tempo_range_bpm")  # older checkpoints lack them; they load defaults
    missing = [k for k in layout if k not in state and k not in optional]
    wrong = [
        f"{k} {tuple(v.shape)} (the file holds {tuple(state[k].shape)})"
        for k, v in layout.items()
        if k in state and state[k].shape != v.shape
    ]
    if missing or wrong:
        what = [f"weights the file does not hold: {', '.join(missing[:5])}"] if missing else []
        what += [f"other shapes: {', '.join(wrong[:5])}"] if wrong else []
        raise CheckpointError(
            f"checkpoint {source} does not match its own configuration, which asks for {'; '.join(what)}"
            + (f" ({len(missing) + len(wrong)} weights in all)" if len(missing) + len(wrong) > 5 else "")
            + ". The file is damaged or not a dgsdp checkpoint; nothing was built"
        )


def load_model(path: str | Path, map_location: str | torch.device = "cpu") -> TrainedModel:
    """Rebuild a trained model from a checkpoint (plain tensors + its run spec as data), EMA weights included.

    Every check runs before the model is built (sizes against the weights: :func:`check_weights`), and anything a
    malformed file makes them raise is one CheckpointError."""
    ckpt = read_checkpoint(path, map_location)
    source = str(Path(path).expanduser())
    with reading(source):
        spec = RunSpec.from_checkpoint(ckpt, source)
        state = ckpt["state_dict"]
        check_weights(spec, state, source)
        if "floor_height" in state:
            try:
                check_floor_height(state["floor_height"], "its floor_height")
            except ConfigError as e:
                raise CheckpointError(f"checkpoint {source}: {e}; the file is damaged or not a dgsdp checkpoint") from e
        if "tempo_range_bpm" in state and tuple(state["tempo_range_bpm"].shape) == (2,):  # others: load_state_dict
            try:
                check_tempo_range(state["tempo_range_bpm"], "its tempo_range_bpm")
            except ConfigError as e:
                raise CheckpointError(f"checkpoint {source}: {e}; the file is damaged or not a dgsdp checkpoint") from e
        model = TrainedModel(spec, source="checkpoint")
        try:
            model.load_state_dict(state)
        except RuntimeError as e:
            raise CheckpointError(f"checkpoint {source} does not match its own configuration: {e}") from e
        expected = model.state_dict()  # after loading: a shape mismatch is reported first, by load_state_dict
        for name, value in state.items():
            want = expected.get(name)
            if (
                want is not None
                and value.dtype != want.dtype
                and not (value.is_floating_point() and want.is_floating_point())
            ):
                raise CheckpointError(
                    f"checkpoint {source}: {name} is {value.dtype}, the model needs {want.dtype}; the file is damaged "
                    "or not a dgsdp checkpoint"
                )
    return model.eval()
