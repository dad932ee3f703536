"""``python evaluate.py checkpoint=<ckpt> protocol=<name>``: a paper-table protocol on a trained checkpoint.

Also runs after training in the same job when the training config sets ``evaluate`` (see
:func:`evaluate_after_training`): the results then go to ``<run folder>/evaluation/<protocol>/``.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import hydra
from hydra.utils import instantiate
from omegaconf import DictConfig, ListConfig, OmegaConf

from dgsdp.cli.config import CONFIG_PATH, compose_config
from dgsdp.cli.runtime import run_main
from dgsdp.data.finedance import SPLIT_SCHEMES, is_finedance
from dgsdp.errors import ConfigError
from dgsdp.evaluation.protocols import ProtocolSpec
from dgsdp.evaluation.results import log_results, write_results
from dgsdp.evaluation.runner import Evaluator
from dgsdp.generation.pipeline import DanceGenerator
from dgsdp.sampling import SamplingSettings
from dgsdp.trained import load_model, read_checkpoint
from dgsdp.trained.spec import RunSpec
from dgsdp.training.module import wandb_run_id
from dgsdp.utils.device import resolve_device

log = logging.getLogger(__name__)
EVALUATION_DIR = "evaluation"


def _data_location(cfg: DictConfig, spec: RunSpec) -> tuple[Path, Path]:
    """Dataset root and feature cache. The root is ``data.root`` when given, else the one the checkpoint was
    trained on (only read). The cache is ``data.cache_dir``, else this run's ``paths.cache_dir``: where to write
    is decided here, never by the checkpoint. A checkpoint trained on the synthetic dataset whose folder is not
    there gets that dataset regenerated under this run's ``paths.data_dir``."""
    data = spec.record.get("data") or {}
    cache = Path(str(cfg.data.get("cache_dir") or cfg.paths.cache_dir)).expanduser()
    if cfg.data.get("root"):
        return Path(str(cfg.data.root)).expanduser(), cache
    root = Path(str(data["root"])).expanduser() if data.get("root") else None
    stored = root is not None and ((root / "motions").is_dir() or is_finedance(root))
    synthetic = data.get("synthetic")
    if isinstance(synthetic, dict):
        import inspect

        from dgsdp.data.synthetic import generate_synthetic_aistpp, outdated_synthetic, synthetic_folder

        params = inspect.signature(generate_synthetic_aistpp).parameters
        # stored settings are data: only the generator's own numeric and boolean parameters are taken
        settings = {k: v for k, v in synthetic.items() if k in params and type(v) in (int, float, bool)}
        settings.setdefault("offbeats", False)  # runs stored without the setting were trained before it existed
        if stored and not outdated_synthetic(root, **settings):
            return root, cache
        local = Path(str(cfg.paths.data_dir)).expanduser() / synthetic_folder(
            settings["offbeats"], settings.get("movement_variation", False)
        )
        if not (local / "motions").is_dir() or outdated_synthetic(local, **settings):
            log.info("regenerating the checkpoint's synthetic dataset in %s", local)
            generate_synthetic_aistpp(local, **settings)
        return local, cache
    if stored:
        return root, cache
    raise ConfigError(
        f"the dataset the checkpoint was trained on ({root or 'not recorded'}) is not here; give "
        "data.root=<AIST++-layout or FineDance folder>"
    )


def _split_scheme(spec: RunSpec) -> str:
    """FineDance's split scheme the checkpoint was trained with (``genre`` when not recorded or not FineDance)."""
    finedance = (spec.record.get("data") or {}).get("finedance") or {}
    scheme = finedance.get("split_scheme", "genre") if isinstance(finedance, dict) else "genre"
    if scheme not in SPLIT_SCHEMES:
        raise ConfigError(
            f"the checkpoint records FineDance split scheme {scheme!r}; known: {', '.join(SPLIT_SCHEMES)}"
        )
    return scheme


def run_info(spec: RunSpec) -> dict[str, Any]:
    """Which training run a checkpoint comes from (for reports that group runs by config and seed)."""
    config = spec.record
    return {
        "run_name": config.get("run_name"),
        "sweep_name": config.get("sweep_name"),
        "seed": spec.seed,
        "experiment": spec.groups.get("experiment"),
        "groups": dict(spec.groups),
        "run_dir": (config.get("paths") or {}).get("output_dir"),
        "wandb_project": ((config.get("logger") or {}).get("wandb") or {}).get("project"),
        # a guidance-distilled student (docs/distillation.md): one denoiser pass per sampling step
        "guidance_student": bool(spec.model.get("guidance_inputs")),
    }


def _cleanup(cfg: DictConfig) -> bool:
    value = cfg.get("cleanup", False)
    if not isinstance(value, bool):
        raise ConfigError(f"cleanup must be true or false (score the dances as generate.py writes them), got {value!r}")
    return value


def evaluate(cfg: DictConfig) -> dict[str, Any]:
    """Evaluate ``cfg.checkpoint`` under ``cfg.protocol``; write and log the results. Returns them and the paths."""
    if not cfg.get("checkpoint"):
        raise ConfigError("give checkpoint=<path of a .ckpt written by train.py>")
    spec = ProtocolSpec.from_config(OmegaConf.to_container(cfg.protocol, resolve=True))
    sampling = SamplingSettings.from_config(cfg.sampling)
    model = load_model(str(cfg.checkpoint))
    root, cache = _data_location(cfg, model.spec)
    generator = DanceGenerator(model, cache_dir=cache, device=resolve_device(str(cfg.device)))
    evaluator = Evaluator(
        generator, spec, data_root=root, cache_dir=cache, sampling=sampling, metrics_mode=cfg.metrics.mode,
        classifier_method=cfg.metrics.classifier, seed=int(cfg.seed), progress=bool(cfg.progress),
        cleanup=_cleanup(cfg), split_scheme=_split_scheme(model.spec),
    )  # fmt: skip
    results = evaluator.run()
    results["checkpoint"] = str(Path(str(cfg.checkpoint)).expanduser().resolve())
    results["run"] = run_info(model.spec)
    results["settings"] = {
        "protocol": OmegaConf.to_container(cfg.protocol, resolve=True),
        "sampling": OmegaConf.to_container(cfg.sampling, resolve=True),
        "metrics": OmegaConf.to_container(cfg.metrics, resolve=True),
        "data": {"root": str(root), "cache_dir": str(cache)},
        "seed": int(cfg.seed),
        "cleanup": _cleanup(cfg),
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
        ckpt = read_checkpoint(checkpoint)
        run_id = wandb_run_id(ckpt)
        if run_id:
            base += [f"+logger.wandb.id={_quote(run_id)}", "+logger.wandb.resume=allow"]
    out: dict[str, str] = {}
    for name in names:
        out_dir = Path(train_cfg.paths.output_dir) / EVALUATION_DIR / str(name)
        cfg = compose_config("evaluate", [*base, f"protocol={name}", *extra], output_dir=out_dir)
        out[str(name)] = str(evaluate(cfg)["paths"]["json"])
    return out


@hydra.main(version_base="1.3", config_path=CONFIG_PATH, config_name="evaluate")
def main(cfg: DictConfig) -> None:
    result = run_main(evaluate, cfg)
    print(result["paths"]["markdown"].read_text())
    print(f"results written: {result['paths']['json']}")


if __name__ == "__main__":
    main()
