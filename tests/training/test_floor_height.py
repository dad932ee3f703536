"""The floor height is a stored fact of each run: measured on the training motions, kept in every checkpoint,
read back by the generator; checkpoints from before it existed load with 0.0; a damaged value is refused. So is the
training songs' tempo range (for tempo folding), which older checkpoints load without."""

import math
import pickle
import shutil
import sys
from pathlib import Path

import pytest
import torch

from dgsdp.cli.config import compose_config
from dgsdp.cli.train import train
from dgsdp.errors import CheckpointError, ConfigError
from dgsdp.generation import DanceGenerator
from dgsdp.trained import load_model

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "generation"))
from gen_helpers import tiny_model  # noqa: E402


def save(path: Path, model, state: dict | None = None) -> Path:
    torch.save({"hyper_parameters": model.spec.to_dict(), "state_dict": state or model.state_dict()}, path)
    return path


def test_floor_height_round_trips_through_a_checkpoint(tmp_path):
    model = tiny_model()
    model.set_floor_height(0.42)
    loaded = load_model(save(tmp_path / "floor.ckpt", model))
    assert float(loaded.floor_height) == pytest.approx(0.42)
    assert DanceGenerator(loaded, cache_dir=tmp_path / "cache").floor_height == pytest.approx(0.42)


def test_checkpoint_without_floor_height_loads_with_zero(tmp_path):
    model = tiny_model()
    model.set_floor_height(0.42)
    state = {k: v for k, v in model.state_dict().items() if k != "floor_height"}
    loaded = load_model(save(tmp_path / "old.ckpt", model, state))
    assert float(loaded.floor_height) == 0.0


@pytest.mark.parametrize(
    ("key", "value"),
    [
        ("floor_height", torch.tensor(float("nan"))),
        ("floor_height", torch.tensor(float("inf"))),
        ("floor_height", torch.tensor(55.0)),
        ("floor_height", torch.zeros(2)),
        ("floor_height", torch.tensor(1)),
        ("tempo_range_bpm", torch.tensor([135.0, 80.0])),
        ("tempo_range_bpm", torch.tensor([0.0, 80.0])),
        ("tempo_range_bpm", torch.tensor([80.0, float("inf")])),
        ("tempo_range_bpm", torch.zeros(3)),
    ],
    ids=[
        "nan",
        "inf",
        "far away",
        "two numbers",
        "integer",
        "tempi reversed",
        "tempo zero",
        "tempo inf",
        "three tempi",
    ],
)
def test_damaged_floor_height_or_tempo_range_is_refused(tmp_path, key, value):
    model = tiny_model()
    state = dict(model.state_dict())
    state[key] = value
    with pytest.raises(CheckpointError, match=f"{key}|floor|does not match"):
        load_model(save(tmp_path / "bad.ckpt", model, state))


def test_set_floor_height_checks_its_value():
    model = tiny_model()
    for bad in (float("nan"), 100.0, "0.1", True):
        with pytest.raises(ConfigError):
            model.set_floor_height(bad)


def test_training_stores_the_floor_of_its_data(tmp_path, tiny_synthetic):
    """The synthetic dataset's floor is y = 0 by construction; raised by 0.25 m, the run's checkpoint says 0.25."""
    root = tmp_path / "raised"
    shutil.copytree(tiny_synthetic["root"], root)
    for path in (root / "motions").glob("*.pkl"):
        with open(path, "rb") as f:
            data = pickle.load(f)  # the dataset this test just wrote
        data["smpl_trans"][:, 1] += 0.25 * float(data["smpl_scaling"][0])
        with open(path, "wb") as f:
            pickle.dump(data, f)
    overrides = [
        "debug=tiny", f"data.root={root}", f"paths.cache_dir={tiny_synthetic['cache']}", "data.synthetic=null",
        "data.progress=false", "logger=csv", "callbacks.progress.refresh_rate=0", "trainer.max_steps=1",
        "trainer.limit_val_batches=0",
    ]  # fmt: skip
    result = train(compose_config("train", overrides, output_dir=tmp_path / "run"))
    ckpt = torch.load(result["checkpoint"], map_location="cpu", weights_only=True)
    assert float(ckpt["state_dict"]["floor_height"]) == pytest.approx(0.25, abs=1e-3)
    assert float(load_model(result["checkpoint"]).floor_height) == pytest.approx(0.25, abs=1e-3)


def test_tempo_range_round_trips_and_old_checkpoints_have_none(tmp_path):
    model = tiny_model()
    assert model.tempo_range is None  # a model that was not trained on songs with known tempi
    model.set_tempo_range((80.0, 135.0))
    assert load_model(save(tmp_path / "new.ckpt", model)).tempo_range == (80.0, 135.0)
    state = {k: v for k, v in model.state_dict().items() if k != "tempo_range_bpm"}
    assert load_model(save(tmp_path / "old.ckpt", model, state)).tempo_range is None
    model.set_tempo_range(None)
    assert model.tempo_range is None and all(math.isnan(v) for v in model.tempo_range_bpm.tolist())


def test_set_tempo_range_checks_its_value():
    model = tiny_model()
    for bad in ([135.0, 80.0], [0.0, 80.0], [80.0, float("inf")], [1.0, 2.0, 3.0], "fast"):
        with pytest.raises(ConfigError, match="tempo range"):
            model.set_tempo_range(bad)
