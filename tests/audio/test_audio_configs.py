"""Every conf/audio/*.yaml builds its encoder through Hydra without loading weights."""

from __future__ import annotations

import pytest
from hydra import compose, initialize_config_dir
from hydra.utils import instantiate

from dgsdp.audio import AUDIO_ENCODERS, EncodecEncoder, JukeboxEncoder, LibrosaEncoder
from dgsdp.resources import CONFIG_DIR

AUDIO_CONF = CONFIG_DIR / "audio"


def build(name: str, overrides: list[str] | None = None):
    with initialize_config_dir(config_dir=str(AUDIO_CONF), version_base="1.3"):
        cfg = compose(config_name=name, overrides=overrides or [])
    return instantiate(cfg)


def test_every_encoder_has_a_config():
    assert set(AUDIO_ENCODERS) <= {p.stem for p in AUDIO_CONF.glob("*.yaml")}


def test_librosa_config_matches_the_paper_settings():
    encoder = build("librosa")
    assert isinstance(encoder, LibrosaEncoder)
    assert (encoder.sample_rate, encoder.hop_length, encoder.feature_dim) == (15360, 512, 35)
    assert encoder.beat_tightness == 100.0


@pytest.mark.parametrize(("name", "cls", "dim"), [("encodec", EncodecEncoder, 128), ("jukebox", JukeboxEncoder, 4800)])
def test_model_configs_build_lazily(name, cls, dim, monkeypatch):
    monkeypatch.delenv("DGSDP_ENCODEC_DIR", raising=False)
    monkeypatch.delenv("DGSDP_JUKEBOX_DIR", raising=False)
    encoder = build(name, ["device=cpu"])
    assert isinstance(encoder, cls) and encoder.feature_dim == dim and encoder.fps == 30
    assert encoder._prior is None if name == "jukebox" else encoder._model is None


def test_config_values_reach_the_encoder(tmp_path, monkeypatch):
    monkeypatch.setenv("DGSDP_JUKEBOX_DIR", str(tmp_path))
    encoder = build("jukebox", ["layer=36", "device=cpu"])
    assert encoder.layer == 36 and encoder.weights_dir == str(tmp_path)
    assert encoder.weight_paths()["prior"] == tmp_path / "prior_level_2.pth.tar"
