"""Every GPU figure of docs/benchmarks.md ("On a GPU") in one run:
``python -m dgsdp.benchmarks.gpu [--edge-src EDGE_REPO_DIR] [--out DIR]``.

In order, each as its own process with its own time limit, its output shown and kept in ``--out``:

1. ``benchmarks.training --models small paper``: samples/s, MFU and the weight update of both model sizes;
2. ``benchmarks.training --data data/synthetic``: a training batch from the host loader against windows kept on the
   device (the synthetic dataset is generated there first if missing);
3. ``train.py experiment=quickstart_row12`` (what the style recipe trains, on the accelerator Lightning picks) at two
   step counts: steps/s is the difference of steps over the difference of wall times, so start-up and data loading
   cancel; then a short run with Lightning's simple profiler, whose table shows where a step's time goes;
4. ``benchmarks.edge`` against EDGE's own code (with ``--edge-src``; EDGE's FK needs pytorch3d's Python source on
   ``PYTHONPATH``);
5. the ``-m gpu`` tests.

A step that fails or runs out of time is reported and the run goes on. The summary at the end repeats each step's
figures. ``--device cpu`` with small ``--steps`` runs the same on a CPU (a dry run of the script).
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import time
from datetime import datetime
from pathlib import Path

import torch

# the lines of each step's output that hold its figures (shown again in the summary)
FIGURE_LINES = re.compile(
    r"^(device:|small |paper |ms per batch:|mfu|sampling_speedup|.*speedup_vs_edge|\d+ passed|.* failed|FAILED)"
)
# the profiler's rows worth repeating: a training batch and its parts (the table lists each hook's mean and total)
PROFILE_ROWS = re.compile(
    r"^\|\s*(Total|run_training_epoch|run_training_batch|\[LightningModule\]DanceDiffusion\.optimizer_step|"
    r"\[Strategy\]SingleDeviceStrategy\.(training_step|backward|batch_to_device)|\[_TrainingEpochLoop\]\.train_dataloader_next)\s*\|"
)


def shown(text: str, table_rows: int = 25) -> str:
    """The output worth echoing: no progress bars, the profiler's table cut to its first (largest) rows."""
    lines, rows = [], 0
    for line in text.splitlines():
        if "it/s" in line:
            continue
        if line.startswith("|"):
            rows += 1
            if rows > table_rows:
                continue
        lines.append(line)
    return "\n".join(lines)[-6000:]


def run_step(name: str, command: list[str], out: Path, limit_s: float, env: dict[str, str]) -> tuple[int, float, str]:
    """Run ``command``, echoing and saving its output to ``out/<name>.log``; (exit code, seconds, output)."""
    print(f"\n=== {name}: {' '.join(command)}", flush=True)
    start = time.perf_counter()
    try:
        done = subprocess.run(command, capture_output=True, text=True, timeout=limit_s, env=env)
        code, text = done.returncode, done.stdout + done.stderr
    except subprocess.TimeoutExpired as e:
        code = 124
        text = (e.stdout or b"").decode(errors="replace") if isinstance(e.stdout, bytes) else (e.stdout or "")
        text += f"\n(stopped after {limit_s:.0f} s)"
    seconds = time.perf_counter() - start
    (out / f"{name}.log").write_text(text)
    print(shown(text), flush=True)
    print(f"=== {name}: exit {code}, {seconds:.1f} s", flush=True)
    return code, seconds, text


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    parser.add_argument("--edge-src", help="a checkout of EDGE's repository; without it the EDGE step is left out")
    parser.add_argument("--out", type=Path, default=None, help="where the logs go (default outputs/gpu_figures/<time>)")
    parser.add_argument("--steps", type=int, nargs=2, default=(300, 1500), metavar=("SHORT", "LONG"),
                        help="the two step counts of the quick-start training runs")  # fmt: skip
    parser.add_argument("--profile-steps", type=int, default=300)
    parser.add_argument("--data", type=Path, default=Path("data/synthetic"), help="the synthetic dataset's folder")
    parser.add_argument("--skip", nargs="*", default=[], choices=["training", "data", "train", "edge", "tests"])
    args = parser.parse_args(argv)
    out = args.out or Path("outputs/gpu_figures") / datetime.now().strftime("%Y-%m-%d_%H-%M-%S")
    out.mkdir(parents=True, exist_ok=True)
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "WANDB_MODE": "offline"}
    py = [sys.executable, "-m"]
    device = ["--device", args.device]
    name = torch.cuda.get_device_name(0) if args.device == "cuda" else "CPU"
    print(f"GPU figures on {name}; torch {torch.__version__}; logs in {out}", flush=True)
    results: dict[str, tuple[int, float, str]] = {}
    if "training" not in args.skip:
        results["training"] = run_step(
            "training", [*py, "dgsdp.benchmarks.training", *device, "--models", "small", "paper"], out, 900, env
        )
    if "data" not in args.skip:
        if not (args.data / "motions").is_dir():
            run_step("synthetic", [*py, "dgsdp.data.synthetic", "--out", str(args.data)], out, 600, env)
        results["data"] = run_step(
            "data", [*py, "dgsdp.benchmarks.training", *device, "--data", str(args.data)], out, 600, env
        )
    if "train" not in args.skip:
        accelerator = "gpu" if args.device == "cuda" else "cpu"
        base = [*py, "dgsdp.cli.train", "experiment=quickstart_row12", f"trainer.accelerator={accelerator}",
                f"data.root={args.data}", "logger=none"]  # fmt: skip
        times = {}
        for steps in args.steps:
            code, seconds, text = run_step(
                f"train_{steps}", [*base, f"trainer.max_steps={steps}", f"hydra.run.dir={out}/train_{steps}"],
                out, 1200, env,
            )  # fmt: skip
            results[f"train_{steps}"] = (code, seconds, text)
            times[steps] = seconds if code == 0 else None
        short, long = args.steps
        if times[short] is not None and times[long] is not None and times[long] > times[short]:
            rate = (long - short) / (times[long] - times[short])
            results["train_rate"] = (
                0,
                0.0,
                f"quickstart_row12 training: {rate:.1f} steps/s ({short} and {long} steps)",
            )
        results["profile"] = run_step(
            "profile",
            [*base, f"trainer.max_steps={args.profile_steps}", "+trainer.profiler=simple", f"hydra.run.dir={out}/prof"],
            out, 900, env,
        )  # fmt: skip
    if "edge" not in args.skip and args.edge_src:
        results["edge"] = run_step(
            "edge", [*py, "dgsdp.benchmarks.edge", "--edge-src", args.edge_src, *device], out, 1500, env
        )
    if "tests" not in args.skip and args.device == "cuda":
        results["tests"] = run_step("tests", [*py, "pytest", "-q", "-m", "gpu", "tests"], out, 1200, env)
    print(f"\n=== summary ({name})")
    failed = 0
    for step, (code, seconds, text) in results.items():
        figures = [line for line in text.splitlines() if FIGURE_LINES.match(line.strip()) or PROFILE_ROWS.match(line)]
        if step == "train_rate":
            figures = [text]
        failed += code != 0
        print(f"{step}: exit {code}, {seconds:.1f} s")
        for line in figures[-12:]:
            print(f"  {line.strip()[:200]}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
