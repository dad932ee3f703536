"""The run spec: everything that defines a trained run, as one typed object.

A :class:`RunSpec` is made from a composed run config (:meth:`RunSpec.from_config`, at the start of training) or
from the record stored in a checkpoint (:meth:`RunSpec.from_checkpoint`, when generating, evaluating or resuming).
It holds the buildable parts as ``_target_`` configs (denoiser, diffusion, loss, optimiser, audio encoder, style
embedder), the motion's skeleton (:class:`~dgsdp.motion.Skeleton`, stored as plain data: names, parents, offsets; a
checkpoint without one is SMPL-24's, as every run before skeletons were data), the sizes the weights depend on (audio
and style dims, style bank size, genres), condition dropout for guidance, the EMA decay, the frame rate and window, the
seed, and a plain copy of the whole run config for the record. The defaults of all of these live in the config files
(``dgsdp/conf``); the spec has none of its own, so an old checkpoint that lacks a field fails with a message naming it.

Everything read from a checkpoint is data: parts are built through :func:`dgsdp.registry.build` with
``source="checkpoint"`` (the project's registered classes only), and the write locations of the stored configs
(``cache_dir`` anywhere, ``device``) are replaced by the caller's.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from dgsdp.errors import CheckpointError, ConfigError
from dgsdp.motion.skeleton import SMPL24, Skeleton
from dgsdp.registry import Kind, Source, build, check_plain, resolve

SPEC_FORMAT = 2
# Stored-config keys that name where to write or which device to use: never taken from a checkpoint.
LOCAL_KEYS = ("cache_dir", "device")
# Denoiser settings that change no weight shape: a run may resume with other values.
SHAPE_FREE_MODEL_KEYS = ("dropout", "gradient_checkpointing")
# The largest sizes a run may ask for (the papers' model: d_model 512, 8 layers, 8 heads, feed-forward 1024, 150
# frames, 1000 diffusion steps, Jukebox's 4800-d features), so that a stored config cannot make a model or schedule
# of unbounded size; any other integer setting of the model or diffusion is bounded by MAX_OTHER_SETTING.
MAX_SIZES = {
    "d_model": 8192, "n_layers": 128, "n_heads": 256, "ff_dim": 65536, "seq_len": 36_000, "music_encoder_layers": 128,
    "num_steps": 100_000, "audio_dim": 16384, "style_dim": 8192, "style_bank_size": 100_000, "n_genres": 10_000,
}  # fmt: skip
MAX_OTHER_SETTING = 100_000
# The buildable parts of a run and the registry kind each must be.
PART_KINDS: dict[str, Kind] = {
    "model": "model", "diffusion": "diffusion", "loss": "loss", "optimizer": "optimizer", "audio": "audio",
    "style": "style",
}  # fmt: skip


@dataclass(frozen=True)
class Conditioning:
    """What the denoiser is conditioned on and how often each condition is dropped in training."""

    audio_dim: int  # 0: no music
    style_kind: str  # none | onehot | genre | prompt
    style_dim: int  # 0: no style
    style_bank_size: int  # rows of the stored style bank (prompts or genres)
    n_genres: int
    music_drop_prob: float
    style_drop_prob: float

    def __post_init__(self) -> None:
        for name in ("audio_dim", "style_dim", "style_bank_size", "n_genres"):
            if getattr(self, name) < 0:
                raise ConfigError(f"conditioning.{name} must be >= 0, got {getattr(self, name)}")
            check_size(f"conditioning.{name}", getattr(self, name))
        for name in ("music_drop_prob", "style_drop_prob"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ConfigError(f"{name} must lie in [0, 1], got {getattr(self, name)}")

    @property
    def style_guidance(self) -> bool:
        """Whether the model learned an unconditional style (so style guidance means something)."""
        return self.style_drop_prob > 0


@dataclass(frozen=True)
class RunSpec:
    """A trained run's definition (see the module docstring). Build parts with the ``build_*`` methods."""

    model: dict[str, Any]  # DanceDenoiser config: _target_, sizes, style injection
    diffusion: dict[str, Any]  # GaussianDiffusion config
    loss: dict[str, Any]  # LossWeights config
    optimizer: dict[str, Any]  # optimiser config (_partial_)
    audio: dict[str, Any] | None  # audio encoder config; None without music
    style: dict[str, Any] | None  # StyleEmbedder config (kind, vocab, text encoder, prompts); None without style
    conditioning: Conditioning
    ema_decay: float
    fps: int
    window_frames: int
    seed: int
    groups: dict[str, str] = field(default_factory=dict)  # config group choices, for dashboards and reports
    record: dict[str, Any] = field(default_factory=dict)  # the whole resolved run config, data only
    skeleton: Skeleton = SMPL24  # the motion's skeleton: the pose vector has skeleton.pose_dim channels

    def __post_init__(self) -> None:
        if self.diffusion.get("_target_") == "dgsdp.diffusion.GaussianDiffusion":
            for key, value in (("timesteps", "uniform"), ("timestep_mean", 0.0), ("timestep_std", 1.0)):
                self.diffusion.setdefault(key, value)  # runs from before this was a setting drew them uniformly
        if not 0.0 <= self.ema_decay < 1.0:
            raise ConfigError(f"ema_decay must lie in [0, 1), got {self.ema_decay}")
        if self.fps <= 0 or self.window_frames <= 0:
            raise ConfigError(f"fps and window frames must be positive, got {self.fps} and {self.window_frames}")
        seq_len = int(self.model.get("seq_len", 0))
        if self.window_frames > seq_len:
            raise ConfigError(
                f"data windows of {self.window_frames} frames are longer than model.seq_len={seq_len}; "
                "raise model.seq_len or shorten data.window_seconds"
            )
        for key in ("d_model", "n_layers", "n_heads", "ff_dim", "seq_len"):
            value = self.model.get(key)
            if value is not None and (not isinstance(value, int) or value <= 0):
                raise ConfigError(f"model.{key} must be a positive integer, got {value!r}")
        for section in ("model", "diffusion"):
            for key, value in (getattr(self, section) or {}).items():
                check_size(f"{section}.{key}", value)
        if self.model.get("d_model") and self.model.get("n_heads") and self.model["d_model"] % self.model["n_heads"]:
            raise ConfigError(
                f"model.d_model={self.model['d_model']} must be a multiple of model.n_heads={self.model['n_heads']}"
            )

    # --- building ------------------------------------------------------------------------------------------
    def build_denoiser(self, source: Source = "config") -> Any:
        c = self.conditioning
        return build(
            self.model, "model", where="model", source=source, audio_dim=c.audio_dim, style_dim=c.style_dim,
            pose_dim=self.skeleton.pose_dim,
        )  # fmt: skip

    def build_diffusion(self, source: Source = "config") -> Any:
        return build(self.diffusion, "diffusion", where="diffusion", source=source)

    def build_loss(self, source: Source = "config") -> Any:
        return build(self.loss, "loss", where="loss", source=source)

    def build_optimizer(self, params: Any) -> Any:
        # the learning rate's schedule and the style's rate are the training module's, not the optimiser's
        node = {k: v for k, v in self.optimizer.items() if k not in ("schedule", "style_lr_scale")}
        factory = build(node, "optimizer", where="optimizer")
        return factory(params)

    def build_audio_encoder(self, source: Source = "config", *, device: str | None = None) -> Any:
        """The run's audio encoder, or None for a model without music."""
        if not self.conditioning.audio_dim:
            return None
        if not self.audio:
            raise CheckpointError("the run does not say which audio encoder it was trained with (audio config)")
        extra = {"device": device} if device is not None and "device" in self.audio else {}
        encoder = build(self.audio, "audio", where="audio", source=source, **extra)
        if encoder.output_dim != self.conditioning.audio_dim:
            raise CheckpointError(
                f"the run's audio encoder gives {encoder.output_dim}-d features, but the model was trained on "
                f"{self.conditioning.audio_dim}-d features"
            )
        return encoder

    def build_style_embedder(self, source: Source = "config", *, cache_dir: str | None = None) -> Any:
        """The run's StyleEmbedder (genre vocabulary, text encoder for free text), or None without style."""
        if not self.style:
            return None
        return build(self.style, "style", where="style", source=source, cache_dir=cache_dir)

    # --- (de)serialisation ---------------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """Plain data for a checkpoint (loads with ``torch.load(weights_only=True)``)."""
        out = dataclasses.asdict(self)
        out["skeleton"] = self.skeleton.to_dict()
        out["format"] = SPEC_FORMAT
        return out

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], source: str = "checkpoint") -> RunSpec:
        """The spec stored by :meth:`to_dict` (or by this project's first checkpoint format); a missing or
        malformed field raises a CheckpointError naming it."""
        if not isinstance(data, Mapping):
            raise CheckpointError(f"{source}: the stored run spec is a {type(data).__name__}, not a mapping")
        check_plain(data, "hyper_parameters", "checkpoint")
        data = dict(data)
        if data.get("format") != SPEC_FORMAT:
            data = _upgrade_format1(data, source)

        def need(mapping: Mapping[str, Any], key: str, kind: type | tuple[type, ...], where: str) -> Any:
            if key not in mapping:
                raise CheckpointError(f"{source}: the stored run spec has no field {where}{key}")
            value = mapping[key]
            if kind is float and isinstance(value, int) and not isinstance(value, bool):
                value = float(value)
            if not isinstance(value, kind) or (kind is int and isinstance(value, bool)):
                raise CheckpointError(
                    f"{source}: field {where}{key} is {value!r} ({type(value).__name__}); expected {_kind_name(kind)}"
                )
            return value

        for section, kind in PART_KINDS.items():  # refuse a foreign class before looking at anything else
            node = data.get(section)
            if isinstance(node, Mapping) and "_target_" in node:
                resolve(kind, node["_target_"], section, "checkpoint")
        cond = need(data, "conditioning", dict, "")
        try:
            stored_skeleton = data.get("skeleton")  # absent: a run from before skeletons were data, SMPL-24
            skeleton = SMPL24 if stored_skeleton is None else Skeleton.from_dict(stored_skeleton, "skeleton")
            conditioning = Conditioning(
                **{
                    f.name: need(cond, f.name, _field_type(f), "conditioning.")
                    for f in dataclasses.fields(Conditioning)
                }
            )
            return cls(
                model=need(data, "model", dict, ""),
                diffusion=need(data, "diffusion", dict, ""),
                loss=need(data, "loss", dict, ""),
                optimizer=need(data, "optimizer", dict, ""),
                audio=_local(need(data, "audio", (dict, type(None)), "")),
                style=_local(need(data, "style", (dict, type(None)), "")),
                conditioning=conditioning,
                ema_decay=need(data, "ema_decay", float, ""),
                fps=need(data, "fps", int, ""),
                window_frames=need(data, "window_frames", int, ""),
                seed=need(data, "seed", int, ""),
                groups={str(k): str(v) for k, v in (data.get("groups") or {}).items()},
                record=dict(data.get("record") or {}),
                skeleton=skeleton,
            )
        except ConfigError as e:
            if isinstance(e, CheckpointError):
                raise
            raise CheckpointError(f"{source}: {e}") from e

    @classmethod
    def from_checkpoint(cls, checkpoint: Mapping[str, Any], source: str) -> RunSpec:
        """The spec of a checkpoint dict loaded with ``torch.load(weights_only=True)``."""
        if not isinstance(checkpoint, Mapping) or "hyper_parameters" not in checkpoint:
            raise CheckpointError(f"{source} is not a dgsdp checkpoint (it has no hyper_parameters)")
        return cls.from_dict(checkpoint["hyper_parameters"], source)

    @classmethod
    def from_config(
        cls,
        cfg: Any,
        *,
        audio_encoder: Any,
        style_embedder: Any,
        style_bank_size: int,
        groups: Mapping[str, str],
        skeleton: Skeleton = SMPL24,
    ) -> RunSpec:
        """The spec of a composed run config (``conf/train.yaml``), with the built audio encoder and style
        embedder (their sizes decide the denoiser's input sizes) and the data's skeleton (its pose size, the
        denoiser's input and output size)."""
        from omegaconf import OmegaConf

        def node(key: str) -> Any:
            value = cfg.get(key)
            return None if value is None else OmegaConf.to_container(value, resolve=True)

        model = node("model")
        if not isinstance(model, dict) or "_target_" not in model:
            raise ConfigError("the model config needs a _target_ (see dgsdp/conf/model/small.yaml)")
        ema_decay = model.pop("ema_decay", None)  # the training EMA's decay, not a denoiser argument
        if ema_decay is None:
            raise ConfigError("model.ema_decay is missing (see dgsdp/conf/model/small.yaml)")
        style_dim = 0 if style_embedder is None else int(style_embedder.dim)
        injection = node("style_injection") or {}
        if style_dim:
            model["style_injection"] = injection.get("mode", "modulation")
            model["modulation_variant"] = injection.get("variant") or "official"
            model["also_concat"] = bool(injection.get("also_concat", False))
        diffusion = node("diffusion")
        # condition dropout for classifier-free guidance is set beside the schedule, but it is the training's
        music_drop, style_drop = diffusion.pop("music_drop_prob", None), diffusion.pop("style_drop_prob", None)
        if music_drop is None or style_drop is None:
            raise ConfigError("diffusion.music_drop_prob and diffusion.style_drop_prob must be set")
        audio = node("audio")
        style = node("style")
        if style is not None:
            style.pop("cache_dir", None)  # where to cache is the caller's choice, not part of the run
        window_frames = int(round(float(cfg.data.window_seconds) * int(cfg.data.fps)))
        return cls(
            model=model,
            diffusion=diffusion,
            loss=node("loss"),
            optimizer=node("optimizer"),
            audio=audio if audio_encoder is not None else None,
            style=style if style_embedder is not None and style_dim else None,
            conditioning=Conditioning(
                audio_dim=0 if audio_encoder is None else audio_encoder.output_dim,
                style_kind="none" if style_embedder is None else str(style_embedder.kind),
                style_dim=style_dim,
                style_bank_size=int(style_bank_size) if style_dim else 0,
                n_genres=0 if style_embedder is None else len(style_embedder.vocab),
                music_drop_prob=float(music_drop),
                style_drop_prob=float(style_drop),
            ),
            ema_decay=float(ema_decay),
            fps=int(cfg.data.fps),
            window_frames=window_frames,
            seed=int(cfg.seed),
            groups=dict(groups),
            record=OmegaConf.to_container(cfg, resolve=True),
            skeleton=skeleton,
        )

    @classmethod
    def from_groups(
        cls,
        *,
        model: str = "small",
        audio_dim: int = 35,
        style_dim: int = 0,
        style_kind: str = "onehot",
        style_bank_size: int = 0,
        n_genres: int = 10,
        injection: str = "modulation",
        diffusion: str = "default",
        loss: str = "edge",
        optimizer: str = "adan",
        skeleton: Skeleton = SMPL24,
        **model_overrides: Any,
    ) -> RunSpec:
        """A spec from the config files of the named group options, with given conditioning sizes and no audio
        encoder or style embedder configs (for benchmarks and tests that build random-init models)."""
        from omegaconf import OmegaConf

        from dgsdp.resources import CONFIG_DIR

        def load(group: str, option: str) -> dict[str, Any]:
            node = OmegaConf.to_container(OmegaConf.load(CONFIG_DIR / group / f"{option}.yaml"), resolve=True)
            node.pop("defaults", None)  # the group's typed schema: its values are all in the file
            return node

        model_cfg = {**load("model", model), **model_overrides}
        ema_decay = model_cfg.pop("ema_decay")
        if style_dim:
            inj = load("style_injection", injection)
            model_cfg.update(
                style_injection=inj["mode"], modulation_variant=inj["variant"] or "official",
                also_concat=bool(inj["also_concat"]),
            )  # fmt: skip
        diffusion_cfg = load("diffusion", diffusion)
        music_drop, style_drop = diffusion_cfg.pop("music_drop_prob"), diffusion_cfg.pop("style_drop_prob")
        return cls(
            model=model_cfg,
            diffusion=diffusion_cfg,
            loss=load("loss", loss),
            optimizer=load("optimizer", optimizer),
            audio=None,
            style=None,
            conditioning=Conditioning(
                audio_dim=audio_dim,
                style_kind=style_kind if style_dim else "none",
                style_dim=style_dim,
                style_bank_size=style_bank_size if style_dim else 0,
                n_genres=n_genres if style_dim else 0,
                music_drop_prob=float(music_drop),
                style_drop_prob=float(style_drop),
            ),  # fmt: skip
            ema_decay=float(ema_decay),
            fps=30,
            window_frames=int(model_cfg["seq_len"]),
            seed=0,
            skeleton=skeleton,
        )

    # --- comparison ----------------------------------------------------------------------------------------
    def architecture(self) -> dict[str, Any]:
        """What the weights' shapes depend on: two runs must agree on it to share a checkpoint."""
        import inspect

        c = self.conditioning
        cls = resolve("model", self.model.get("_target_"), "model", "checkpoint")
        defaults = {
            name: p.default for name, p in inspect.signature(cls).parameters.items() if p.default is not p.empty
        }
        # a key an older run did not store has the value it was built with
        model = {**defaults, **getattr(cls, "legacy_settings", {}), **self.model, "pose_dim": self.skeleton.pose_dim}
        return {
            # lists as tuples: a config's [] is the constructor's default ()
            "model": {
                k: tuple(v) if isinstance(v, list) else v for k, v in model.items() if k not in SHAPE_FREE_MODEL_KEYS
            },  # fmt: skip
            "skeleton": self.skeleton.to_dict(),
            "audio_dim": c.audio_dim,
            "style_kind": c.style_kind,
            "style_dim": c.style_dim,
            "style_bank_size": c.style_bank_size,
            "n_genres": c.n_genres,
        }

    def check_resumable_with(self, other: RunSpec, source: str) -> None:
        """Raise one CheckpointError listing every difference that stops ``other`` (the configured run) from
        resuming this checkpoint's run: architecture and optimiser."""
        diffs = _diff(self.architecture(), other.architecture(), "")
        diffs += _diff(_same_optimizer(self.optimizer), _same_optimizer(other.optimizer), "optimizer.")
        if diffs:
            raise CheckpointError(
                f"checkpoint {source} was trained with a different configuration:\n  "
                + "\n  ".join(diffs)
                + "\nUse the same config groups (audio, style, model, optimizer, ...) as the checkpoint's run, or "
                "start a new run."
            )


