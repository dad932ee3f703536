"""Steps to quality: the style figures of checkpoints saved along training runs, drawn against steps and minutes.

``python -m dgsdp.benchmarks.curves --run row9=RUN[,RUN...] --run row13=RUN[,...] --png curves.png``

Each ``RUN`` is a training run's output folder holding the checkpoints it saved along the way
(``checkpoints/step*.ckpt``: train with ``callbacks.model_checkpoint.save_top_k=-1
callbacks.model_checkpoint.every_n_train_steps=<N>``), one folder per seed of the recipe named before the ``=``.
Every checkpoint is scored by the style benchmark (:mod:`dgsdp.benchmarks.style`) on the raw model (no finishing:
what the model itself does): genre by name, free text on each held-out list (``--heldout``, the three shipped lists
by default), speed words (the modifier pairs ordered right) and speed rank; with ``--protocol table1`` also by the
papers' FID_k and beat alignment (BAS) on the dataset's test split (evaluate.py's protocol, raw model). The time
axis is the checkpoint's own ``train_seconds`` (training wall time up to that checkpoint, validation and saving
included; checkpoints of older runs have none and are drawn against steps only).

The result: a JSON of every figure per checkpoint, and a PNG with one panel per figure, steps on top, minutes below,
one curve per recipe (the mean over its seeds, a band from the lowest to the highest seed), logged to wandb too
with ``--wandb`` (a run named ``curves``; offline unless wandb is set up). Scoring is the slow part: each checkpoint
dances every held-out clip, so ``--max-clips`` (e.g. 40) screens faster on fewer clips.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from dgsdp.errors import ConfigError, DgsdpError

SHIPPED_LISTS = ("aistpp", "aistpp_second", "aistpp_third")
# (key in a point's figures, the panel's title, the target line drawn, if any)
PANELS: tuple[tuple[str, str, float | None], ...] = (
    ("genre_acc", "genre by name", 0.85),
    ("text_acc_min", "free text (worst held-out list)", 0.75),
    ("modifiers_right", "speed words ordered right", 0.85),
    ("speed_spearman", "speed rank (Spearman)", 0.6),
    ("FID_k", "FID_k (test split)", None),
    ("BeatAlign", "beat alignment (test split)", None),
)
_STEP = re.compile(r"step(\d+)")


@dataclass(frozen=True)
class Checkpoint:
    """One checkpoint of a run: its path, its training step and the training seconds it records (None: older)."""

    path: Path
    step: int
    seconds: float | None


def parse_runs(specs: Sequence[str]) -> dict[str, list[Path]]:
    """``["row9=a,b", "row13=c"]`` -> ``{"row9": [a, b], "row13": [c]}``; each folder must exist."""
    runs: dict[str, list[Path]] = {}
    for spec in specs:
        name, sep, folders = spec.partition("=")
        if not sep or not name.strip() or not folders.strip():
            raise ConfigError(f"--run {spec!r}: give NAME=RUN_FOLDER[,RUN_FOLDER...] (one folder per seed)")
        paths = [Path(f).expanduser() for f in folders.split(",") if f.strip()]
        missing = [str(p) for p in paths if not p.is_dir()]
        if missing:
            raise ConfigError(f"--run {name}: no such run folder: {', '.join(missing)}")
        runs.setdefault(name.strip(), []).extend(paths)
    if not runs:
        raise ConfigError("give at least one --run NAME=RUN_FOLDER")
    return runs


def run_checkpoints(run: Path) -> list[Checkpoint]:
    """The step checkpoints a run saved along the way (``checkpoints/step<N>.ckpt``, not ``last.ckpt``), by step,
    each with its recorded training seconds."""
    from dgsdp.safety.checkpoint_file import load_checkpoint

    found = []
    for path in sorted((run / "checkpoints").glob("step*.ckpt")):
        match = _STEP.match(path.stem)
        if match is None:
            continue
        record = load_checkpoint(path, what="checkpoint", mmap=True)
        seconds = record.get("train_seconds")
        step = record.get("global_step")
        found.append(Checkpoint(
            path, int(step) if isinstance(step, int) else int(match.group(1)),
            float(seconds) if isinstance(seconds, int | float) else None,
        ))  # fmt: skip
    if not found:
        raise ConfigError(
            f"{run} has no step checkpoints (checkpoints/step*.ckpt): train it with "
            "callbacks.model_checkpoint.save_top_k=-1 callbacks.model_checkpoint.every_n_train_steps=<N>"
        )
    return sorted(found, key=lambda c: c.step)


def style_figures(result: dict[str, Any]) -> dict[str, float]:
    """The raw model's figures of one style-benchmark result: genre accuracy, free text per held-out list and the
    worst of them, speed words and speed rank."""
    raw = result["raw"]
    out = {key: float(raw.get(key, math.nan)) for key in ("genre_acc", "modifiers_right", "speed_spearman")}
    lists = {name: float(figures["text_acc"]) for name, figures in (raw.get("text_by_list") or {}).items()}
    if not lists:
        lists = {"heldout": float(raw.get("text_acc", math.nan))}
    out.update({f"text_acc/{name}": value for name, value in lists.items()})
    out["text_acc_min"] = min(lists.values())
    return out


def paper_figures(checkpoint: Path, protocol: str, overrides: Sequence[str], out_dir: Path) -> dict[str, float]:
    """FID_k and BeatAlign of the raw model under an evaluate.py protocol (its first model row)."""
    from dgsdp.cli.config import compose_config
    from dgsdp.cli.evaluate import evaluate

    cfg = compose_config(
        "evaluate", [f"checkpoint={checkpoint}", f"protocol={protocol}", "progress=false", *overrides],
        output_dir=out_dir,
    )  # fmt: skip
    rows = evaluate(cfg)["results"]["rows"]
    metrics = rows[0]["metrics"]
    return {
        key: float(metrics[key]["mean"]) if metrics.get(key, {}).get("mean") is not None else math.nan
        for key in ("FID_k", "BeatAlign")
    }


def measure(
    runs: dict[str, list[Path]],
    score: Callable[[Path], dict[str, float]],
    progress: Callable[[str], None] = print,
) -> list[dict[str, Any]]:
    """Every checkpoint of every run scored by ``score`` (path -> figures): one record per checkpoint."""
    points = []
    for recipe, folders in runs.items():
        for seed_index, folder in enumerate(folders):
            for ckpt in run_checkpoints(folder):
                progress(f"{recipe} run {seed_index} ({folder}): step {ckpt.step}")
                figures = score(ckpt.path)
                points.append({
                    "recipe": recipe, "run": str(folder), "seed_index": seed_index, "checkpoint": str(ckpt.path),
                    "step": ckpt.step, "minutes": None if ckpt.seconds is None else ckpt.seconds / 60.0,
                    "figures": figures,
                })  # fmt: skip
    return points


def curves(points: Sequence[dict[str, Any]], key: str, axis: str) -> dict[str, dict[str, np.ndarray]]:
    """Per recipe, ``key`` against ``axis`` ("step" or "minutes"): the mean, lowest and highest over its runs at each
    step (minutes: the runs' mean minutes at that step); points without the axis or the figure are left out."""
    out: dict[str, dict[str, np.ndarray]] = {}
    for recipe in dict.fromkeys(p["recipe"] for p in points):
        by_step: dict[int, list[tuple[float, float]]] = {}
        for p in points:
            value = p["figures"].get(key, math.nan)
            x = p["step"] if axis == "step" else p["minutes"]
            if p["recipe"] != recipe or x is None or not math.isfinite(value):
                continue
            by_step.setdefault(p["step"], []).append((float(x), float(value)))
        if not by_step:
            continue
        steps = sorted(by_step)
        xs = np.array([np.mean([x for x, _ in by_step[s]]) for s in steps])
        values = [[v for _, v in by_step[s]] for s in steps]
        out[recipe] = {
            "x": xs, "mean": np.array([np.mean(v) for v in values]), "low": np.array([min(v) for v in values]),
            "high": np.array([max(v) for v in values]), "runs": np.array([len(v) for v in values]),
        }  # fmt: skip
    return out


def save_png(points: Sequence[dict[str, Any]], path: Path) -> list[str]:
    """The curves as one PNG (figures as columns; steps, then minutes, as rows); returns the figures drawn."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from dgsdp.utils.io import atomic_path

    drawn = [(k, t, target) for k, t, target in PANELS if any(math.isfinite(p["figures"].get(k, math.nan))
                                                            for p in points)]  # fmt: skip
    if not drawn:
        raise ConfigError("no figure to draw: every score was missing")
    timed = any(p["minutes"] is not None for p in points)
    rows = ("step", "minutes") if timed else ("step",)
    fig, axes = plt.subplots(len(rows), len(drawn), figsize=(3.6 * len(drawn), 3.0 * len(rows)), squeeze=False)
    for col, (key, title, target) in enumerate(drawn):
        for row, axis in enumerate(rows):
            ax = axes[row][col]
            for recipe, c in curves(points, key, axis).items():
                line = ax.plot(c["x"], c["mean"], marker="o", ms=3, label=f"{recipe} ({int(c['runs'].max())} runs)")
                if (c["runs"] > 1).any():
                    ax.fill_between(c["x"], c["low"], c["high"], color=line[0].get_color(), alpha=0.2)
            if target is not None:
                ax.axhline(target, color="grey", lw=0.8, ls="--")
            ax.set_xlabel("training steps" if axis == "step" else "training minutes")
            if row == 0:
                ax.set_title(title, fontsize=10)
            ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=7)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=100, format="png")
    plt.close(fig)
    return [k for k, _, _ in drawn]


def log_to_wandb(points: Sequence[dict[str, Any]], png: Path | None, project: str) -> None:
    """The curves' PNG and every point as a table in one wandb run named ``curves``."""
    import wandb

    # the folder read now: wandb keeps the settings of an earlier run in this process otherwise
    run = wandb.init(project=project, name="curves", job_type="curves", dir=os.environ.get("WANDB_DIR") or None)
    try:
        keys = sorted({k for p in points for k in p["figures"]})
        table = wandb.Table(columns=["recipe", "seed_index", "step", "minutes", *keys])
        for p in points:
            table.add_data(p["recipe"], p["seed_index"], p["step"], p["minutes"],
                           *[p["figures"].get(k, math.nan) for k in keys])  # fmt: skip
        logged: dict[str, Any] = {"curves/points": table}
        if png is not None:
            logged["curves/plot"] = wandb.Image(str(png))
        run.log(logged)
    finally:
        run.finish()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m dgsdp.benchmarks.curves",
        description="Steps to quality: style-benchmark figures (and, with --protocol, FID_k and BAS) of the "
        "checkpoints saved along training runs, drawn against steps and training minutes.",
    )
    parser.add_argument("--run", action="append", required=True, metavar="NAME=RUN[,RUN...]",
                        help="a recipe and its run folders (one per seed); repeat for each recipe")  # fmt: skip
    parser.add_argument("--max-clips", type=int, default=None, help="at most this many held-out clips (balanced)")
    parser.add_argument("--heldout", action="append", default=None,
                        help="held-out description lists (default: the three shipped)")  # fmt: skip
    parser.add_argument("--data-root", default=None, help="AIST++-layout dataset (default: each checkpoint's)")
    parser.add_argument("--protocol", default=None, help="also FID_k and BAS under this evaluate.py protocol "
                        "(e.g. table1; slower)")  # fmt: skip
    parser.add_argument("--evaluate-override", action="append", default=[], metavar="KEY=VALUE",
                        help="an evaluate.py override for --protocol (e.g. protocol.trials=1)")  # fmt: skip
    parser.add_argument("--png", type=Path, default=Path("curves.png"), help="the plot (default curves.png)")
    parser.add_argument("--json", type=Path, default=None, help="every figure per checkpoint (default: beside "
                        "the png)")  # fmt: skip
    parser.add_argument("--wandb", default=None, metavar="PROJECT", help="also log the plot and the points there")
    parser.add_argument("overrides", nargs="*", help="generate.py settings for the style benchmark")
    args = parser.parse_args(argv)
    try:
        from dgsdp.benchmarks.style import StyleBenchmark

        runs = parse_runs(args.run)
        heldout = args.heldout or list(SHIPPED_LISTS)
        evaluations = args.png.with_suffix("").with_name(args.png.stem + "-evaluations")

        def score(checkpoint: Path) -> dict[str, float]:
            bench = StyleBenchmark(
                str(checkpoint), args.overrides, data_root=args.data_root, max_clips=args.max_clips, raw_only=True,
                progress=False, heldout=heldout,
            )  # fmt: skip
            figures = style_figures(bench.run())
            if args.protocol:
                out = evaluations / checkpoint.parent.parent.name / checkpoint.stem
                overrides = list(args.evaluate_override)
                if args.data_root:
                    overrides.append(f"data.root={args.data_root}")
                figures.update(paper_figures(checkpoint, args.protocol, overrides, out))
            return figures

        points = measure(runs, score, progress=lambda line: print(line, flush=True))
        from dgsdp.utils.io import atomic_write_text

        json_path = args.json or args.png.with_suffix(".json")
        atomic_write_text(json_path, json.dumps(points, indent=1) + "\n")
        drawn = save_png(points, args.png)
        print(f"curves of {', '.join(drawn)}: {args.png}; every figure: {json_path}")
        if args.wandb:
            log_to_wandb(points, args.png, args.wandb)
    except DgsdpError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
