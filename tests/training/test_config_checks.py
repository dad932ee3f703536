"""train.py checks everything it can before any data is prepared: one clear error, no half-made run folder."""

import os
import subprocess
import sys

import pytest
import torch
from test_train import run, tiny_overrides

from dgsdp.cli.config import compose_config
from dgsdp.cli.train import train
from dgsdp.errors import CheckpointError, ConfigError, DgsdpError


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ("model.d_model=0", "model.d_model must be a positive integer"),
        ("model.n_layers=-2", "model.n_layers must be a positive integer"),
        ("model.n_heads=3", "must be a multiple of model.n_heads=3"),
        ("trainer.accelerator=quantum", "trainer.accelerator='quantum' is not one of"),
        ("trainer.devices=0", "trainer.devices must be a positive number"),
        ("evaluate=table9", "evaluate: 'table9' is not one of bailando, finedance, table1, table2, table3"),
        ("ckpt_path=/nonexistent/last.ckpt", "does not exist"),
        ("data.tempo_augment=[1.2,0.9]", "needs 0 < lo <= hi"),
        ("audio=none data.tempo_augment=[0.8,1.25]", "needs an audio encoder that gives features per frame"),
    ],
)
def test_bad_settings_fail_before_any_data_is_prepared(tmp_path, override, message):
    data = {"root": str(tmp_path / "no-dataset-here"), "cache": str(tmp_path / "cache")}
    cfg = compose_config("train", tiny_overrides(data, *override.split()), output_dir=tmp_path / "run")
    with pytest.raises(ConfigError, match=message):
        train(cfg)
    assert not (tmp_path / "no-dataset-here").exists() and not (tmp_path / "cache").exists()


@pytest.mark.skipif(torch.cuda.is_available(), reason="checks the message on a machine without a GPU")
def test_gpu_accelerator_without_a_gpu_says_what_to_use(tmp_path):
    data = {"root": str(tmp_path / "none"), "cache": str(tmp_path / "cache")}
    cfg = compose_config("train", tiny_overrides(data, "trainer.accelerator=gpu"), output_dir=tmp_path)
    with pytest.raises(ConfigError, match="no CUDA GPU; use trainer=cpu"):
        train(cfg)


def test_resume_with_another_optimizer_or_size_lists_every_difference(tmp_path, tiny_synthetic):
    _, first = run(tmp_path / "a", tiny_synthetic, "trainer.max_steps=1", "trainer.limit_val_batches=0")
    with pytest.raises(CheckpointError) as info:
        run(
            tmp_path / "b", tiny_synthetic, "optimizer=adamw", "model.ff_dim=32", "trainer.max_steps=2",
            "trainer.max_epochs=-1",
            f"ckpt_path={first['checkpoint']}",
        )  # fmt: skip
    text = str(info.value)
    assert "optimizer._target_: checkpoint 'dgsdp.training.Adan', config 'torch.optim.AdamW'" in text
    assert "ff_dim" in text


def test_unreadable_checkpoint_is_refused_up_front(tmp_path, tiny_synthetic):
    bad = tmp_path / "garbage.ckpt"
    bad.write_bytes(b"not a checkpoint at all")
    data = {"root": str(tmp_path / "none"), "cache": str(tmp_path / "cache")}
    cfg = compose_config("train", tiny_overrides(data, f"ckpt_path={bad}"), output_dir=tmp_path / "run")
    with pytest.raises(CheckpointError, match="cannot read checkpoint"):
        train(cfg)
    assert not (tmp_path / "none").exists()


def test_command_line_error_is_one_line_and_leaves_no_run_folder(tmp_path, repo_root):
    out = tmp_path / "outputs"
    cmd = [sys.executable, str(repo_root / "train.py"), "model.d_model=0", f"paths.log_dir={out}",
           f"paths.data_dir={tmp_path / 'data'}"]  # fmt: skip
    env = {**os.environ, "PYTHONPATH": str(repo_root), "HF_HUB_OFFLINE": "1", "WANDB_MODE": "offline"}
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=300)
    assert proc.returncode != 0
    assert "model.d_model must be a positive integer" in proc.stderr
    assert "Traceback" not in proc.stderr + proc.stdout
    runs = list((out / "train" / "runs").glob("*")) if (out / "train" / "runs").exists() else []
    assert runs == []
    assert not (tmp_path / "data").exists()


def test_bf16_training_on_a_cpu_without_bf16_instructions_is_refused(tmp_path, monkeypatch):
    import dgsdp.utils.device

    data = {"root": str(tmp_path / "none"), "cache": str(tmp_path / "cache")}
    overrides = tiny_overrides(data, "trainer.accelerator=cpu", "trainer.precision=bf16-mixed")
    cfg = compose_config("train", overrides, output_dir=tmp_path / "run")
    monkeypatch.setattr(dgsdp.utils.device, "cpu_has_native_bf16", lambda: False)
    with pytest.raises(ConfigError, match="trainer.precision=bf16-mixed asks for bf16 autocast on a CPU without bf16"):
        train(cfg)
    assert not (tmp_path / "none").exists()
    monkeypatch.setattr(dgsdp.utils.device, "cpu_has_native_bf16", lambda: True)  # then it goes on to the data
    with pytest.raises(DgsdpError, match=r"no AIST\+\+ dataset at"):
        train(cfg)
