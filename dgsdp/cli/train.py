"""``python train.py``: seed, data, model, callbacks, loggers, trainer, fit (lightning-hydra-template order)."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import hydra
import lightning as L
import torch
from hydra.core.hydra_config import HydraConfig
from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf

from dgsdp.cli.config import CONFIG_DIR, audio_encoder_from_config, build_hparams
from dgsdp.errors import ConfigError, DgsdpError
from dgsdp.training.distributed import is_writer, log_files_on_writer_only
from dgsdp.training.module import DanceDiffusion, check_compatible, plain
from dgsdp.training.resume import check_resume_has_work
from dgsdp.utils.io import atomic_write_text

log = logging.getLogger(__name__)
GROUP_CHOICES = ("data", "audio", "text_encoder", "style", "style_injection", "model", "diffusion", "loss",
                 "optimizer", "trainer", "logger", "experiment")  # fmt: skip


def group_choices() -> dict[str, str]:
    """The config group choices of this run (audio=encodec, style=prompt, ...), for dashboards."""
    if not HydraConfig.initialized():
        return {}
    choices = HydraConfig.get().runtime.choices
    return {g: str(choices.get(g)) for g in GROUP_CHOICES if g in choices}


def _resume_logger_ids(cfg: DictConfig, ckpt: dict[str, Any]) -> None:
    """On resume, continue the same wandb run (its id is stored in the checkpoint)."""
    if "wandb" not in (cfg.get("logger") or {}):
        return
    run_id = ckpt.get("logger_run_ids", {}).get("WandbLogger")
    if run_id:
        OmegaConf.set_struct(cfg, False)
        cfg.logger.wandb.id = run_id
        cfg.logger.wandb.resume = "allow"


def train(cfg: DictConfig) -> dict[str, Any]:
    """Run one training job. Returns the final metrics and the checkpoint folder."""
    log_files_on_writer_only()  # data-parallel runs: one log file, written by rank 0
    L.seed_everything(int(cfg.seed), workers=True)  # seed 0 is a seed, not "no seed"

    audio_encoder = audio_encoder_from_config(cfg)
    style_embedder = instantiate(cfg.style) if cfg.get("style") else None
    datamodule = instantiate(cfg.data, audio_encoder=audio_encoder)
    datamodule.prepare_data()
    datamodule.setup("fit")
    bank = style_embedder.bank() if style_embedder is not None and style_embedder.dim else None

    hparams = build_hparams(cfg, audio_encoder, style_embedder, 0 if bank is None else len(bank))
    hparams["groups"] = group_choices()
    model = DanceDiffusion(hparams)
    model.normalizer.load_state_dict(datamodule.normalizer.state_dict())
    model.set_style_bank(bank)
    n_params = sum(p.numel() for p in model.denoiser.parameters())
    log.info("denoiser: %.2fM parameters", n_params / 1e6)

    if cfg.get("ckpt_path"):
        ckpt_path = Path(cfg.ckpt_path).expanduser()
        if not ckpt_path.is_file():
            raise ConfigError(f"ckpt_path {ckpt_path} does not exist; give the path of a checkpoint to resume from")
        saved = torch.load(ckpt_path, map_location="cpu", weights_only=True)
        check_compatible(saved.get("hyper_parameters", {}), plain(hparams), str(ckpt_path))
        check_resume_has_work(cfg.trainer, saved)
        _resume_logger_ids(cfg, saved)

    callbacks = [instantiate(c) for c in (cfg.get("callbacks") or {}).values() if c and "_target_" in c]
    loggers = [instantiate(lg) for lg in (cfg.get("logger") or {}).values() if lg and "_target_" in lg]
    record = {"config": hparams["config"], "groups": hparams["groups"], "n_params": n_params}
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

        result["evaluation"] = evaluate_after_training(cfg, result["checkpoint"], group_choices())
    return result


@hydra.main(version_base="1.3", config_path=str(CONFIG_DIR), config_name="train")
def main(cfg: DictConfig) -> float | None:
    try:
        result = train(cfg)
    except DgsdpError as e:
        log.error("%s", e)
        raise SystemExit(f"error: {e}") from None
    if "checkpoint" in result:
        print(f"checkpoint written: {result['checkpoint']}")
    return result["metrics"].get("val/loss")


if __name__ == "__main__":
    main()
