"""Training runs: tiny runs of the real configs on synthetic data, resume, checkpoints, dashboards."""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

from dgsdp.cli.config import compose_config
from dgsdp.cli.train import train
from dgsdp.errors import ConfigError
from dgsdp.trained import load_model

COMBOS = [
    ("librosa", "none", "modulation"),
    ("librosa", "onehot", "modulation"),
    ("librosa", "onehot", "concat"),
    ("librosa", "genre", "modulation"),
    ("librosa", "genre", "concat"),
    ("librosa", "prompt", "modulation"),
    ("librosa", "prompt", "concat"),
    ("none", "prompt", "modulation"),
]


def tiny_overrides(data, *extra):
    return [
        "debug=tiny", f"data.root={data['root']}", f"paths.cache_dir={data['cache']}", "data.synthetic=null",
        "data.progress=false", "logger=csv", "callbacks.progress.refresh_rate=0", *extra,
    ]  # fmt: skip


def run(tmp_path, data, *extra):
    cfg = compose_config("train", tiny_overrides(data, *extra), output_dir=tmp_path)
    return cfg, train(cfg)


@pytest.mark.parametrize(("audio", "style", "injection"), COMBOS)
def test_fast_dev_run_audio_style_injection(tmp_path, tiny_synthetic, audio, style, injection):
    cfg, result = run(
        tmp_path, tiny_synthetic, f"audio={audio}", f"style={style}", f"style_injection={injection}",
        "+trainer.fast_dev_run=true",
    )  # fmt: skip
    assert result["global_step"] == 1
    assert torch.isfinite(torch.tensor(result["metrics"]["train/loss"]))


def test_fast_dev_run_encodec_tiny_model(tmp_path, tiny_synthetic):
    from transformers import EncodecConfig, EncodecModel

    torch.manual_seed(0)
    tiny = dict(num_filters=4, num_residual_layers=1, hidden_size=16, codebook_size=32, codebook_dim=16)
    EncodecModel(EncodecConfig(num_lstm_layers=1, **tiny)).save_pretrained(tmp_path / "encodec")
    cfg, result = run(
        tmp_path, tiny_synthetic, "audio=encodec", f"audio.local_dir={tmp_path / 'encodec'}", "audio.device=cpu",
        "+trainer.fast_dev_run=true",
    )  # fmt: skip
    assert result["global_step"] == 1
    ckpt_cfg = cfg.audio
    assert ckpt_cfg.model_id == "facebook/encodec_24khz"


def _state(path):
    return torch.load(path, map_location="cpu", weights_only=True)


def test_resume_matches_uninterrupted_run(tmp_path, tiny_synthetic):
    extra = ("trainer.limit_val_batches=0", "callbacks.model_checkpoint.every_n_train_steps=3")
    _, full = run(tmp_path / "full", tiny_synthetic, "trainer.max_steps=6", *extra)
    _, half = run(tmp_path / "half", tiny_synthetic, "trainer.max_steps=3", *extra)
    half_ckpt = _state(half["checkpoint"])
    assert half_ckpt["global_step"] == 3
    _, resumed = run(
        tmp_path / "resumed", tiny_synthetic, "trainer.max_steps=6", f"ckpt_path={half['checkpoint']}", *extra
    )
    a, b = _state(full["checkpoint"]), _state(resumed["checkpoint"])
    assert a["global_step"] == b["global_step"] == 6
    for key in a["state_dict"]:  # weights, EMA weights, normaliser, style bank: exact
        assert torch.equal(a["state_dict"][key], b["state_dict"][key]), key
    opt_a, opt_b = a["optimizer_states"][0]["state"], b["optimizer_states"][0]["state"]
    assert opt_a.keys() == opt_b.keys()
    for p in opt_a:
        for k in opt_a[p]:
            assert torch.equal(torch.as_tensor(opt_a[p][k]), torch.as_tensor(opt_b[p][k])), (p, k)


