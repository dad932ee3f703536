"""Encodec encoder on tiny random models of the real architecture; real weights when available."""

from __future__ import annotations

import os

import numpy as np
import pytest
import torch
from transformers import EncodecConfig

from dgsdp.audio import EncodecEncoder, build_audio_encoder
from dgsdp.audio.base import resample_frames
from dgsdp.errors import WeightsError

TINY = dict(num_filters=4, num_residual_layers=1, hidden_size=16, codebook_size=32, codebook_dim=16, num_lstm_layers=1)


def tiny_encoder(**kwargs) -> EncodecEncoder:
    torch.manual_seed(0)
    return EncodecEncoder.from_config(EncodecConfig(**TINY), device="cpu", **kwargs)


@pytest.mark.parametrize(("seconds", "n_frames"), [(5.0, 150), (37.0, 1110)])
def test_tiny_model_gives_30_fps_features(seconds, n_frames):
    encoder = tiny_encoder()
    y = (0.1 * np.random.default_rng(0).standard_normal(int(seconds * 24000))).astype(np.float32)
    features = encoder.encode(y, 24000)
    assert encoder.feature_dim == 16 and features.shape == (n_frames, 16)
    assert np.isfinite(features).all() and features.std() > 0


def test_features_follow_the_raw_75_hz_latent():
    """Row i of the output is the latent at time i/30 s: compare with linear interpolation of the raw latent."""
    encoder = tiny_encoder(chunk_seconds=None)
    t = np.arange(5 * 24000) / 24000
    y = (0.3 * np.sin(2 * np.pi * 200 * t) * (0.5 + 0.5 * np.sin(2 * np.pi * 0.5 * t))).astype(np.float32)
    latent = encoder._latent(y)  # (375, 16) at 75 Hz
    expected = np.stack([np.interp(np.arange(150) / 30, np.arange(375) / 75, c) for c in latent.T], axis=1)
    features = encoder.encode(y, 24000)
    inner = slice(5, 145)  # away from the resampling filter's edges
    scale = np.abs(expected[inner]).max()
    assert np.abs(features[inner] - expected[inner]).max() < 0.05 * scale


def test_chunking_matches_whole_song_when_the_receptive_field_is_finite():
    whole = tiny_encoder(chunk_seconds=None)
    with torch.no_grad():  # a zero LSTM adds nothing: the encoder becomes purely convolutional
        for name, p in whole.model.named_parameters():
            if "lstm" in name:
                p.zero_()
    chunked = tiny_encoder(chunk_seconds=2.0, context_seconds=1.0)
    chunked.model.load_state_dict(whole.model.state_dict())
    y = (0.1 * np.random.default_rng(1).standard_normal(5 * 24000)).astype(np.float32)
    a, b = whole._encode(y, None), chunked._encode(y, None)
    assert a.shape == b.shape == (150, 16)
    np.testing.assert_allclose(a, b, atol=1e-5 * np.abs(a).max())


def test_half_precision_runs():
    features = tiny_encoder(half_precision=True).encode(np.zeros(24000, np.float32) + 0.01, 24000)
    assert features.shape == (30, 16) and features.dtype == np.float32


@pytest.mark.parametrize(("res_type", "tol"), [("fft", 1e-3), ("soxr_hq", 1e-2)])
def test_resample_frames_against_a_sampled_sine(res_type, tol):
    """A 1 Hz sine sampled at 75 Hz, resampled to 30 FPS, is the same sine sampled at 30 FPS."""
    src = np.sin(2 * np.pi * 1.0 * np.arange(750) / 75)[:, None] * np.array([[1.0, -2.0]])
    out = resample_frames(src.astype(np.float32), 75.0, 30.0, res_type=res_type)
    expected = np.sin(2 * np.pi * 1.0 * np.arange(300) / 30)[:, None] * np.array([[1.0, -2.0]])
    assert out.shape == (300, 2)
    np.testing.assert_allclose(out[30:270], expected[30:270], atol=tol * 2)


def test_missing_weights_say_what_to_do(tmp_path):
    y = np.zeros(24000, np.float32)
    with pytest.raises(WeightsError, match="does not exist.*huggingface-cli download"):
        EncodecEncoder(local_dir=tmp_path / "nowhere").encode(y, 24000)
    assert os.environ.get("HF_HUB_OFFLINE") == "1"
    with pytest.raises(WeightsError, match="Cannot load Encodec weights.*HF_HUB_OFFLINE"):
        build_audio_encoder("encodec", model_id="dgsdp-test/no-such-model").encode(y, 24000)


def test_settings_change_the_cache_namespace():
    assert EncodecEncoder().settings() != EncodecEncoder(chunk_seconds=10.0).settings()


@pytest.mark.skipif(not os.environ.get("DGSDP_ENCODEC_DIR"), reason="set DGSDP_ENCODEC_DIR to the weights folder")
def test_real_weights():
    encoder = EncodecEncoder(local_dir=os.environ["DGSDP_ENCODEC_DIR"], device="cpu")
    t = np.arange(5 * 24000) / 24000
    features = encoder.encode((0.3 * np.sin(2 * np.pi * 440 * t)).astype(np.float32), 24000)
    assert features.shape == (150, 128) and np.isfinite(features).all()
