"""Typed schemas of config groups, registered in Hydra's config store: a wrong type or a misspelled key in these
groups fails when the config is composed, with Hydra's message naming the key.

Each group's option files start with ``defaults: [schema, _self_]``."""

from __future__ import annotations

from dataclasses import dataclass, field

from hydra.core.config_store import ConfigStore

from dgsdp.sampling import SamplingSettings


@dataclass
class DenoiserConfig:
    """``conf/model``: the denoiser's sizes (keyword arguments of :class:`dgsdp.model.DanceDenoiser`) and the
    training EMA's decay."""

    _target_: str = "dgsdp.model.DanceDenoiser"
    seq_len: int = 150
    d_model: int = 512
    n_layers: int = 8
    n_heads: int = 8
    ff_dim: int = 1024
    dropout: float = 0.1
    music_encoder_layers: int = 2
    modulation_shared: bool = True
    rotary_placement: str = "qk"
    cross_attention_rotary: bool = True
    null_music: str = "input"
    aligned_music: bool = False
    style_film: bool = False
    style_standardize: float | None = None
    guidance_inputs: int = 0
    gradient_checkpointing: bool = False
    speed_conditioning: bool = False
    movement_channels: list[str] = field(default_factory=list)
    ema_decay: float = 0.9999


def register_schemas() -> None:
    store = ConfigStore.instance()
    store.store(group="sampling", name="schema", node=SamplingSettings)
    store.store(group="model", name="schema", node=DenoiserConfig)