def test_checkpoint_is_plain_and_loads_weights_only(tmp_path, tiny_synthetic):
    _, result = run(tmp_path, tiny_synthetic, "trainer.max_steps=2", "trainer.limit_val_batches=0")
    ckpt = torch.load(result["checkpoint"], map_location="cpu", weights_only=True)
    assert type(ckpt["hyper_parameters"]) is dict
    assert ckpt["hyper_parameters"]["conditioning"]["audio_dim"] == 35
    assert "ema.module.output_proj.weight" in ckpt["state_dict"]
    assert "normalizer.data_min" in ckpt["state_dict"] and "style_vectors" in ckpt["state_dict"]
    model = load_model(result["checkpoint"])
    assert torch.equal(model.normalizer.data_min, ckpt["state_dict"]["normalizer.data_min"])


def test_checkpoint_from_other_config_fails_clearly(tmp_path, tiny_synthetic):
    _, result = run(tmp_path / "a", tiny_synthetic, "trainer.max_steps=1", "trainer.limit_val_batches=0")
    with pytest.raises(ConfigError, match=r"(?s)different configuration:.*audio_dim: checkpoint 35, config 0"):
        run(
            tmp_path / "b",
            tiny_synthetic,
            "audio=none",
            "trainer.max_steps=2",
            "trainer.max_epochs=-1",
            f"ckpt_path={result['checkpoint']}",
        )
    with pytest.raises(ConfigError, match="does not exist"):
        run(tmp_path / "c", tiny_synthetic, f"ckpt_path={tmp_path / 'missing.ckpt'}")


