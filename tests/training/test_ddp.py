"""Data-parallel training on 2 CPU processes (gloo), through the real entry point: Lightning's launcher
(``python train.py trainer=ddp trainer.devices=2 trainer.accelerator=cpu``) and torchrun.

Run A trains 8 steps (6 batches per rank make an epoch, so it crosses into epoch 1) and keeps the checkpoints of
steps 3 and 6, as a run killed after step 3 would leave them. Run B resumes A's step-3 checkpoint (mid-epoch)
under torchrun and trains to step 8. A probe callback (ddp_probe.py) records on every rank the windows of each
batch, the timesteps and noise drawn, the losses, the first step's gradients and the final weights.
"""

import csv
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from test_train import tiny_overrides

from dgsdp.cli.config import compose_config
from dgsdp.cli.train import train
from dgsdp.errors import ConfigError

REPO_ROOT = Path(__file__).resolve().parents[2]  # the checkout under test: train.py lives here
BATCH = 4
WORLD = 2


def ddp_args(data, out, probe, *extra):
    return [
        "trainer=ddp", f"trainer.devices={WORLD}", "trainer.accelerator=cpu", *tiny_overrides(data),
        "style=onehot", f"data.batch_size={BATCH}", "trainer.max_epochs=-1", "trainer.limit_val_batches=0",
        "trainer.log_every_n_steps=2", "callbacks.model_checkpoint.every_n_train_steps=3",
        "callbacks.model_checkpoint.save_top_k=-1",
        "+callbacks.probe._target_=tests.training.ddp_probe.Probe", f"+callbacks.probe.out={probe}",
        f"hydra.run.dir={out}", *extra,
    ]  # fmt: skip


def launch(cmd, tmp):
    env = {**os.environ, "PYTHONPATH": str(REPO_ROOT), "OMP_NUM_THREADS": "1", "WANDB_MODE": "offline"}
    env.pop("LOCAL_RANK", None)
    done = subprocess.run(cmd, env=env, cwd=tmp, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-5000:]
    return done


def probes(folder):
    return [torch.load(folder / f"rank{r}.pt", weights_only=True) for r in range(WORLD)]


@pytest.fixture(scope="module")
def run_a(tmp_path_factory, tiny_synthetic):
    tmp = tmp_path_factory.mktemp("ddp_a")
    cmd = [sys.executable, str(REPO_ROOT / "train.py"),
           *ddp_args(tiny_synthetic, tmp / "run", tmp / "probe", "trainer.max_steps=8")]  # fmt: skip
    launch(cmd, tmp)
    return {"dir": tmp / "run", "probe": probes(tmp / "probe")}


@pytest.fixture(scope="module")
def run_b(tmp_path_factory, tiny_synthetic, run_a):
    tmp = tmp_path_factory.mktemp("ddp_b")
    ckpt = run_a["dir"] / "checkpoints" / "step0000003.ckpt"
    cmd = [sys.executable, "-m", "torch.distributed.run", "--standalone", f"--nproc_per_node={WORLD}",
           str(REPO_ROOT / "train.py"),
           *ddp_args(tiny_synthetic, tmp / "run", tmp / "probe", "trainer.max_steps=8", f"ckpt_path={ckpt}")]  # fmt: skip
    launch(cmd, tmp)
    return {"dir": tmp / "run", "probe": probes(tmp / "probe")}


