"""Entry points: each answers --help; tiny runs of the dataset generator and of training write their files.

All run in one fresh interpreter (tests/cli/cli_driver.py), the way ``python train.py`` and ``python -m ...`` run
them, so that the imports (several seconds) are paid once."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch
import yaml

REPO = Path(__file__).resolve().parents[2]
DRIVER = Path(__file__).with_name("cli_driver.py")

# entry point: (how it is run, a word its help must show). Hydra apps list their config groups and config (the
# README's commands name these keys); argparse tools print a usage line.
HELP = {
    "train.py": ({"script": str(REPO / "train.py")}, "audio"),
    "generate.py": ({"script": str(REPO / "generate.py")}, "checkpoint"),
    "evaluate.py": ({"script": str(REPO / "evaluate.py")}, "checkpoint"),
    "dgsdp.sweep": ({"module": "dgsdp.sweep"}, "usage:"),
    "dgsdp.report": ({"module": "dgsdp.report"}, "usage:"),
    "dgsdp.data.synthetic": ({"module": "dgsdp.data.synthetic"}, "usage:"),
}
TRAIN_STEPS = 2


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Every entry point's --help, then two tiny runs: the synthetic dataset generator (2 genres x 2 dances x 6 s)
    and training on its output (2 steps; no audio encoder: librosa's first feature extraction alone would take
    longer than everything else here)."""
    tmp = tmp_path_factory.mktemp("cli")
    data = tmp / "data"
    jobs = [{"name": name, **target, "argv": ["--help"]} for name, (target, _) in HELP.items()]
    synthetic_argv = ["--out", str(data), "--sequences-per-genre", "2", "--seconds", "6", "--sample-rate", "22050",
                      "--genres", "BR", "PO", "--num-ignored", "0"]  # fmt: skip
    jobs.append({"name": "synthetic", "module": "dgsdp.data.synthetic", "argv": synthetic_argv})
    train_argv = [
        "debug=tiny", "audio=none", "style=onehot", "logger=none", f"data.root={data}", "data.synthetic=null",
        f"paths.cache_dir={tmp / 'cache'}", "data.progress=false", "callbacks.progress.refresh_rate=0",
        f"trainer.max_steps={TRAIN_STEPS}", "trainer.max_epochs=-1", "trainer.limit_val_batches=0",
        f"hydra.run.dir={tmp / 'run'}",
    ]  # fmt: skip
    jobs.append({"name": "train", "script": str(REPO / "train.py"), "argv": train_argv})
    (tmp / "jobs.json").write_text(json.dumps(jobs))
    env = {**os.environ, "PYTHONPATH": str(REPO), "HF_HUB_OFFLINE": "1", "WANDB_MODE": "offline",
           "OMP_NUM_THREADS": "1"}  # fmt: skip
    proc = subprocess.run(
        [sys.executable, str(DRIVER), str(tmp / "results.json"), str(tmp / "jobs.json")],
        cwd=tmp, env=env, capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-3000:]
    return {"results": json.loads((tmp / "results.json").read_text()), "run_dir": tmp / "run", "data": data}


@pytest.mark.parametrize("name", list(HELP))
def test_help(runs, name):
    result = runs["results"][name]
    assert result["code"] == 0, result
    text = result["stdout"]
    assert HELP[name][1] in text.lower(), text[:2000]
    assert len(text.splitlines()) >= 3


def test_synthetic_dataset_run_writes_the_aistpp_layout(runs):
    result = runs["results"]["synthetic"]
    assert result["code"] == 0, (result["code"], result["stderr"][-3000:])
    data = runs["data"]
    motions = sorted(p.stem for p in (data / "motions").glob("*.pkl"))
    assert len(motions) == 4 and {m[:3] for m in motions} == {"gBR", "gPO"}
    music_ids = {m.split("_")[4] for m in motions}
    assert {p.stem for p in (data / "wavs").glob("*.wav")} == music_ids
    listed = [line for f in (data / "splits").glob("*.txt") for line in f.read_text().split()]
    assert set(listed) <= set(motions) and listed


def test_tiny_training_run_writes_a_checkpoint(runs):
    result = runs["results"]["train"]
    assert result["code"] == 0, (result["code"], result["stderr"][-3000:])
    run_dir = runs["run_dir"]
    ckpt_path = run_dir / "checkpoints" / "last.ckpt"
    assert ckpt_path.is_file(), sorted(str(p.relative_to(run_dir)) for p in run_dir.rglob("*"))
    ckpt = torch.load(ckpt_path, map_location="cpu", weights_only=True)
    assert ckpt["global_step"] == TRAIN_STEPS
    weights = [v for k, v in ckpt["state_dict"].items() if k.endswith(".weight")]
    assert weights and all(torch.isfinite(w).all() for w in weights)
    config = yaml.safe_load((run_dir / ".hydra" / "config.yaml").read_text())
    assert config["model"]["d_model"] == 32 and config["trainer"]["max_steps"] == TRAIN_STEPS
