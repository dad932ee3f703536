"""``python evaluate.py checkpoint=<ckpt> protocol=<name>``: a paper-table protocol on a trained checkpoint.

Also runs after training in the same job when the training config sets ``evaluate`` (see
:func:`evaluate_after_training`): the results then go to ``<run folder>/evaluation/<protocol>/``.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import hydra
import torch
from hydra.utils import instantiate
from omegaconf import DictConfig, ListConfig, OmegaConf

from dgsdp.cli.config import CONFIG_PATH, compose_config
from dgsdp.errors import ConfigError, DgsdpError
from dgsdp.evaluation.protocols import ProtocolSpec
from dgsdp.evaluation.results import log_results, write_results
from dgsdp.evaluation.runner import Evaluator, SamplingSettings
from dgsdp.utils.device import resolve_device

log = logging.getLogger(__name__)
EVALUATION_DIR = "evaluation"


def _data_location(cfg: DictConfig, ckpt_config: dict[str, Any]) -> tuple[Path, Path]:
    """Dataset root and feature cache: the config's ``data.*`` when set, else the checkpoint's training data."""
    data = ckpt_config.get("data") or {}
    root = cfg.data.get("root") or data.get("root")
    cache = cfg.data.get("cache_dir") or data.get("cache_dir") or (ckpt_config.get("paths") or {}).get("cache_dir")
    if not root or not cache:
        raise ConfigError(
            "the checkpoint's config does not name its dataset; give data.root=<AIST++ folder> and "
            "data.cache_dir=<feature cache folder>"
        )
    root = Path(str(root)).expanduser()
    if not (root / "motions").is_dir() and data.get("synthetic") and not cfg.data.get("root"):
        from dgsdp.data.synthetic import generate_synthetic_aistpp

        log.info("regenerating the checkpoint's synthetic dataset in %s", root)
        generate_synthetic_aistpp(root, **data["synthetic"])
    return root, Path(str(cache)).expanduser()


def run_info(model: Any) -> dict[str, Any]:
    """Which training run a checkpoint comes from (for reports that group runs by config and seed)."""
    config = model.hparams.get("config") or {}
    groups = dict(model.hparams.get("groups") or {})
    return {
        "run_name": config.get("run_name"),
        "sweep_name": config.get("sweep_name"),
        "seed": config.get("seed"),
        "experiment": groups.get("experiment"),
        "groups": groups,
        "run_dir": (config.get("paths") or {}).get("output_dir"),
        "wandb_project": ((config.get("logger") or {}).get("wandb") or {}).get("project"),
    }


def evaluate(cfg: DictConfig) -> dict[str, Any]:
    """Evaluate ``cfg.checkpoint`` under ``cfg.protocol``; write and log the results. Returns them and the paths."""
    from dgsdp.training.module import load_checkpoint

    if not cfg.get("checkpoint"):
        raise ConfigError("give checkpoint=<path of a .ckpt written by train.py>")
    model = load_checkpoint(str(cfg.checkpoint))
    ckpt_config = dict(model.hparams.get("config") or {})
    root, cache = _data_location(cfg, ckpt_config)
    spec = ProtocolSpec.from_config(OmegaConf.to_container(cfg.protocol, resolve=True))
    sampling = SamplingSettings(**OmegaConf.to_container(cfg.sampling, resolve=True))
    evaluator = Evaluator(
        model, spec, data_root=root, cache_dir=cache, sampling=sampling, metrics_mode=cfg.metrics.mode,
        classifier_method=cfg.metrics.classifier, seed=int(cfg.seed), device=resolve_device(cfg.device),
        progress=bool(cfg.progress),
    )  # fmt: skip
    results = evaluator.run()
    results["checkpoint"] = str(Path(str(cfg.checkpoint)).expanduser().resolve())
    results["run"] = run_info(model)
    results["settings"] = {
        "protocol": OmegaConf.to_container(cfg.protocol, resolve=True),
        "sampling": OmegaConf.to_container(cfg.sampling, resolve=True),
        "metrics": OmegaConf.to_container(cfg.metrics, resolve=True),
        "data": {"root": str(root), "cache_dir": str(cache)},
        "seed": int(cfg.seed),
        "features": "y-up 60 FPS (linear interpolation of 30 FPS joints), PFC z-up 30 FPS",
    }
    loggers = [instantiate(lg) for lg in (cfg.get("logger") or {}).values() if lg and "_target_" in lg]
    results["loggers"] = [type(lg).__name__ for lg in loggers]
    paths = write_results(results, cfg.output_dir)
    log_results(results, loggers)
    log.info("results: %s", paths["markdown"])
    return {"results": results, "paths": paths}


def _quote(value: Any) -> str:
    """A value as a quoted Hydra override string."""
    text = str(value).replace("\\", "\\\\").replace("'", "\\'")
    return f"'{text}'"


def compose_evaluate_config(overrides: Sequence[str], output_dir: str | Path) -> DictConfig:
    """Compose ``conf/evaluate.yaml`` with ``overrides``; safe to call inside a running Hydra job (its global
    state is restored afterwards)."""
    from hydra.core.global_hydra import GlobalHydra
    from hydra.core.hydra_config import HydraConfig

    saved_hydra = GlobalHydra.instance().hydra if GlobalHydra.instance().is_initialized() else None
    saved_cfg = HydraConfig.instance().cfg
    try:
        cfg = compose_config("evaluate", list(overrides), output_dir=output_dir)
        OmegaConf.resolve(cfg)
        return cfg
    finally:
        GlobalHydra.instance().clear()
        if saved_hydra is not None:
            GlobalHydra.instance().initialize(saved_hydra)
        HydraConfig.instance().cfg = saved_cfg


def evaluate_after_training(train_cfg: DictConfig, checkpoint: str, groups: dict[str, str]) -> dict[str, str]:
    """Run the protocols named by ``train_cfg.evaluate`` (a name or a list) on the final checkpoint.

    Results go to ``<run folder>/evaluation/<protocol>/``; ``train_cfg.evaluate_overrides`` are extra overrides of
    ``conf/evaluate.yaml`` (e.g. ``[sampling.steps=10, protocol.trials=5]``). The run's logger choice is reused
    (a wandb run is continued). Returns {protocol: results.json path}.
    """
    names = train_cfg.evaluate
    names = list(names) if isinstance(names, ListConfig | list | tuple) else [names]
    extra = [str(o) for o in (train_cfg.get("evaluate_overrides") or [])]
    base = [
        f"checkpoint={_quote(checkpoint)}", f"seed={int(train_cfg.seed)}", f"run_name={_quote(train_cfg.run_name)}",
    ]  # fmt: skip
    if train_cfg.get("sweep_name"):
        base.append(f"sweep_name={_quote(train_cfg.sweep_name)}")
    logger = groups.get("logger")
    if logger:
        base.append(f"logger={logger}")
    if "wandb" in (train_cfg.get("logger") or {}):
        ckpt = torch.load(checkpoint, map_location="cpu", weights_only=True)
        run_id = ckpt.get("logger_run_ids", {}).get("WandbLogger")
        if run_id:
            base += [f"+logger.wandb.id={_quote(run_id)}", "+logger.wandb.resume=allow"]
    out: dict[str, str] = {}
    for name in names:
        out_dir = Path(train_cfg.paths.output_dir) / EVALUATION_DIR / str(name)
        cfg = compose_evaluate_config([*base, f"protocol={name}", *extra], out_dir)
        out[str(name)] = str(evaluate(cfg)["paths"]["json"])
    return out


@hydra.main(version_base="1.3", config_path=CONFIG_PATH, config_name="evaluate")
def main(cfg: DictConfig) -> None:
    try:
        result = evaluate(cfg)
    except DgsdpError as e:
        log.error("%s", e)
        raise SystemExit(f"error: {e}") from None
    print(result["paths"]["markdown"].read_text())
    print(f"results written: {result['paths']['json']}")


if __name__ == "__main__":
    main()