def n_train_windows(data):
    """Windows of the tiny dataset counted from the motion files: (frames - 150) // 15 + 1 per train dance."""
    from dgsdp.data.aistpp import load_motion_pkl, read_split

    total = 0
    for name in read_split(data["root"], "train"):
        poses, _ = load_motion_pkl(f"{data['root']}/motions/{name}.pkl")
        frames_30fps = (len(poses) + 1) // 2  # 60 FPS -> 30 FPS
        total += max(0, (frames_30fps - 150) // 15 + 1)
    return total


def steps_of(probe, epoch=None):
    return [s for s in probe["record"]["steps"] if epoch is None or s["epoch"] == epoch]


def test_each_rank_sees_a_distinct_shard_and_the_epoch_is_covered_once(run_a, tiny_synthetic):
    n = n_train_windows(tiny_synthetic)
    per_rank_batches = n // WORLD // BATCH
    shards = [[w for s in steps_of(p, epoch=0) for w in s["windows"]] for p in run_a["probe"]]
    assert [len(steps_of(p, epoch=0)) for p in run_a["probe"]] == [per_rank_batches] * WORLD
    assert all(len(shard) == len(set(shard)) == per_rank_batches * BATCH for shard in shards)
    assert not set(shards[0]) & set(shards[1])  # disjoint shards
    union = set(shards[0]) | set(shards[1])
    assert len(union) == WORLD * per_rank_batches * BATCH  # each window of the epoch once
    assert n - len(union) < WORLD * BATCH  # only the remainder of a full round of batches waits for a later epoch
    # a new epoch is a new permutation: rank 0's first batch of epoch 1 differs from that of epoch 0
    assert steps_of(run_a["probe"][0], epoch=1)[0]["windows"] != steps_of(run_a["probe"][0], epoch=0)[0]["windows"]


def test_each_rank_draws_its_own_noise_and_timesteps(run_a):
    r0, r1 = (steps_of(p) for p in run_a["probe"])
    assert len(r0) == len(r1) == 8
    for a, b in zip(r0, r1, strict=True):
        assert a["step"] == b["step"]
        assert not torch.equal(a["t"], b["t"])
        assert not torch.allclose(a["noise"], b["noise"])
    # and a rank's draws change from step to step
    assert not torch.equal(r0[0]["t"], r0[1]["t"])


def test_gradients_are_averaged_and_weights_identical_across_ranks(run_a):
    p0, p1 = run_a["probe"]
    g0, g1 = p0["record"]["grads"], p1["record"]["grads"]
    # the gradient DDP applied = the mean of the ranks' own gradients (recomputed on each rank with the step's
    # randomness) = the gradient of one process's loss over the union of the two batches (equal sizes, mean loss)
    assert torch.equal(g0["ddp"], g1["ddp"])
    assert torch.allclose(g0["ddp"], (g0["local"] + g1["local"]) / 2, atol=1e-6, rtol=1e-5)
    assert not torch.allclose(g0["local"], g1["local"])  # the ranks' own gradients did differ
    for key in p0["state"]:  # weights, EMA weights, normaliser, style bank
        assert torch.equal(p0["state"][key], p1["state"][key]), key
    assert p0["state"]["style_vectors"].abs().sum() > 0
    for p in (p0, p1):  # the style bank was built once, not rebuilt by any training step
        assert len({s["style_bank_id"] for s in steps_of(p)}) == 1


@pytest.mark.slow  # a second DDP run (about 25 s of the default suite); the resume itself is tested without DDP
def test_resumed_ddp_run_continues_exactly(run_a, run_b):
    for a, b in zip(run_a["probe"], run_b["probe"], strict=True):
        later = [s for s in steps_of(a) if s["step"] >= 3]
        resumed = steps_of(b)
        assert [s["step"] for s in resumed] == [3, 4, 5, 6, 7]
        for x, y in zip(later, resumed, strict=True):
            assert x["windows"] == y["windows"] and torch.equal(x["t"], y["t"]) and torch.equal(x["noise"], y["noise"])
            assert x["loss"] == y["loss"]
        for key in a["state"]:
            assert torch.equal(a["state"][key], b["state"][key]), key
    # the interrupted epoch: steps 0-2 before the checkpoint and 3-5 after it see every window of it once
    seen = [w for p, q in zip(run_a["probe"], run_b["probe"], strict=True)
            for s in [*steps_of(p, 0)[:3], *steps_of(q, 0)] for w in s["windows"]]  # fmt: skip
    everything = [w for p in run_a["probe"] for s in steps_of(p, 0) for w in s["windows"]]
    assert len(seen) == len(set(seen)) and set(seen) == set(everything)
    a_last = torch.load(run_a["dir"] / "checkpoints" / "last.ckpt", weights_only=True)
    b_last = torch.load(run_b["dir"] / "checkpoints" / "last.ckpt", weights_only=True)
    assert a_last["global_step"] == b_last["global_step"] == 8
    for key in a_last["state_dict"]:
        assert torch.equal(a_last["state_dict"][key], b_last["state_dict"][key]), key


@pytest.mark.parametrize("which", ["run_a", pytest.param("run_b", marks=pytest.mark.slow)])
def test_run_folder_is_written_once(which, request):
    folder = request.getfixturevalue(which)["dir"]
    expected = (
        {"step0000003.ckpt", "step0000006.ckpt", "last.ckpt"} if which == "run_a" else {"step0000006.ckpt", "last.ckpt"}
    )
    assert {p.name for p in (folder / "checkpoints").iterdir()} == expected  # no temporary files left
    assert sorted(p.name for p in folder.glob("*.log")) == ["train.log"]  # rank 1 writes no log of its own
    assert [p.relative_to(folder).as_posix() for p in folder.rglob("metrics.csv")] == ["csv/metrics.csv"]
    rows = list(csv.DictReader((folder / "csv" / "metrics.csv").open()))
    steps = [int(r["step"]) for r in rows if r.get("train/loss")]
    assert steps and len(steps) == len(set(steps))  # each logged step once, not once per rank
    assert sorted(p.name for p in folder.iterdir()) == [".hydra", "checkpoints", "csv", "train.log"]


def test_resume_with_nothing_left_to_do_says_how_to_train_on(tmp_path, run_a, tiny_synthetic):
    last = run_a["dir"] / "checkpoints" / "last.ckpt"
    overrides = [*tiny_overrides(tiny_synthetic), "style=onehot", "trainer.max_epochs=-1", "trainer.max_steps=8",
                 f"ckpt_path={last}"]  # fmt: skip
    cfg = compose_config("train", overrides, output_dir=tmp_path)
    with pytest.raises(ConfigError, match=r"checkpoint is at step 8 and trainer.max_steps=8; raise trainer.max_steps"):
        train(cfg)
    assert not (tmp_path / "checkpoints").exists()
