"""The floor height is a stored fact of each run: measured on the training motions, kept in every checkpoint,
read back by the generator; checkpoints from before it existed load with 0.0; a damaged value is refused."""

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
    "value",
    [torch.tensor(float("nan")), torch.tensor(float("inf")), torch.tensor(55.0), torch.zeros(2), torch.tensor(1)],
    ids=["nan", "inf", "far away", "two numbers", "integer"],
)
def test_damaged_floor_height_is_refused(tmp_path, value):
    model = tiny_model()
    state = dict(model.state_dict())
    state["floor_height"] = value
    with pytest.raises(CheckpointError, match="floor_height|floor"):
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
