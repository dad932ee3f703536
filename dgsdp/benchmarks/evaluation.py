"""Evaluation benchmark: ``python -m dgsdp.benchmarks.evaluation [--steps 2] [--trials 1]``.

Times (1) kinetic + geometric features of 100 random motions of 300 frames (60 FPS, y-up), and (2) the whole
``table1`` protocol on CPU with a tiny random-init model trained for a few steps on a small synthetic dataset
(data generation and training are timed apart and not counted).
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from dgsdp.metrics import geometric_features_batch, kinetic_features_batch


def time_features(n: int = 100, frames: int = 300, seed: int = 0) -> float:
    """Seconds for the kinetic and geometric features of ``n`` random-walk motions (frames, 24, 3)."""
    rng = np.random.default_rng(seed)
    motions = [np.cumsum(rng.normal(0, 0.01, (frames, 24, 3)), axis=0) + [0, 1, 0] for _ in range(n)]
    start = time.perf_counter()
    kinetic_features_batch(motions, fps=60)
    geometric_features_batch(motions, fps=60)
    return time.perf_counter() - start


def time_table1(workdir: Path, steps: int, trials: int) -> dict[str, float]:
    """Seconds to prepare (data + tiny training) and to run the table1 protocol on the resulting checkpoint."""
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    os.environ.setdefault("WANDB_MODE", "offline")
    from dgsdp.cli.config import compose_config
    from dgsdp.cli.evaluate import evaluate
    from dgsdp.cli.train import train
    from dgsdp.data.synthetic import generate_synthetic_aistpp

    t0 = time.perf_counter()
    root = generate_synthetic_aistpp(workdir / "data", sequences_per_genre=2, seconds=7.0, num_ignored=0)
    cache = workdir / "cache"
    cfg = compose_config("train", [
        "debug=tiny", f"data.root={root}", "data.synthetic=null", f"paths.cache_dir={cache}", "data.progress=false",
        "logger=none", "callbacks.progress.refresh_rate=0", "style=onehot", "trainer.limit_val_batches=0",
    ], output_dir=workdir / "train")  # fmt: skip
    checkpoint = train(cfg)["checkpoint"]
    t1 = time.perf_counter()
    cfg = compose_config("evaluate", [
        f"checkpoint={checkpoint}", "protocol=table1", f"sampling.steps={steps}", f"protocol.trials={trials}",
        "progress=false", "logger=none", "device=cpu",
    ], output_dir=workdir / "eval")  # fmt: skip
    results = evaluate(cfg)["results"]
    t2 = time.perf_counter()
    return {"prepare_s": t1 - t0, "table1_s": t2 - t1, "clips": float(results["n_clips"]["5"])}


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m dgsdp.benchmarks.evaluation", description=__doc__)
    parser.add_argument("--steps", type=int, default=2, help="DDIM sampling steps of the table1 run")
    parser.add_argument("--trials", type=int, default=1, help="trials of the table1 run")
    parser.add_argument("--skip-protocol", action="store_true", help="only time the features")
    args = parser.parse_args(argv)
    seconds = time_features()
    print(f"features: kinetic + geometric of 100 x 300 frames: {seconds:.2f} s ({seconds * 10:.1f} ms per motion)")
    if args.skip_protocol:
        return
    with tempfile.TemporaryDirectory() as tmp:
        t = time_table1(Path(tmp), args.steps, args.trials)
    print(
        f"table1 protocol, tiny model, CPU, {args.steps} DDIM steps, {args.trials} trial(s), {t['clips']:.0f} clips, "
        f"2 guidance rows + ground truth: {t['table1_s']:.1f} s (data + training beforehand: {t['prepare_s']:.1f} s)"
    )


if __name__ == "__main__":
    main()