def check_size(name: str, value: Any) -> None:
    """Refuse an integer setting above its bound in MAX_SIZES (MAX_OTHER_SETTING for the others)."""
    if isinstance(value, bool) or not isinstance(value, int):
        return
    limit = MAX_SIZES.get(name.rpartition(".")[2], MAX_OTHER_SETTING)
    if value > limit:
        raise ConfigError(f"{name}={value:,} is larger than any model this project builds (at most {limit:,})")


SAME_OPTIMIZERS = {"adan_pytorch.Adan": "dgsdp.training.Adan"}
"""Optimiser targets of earlier runs -> today's class with the same update and state (a run resumes under it)."""


def _same_optimizer(node: Mapping[str, Any]) -> dict[str, Any]:
    """An optimiser config with its target named as today's (:data:`SAME_OPTIMIZERS`) and its lists as tuples."""
    out = {k: tuple(v) if isinstance(v, list) else v for k, v in node.items()}
    if out.get("_target_") in SAME_OPTIMIZERS:
        out["_target_"] = SAME_OPTIMIZERS[out["_target_"]]
    return out


def _diff(a: Mapping[str, Any], b: Mapping[str, Any], prefix: str) -> list[str]:
    out = []
    for key in sorted(set(a) | set(b)):
        if a.get(key) != b.get(key):
            out.append(f"{prefix}{key}: checkpoint {a.get(key)!r}, config {b.get(key)!r}")
    return out


