"""Jukebox features: slicing, resampling and layer truncation with a stand-in; tiny real models when
the optional package jukebox-infer is installed; the released weights when DGSDP_JUKEBOX_DIR is set."""

from __future__ import annotations

import os
import sys

import numpy as np
import pytest
import torch
from torch import nn

from dgsdp.audio import JukeboxEncoder
from dgsdp.audio.jukebox_encoder import select_prior_state, slice_starts, truncate_prior
from dgsdp.errors import ConfigError, WeightsError

SR = 44100
TINY_VQVAE = dict(width=8, depth=1, emb_width=8, l_bins=64)
TINY_PRIOR = dict(prior_width=32, prior_depth=3, heads=2, n_ctx=2048, blocks=32, init_scale=1.0)


class StandIn(JukeboxEncoder):
    """Follows the extraction protocol without the package: per slice, 3 columns at 344.53 tokens/s:
    [slice number, peak of the slice it was given, samples it was given]."""

    def __init__(self, **kwargs):
        super().__init__(device="cpu", **kwargs)
        self.feature_dim = 3
        self.slices = 0

    @property
    def token_rate_hz(self) -> float:
        return SR / 128

    def _slice_activations(self, audio):
        n_tokens = len(audio) // 128
        row = [self.slices, np.abs(audio).max(), len(audio)]
        self.slices += 1
        return np.tile(np.asarray(row, np.float32), (n_tokens, 1))


def test_slice_starts_hand_cases():
    assert slice_starts(10, 4) == [0, 4, 6]
    assert slice_starts(8, 4) == [0, 4]
    assert slice_starts(3, 4) == [0]
    assert slice_starts(4, 4) == [0]


