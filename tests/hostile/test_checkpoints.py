"""Checkpoints and weights from strangers: truncated, not ours, wrong shapes or dtypes, or a stored config whose
``_target_`` names a function with an attacker's arguments. Each ends in a DgsdpError and runs nothing."""

from __future__ import annotations

import copy
import functools
import os
import pickle
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import refused, shell_touch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "generation"))
from gen_helpers import tiny_model, tiny_spec  # noqa: E402

from dgsdp.audio.jukebox_encoder import _load_checkpoint_state  # noqa: E402
from dgsdp.errors import DgsdpError, WeightsError  # noqa: E402
from dgsdp.trained import load_model  # noqa: E402


@functools.lru_cache(maxsize=1)
def _model():
    return tiny_model()


def save_ckpt(path: Path, hparams: dict | None = None, state: dict | None = None, **extra) -> Path:
    model = _model()
    ckpt = {
        "hyper_parameters": copy.deepcopy(hparams if hparams is not None else model.spec.to_dict()),
        "state_dict": state if state is not None else model.state_dict(),
        **extra,
    }
    torch.save(ckpt, path)
    return path


def test_a_valid_tiny_checkpoint_loads(tmp_path):
    model = load_model(str(save_ckpt(tmp_path / "ok.ckpt")))
    assert model.denoiser.seq_len == 150


@pytest.mark.parametrize("keep", [0, 10, 0.5, 0.95])
def test_truncated_checkpoint(tmp_path, keep):
    blob = save_ckpt(tmp_path / "full.ckpt").read_bytes()
    path = tmp_path / "cut.ckpt"
    path.write_bytes(blob[: keep if isinstance(keep, int) else int(len(blob) * keep)])
    with pytest.raises(DgsdpError) as exc:
        load_model(str(path))
    refused(exc, str(path))


class _Gadget:
    def __init__(self, func, *args):
        self.func, self.args = func, args

    def __reduce__(self):
        return self.func, self.args


def test_pickle_that_is_not_a_zip(tmp_path, marker):
    """An old-style (non-zip) pickle with a payload: torch's weights-only reader refuses it."""
    path = tmp_path / "evil.ckpt"
    path.write_bytes(pickle.dumps({"hyper_parameters": _Gadget(os.system, shell_touch(marker)), "state_dict": {}}))
    with pytest.raises(DgsdpError) as exc:
        load_model(str(path))
    refused(exc, str(path))


def test_torch_saved_object_with_payload(tmp_path, marker):
    path = tmp_path / "evil.ckpt"
    torch.save({"hyper_parameters": _Gadget(os.system, shell_touch(marker)), "state_dict": {}}, path)
    with pytest.raises(DgsdpError) as exc:
        load_model(str(path))
    refused(exc, str(path))


@pytest.mark.parametrize(
    "content, fragment",
    [({"state_dict": {}}, "hyper_parameters"), ({"hyper_parameters": {}}, "state_dict"), ([1, 2, 3], "dgsdp checkpoint"),
     (torch.zeros(3), "dgsdp checkpoint")],
    ids=["no hparams", "no state", "a list", "a tensor"],
)  # fmt: skip
def test_wrong_keys(tmp_path, content, fragment):
    path = tmp_path / "keys.ckpt"
    torch.save(content, path)
    with pytest.raises(DgsdpError) as exc:
        load_model(str(path))
    refused(exc, str(path), fragment)


def test_wrong_shapes(tmp_path):
    state = {k: (torch.zeros(v.shape[0] + 1, *v.shape[1:]) if v.ndim else v) for k, v in _model().state_dict().items()}
    path = save_ckpt(tmp_path / "shapes.ckpt", state=state)
    with pytest.raises(DgsdpError) as exc:
        load_model(str(path))
    refused(exc, str(path), "does not match its own configuration", "(the file holds")


def test_wrong_dtypes(tmp_path):
    """Weights of the wrong dtype (complex tensors, whose imaginary part a float model would drop) are refused."""
    state = {k: (v.to(torch.complex64) if v.is_floating_point() else v) for k, v in _model().state_dict().items()}
    path = save_ckpt(tmp_path / "dtypes.ckpt", state=state)
    with pytest.raises(DgsdpError) as exc:
        load_model(str(path))
    refused(exc, str(path))


@pytest.mark.parametrize("broken", ["model: null", "model.d_model: -4", "model.n_heads: text", "conditioning: []"])
def test_wrong_hyper_parameters(tmp_path, broken):
    hparams = tiny_spec().to_dict()
    section, _, rest = broken.partition(".")
    if rest:
        key, value = rest.split(": ")
        hparams[section][key] = int(value) if value.lstrip("-").isdigit() else value
    else:
        section, value = broken.split(": ")
        hparams[section] = None if value == "null" else []
    path = save_ckpt(tmp_path / "hp.ckpt", hparams=hparams)
    with pytest.raises(DgsdpError) as exc:
        load_model(str(path))
    refused(exc, str(path))


def _targets(marker: Path) -> dict[str, dict]:
    return {
        "builtins.open": {"_target_": "builtins.open", "file": str(marker), "mode": "w"},
        "numpy.savetxt": {"_target_": "numpy.savetxt", "fname": str(marker), "X": [1.0]},
        "os.system": {"_target_": "os.system", "command": shell_touch(marker)},
        "nested": {"_target_": "dgsdp.audio.LibrosaEncoder", "sample_rate": {"_target_": "os.system",
                   "command": shell_touch(marker)}},
    }  # fmt: skip


