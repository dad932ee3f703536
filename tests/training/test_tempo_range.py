"""The training songs' tempo range is a stored fact of each run, like its floor: kept in every checkpoint, read
back for tempo folding; checkpoints from before it existed load without one; a damaged value is refused."""

import math
import sys
from pathlib import Path

import pytest
import torch

from dgsdp.errors import CheckpointError, ConfigError
from dgsdp.trained import load_model

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "generation"))
from gen_helpers import tiny_model  # noqa: E402


def save(path: Path, model, state: dict | None = None) -> Path:
    torch.save({"hyper_parameters": model.spec.to_dict(), "state_dict": state or model.state_dict()}, path)
    return path


def test_tempo_range_round_trips_and_old_checkpoints_have_none(tmp_path):
    model = tiny_model()
    assert model.tempo_range is None  # a model that was not trained on songs with known tempi
    model.set_tempo_range((80.0, 135.0))
    assert load_model(save(tmp_path / "new.ckpt", model)).tempo_range == (80.0, 135.0)
    state = {k: v for k, v in model.state_dict().items() if k != "tempo_range_bpm"}
    assert load_model(save(tmp_path / "old.ckpt", model, state)).tempo_range is None
    model.set_tempo_range(None)
    assert model.tempo_range is None and all(math.isnan(v) for v in model.tempo_range_bpm.tolist())


@pytest.mark.parametrize(
    "value",
    [torch.tensor([135.0, 80.0]), torch.tensor([0.0, 80.0]), torch.tensor([80.0, float("inf")]), torch.zeros(3)],
    ids=["reversed", "zero", "inf", "three numbers"],
)
def test_damaged_tempo_range_is_refused(tmp_path, value):
    model = tiny_model()
    state = dict(model.state_dict())
    state["tempo_range_bpm"] = value
    with pytest.raises(CheckpointError, match="tempo_range_bpm|does not match"):
        load_model(save(tmp_path / "bad.ckpt", model, state))
    with pytest.raises(ConfigError, match="tempo range"):
        model.set_tempo_range(value.tolist())
