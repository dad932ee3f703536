"""Sampler.predict_x0 runs all guidance passes as one batched forward; the result equals separate denoiser passes
combined by the guidance formula by hand."""

import pytest
import torch
from model_helpers import inputs, tiny_denoiser

from dgsdp.diffusion import GaussianDiffusion
from dgsdp.sampling import Condition, Guidance, Sampler

CLOSE = {"rtol": 1e-5, "atol": 1e-5}
B, N = 3, 10


class Recorder(torch.nn.Module):
    """Passes calls to the denoiser and records each call's batch size."""

    def __init__(self, model: torch.nn.Module) -> None:
        super().__init__()
        self.model, self.batches = model, []

    def forward(self, x_t, t, music, style, keep_music, keep_style):
        self.batches.append(x_t.shape[0])
        return self.model(x_t, t, music, style, keep_music, keep_style)


def single(model, x_t, t, music, style, keep_music: bool, keep_style: bool) -> torch.Tensor:
    """One denoiser pass with every row's conditions kept or dropped alike."""
    full = torch.full((x_t.shape[0],), True)
    with torch.no_grad():
        return model(x_t, t, music, style, full & keep_music, full & keep_style)


@pytest.fixture(scope="module")
def model():
    return tiny_denoiser()


def predict(model, clip: bool, style_guidance: bool, cond: Condition, guidance: Guidance, x_t, t):
    recorder = Recorder(model)
    sampler = Sampler(recorder, GaussianDiffusion(num_steps=1000, clip_x0=clip), style_guidance=style_guidance)
    return sampler.predict_x0(x_t, t, cond, guidance), recorder.batches


@pytest.mark.parametrize("per_frame", [False, True])
@pytest.mark.parametrize(("w_music", "w_style"), [(2.5, 1.5), (1.0, 2.0), (0.0, 3.0)])
def test_three_passes_with_style_guidance(model, per_frame, w_music, w_style):
    x_t, t, music, style = inputs(B, N, per_frame=per_frame)
    out, batches = predict(model, False, True, Condition(music, style), Guidance(w_music, w_style), x_t, t)
    assert batches == [3 * B]  # one forward for the three passes
    x_u = single(model, x_t, t, music, style, False, False)
    x_m = single(model, x_t, t, music, style, True, False)
    x_ms = single(model, x_t, t, music, style, True, True)
    expected = x_u + w_music * (x_m - x_u) + w_style * (x_ms - x_m)
    torch.testing.assert_close(out, expected, **CLOSE)
    assert (x_ms - x_m).abs().amax() > 1e-3 and (x_m - x_u).abs().amax() > 1e-3  # the passes differ


@pytest.mark.parametrize("style_guidance", [False, True])
def test_two_passes_music_guidance_keep_the_style(model, style_guidance):
    """Without style guidance (or without a style) both passes keep the style; only music is guided."""
    x_t, t, music, style = inputs(B, N)
    if style_guidance:
        style = None  # style guidance on, but nothing to guide
    out, batches = predict(model, False, style_guidance, Condition(music, style), Guidance(2.0, 3.0), x_t, t)
    assert batches == [2 * B]
    x_u = single(model, x_t, t, music, style, False, True)
    x_m = single(model, x_t, t, music, style, True, True)
    torch.testing.assert_close(out, x_u + 2.0 * (x_m - x_u), **CLOSE)


def test_weights_of_one_run_a_single_conditional_pass(model):
    x_t, t, music, style = inputs(B, N)
    for style_guidance, guidance in ((True, Guidance(1.0, 1.0)), (False, Guidance(1.0, 4.0))):
        out, batches = predict(model, False, style_guidance, Condition(music, style), guidance, x_t, t)
        assert batches == [B]
        torch.testing.assert_close(out, single(model, x_t, t, music, style, True, True), **CLOSE)


def test_guided_prediction_is_clipped_after_combining(model):
    x_t, t, music, style = inputs(B, N)
    out, _ = predict(model, True, True, Condition(music, style), Guidance(6.0, 4.0), x_t, t)
    x_u = single(model, x_t, t, music, style, False, False)
    x_m = single(model, x_t, t, music, style, True, False)
    x_ms = single(model, x_t, t, music, style, True, True)
    combined = x_u + 6.0 * (x_m - x_u) + 4.0 * (x_ms - x_m)
    assert combined.abs().amax() > 1  # the clip matters here
    torch.testing.assert_close(out, combined.clamp(-1, 1), **CLOSE)


def test_guidance_rows_match_rows_guided_alone(model):
    x_t, t, music, style = inputs(B, N)
    cond, guidance = Condition(music, style), Guidance(2.0, 1.5)
    out, _ = predict(model, False, True, cond, guidance, x_t, t)
    for i in range(B):
        row = slice(i, i + 1)
        alone, _ = predict(model, False, True, Condition(music[row], style[row]), guidance, x_t[row], t[row])
        torch.testing.assert_close(out[row], alone, **CLOSE)