def test_killed_run_loses_at_most_the_steps_since_last_checkpoint(tmp_path, tiny_synthetic, repo_root):
    """Kill a training process after its first checkpoint, then resume from last.ckpt."""
    out = tmp_path / "run"
    args = [
        sys.executable, str(repo_root / "train.py"), *tiny_overrides(tiny_synthetic),
        "trainer.max_steps=100000", "trainer.max_epochs=-1", "trainer.limit_val_batches=0",
        "callbacks.model_checkpoint.every_n_train_steps=2", f"hydra.run.dir={out}",
    ]  # fmt: skip
    env = {**os.environ, "PYTHONPATH": str(repo_root)}
    proc = subprocess.Popen(args, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    last = out / "checkpoints" / "last.ckpt"
    try:
        import time

        deadline = time.time() + 240
        while time.time() < deadline and not (last.is_file() and _state(last)["global_step"] >= 4):
            time.sleep(0.5)
    finally:
        proc.kill()
        proc.wait()
    saved_step = _state(last)["global_step"]
    assert saved_step >= 4 and saved_step % 2 == 0
    _, resumed = run(
        tmp_path / "resumed", tiny_synthetic, f"trainer.max_steps={saved_step + 2}", "trainer.max_epochs=-1",
        "trainer.limit_val_batches=0",
        f"ckpt_path={last}",
    )  # fmt: skip
    assert resumed["global_step"] == saved_step + 2


def test_wandb_offline_run_holds_config_and_group_choices(tmp_path, tiny_synthetic, monkeypatch):
    monkeypatch.setenv("WANDB_MODE", "offline")
    _, result = run(tmp_path, tiny_synthetic, "logger=wandb", "trainer.max_steps=1", "trainer.limit_val_batches=0")
    runs = list((tmp_path / "wandb").glob("offline-run-*"))
    assert len(runs) == 1
    record = yaml.safe_load((runs[0] / "files" / "dgsdp_config.yaml").read_text())
    groups = record["groups"]
    assert groups["audio"] == "librosa" and groups["style"] == "prompt" and groups["style_injection"] == "modulation"
    assert record["config"]["model"]["d_model"] == 32
    # the same values went to wandb's own run log (what `wandb sync` uploads)
    log = next(runs[0].glob("run-*.wandb")).read_bytes()
    compact = log.replace(b" ", b"")
    assert b'"style_injection":"modulation"' in compact and b'"audio":"librosa"' in compact and b"d_model" in log


def test_resumed_run_continues_its_wandb_run(tmp_path, tiny_synthetic, monkeypatch):
    monkeypatch.setenv("WANDB_MODE", "offline")
    extra = ("logger=wandb", "trainer.limit_val_batches=0", "trainer.max_epochs=-1")
    _, first = run(tmp_path / "a", tiny_synthetic, "trainer.max_steps=1", *extra)
    _, resumed = run(tmp_path / "b", tiny_synthetic, "trainer.max_steps=2", f"ckpt_path={first['checkpoint']}", *extra)
    run_id = _state(first["checkpoint"])["logger_run_ids"]["WandbLogger"]
    assert resumed["global_step"] == 2
    assert next((tmp_path / "b" / "wandb").glob("offline-run-*")).name.endswith(run_id)
    assert _state(resumed["checkpoint"])["logger_run_ids"]["WandbLogger"] == run_id


@pytest.mark.slow  # two subprocess jobs (about 14 s); one job's wandb run is tested in the default suite
def test_two_job_multirun_creates_two_wandb_runs(tmp_path, tiny_synthetic, repo_root):
    sweep = tmp_path / "sweep"
    args = [
        sys.executable, str(repo_root / "train.py"), "-m", *tiny_overrides(tiny_synthetic),
        "logger=wandb", "trainer.max_steps=1", "trainer.limit_val_batches=0", "seed=0,1", "sweep_name=test-sweep",
        f"hydra.sweep.dir={sweep}",
    ]  # fmt: skip
    env = {**os.environ, "PYTHONPATH": str(repo_root), "WANDB_MODE": "offline"}
    done = subprocess.run(args, env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    runs = sorted(sweep.glob("*/wandb/offline-run-*"))
    assert len(runs) == 2
    seeds = set()
    for r in runs:
        record = yaml.safe_load((r / "files" / "dgsdp_config.yaml").read_text())
        assert record["config"]["sweep_name"] == "test-sweep"
        seeds.add(record["config"]["seed"])
        assert b"test-sweep" in next(r.glob("run-*.wandb")).read_bytes()  # the wandb group
    assert seeds == {0, 1}
    assert len({Path(r).name for r in runs}) == 2


@pytest.mark.slow
def test_it_learns_and_music_helps(tmp_path):
    """The small model on the default synthetic dataset: the validation loss (EMA weights, fixed noise) falls well
    below its value at initialisation, and below that of a no-music model trained identically."""
    import lightning as L
    from hydra.utils import instantiate

    from dgsdp.cli.train import audio_encoder_from_config
    from dgsdp.data.synthetic import generate_synthetic_aistpp

    root = generate_synthetic_aistpp(tmp_path / "data", seed=0)
    common = [
        f"data.root={root}", f"paths.cache_dir={tmp_path / 'cache'}", "data.synthetic=null", "data.progress=false",
        "logger=csv", "trainer.max_steps=400", "trainer.check_val_every_n_epoch=100",
        "callbacks.progress.refresh_rate=0", "model.ema_decay=0.99", "style=none",
    ]  # fmt: skip
    val_loss = {}
    for audio in ("librosa", "none"):
        cfg = compose_config("train", [*common, f"audio={audio}"], output_dir=tmp_path / audio)
        datamodule = instantiate(cfg.data, audio_encoder=audio_encoder_from_config(cfg))
        result = train(cfg)
        model = load_model(result["checkpoint"])
        trainer = L.Trainer(logger=False, enable_progress_bar=False, accelerator="cpu")
        val_loss[audio] = trainer.validate(model, datamodule=datamodule, verbose=False)[0]["val/loss"]
        if audio == "librosa":  # a freshly initialised model of the same config (its EMA = its initial weights)
            torch.manual_seed(0)
            untrained = type(model)(model.spec)
            untrained.normalizer.load_state_dict(model.normalizer.state_dict())
            val_loss["initial"] = trainer.validate(untrained, datamodule=datamodule, verbose=False)[0]["val/loss"]
    print(val_loss)
    assert val_loss["librosa"] < 0.5 * val_loss["initial"]
    assert val_loss["librosa"] < val_loss["none"]


def test_sample_render_callback_writes_samples(tmp_path, tiny_synthetic):
    _, result = run(
        tmp_path, tiny_synthetic, "+trainer.limit_train_batches=2", "callbacks.samples.every_n_epochs=1",
        "callbacks.samples.num_samples=1", "callbacks.samples.sampling_steps=2",
    )  # fmt: skip
    folder = tmp_path / "samples" / "epoch0000"
    joints = np.load(folder / "sample0.npy")
    assert joints.shape == (150, 24, 3) and np.isfinite(joints).all()
    assert any(folder.glob("sample0.*4")) or any(folder.glob("sample0.gif"))  # the rendered video
