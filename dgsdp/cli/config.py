"""Config helpers shared by the entry points: the project root resolver and turning configs into parts."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf, open_dict

from dgsdp.audio import AudioEncoder
from dgsdp.errors import ConfigError

PROJECT_ROOT = Path(__file__).resolve().parents[2]
CONFIG_DIR = Path(__file__).resolve().parents[1] / "conf"

if not OmegaConf.has_resolver("dgsdp_root"):
    OmegaConf.register_new_resolver("dgsdp_root", lambda: str(PROJECT_ROOT))
if not OmegaConf.has_resolver("dgsdp_precision"):  # conf/trainer/ddp.yaml: bf16-mixed on GPUs, 32-true on CPUs
    from dgsdp.training.distributed import precision_for

    OmegaConf.register_new_resolver("dgsdp_precision", precision_for)


def compose_config(
    config_name: str = "train", overrides: Sequence[str] = (), output_dir: str | Path | None = None
) -> DictConfig:
    """Compose a config as the entry point would, with Hydra's runtime values set (for notebooks and tests).

    ``output_dir`` stands for the run folder Hydra would create (``paths.output_dir``)."""
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra
    from hydra.core.hydra_config import HydraConfig

    GlobalHydra.instance().clear()
    with initialize_config_dir(str(CONFIG_DIR), version_base="1.3"):
        cfg = compose(config_name, overrides=list(overrides), return_hydra_config=True)
    if output_dir is not None:
        with open_dict(cfg):
            cfg.hydra.runtime.output_dir = str(output_dir)
    HydraConfig.instance().set_config(cfg)
    with open_dict(cfg):
        del cfg["hydra"]  # as in a Hydra app: the task's config has no hydra node
    return cfg


def audio_encoder_from_config(cfg: DictConfig) -> AudioEncoder | None:
    """The configured audio encoder, or None for ``audio=none`` (unconditional)."""
    if not cfg.get("audio") or cfg.audio.get("_target_") is None:
        return None
    return instantiate(cfg.audio)


def build_hparams(
    cfg: DictConfig, audio_encoder: AudioEncoder | None, style_embedder: Any, style_bank_size: int
) -> dict[str, Any]:
    """The model's plain-dict hyper-parameters (stored in checkpoints) from a run config."""
    model = OmegaConf.to_container(cfg.model, resolve=True)
    ema_decay = model.pop("ema_decay", 0.9999)
    injection = cfg.get("style_injection") or {}
    if style_embedder is not None and style_embedder.dim:
        model["style_injection"] = injection.get("mode", "modulation")
        model["modulation_variant"] = injection.get("variant") or "official"
        model["also_concat"] = bool(injection.get("also_concat", False))
    diffusion = OmegaConf.to_container(cfg.diffusion, resolve=True)
    conditioning = {
        "audio": None if audio_encoder is None else audio_encoder.name,
        "audio_dim": 0 if audio_encoder is None else int(audio_encoder.feature_dim),
        "audio_settings": None if audio_encoder is None else audio_encoder.settings(),
        "style_kind": "none" if style_embedder is None else style_embedder.kind,
        "style_dim": 0 if style_embedder is None else int(style_embedder.dim),
        "style_bank_size": int(style_bank_size) if style_embedder is not None and style_embedder.dim else 0,
        "n_genres": 0 if style_embedder is None else len(style_embedder.vocab),
        "text_encoder": OmegaConf.to_container(cfg.text_encoder, resolve=True) if cfg.get("text_encoder") else None,
        "music_drop_prob": float(diffusion.pop("music_drop_prob", 0.25)),
        "style_drop_prob": float(diffusion.pop("style_drop_prob", 0.0)),
    }
    window_frames = int(round(cfg.data.window_seconds * cfg.data.fps))
    if window_frames > model["seq_len"]:
        raise ConfigError(
            f"data windows of {window_frames} frames are longer than model.seq_len={model['seq_len']}; "
            "raise model.seq_len or shorten data.window_seconds"
        )
    return {
        "model": model,
        "conditioning": conditioning,
        "diffusion": diffusion,
        "loss": OmegaConf.to_container(cfg.loss, resolve=True),
        "optimizer": OmegaConf.to_container(cfg.optimizer, resolve=True),
        "ema": {"decay": float(ema_decay)},
        "data": {"fps": int(cfg.data.fps), "window_frames": window_frames},
        "config": OmegaConf.to_container(cfg, resolve=True),
    }