def test_stand_in_slices_normalises_and_resamples_a_long_song():
    encoder = StandIn()
    y = np.full(37 * SR, 0.25, np.float32)
    features = encoder.encode(y, SR)
    assert features.shape == (1110, 3) and encoder.slices == 8  # 7 full slices + 1 aligned to the end
    # 5 s slices = 150 frames each; frames 1050.. come from the end-aligned slice starting at 32 s
    expected_slice = np.minimum(np.arange(1110) // 150, 7)
    np.testing.assert_allclose(features[:, 0], expected_slice, atol=1e-4)
    np.testing.assert_allclose(features[:, 1], 1.0, atol=1e-4)  # every slice peak-normalised
    np.testing.assert_allclose(features[:, 2], 5 * SR, rtol=1e-5)  # every slice full length


def test_per_window_features_encode_each_window_as_its_own_slice():
    """EDGE's test.py: every 5 s window (2.5 s apart) is its own slice file, encoded from an empty context; the
    window past the song's end is padded with silence."""
    encoder = StandIn(per_window=True)
    y = np.concatenate([np.full(5 * SR, 0.5), np.full(4 * SR, 0.25)]).astype(np.float32)  # 9 s
    windows = encoder.encode_windows(y, SR, [0, 75, 150], 150)
    assert windows.shape == (3, 150, 3) and encoder.slices == 3
    for k in range(3):
        np.testing.assert_allclose(windows[k, :, 0], k, atol=1e-4)  # one slice per window, in order
    np.testing.assert_allclose(windows[..., 2], 5 * SR, rtol=1e-5)  # each a full 5 s slice (the last padded)
    np.testing.assert_allclose(windows[..., 1], 1.0, atol=1e-4)  # each peak-normalised on its own


def test_stand_in_short_and_silent_audio():
    encoder = StandIn()
    short = encoder.encode(np.full(int(0.2 * SR), 0.5, np.float32), SR)
    assert short.shape == (6, 3) and np.allclose(short[:, 2], int(0.2 * SR), rtol=1e-4)
    silent = StandIn().encode(np.zeros(3 * SR, np.float32), SR)
    assert silent.shape == (90, 3) and np.allclose(silent[:, 1], 0.0, atol=1e-6)


class FakeBlock(nn.Linear):
    pass


class FakePrior(nn.Module):
    """The attributes truncation touches: prior.prior.transformer._attn_mods and prior.prior.x_out."""

    def __init__(self, depth: int) -> None:
        super().__init__()
        self.prior = nn.Module()
        self.prior.transformer = nn.Module()
        self.prior.transformer._attn_mods = nn.ModuleList(FakeBlock(2, 2) for _ in range(depth))
        self.prior.x_out = nn.Linear(2, 5)


def test_layer_truncation_and_state_selection():
    prior = FakePrior(depth=6)
    truncate_prior(prior, 4)
    assert len(prior.prior.transformer._attn_mods) == 4 and not hasattr(prior.prior, "x_out")
    assert prior.prior.only_encode
    for bad in (0, 7):
        with pytest.raises(ConfigError, match="1..6"):
            truncate_prior(FakePrior(depth=6), bad)
    state = {f"module.prior.transformer._attn_mods.{i}.w": torch.zeros(1) for i in range(12)}
    state |= {"module.prior.x_out.weight": torch.zeros(1), "prior.x_emb.weight": torch.zeros(1)}
    kept = select_prior_state(state, layer=10)
    assert sorted(kept) == sorted(["prior.x_emb.weight"] + [f"prior.transformer._attn_mods.{i}.w" for i in range(10)])


def test_missing_package_names_the_pip_extra(monkeypatch):
    # without jukebox-infer (a None entry in sys.modules makes its import fail, installed or not)
    for name in [m for m in sys.modules if m == "jukebox_infer" or m.startswith("jukebox_infer.")]:
        monkeypatch.delitem(sys.modules, name)
    monkeypatch.setitem(sys.modules, "jukebox_infer", None)
    with pytest.raises(WeightsError, match=r"dgsdp\[jukebox\]"):
        JukeboxEncoder(device="cpu").encode(np.zeros(SR, np.float32), SR)


def test_bad_settings():
    with pytest.raises(ConfigError):
        JukeboxEncoder(layer=0)
    with pytest.raises(ConfigError):
        JukeboxEncoder(slice_seconds=0)


# ---------------------------------------------------------------- the real package's model classes


@pytest.fixture(scope="module")
def tiny():
    pytest.importorskip("jukebox_infer")
    torch.manual_seed(0)
    return JukeboxEncoder.from_hparams(TINY_VQVAE, TINY_PRIOR, layer=2, device="cpu", fp16=False)


@pytest.mark.parametrize(("seconds", "n_frames"), [(5.0, 150), (37.0, 1110)])
def test_tiny_model_gives_30_fps_features(tiny, seconds, n_frames):
    y = (0.3 * np.random.default_rng(0).standard_normal(int(seconds * SR))).astype(np.float32)
    features = tiny.encode(y, SR)
    assert features.shape == (n_frames, 32) and np.isfinite(features).all() and features.std() > 0
    assert len(tiny._prior.prior.transformer._attn_mods) == 2
    assert tiny.token_rate_hz == pytest.approx(344.53125)


def test_tiny_model_matches_the_package_forward(monkeypatch):
    """Our conditioning + truncated layer loop equals the package's own full forward pass."""
    pytest.importorskip("jukebox_infer")
    # The package asserts CUDA tensor types; let its checks accept CPU tensors for this comparison.
    monkeypatch.setattr(torch.cuda, "LongTensor", torch.LongTensor)
    small = dict(TINY_PRIOR, n_ctx=256, blocks=4)
    torch.manual_seed(1)
    full = JukeboxEncoder.from_hparams(TINY_VQVAE, small, layer=3, device="cpu", fp16=False)
    prior = full._prior
    tokens = torch.randint(0, 64, (1, 256), generator=torch.Generator().manual_seed(0))
    total = int(62.0 * SR) // prior.raw_to_tokens * prior.raw_to_tokens
    meta = dict(artist="unknown", genre="unknown", total_length=total, offset=0, lyrics="")
    x_cond, y_cond, _ = prior.get_cond(None, prior.get_y(prior.labeller.get_batch_labels([meta], "cpu"), 0))
    reference = prior.prior.forward(tokens, x_cond=x_cond, y_cond=y_cond, fp16=False)[0]
    ours = full._activations(tokens)
    torch.testing.assert_close(ours, reference, rtol=1e-5, atol=1e-6)
    # a shorter clip sees only its own prefix (causal model): same rows as the full sequence
    torch.testing.assert_close(full._activations(tokens[:, :100]), ours[:100], rtol=1e-5, atol=1e-6)
    # truncation really stops early: block 2's output differs from block 3's
    two = JukeboxEncoder.from_hparams(TINY_VQVAE, small, layer=2, device="cpu", fp16=False)
    two._prior.load_state_dict({k: v for k, v in prior.state_dict().items() if ".2." not in k or "_attn_mods" not in k})
    assert (two._activations(tokens) - ours).abs().max() > 1e-3


def test_loading_checkpoints_through_the_meta_device(tiny, tmp_path):
    """The released-weights path (meta build, selected tensors, fp16) on tiny saved checkpoints."""
    torch.save({"model": tiny._vqvae.state_dict()}, tmp_path / "vqvae.pth.tar")
    deeper = JukeboxEncoder.from_hparams(TINY_VQVAE, TINY_PRIOR, layer=3, device="cpu", fp16=False)
    state = {f"module.{k}": v for k, v in deeper._prior.state_dict().items()}
    for k, v in tiny._prior.state_dict().items():  # blocks 0-1 and embeddings from `tiny`
        state[f"module.{k}"] = v
    torch.save({"model": state, "step": 0}, tmp_path / "prior_level_2.pth.tar")
    loaded = JukeboxEncoder(
        weights_dir=tmp_path,
        layer=2,
        device="cpu",
        fp16=True,
        vqvae_overrides=TINY_VQVAE,
        prior_overrides=TINY_PRIOR,
    )
    y = (0.3 * np.random.default_rng(2).standard_normal(3 * SR)).astype(np.float32)
    got = loaded.encode(y, SR)
    assert len(loaded._prior.prior.transformer._attn_mods) == 2
    assert loaded._prior.prior.transformer._attn_mods[0].attn.c_attn.w.dtype == torch.float16
    np.testing.assert_allclose(got, tiny.encode(y, SR), atol=2e-2 * np.abs(got).max())


def test_missing_weights_say_where_and_how(tmp_path):
    pytest.importorskip("jukebox_infer")
    with pytest.raises(WeightsError, match="prior_level_2.pth.tar.*curl"):
        JukeboxEncoder(weights_dir=tmp_path, device="cpu").encode(np.zeros(SR, np.float32), SR)


@pytest.mark.skipif(not os.environ.get("DGSDP_JUKEBOX_DIR"), reason="set DGSDP_JUKEBOX_DIR to the 5B weights")
@pytest.mark.slow
def test_released_weights():
    pytest.importorskip("jukebox_infer")
    encoder = JukeboxEncoder(weights_dir=os.environ["DGSDP_JUKEBOX_DIR"], layer=66)
    t = np.arange(5 * SR) / SR
    features = encoder.encode((0.3 * np.sin(2 * np.pi * 440 * t)).astype(np.float32), SR)
    assert features.shape == (150, 4800) and np.isfinite(features).all()
