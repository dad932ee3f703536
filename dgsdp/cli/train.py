"""``python train.py``: check, seed, data, model, callbacks, loggers, trainer, fit (lightning-hydra-template order).

Everything that can be checked is checked before any data is prepared: the model sizes, the trainer's
accelerator, the evaluation protocols, and on resume that the checkpoint is readable and was trained with the same
model and optimiser. A problem ends the run with one message and no half-made run folder.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import hydra
import lightning as L
import torch
from hydra.core.hydra_config import HydraConfig
from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf, open_dict

from dgsdp.cli.config import CONFIG_PATH, as_list, check_options
from dgsdp.cli.runtime import run_main
from dgsdp.data.datamodule import check_tempo_augment
from dgsdp.errors import ConfigError
from dgsdp.registry import build
from dgsdp.style.movement import movement_channels
from dgsdp.trained import check_weights, read_checkpoint
from dgsdp.trained.spec import RunSpec
from dgsdp.training.distill import (
    DistillSettings,
    GuidanceDistillation,
    check_same_data,
    check_student_spec,
    load_teacher,
    student_guidance_inputs,
)
from dgsdp.training.distributed import is_writer, log_files_on_writer_only
from dgsdp.training.module import DanceDiffusion, wandb_run_id
from dgsdp.training.resume import check_resume_has_work
from dgsdp.utils.device import check_cpu_bf16
from dgsdp.utils.io import atomic_write_text

log = logging.getLogger(__name__)
GROUP_CHOICES = ("data", "audio", "text_encoder", "style", "style_injection", "model", "diffusion", "loss",
                 "optimizer", "trainer", "logger", "experiment")  # fmt: skip
ACCELERATORS = ("auto", "cpu", "gpu", "cuda", "mps", "tpu")


def group_choices() -> dict[str, str]:
    """The config group choices of this run (audio=encodec, style=prompt, ...), for dashboards."""
    if not HydraConfig.initialized():
        return {}
    choices = HydraConfig.get().runtime.choices
    return {g: str(choices.get(g)) for g in GROUP_CHOICES if g in choices}


def has_audio_features(cfg: DictConfig) -> bool:
    """Whether the run has a music encoder (not ``audio=none``)."""
    return bool(cfg.get("audio")) and cfg.audio.get("_target_") is not None


def audio_encoder_from_config(cfg: DictConfig) -> Any:
    """The configured audio encoder (its weights load only when it first encodes), or None for ``audio=none``."""
    if not has_audio_features(cfg):
        return None
    return build(cfg.audio, "audio", where="audio")


def style_embedder_from_config(cfg: DictConfig) -> Any:
    """The configured StyleEmbedder (its text encoder loads only when it first embeds), or None."""
    return build(cfg.style, "style", where="style") if cfg.get("style") else None


def check_config(cfg: DictConfig) -> dict[str, Any] | None:
    """Check what can be checked before any work starts. Returns the resume checkpoint (read once), if any."""
    model = cfg.get("model") or {}
    if model.get("guidance_inputs") and not DistillSettings.from_config(cfg.get("distill")).teacher:
        raise ConfigError(
            "model.guidance_inputs is set by guidance distillation: give the teacher with distill.teacher=<checkpoint> "
            "and leave model.guidance_inputs at 0"
        )
    for key in ("seq_len", "d_model", "n_layers", "n_heads", "ff_dim"):
        value = model.get(key)
        if not isinstance(value, int) or isinstance(value, bool) or value <= 0:
            raise ConfigError(f"model.{key} must be a positive integer, got {value!r}")
    if model.d_model % model.n_heads:
        raise ConfigError(f"model.d_model={model.d_model} must be a multiple of model.n_heads={model.n_heads}")
    trainer = cfg.get("trainer") or {}
    accelerator = str(trainer.get("accelerator", "auto"))
    if accelerator not in ACCELERATORS:
        raise ConfigError(f"trainer.accelerator={accelerator!r} is not one of {', '.join(ACCELERATORS)}")
    if accelerator in ("gpu", "cuda") and not torch.cuda.is_available():
        raise ConfigError(
            f"trainer.accelerator={accelerator} but this machine has no CUDA GPU; use trainer=cpu (or "
            "trainer.accelerator=cpu; with trainer=ddp also trainer.precision=32-true)"
        )
    precision = str(trainer.get("precision", "32-true"))
    on_cpu = accelerator == "cpu" or (accelerator == "auto" and not torch.cuda.is_available())
    if precision.startswith("bf16") and on_cpu:
        check_cpu_bf16(f"trainer.precision={precision}")
    check_tempo_augment((cfg.get("data") or {}).get("tempo_augment"), has_features=has_audio_features(cfg))
    devices = trainer.get("devices", 1)
    if not (devices == "auto" or (isinstance(devices, int) and devices != 0) or OmegaConf.is_list(devices)):
        raise ConfigError(f"trainer.devices must be a positive number, 'auto' or a list of ids, got {devices!r}")
    if cfg.get("evaluate"):
        check_options("protocol", as_list(cfg.evaluate) or [], "evaluate")
    if (cfg.get("audio") or {}).get("per_window"):
        raise ConfigError(
            "audio.per_window=true is EDGE's generation procedure (each window's features from its own audio), set "
            "by the EDGE import; training reads whole-song features: leave audio.per_window=false"
        )
    if not cfg.get("ckpt_path"):
        return None
    checkpoint = read_checkpoint(str(cfg.ckpt_path))
    check_resume_has_work(cfg.trainer, checkpoint)
    return checkpoint


def _resume_logger_ids(cfg: DictConfig, ckpt: dict[str, Any]) -> None:
    """On resume, continue the same wandb run (its id is stored in the checkpoint)."""
    if "wandb" not in (cfg.get("logger") or {}):
        return
    run_id = wandb_run_id(ckpt)
    if run_id:
        with open_dict(cfg):
            cfg.logger.wandb.id = str(run_id)
            cfg.logger.wandb.resume = "allow"


def train(cfg: DictConfig) -> dict[str, Any]:
    """Run one training job. Returns the final metrics and the checkpoint folder."""
    log_files_on_writer_only()  # data-parallel runs: one log file, written by rank 0
    resume = check_config(cfg)
    distill = DistillSettings.from_config(cfg.get("distill"))
    teacher = load_teacher(distill)
    if teacher is not None:  # the student takes the guidance weights as an input
        with open_dict(cfg):
            cfg.model.guidance_inputs = student_guidance_inputs(teacher)
    L.seed_everything(int(cfg.seed), workers=True)  # seed 0 is a seed, not "no seed"

    audio_encoder = audio_encoder_from_config(cfg)
    style_embedder = style_embedder_from_config(cfg)
    # a model conditioned on movement channels (its speed, level, ...) reads each training window's values
    model_cfg = cfg.get("model") or {}
    channels = movement_channels(model_cfg.get("movement_channels"), bool(model_cfg.get("speed_conditioning", False)))
    datamodule = instantiate(cfg.data, audio_encoder=audio_encoder, movement_channels=channels)
    datamodule.prepare_data()
    datamodule.setup("fit")
    bank = style_embedder.bank() if style_embedder is not None and style_embedder.dim else None

    spec = RunSpec.from_config(
        cfg,
        audio_encoder=audio_encoder,
        style_embedder=style_embedder,
        style_bank_size=0 if bank is None else len(bank),
        groups=group_choices(),
        skeleton=datamodule.skeleton,
    )
    if resume is not None:
        saved = RunSpec.from_checkpoint(resume, str(cfg.ckpt_path))
        saved.check_resumable_with(spec, str(cfg.ckpt_path))
        check_weights(spec, resume.get("state_dict"), str(cfg.ckpt_path))  # before the model is built
        _resume_logger_ids(cfg, resume)
    if teacher is None:
        model = DanceDiffusion(spec)
    else:
        check_student_spec(spec, teacher, str(distill.teacher))
        check_same_data(teacher, datamodule.normalizer, bank, str(distill.teacher))
        model = GuidanceDistillation(spec, teacher, distill.max_weight)
    model.normalizer.load_state_dict(datamodule.normalizer.state_dict())
    if getattr(datamodule, "floor_height", None) is not None:  # measured on the training motions (docs/floor.md)
        model.set_floor_height(datamodule.floor_height)
    model.set_tempo_range(getattr(datamodule, "tempo_range_bpm", None))  # the songs' tempi (sampling.tempo_fold)
    model.set_style_bank(bank)
    if channels:  # the training windows' movement values: what generation asks each genre for (docs/style.md)
        model.set_movement_statistics(
            datamodule.movement_quantiles, datamodule.movement_reference, datamodule.movement_spread
        )
    n_params = sum(p.numel() for p in model.denoiser.parameters())
    log.info("denoiser: %.2fM parameters", n_params / 1e6)

    callbacks = [instantiate(c) for c in (cfg.get("callbacks") or {}).values() if c and "_target_" in c]
    loggers = [instantiate(lg) for lg in (cfg.get("logger") or {}).values() if lg and "_target_" in lg]
    record = {"config": spec.record, "groups": spec.groups, "n_params": n_params}
    for logger in loggers:
        logger.log_hyperparams(record)
        if type(logger).__name__ == "WandbLogger" and is_writer():
            # a readable copy in the run's files folder (uploaded with the run; offline runs keep it on disk)
            run_files = Path(logger.experiment.dir)
            atomic_write_text(run_files / "dgsdp_config.yaml", OmegaConf.to_yaml(OmegaConf.create(record)))
    trainer: L.Trainer = instantiate(cfg.trainer, callbacks=callbacks, logger=loggers or False)
    try:
        trainer.fit(model, datamodule=datamodule, ckpt_path=cfg.get("ckpt_path"))
    finally:
        for logger in loggers:
            experiment = getattr(logger, "_experiment", None)
            if experiment is not None and hasattr(experiment, "finish"):
                experiment.finish()  # wandb: close this job's run so the next multirun job gets its own
    metrics = {k: float(v) for k, v in trainer.callback_metrics.items() if torch.is_tensor(v) and v.numel() == 1}
    ckpt_dir = Path(cfg.paths.output_dir) / "checkpoints"
    result = {"metrics": metrics, "checkpoint_dir": str(ckpt_dir), "global_step": trainer.global_step}
    last = ckpt_dir / "last.ckpt"
    if last.is_file():
        log.info("checkpoint: %s", last)
        result["checkpoint"] = str(last)
    if cfg.get("evaluate"):
        if "checkpoint" not in result:
            raise ConfigError("evaluate= needs the final checkpoint: keep callbacks.model_checkpoint (save_last)")
        from dgsdp.cli.evaluate import evaluate_after_training

        result["evaluation"] = evaluate_after_training(cfg, result["checkpoint"], spec.groups)
    return result


@hydra.main(version_base="1.3", config_path=CONFIG_PATH, config_name="train")
def main(cfg: DictConfig) -> float | None:
    result = run_main(train, cfg)
    if "checkpoint" in result:
        print(f"checkpoint written: {result['checkpoint']}")
    return result["metrics"].get("val/loss")


if __name__ == "__main__":
    main()
