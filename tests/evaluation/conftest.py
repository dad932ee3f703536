"""A tiny trained checkpoint on a small synthetic dataset, evaluated with table1 right after training."""

import pytest

from dgsdp.cli.config import compose_config
from dgsdp.cli.train import train
from dgsdp.data.synthetic import generate_synthetic_aistpp

FAST_EVAL = ["sampling.steps=2", "progress=false"]


@pytest.fixture(scope="session")
def eval_data(tmp_path_factory):
    base = tmp_path_factory.mktemp("eval_data")
    root = generate_synthetic_aistpp(base / "data", seed=0, sequences_per_genre=2, seconds=7.0, num_ignored=0)
    return {"root": str(root), "cache": str(base / "cache")}


@pytest.fixture(scope="session")
def trained_run(tmp_path_factory, eval_data):
    """Train a random-init tiny model (4 steps, one-hot style) with ``evaluate=table1`` (2 trials, 2 DDIM steps)."""
    out = tmp_path_factory.mktemp("eval_run")
    overrides = [
        "debug=tiny", f"data.root={eval_data['root']}", "data.synthetic=null", f"paths.cache_dir={eval_data['cache']}",
        "data.progress=false", "logger=csv", "callbacks.progress.refresh_rate=0", "style=onehot",
        "trainer.limit_val_batches=0", "evaluate=table1",
        'evaluate_overrides=["sampling.steps=2","protocol.trials=2","progress=false"]',
    ]  # fmt: skip
    cfg = compose_config("train", overrides, output_dir=out)
    result = train(cfg)
    return {"dir": out, "checkpoint": result["checkpoint"], "evaluation": result["evaluation"], **eval_data}


def compose_eval(run, output_dir, *overrides):
    """The evaluate config for the trained run's checkpoint, fast sampling, written to ``output_dir``."""
    return compose_config(
        "evaluate", [f"checkpoint={run['checkpoint']}", *FAST_EVAL, *overrides], output_dir=output_dir
    )
