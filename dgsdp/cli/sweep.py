"""``python -m dgsdp.sweep <table> [--jobs N] [--dry-run] [overrides ...]``: one paper table as a Hydra multirun.

A sweep file (``<table>.yaml`` in the shipped ``dgsdp/sweeps/``, or any path) is a global config appended to the training config: it names the table
(``sweep_name``), the evaluation protocol run after training (``evaluate``) and the grid in
``hydra.sweeper.params`` (experiment rows x seeds). This launcher puts the sweep folder on Hydra's search path,
checks the grid before launching (Hydra's ``glob()`` matching nothing would silently launch zero jobs and exit 0),
launches with the joblib launcher (``--jobs`` in parallel) unless a ``hydra/launcher=...`` override picks another
(``submitit_slurm`` for SLURM), and checks afterwards that every expected job ran. Overrides are appended to every
job (``debug=tiny data.root=...``); ``key=a,b`` overrides extend the file's grid, and any override of a key the file sweeps replaces it.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from datetime import datetime
from pathlib import Path
from typing import Any

from omegaconf import OmegaConf

from dgsdp.cli.runtime import check_command_line, run_suffix
from dgsdp.errors import ConfigError
from dgsdp.resources import CONFIG_DIR, CONFIG_PATH, SWEEPS_DIR, default_log_dir

DRY_RUN_RECORD = "sweep_job.json"


def available_sweeps(sweeps_dir: Path = SWEEPS_DIR) -> list[str]:
    return sorted(p.stem for p in sweeps_dir.glob("*.yaml"))


def resolve_sweep(name_or_path: str) -> Path:
    """The sweep file named by a table name (``table4``) or a path to a ``.yaml``; ConfigError if absent."""
    path = Path(name_or_path).expanduser()
    if path.suffix in (".yaml", ".yml") and path.is_file():
        return path.resolve()
    candidate = SWEEPS_DIR / f"{name_or_path}.yaml"
    if candidate.is_file():
        return candidate
    raise ConfigError(
        f"no sweep {name_or_path!r}: give a file in {SWEEPS_DIR} ({', '.join(available_sweeps())}) "
        "or the path of a sweep .yaml"
    )


def _group_options(group: str) -> list[str] | None:
    """Config names of a training config group (``experiment`` -> table4_row0, ...), None if not a group."""
    folder = CONFIG_DIR / group
    return sorted(p.stem for p in folder.glob("*.yaml")) if folder.is_dir() else None


def sweep_grid(sweep_file: Path, overrides: list[str]) -> dict[str, list[str]]:
    """Values of every swept key: the file's ``hydra.sweeper.params`` updated by ``key=a,b`` overrides.

    Globs are matched against the config group's files, explicit choices of a group are checked to exist.
    Raises ConfigError for a key that sweeps over nothing.
    """
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from hydra.core.override_parser.types import Glob

    raw = OmegaConf.load(sweep_file)
    params = OmegaConf.select(raw, "hydra.sweeper.params", default=None)
    lines = {str(k): f"{k}={v}" for k, v in (params or {}).items()}
    parser = OverridesParser.create()
    for line in overrides:
        parsed = parser.parse_overrides([line])[0]
        key = parsed.key_or_group.lstrip("+")
        if parsed.is_sweep_override() or key in lines:  # the command line wins over the file, as in Hydra
            lines[key] = line.lstrip("+")
    grid: dict[str, list[str]] = {}
    for key, line in lines.items():
        override = parser.parse_overrides([line])[0]
        options = _group_options(override.key_or_group)
        value = override.value()
        if isinstance(value, Glob):
            values = value.filter(options or [])
        elif override.is_sweep_override():
            values = list(override.sweep_string_iterator())
        else:
            values = [str(value)]
        if options is not None:
            missing = [v for v in values if v not in options]
            if missing:
                raise ConfigError(
                    f"sweep {sweep_file.stem}: {key} {missing} not found in {CONFIG_DIR / key} "
                    f"(options: {', '.join(options)})"
                )
        if not values:
            raise ConfigError(
                f"sweep {sweep_file.stem}: '{line}' matches no config"
                + (f" in {CONFIG_DIR / key} (options: {', '.join(options)})" if options is not None else "")
                + "; fix the pattern (Hydra's glob() does not look into sub-folders)"
            )
        grid[key] = values
    if not grid:
        raise ConfigError(f"sweep {sweep_file.stem} sweeps over nothing: set hydra.sweeper.params in {sweep_file}")
    return grid


def _record_job(cfg: Any) -> None:
    """Dry-run job: write what would be trained (composed config's row, seed, evaluation) instead of training."""
    from hydra.core.hydra_config import HydraConfig

    choices = HydraConfig.get().runtime.choices
    record = {
        "experiment": choices.get("experiment"),
        "run_name": cfg.run_name,
        "seed": int(cfg.seed),
        "sweep_name": cfg.sweep_name,
        "evaluate": OmegaConf.to_container(cfg.evaluate) if OmegaConf.is_config(cfg.evaluate) else cfg.evaluate,
        "overrides": list(HydraConfig.get().overrides.task),
    }
    out = Path(HydraConfig.get().runtime.output_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / DRY_RUN_RECORD).write_text(json.dumps(record, indent=1))


def _train_job(cfg: Any) -> None:
    from dgsdp.cli.train import main as train_main

    train_main.__wrapped__(cfg)  # the plain task function behind @hydra.main


def _default_sweep_dir(name: str, overrides: list[str]) -> Path:
    log_dir = default_log_dir()
    for line in overrides:
        if line.startswith("paths.log_dir="):
            log_dir = Path(line.split("=", 1)[1]).expanduser()
    return log_dir / "sweeps" / name / f"{datetime.now():%Y-%m-%d_%H-%M-%S}_{run_suffix()}"


def launch(sweep: str, overrides: list[str] | None = None, *, jobs: int = 1, dry_run: bool = False) -> dict[str, Any]:
    """Launch a sweep; returns {"sweep_dir", "expected_jobs", "jobs", "grid"}. ConfigError if it cannot run."""
    from hydra import main as hydra_main

    from dgsdp.cli.schema import register_schemas

    register_schemas()  # the typed schemas the config groups name (model/schema, sampling/schema)
    if isinstance(jobs, bool) or not isinstance(jobs, int) or jobs < 1:
        raise ConfigError(f"--jobs must be a whole number of parallel jobs, at least 1; got {jobs!r}")
    overrides = list(overrides or [])
    check_command_line(overrides)
    sweep_file = resolve_sweep(sweep)
    grid = sweep_grid(sweep_file, overrides)
    expected = math.prod(len(v) for v in grid.values())
    sweep_dir_arg = next((o for o in overrides if o.startswith("hydra.sweep.dir=")), None)
    if sweep_dir_arg is None:
        sweep_dir = _default_sweep_dir(sweep_file.stem, overrides)
        overrides.append(f"hydra.sweep.dir={sweep_dir}")
    else:
        sweep_dir = Path(sweep_dir_arg.split("=", 1)[1]).expanduser()
    if not any(o.startswith("hydra/launcher=") for o in overrides):
        overrides += ["hydra/launcher=joblib", f"hydra.launcher.n_jobs={int(jobs)}"]
    argv = [
        "dgsdp.sweep", "-m", f"hydra.searchpath=[file://{sweep_file.parent.parent}]",
        f"+{sweep_file.parent.name}={sweep_file.stem}", *overrides,
    ]  # fmt: skip
    task = hydra_main(version_base="1.3", config_path=CONFIG_PATH, config_name="train")(
        _record_job if dry_run else _train_job
    )
    saved_argv = sys.argv
    sys.argv = argv
    try:
        task()
    finally:
        sys.argv = saved_argv
    marker = DRY_RUN_RECORD if dry_run else ".hydra"
    done = sorted(p.parent for p in sweep_dir.glob(f"*/{marker}"))
    if len(done) != expected:
        raise ConfigError(
            f"sweep {sweep_file.stem} ran {len(done)} job(s) in {sweep_dir}, expected {expected} "
            f"({' x '.join(f'{k}: {len(v)}' for k, v in grid.items())}); see the job logs there"
        )
    return {"sweep_dir": sweep_dir, "expected_jobs": expected, "jobs": done, "grid": grid}


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        prog="python -m dgsdp.sweep",
        description="Train and evaluate every row of a paper table (a shipped sweep file or a .yaml) as a Hydra multirun.",
        epilog="Examples: python -m dgsdp.sweep table4 --jobs 2 | python -m dgsdp.sweep table1 debug=tiny "
        "data.root=/data/synthetic | python -m dgsdp.sweep table5 hydra/launcher=submitit_slurm "
        "hydra.launcher.partition=gpu",
    )
    parser.add_argument("sweep", nargs="?", help=f"one of {', '.join(available_sweeps())}, or a sweep .yaml")
    parser.add_argument("overrides", nargs="*", help="Hydra overrides appended to every job")
    parser.add_argument("--jobs", type=int, default=1, help="jobs run in parallel by the joblib launcher")
    parser.add_argument("--dry-run", action="store_true", help="compose every job and record it; train nothing")
    parser.add_argument("--list", action="store_true", help="list the sweeps and their grids, then exit")
    args = parser.parse_intermixed_args(argv)
    try:
        if args.list or args.sweep is None:
            for name in available_sweeps():
                grid = sweep_grid(SWEEPS_DIR / f"{name}.yaml", [])
                n = math.prod(len(v) for v in grid.values())
                print(f"{name}: {n} jobs  " + "  ".join(f"{k}={','.join(v)}" for k, v in grid.items()))
            return
        result = launch(args.sweep, args.overrides, jobs=args.jobs, dry_run=args.dry_run)
    except ConfigError as e:
        raise SystemExit(f"error: {e}") from None
    print(f"{len(result['jobs'])} job(s) in {result['sweep_dir']}")
    if not args.dry_run:
        print(f"report: python -m dgsdp.report {result['sweep_dir']}")


if __name__ == "__main__":
    main()
