"""The learning-rate schedule (optimizer.schedule): its factors worked out by hand, its config checked, and a tiny
run whose optimiser ends on the rate the schedule gives at its last step."""

from __future__ import annotations

import math

import pytest
import torch

from dgsdp.errors import ConfigError
from dgsdp.training.lr_schedule import LRSchedule


def test_factors_by_hand():
    warm_cosine = LRSchedule(warmup_steps=4, decay="cosine", final_lr_ratio=0.1)
    assert [warm_cosine.factor(s, 14) for s in range(4)] == pytest.approx([0.25, 0.5, 0.75, 1.0])
    # after the warm-up: cosine from 1 at step 4 to 0.1 at step 13 (the last), halfway at step 8.5
    assert warm_cosine.factor(4, 14) == pytest.approx(1.0)
    assert warm_cosine.factor(13, 14) == pytest.approx(0.1) and warm_cosine.factor(50, 14) == pytest.approx(0.1)
    progress = (7 - 4) / 9
    assert warm_cosine.factor(7, 14) == pytest.approx(0.1 + 0.9 * 0.5 * (1 + math.cos(math.pi * progress)))
    linear = LRSchedule(decay="linear")
    assert [linear.factor(s, 5) for s in range(5)] == pytest.approx([1.0, 0.75, 0.5, 0.25, 0.0])
    assert LRSchedule().constant and not LRSchedule(warmup_steps=1).constant and LRSchedule().factor(99, 5) == 1.0
    assert LRSchedule(warmup_steps=3).factor(10, 5) == 1.0  # a warm-up alone, then constant


@pytest.mark.parametrize(
    "node, fragment",
    [({"decay": "exp"}, "decay must be one of"), ({"warmup_steps": -1}, "warmup_steps"),
     ({"warmup_steps": 2.5}, "warmup_steps"), ({"final_lr_ratio": 1.5}, "final_lr_ratio"),
     ({"warmup": 3}, "unknown keys"), (["cosine"], "must be a mapping")],
)  # fmt: skip
def test_bad_schedules_are_refused(node, fragment):
    with pytest.raises(ConfigError, match=fragment):
        LRSchedule.from_config(node)


def test_a_decay_needs_the_runs_length():
    optimizer = torch.optim.SGD([torch.nn.Parameter(torch.zeros(1))], lr=1.0)
    with pytest.raises(ConfigError, match="trainer.max_steps"):
        LRSchedule(decay="cosine").scheduler(optimizer, -1)
    scheduler = LRSchedule(warmup_steps=2).scheduler(optimizer, None)  # a warm-up alone needs no length
    assert optimizer.param_groups[0]["lr"] == pytest.approx(0.5)
    optimizer.step()
    scheduler.step()
    assert optimizer.param_groups[0]["lr"] == pytest.approx(1.0)


def test_a_tiny_run_follows_the_schedule(tmp_path):
    """Four steps with a 2-step warm-up and a linear decay to 0.2: the optimiser ends on 0.2 x lr, and the run's
    checkpoint records the schedule with the optimiser."""
    from dgsdp.cli.config import compose_config
    from dgsdp.cli.train import train
    from dgsdp.data.synthetic import generate_synthetic_aistpp
    from dgsdp.safety.checkpoint_file import load_checkpoint

    root = generate_synthetic_aistpp(tmp_path / "data", seed=0, sequences_per_genre=2, seconds=6.0, num_ignored=0)
    overrides = [
        "debug=tiny", f"data.root={root}", "data.synthetic=null", f"paths.cache_dir={tmp_path / 'cache'}",
        "data.progress=false", "logger=none", "~callbacks.progress", "trainer.max_steps=4",
        "trainer.limit_val_batches=0", "optimizer.lr=1e-3",
        "+optimizer.schedule={warmup_steps: 2, decay: linear, final_lr_ratio: 0.2}",
    ]  # fmt: skip
    result = train(compose_config("train", overrides, output_dir=tmp_path / "run"))
    record = load_checkpoint(result["checkpoint"])
    assert record["hyper_parameters"]["optimizer"]["schedule"] == {"warmup_steps": 2, "decay": "linear",
                                                                   "final_lr_ratio": 0.2}  # fmt: skip
    (state,) = record["lr_schedulers"]
    assert state["last_epoch"] == 4 and state["_last_lr"] == pytest.approx([1e-3 * 0.2])
    assert record["train_seconds"] > 0
