"""A checkpoint's config is data: only the project's registered classes are built from it, nothing it names is
imported or called, and the places it names are never written to."""

import copy
import sys
from pathlib import Path

import pytest
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "generation"))
from gen_helpers import tiny_model  # noqa: E402

from dgsdp.errors import CheckpointError  # noqa: E402
from dgsdp.generation import DanceGenerator  # noqa: E402
from dgsdp.trained import RunSpec, load_model  # noqa: E402
from dgsdp.trained.spec import _upgrade_format1  # noqa: E402


@pytest.fixture(scope="module")
def saved():
    model = tiny_model()
    return {"state_dict": model.state_dict(), "hyper_parameters": model.spec.to_dict(), "dgsdp_format": 2}


def save(tmp_path, ckpt, name="x.ckpt") -> Path:
    path = tmp_path / name
    torch.save(ckpt, path)
    return path


def test_a_clean_checkpoint_loads_and_keeps_its_spec(saved, tmp_path):
    model = load_model(save(tmp_path, saved))
    assert model.spec == RunSpec.from_dict(saved["hyper_parameters"])
    assert model.spec.conditioning.style_dim == 10


ATTACKS = {
    "model": ("builtins.exec", {"__source": "open(MARKER, 'w')"}),
    "diffusion": ("numpy.savetxt", {"fname": "MARKER", "X": [1.0]}),
    "loss": ("pathlib.Path.touch", {"self": "MARKER"}),
    "audio": ("os.system", {"command": "touch MARKER"}),
    "style": ("builtins.open", {"file": "MARKER", "mode": "w"}),
}


@pytest.mark.parametrize("section", sorted(ATTACKS))
def test_a_foreign_target_is_refused_naming_key_and_value(saved, tmp_path, section):
    marker = tmp_path / "marker"
    target, kwargs = ATTACKS[section]
    ckpt = copy.deepcopy(saved)
    ckpt["hyper_parameters"][section] = {
        "_target_": target,
        **{k: str(v).replace("MARKER", str(marker)) for k, v in kwargs.items()},
    }
    path = save(tmp_path, ckpt)
    with pytest.raises(CheckpointError, match=rf"{section}\._target_ = '{target}'"):
        generator = DanceGenerator(load_model(path), cache_dir=tmp_path / "cache")
        generator.audio_encoder  # noqa: B018 - building the audio encoder is where a stored audio config is used
        generator.embedder()
    assert not marker.exists()


def test_a_target_nested_in_a_stored_config_is_refused(saved, tmp_path):
    marker = tmp_path / "marker"
    ckpt = copy.deepcopy(saved)
    ckpt["hyper_parameters"]["style"]["vocab"] = {"_target_": "builtins.open", "file": str(marker), "mode": "w"}
    generator = DanceGenerator(load_model(save(tmp_path, ckpt)), cache_dir=tmp_path / "cache")
    with pytest.raises(CheckpointError, match=r"style\.vocab\._target_"):
        generator.embedder()
    ckpt = copy.deepcopy(saved)
    ckpt["hyper_parameters"]["style"]["kind"] = "prompt"
    ckpt["hyper_parameters"]["style"]["text_encoder"] = {"_target_": "subprocess.run", "args": ["touch", str(marker)]}
    generator = DanceGenerator(load_model(save(tmp_path, ckpt)), cache_dir=tmp_path / "cache")
    with pytest.raises(CheckpointError, match=r"style\.text_encoder\._target_ = 'subprocess.run'"):
        generator.embedder().text_encoder  # noqa: B018
    assert not marker.exists()


def test_stored_write_locations_are_replaced_by_the_callers(saved, tmp_path):
    ckpt = copy.deepcopy(saved)
    elsewhere = tmp_path / "not-here"
    ckpt["hyper_parameters"]["style"]["cache_dir"] = str(elsewhere)
    ckpt["hyper_parameters"]["audio"]["cache_dir"] = str(elsewhere)
    generator = DanceGenerator(load_model(save(tmp_path, ckpt)), cache_dir=tmp_path / "mine")
    assert generator.embedder().cache_dir == tmp_path / "mine"
    assert "cache_dir" not in generator.spec.audio
    assert not elsewhere.exists()


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda h: h.pop("ema_decay"), "no field ema_decay"),
        (lambda h: h["conditioning"].pop("style_dim"), "no field conditioning.style_dim"),
        (lambda h: h.__setitem__("fps", "thirty"), "field fps is 'thirty'"),
        (lambda h: h["model"].__setitem__("d_model", -4), "model.d_model must be a positive integer"),
        (lambda h: h["conditioning"].__setitem__("music_drop_prob", 3.0), "music_drop_prob must lie in"),
    ],
)
def test_missing_or_malformed_fields_are_named(saved, tmp_path, change, message):
    ckpt = copy.deepcopy(saved)
    change(ckpt["hyper_parameters"])
    with pytest.raises(CheckpointError, match=message):
        load_model(save(tmp_path, ckpt))


def test_a_pickled_object_in_a_checkpoint_is_never_loaded(saved, tmp_path):
    marker = tmp_path / "marker"

    class Payload:
        def __reduce__(self):
            return (open, (str(marker), "w"))

    ckpt = copy.deepcopy(saved)
    ckpt["extra"] = Payload()
    path = save(tmp_path, ckpt)  # unpickling this file would call open(marker, "w")
    with pytest.raises(CheckpointError, match="cannot read checkpoint"):
        load_model(path)
    assert not marker.exists()


def test_first_format_checkpoints_upgrade_or_name_the_missing_field():
    first = {
        "model": {"seq_len": 150, "d_model": 32, "n_layers": 1, "n_heads": 2, "ff_dim": 64},
        "conditioning": {"audio_dim": 35, "style_dim": 0, "style_bank_size": 0, "n_genres": 0, "style_kind": "none",
                         "music_drop_prob": 0.25, "style_drop_prob": 0.0},
        "diffusion": {"num_steps": 1000}, "loss": {"simple": 1.0}, "optimizer": {"name": "adamw", "lr": 1e-4},
        "ema": {"decay": 0.99}, "data": {"fps": 30, "window_frames": 150},
        "config": {"seed": 3, "audio": {"_target_": "dgsdp.audio.LibrosaEncoder"}},
    }  # fmt: skip
    spec = RunSpec.from_dict(first)
    assert spec.seed == 3 and spec.optimizer["_target_"] == "torch.optim.AdamW" and spec.ema_decay == 0.99
    assert spec.build_denoiser("checkpoint").d_model == 32
    broken = copy.deepcopy(first)
    del broken["data"]
    with pytest.raises(CheckpointError, match="no field data"):
        _upgrade_format1(broken, "old.ckpt")