@pytest.mark.parametrize("target", ["builtins.open", "numpy.savetxt", "os.system", "nested"])
@pytest.mark.parametrize("section", ["audio", "style"])
def test_stored_config_target_never_runs(tmp_path, marker, target, section):
    """The run config stored in a checkpoint is data: its ``_target_`` is never called with its arguments."""
    from dgsdp.generation import DanceGenerator

    hparams = tiny_spec().to_dict()  # its audio config is LibrosaEncoder, 35-d like the tiny model
    hparams[section] = _targets(marker)[target]
    path = save_ckpt(tmp_path / "target.ckpt", hparams=hparams)
    with pytest.raises(DgsdpError) as exc:
        generator = DanceGenerator.from_checkpoint(path, cache_dir=tmp_path / "cache")
        generator.audio_encoder  # noqa: B018 - builds the audio encoder from the stored config
        generator.resolve_style("krump")  # builds the style embedder from the stored config
    refused(exc, target.split(".")[-1] if target != "nested" else "refused")


# --- Jukebox weights: tensors only, no fallback that runs code ------------------------------------------------------
def _jukebox_file(path: Path, zip_format: bool, **entries) -> Path:
    content = {"hps": {"sr": 44100, "levels": 3, "name": "vqvae"}, "model": {"w": torch.ones(2, 2)}, "step": 7}
    content.update(entries)
    torch.save(content, path, _use_new_zipfile_serialization=zip_format)
    return path


@pytest.mark.parametrize("zip_format", [True, False], ids=["zip", "legacy 2020 format"])
def test_jukebox_files_load_as_tensors(tmp_path, zip_format):
    state = _load_checkpoint_state(_jukebox_file(tmp_path / "vqvae.pth.tar", zip_format))
    assert set(state) == {"w"} and torch.equal(state["w"], torch.ones(2, 2))


@pytest.mark.parametrize("zip_format", [True, False], ids=["zip", "legacy"])
def test_jukebox_file_with_payload_is_refused(tmp_path, marker, zip_format):
    path = _jukebox_file(tmp_path / "prior_level_2.pth.tar", zip_format, hps=_Gadget(os.system, shell_touch(marker)))
    with pytest.raises(WeightsError) as exc:
        _load_checkpoint_state(path)
    refused(exc, str(path), "refused", "re-download")


@pytest.mark.parametrize("case", ["truncated", "no model", "text"])
def test_broken_jukebox_files(tmp_path, case):
    path = tmp_path / "vqvae.pth.tar"
    if case == "truncated":
        path.write_bytes(_jukebox_file(tmp_path / "full", True).read_bytes()[:100])
    elif case == "no model":
        torch.save({"hps": {}, "step": 1}, path)
    else:
        path.write_text("<html>404 Not Found</html>")
    with pytest.raises(WeightsError) as exc:
        _load_checkpoint_state(path)
    refused(exc, str(path), "re-download")


def test_no_unsafe_torch_load_left_in_the_package():
    """Every torch.load in dgsdp/ reads weights only (tensors and plain values)."""
    root = Path(__file__).resolve().parents[2] / "dgsdp"
    offenders = []
    for py in root.rglob("*.py"):
        text = py.read_text()
        for i, line in enumerate(text.splitlines(), 1):
            if "weights_only=False" in line or ("pickle.load" in line and "safe_pickle" not in py.name):
                offenders.append(f"{py.relative_to(root)}:{i}")
            if "allow_pickle=True" in line:
                offenders.append(f"{py.relative_to(root)}:{i}")
    assert not offenders, offenders
    assert np is not None


# --- text encoder configs (stored in checkpoints inside the style config) -----------------------------------------
@pytest.mark.parametrize("target", ["builtins.open", "numpy.savetxt", "os.system", "nested", "antigravity.fly"])
def test_text_encoder_config_builds_only_text_encoders(tmp_path, marker, target):
    from dgsdp.style import StyleEmbedder

    configs = {
        "builtins.open": {"_target_": "builtins.open", "file": str(marker), "mode": "w"},
        "numpy.savetxt": {"_target_": "numpy.savetxt", "fname": str(marker), "X": [1.0]},
        "os.system": {"_target_": "os.system", "command": shell_touch(marker)},
        "nested": {"_target_": "dgsdp.style.MiniLMTextEncoder",
                   "device": {"_target_": "builtins.open", "file": str(marker), "mode": "w"}},
        "antigravity.fly": {"_target_": "antigravity.fly"},  # importing a module by name is refused too
    }  # fmt: skip
    embedder = StyleEmbedder("prompt", text_encoder=configs[target], cache_dir=tmp_path)
    with pytest.raises(DgsdpError) as exc:
        embedder.text_encoder  # noqa: B018
    refused(exc, "refused")
    assert "antigravity" not in sys.modules


def test_text_encoder_config_of_the_project_still_builds(tmp_path):
    from dgsdp.style import MiniLMTextEncoder, StyleEmbedder

    embedder = StyleEmbedder("prompt", text_encoder={"_target_": "dgsdp.style.MiniLMTextEncoder", "_recursive_": False})
    assert isinstance(embedder.text_encoder, MiniLMTextEncoder) and not embedder.text_encoder.loaded
