"""Evaluation results on disk (JSON and a markdown table) and in the run's loggers (csv, wandb, ...)."""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from dgsdp.errors import DataError
from dgsdp.evaluation.protocols import METRICS
from dgsdp.utils.io import atomic_write_text

RESULTS_JSON = "results.json"
RESULTS_MD = "results.md"
DECIMALS = {"BeatAlign": 4, "PFC": 3, "FID_k": 2, "FID_g": 2, "Div_k": 2, "Div_g": 2, "StyleAcc": 3}
NOT_AVAILABLE = "n/a"


def format_value(metric: str, mean: float | None, std: float | None = None, n: int = 1) -> str:
    """``12.34 ± 0.56`` (std shown when more than one value went into the mean), ``n/a`` for None."""
    if mean is None or not math.isfinite(mean):
        return NOT_AVAILABLE
    d = DECIMALS.get(metric, 3)
    if std is None or n <= 1:
        return f"{mean:.{d}f}"
    return f"{mean:.{d}f} ± {std:.{d}f}"


def markdown_table(header: list[str], rows: Iterable[list[str]]) -> str:
    """A GitHub markdown table."""
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def results_markdown(results: Mapping[str, Any]) -> str:
    """The results of one evaluation as a markdown document: settings line, table, warnings."""
    metrics = list(results.get("metrics", METRICS))
    rows = [
        [row["name"], *(format_value(m, **_stats(row["metrics"][m])) for m in metrics), str(row["trials"])]
        for row in results["rows"]
    ]
    run = results.get("run", {})
    title = f"# Evaluation: protocol {results['protocol']}"
    if run.get("run_name"):
        title += f", run {run['run_name']} (seed {run.get('seed')})"
    out = [title, "", f"Checkpoint: `{results.get('checkpoint', '?')}`", ""]
    sampling = (results.get("settings") or {}).get("sampling")
    if sampling:
        student = "; a guidance-distilled student, one pass per step" if run.get("guidance_student") else ""
        out[-1:] = [f"Sampling: {sampling_summary(sampling)}{student}", ""]
    if results.get("beats"):
        out += [f"BeatAlign scored against: {results['beats']}", ""]
    if results.get("finishing"):
        out += [f"Finishing: {results['finishing']['description']}", ""]
    out.append(markdown_table(["row", *metrics, "trials"], rows))
    notes = [f"- {r['name']}: {r['notes']}" for r in results["rows"] if r.get("notes")]
    if notes:
        out += ["Notes:", *notes, ""]
    if results.get("warnings"):
        out.append("Warnings (values reported as n/a or from a documented fallback):")
        out += [f"- {w['row']} / {w['metric']}: {w['message']}" for w in results["warnings"]]
    return "\n".join(out) + "\n"


def sampling_summary(sampling: Mapping[str, Any]) -> str:
    """One line saying how the dances were sampled, e.g. ``ddim, 50 steps, eta 1, long-form edge, x0 clip 1``."""
    method, steps = sampling.get("method", "?"), sampling.get("steps", "?")
    parts = [f"{method}, {steps} steps"]
    if method == "ddim":
        parts.append(f"eta {sampling.get('eta', '?'):g}" if isinstance(sampling.get("eta"), int | float) else "eta ?")
    parts.append(f"long-form {sampling.get('longform', 'fuse')}")
    clip = sampling.get("clip_x0")
    parts.append("x0 clip of the run" if clip is None else f"x0 clip {clip:g}")
    projected = sampling.get("project_rotations", "none")  # results written before the setting did not project
    if projected != "none":
        parts.append(f"{projected} rotations projected")
    papers = sampling.get("longform") == "edge" and method == "ddim" and projected == "none"
    preset = " (the papers' sampling, sampling=edge)" if papers else ""
    return ", ".join(parts) + preset


def _stats(summary: Mapping[str, Any]) -> dict[str, Any]:
    return {"mean": summary.get("mean"), "std": summary.get("std"), "n": summary.get("n", 1)}


def write_results(results: Mapping[str, Any], out_dir: str | Path) -> dict[str, Path]:
    """Write ``results.json`` and ``results.md`` into ``out_dir``; returns their paths."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = {"json": out_dir / RESULTS_JSON, "markdown": out_dir / RESULTS_MD}
    atomic_write_text(paths["json"], json.dumps(results, indent=1, allow_nan=False))
    atomic_write_text(paths["markdown"], results_markdown(results))
    return paths


def read_results(path: str | Path) -> dict[str, Any]:
    """Read a ``results.json``; DataError for a missing or unreadable file."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as e:
        raise DataError(f"cannot read evaluation results {path} ({e}); re-run the evaluation") from e
    if "rows" not in data or "protocol" not in data:
        raise DataError(f"{path} is not an evaluation result (no 'protocol'/'rows')")
    return data


def flat_metrics(results: Mapping[str, Any]) -> dict[str, float]:
    """``{"eval/<protocol>/<row>/<metric>": mean, ..._std: std}`` of the computable values, for loggers."""
    out = {}
    for row in results["rows"]:
        for metric, summary in row["metrics"].items():
            if summary.get("mean") is not None:
                key = f"eval/{results['protocol']}/{row['name']}/{metric}"
                out[key] = float(summary["mean"])
                out[f"{key}_std"] = float(summary["std"])
    return out


def log_results(results: Mapping[str, Any], loggers: Iterable[Any]) -> None:
    """Send the means and stds to Lightning loggers; wandb also gets the table."""
    metrics = flat_metrics(results)
    names = list(results.get("metrics", METRICS))
    for logger in loggers:
        logger.log_metrics(metrics, step=0)
        if hasattr(logger, "log_table"):
            data = [
                [r["name"], *(r["metrics"][m]["mean"] for m in names), *(r["metrics"][m]["std"] for m in names)]
                for r in results["rows"]
            ]
            columns = ["row", *names, *(f"{m}_std" for m in names)]
            logger.log_table(key=f"eval/{results['protocol']}", columns=columns, data=data)
        logger.save()
        if hasattr(logger, "finalize"):
            logger.finalize("success")