def _local(node: dict[str, Any] | None) -> dict[str, Any] | None:
    """A stored part config without its write locations and device (the caller decides those)."""
    if node is None:
        return None

    def strip(value: Any) -> Any:
        if isinstance(value, dict):
            return {k: strip(v) for k, v in value.items() if k not in LOCAL_KEYS}
        if isinstance(value, list):
            return [strip(v) for v in value]
        return value

    return strip(node)


def _field_type(f: dataclasses.Field) -> type:
    return {"int": int, "float": float, "str": str}[str(f.type)]


def _kind_name(kind: type | tuple[type, ...]) -> str:
    kinds = kind if isinstance(kind, tuple) else (kind,)
    names = {dict: "a mapping", int: "an integer", float: "a number", str: "a string", type(None): "null"}
    return " or ".join(names.get(k, k.__name__) for k in kinds)


def _upgrade_format1(data: dict[str, Any], source: str) -> dict[str, Any]:
    """This project's first checkpoint layout (sections model/conditioning/diffusion/loss/optimizer/ema/data/
    config) in today's fields. Fields it never had raise a CheckpointError naming them."""
    for key in ("model", "conditioning", "diffusion", "loss", "optimizer", "data", "config"):
        if key not in data:
            raise CheckpointError(
                f"{source}: the stored run spec has no field {key} (neither this project's current format "
                f"{SPEC_FORMAT} nor its first one); it was not written by dgsdp's train.py"
            )
    config = data["config"]
    cond = dict(data["conditioning"])
    model = dict(data["model"])
    model.setdefault("_target_", "dgsdp.model.DanceDenoiser")
    diffusion = {k: v for k, v in dict(data["diffusion"]).items() if k not in ("music_drop_prob", "style_drop_prob")}
    diffusion.setdefault("_target_", "dgsdp.diffusion.GaussianDiffusion")
    loss = {"_target_": "dgsdp.diffusion.LossWeights", **dict(data["loss"])}
    optimizer = dict(data["optimizer"])
    name = optimizer.pop("name", "adan")
    optimizer = {
        "_target_": {"adan": "dgsdp.training.Adan", "adamw": "torch.optim.AdamW"}.get(name, name),
        "_partial_": True,
        **optimizer,
    }
    audio = config.get("audio") if int(cond.get("audio_dim", 0)) else None
    style = config.get("style") if int(cond.get("style_dim", 0)) else None
    if isinstance(style, dict):
        style = {k: v for k, v in style.items() if k != "_recursive_"}
    return {
        "format": SPEC_FORMAT,
        "model": model,
        "diffusion": diffusion,
        "loss": loss,
        "optimizer": optimizer,
        "audio": audio,
        "style": style,
        "conditioning": {k: cond.get(k) for k in (f.name for f in dataclasses.fields(Conditioning))},
        "ema_decay": (data.get("ema") or {}).get("decay"),
        "fps": (data["data"] or {}).get("fps"),
        "window_frames": (data["data"] or {}).get("window_frames"),
        "seed": config.get("seed"),
        "groups": data.get("groups") or {},
        "record": config,
    }
