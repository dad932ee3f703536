"""Conditioning computed once per sampling run gives the same predictions and samples as the per-step path."""

import pytest
import torch

from dgsdp.diffusion import GaussianDiffusion
from dgsdp.generation import ChunkedDenoiser
from dgsdp.model import DanceDenoiser
from dgsdp.sampling import Condition, Guidance, Sampler


def tiny_denoiser(injection: str, **kwargs) -> DanceDenoiser:
    torch.manual_seed(0)
    model = DanceDenoiser(pose_dim=151, seq_len=40, d_model=32, n_layers=2, n_heads=2, ff_dim=64, dropout=0.0,
                          audio_dim=7, music_encoder_layers=1, style_dim=6, style_injection=injection, **kwargs)  # fmt: skip
    for p in model.parameters():  # away from the init's zero null style and small null music
        p.data.add_(0.05 * torch.randn_like(p))
    return model.eval()


# the default (rotary cross-attention: the music tokens are cached), cached cross-attention keys and values (no
# rotary in cross-attention), and frame-aligned music with each
ARCHITECTURES = [{}, {"cross_attention_rotary": False}, {"aligned_music": True},
                 {"aligned_music": True, "cross_attention_rotary": False}]  # fmt: skip


@pytest.mark.parametrize("injection", ["modulation", "concat"])
@pytest.mark.parametrize("per_frame_style", [False, True])
@pytest.mark.parametrize("architecture", ARCHITECTURES)
def test_cached_forward_equals_the_plain_forward(injection, per_frame_style, architecture):
    model = tiny_denoiser(injection, modulation_shared=False, **architecture)
    b, n = 6, 33
    x, t = torch.randn(b, n, 151), torch.tensor([999, 500, 3, 0, 250, 999])
    music = torch.randn(b, n, 7)
    style = torch.randn(b, n, 6) if per_frame_style else torch.randn(b, 6)
    keep_music = torch.tensor([True, False, True, False, True, True])
    keep_style = torch.tensor([True, True, False, False, True, False])
    plain = model(x, t, music, style, keep_music, keep_style)
    cond = model.condition(music, style, keep_music, keep_style)
    for _ in range(2):  # reused across steps, with other x and t
        torch.testing.assert_close(model(x, t, cond=cond), plain, atol=2e-6, rtol=0)
        x, t = torch.randn(b, n, 151), torch.randint(0, 1000, (b,))
        plain = model(x, t, music, style, keep_music, keep_style)
    # the dropped rows' music does not matter
    other = music.clone()
    other[~keep_music] = 1e3
    torch.testing.assert_close(model(x, t, cond=model.condition(other, style, keep_music, keep_style)), plain,
                               atol=2e-6, rtol=0)  # fmt: skip
    with pytest.raises(ValueError, match="conditioning is for"):
        model(x[:2], t[:2], cond=cond)


def test_condition_without_music_or_style():
    model = tiny_denoiser("modulation")
    x, t = torch.randn(3, 20, 151), torch.tensor([5, 600, 999])
    plain = model(x, t)
    torch.testing.assert_close(model(x, t, cond=model.condition(None, None, n_frames=20, batch=3)), plain,
                               atol=2e-6, rtol=0)  # fmt: skip
    with pytest.raises(ValueError, match="number of frames"):
        model.condition(None, None)


class PlainOnly(torch.nn.Module):
    """The same denoiser, seen through the per-step interface only (no ``condition``)."""

    def __init__(self, inner: torch.nn.Module) -> None:
        super().__init__()
        self.inner = inner

    def forward(self, x_t, t, music=None, style=None, keep_music=None, keep_style=None):
        return self.inner(x_t, t, music, style, keep_music, keep_style)


def edited_sampling(denoiser, cond: Condition, method: str, style_guidance: bool) -> torch.Tensor:
    """6 steps of 5 rows of 40 frames with the first 10 frames given; the guidance's ramp and edit cap change the
    weights (and the guidance passes) between steps."""
    mask = torch.zeros(1, 40, 151)
    mask[:, :10] = 1
    return Sampler(denoiser, GaussianDiffusion(), style_guidance=style_guidance).sample(
        (5, 40, 151), cond, method=method, steps=6, guidance=Guidance(2.5, 1.5, ramp_fraction=0.5, edit_cap_below_t=400),
        mask=mask, known=torch.zeros(5, 40, 151), generator=torch.Generator().manual_seed(0),
    )  # fmt: skip


@pytest.mark.parametrize(
    ("method", "style_guidance", "chunk_size"),
    [("ddim", False, 0), ("ddim", True, 4), ("dpmpp_2m", True, 0), ("unipc", False, 4), ("unipc", True, 0)],
)
def test_cached_sampling_equals_the_per_step_path(method, style_guidance, chunk_size):
    model = tiny_denoiser("modulation")
    cached = ChunkedDenoiser(model, chunk_size) if chunk_size else model
    plain = ChunkedDenoiser(PlainOnly(model), chunk_size) if chunk_size else PlainOnly(model)
    cond = Condition(torch.randn(5, 40, 7), torch.randn(5, 6))
    outs = [edited_sampling(d, cond, method, style_guidance) for d in (cached, plain)]
    torch.testing.assert_close(outs[0], outs[1], atol=1e-5, rtol=0)


@pytest.mark.parametrize("null_music", ["input", "output"])
@pytest.mark.parametrize("chunk_size", [0, 4])
def test_music_named_by_rows_equals_the_music_repeated(null_music, chunk_size):
    """condition(music, ..., music_rows=r) hears music[r[i]] in row i: the same as the music repeated over the
    guidance passes (what the sampler did before, with a copy of the run's music per pass)."""
    model = ChunkedDenoiser(tiny_denoiser("modulation", null_music=null_music), chunk_size)
    b, n = 3, 20
    music, style = torch.randn(b, n, 7), torch.randn(2 * b, 6)
    keep_music = torch.tensor([False] * b + [True] * b)
    keep = torch.ones(2 * b, dtype=torch.bool)
    x, t = torch.randn(2 * b, n, 151), torch.full((2 * b,), 400)
    repeated = model.condition(music.repeat(2, 1, 1), style, keep_music, keep, n_frames=n, batch=2 * b)
    rows = torch.arange(b).repeat(2)
    named = model.condition(music, style, keep_music, keep, n_frames=n, batch=2 * b, music_rows=rows)
    expected = model(x, t, cond=repeated)
    torch.testing.assert_close(model(x, t, cond=named), expected)
    # another row order hears other music: the rows are used, not ignored
    shuffled = model.condition(music, style, keep_music, keep, n_frames=n, batch=2 * b, music_rows=rows.flip(0))
    assert not torch.allclose(model(x, t, cond=shuffled)[b:], expected[b:])


class PlainStudent(PlainOnly):
    """A guidance-distilled student seen through the per-step interface only."""

    @property
    def guidance_inputs(self) -> int:
        return self.inner.guidance_inputs

    def forward(self, x_t, t, music=None, style=None, keep_music=None, keep_style=None, *, guidance=None):
        return self.inner(x_t, t, music, style, keep_music, keep_style, guidance=guidance)


@pytest.mark.parametrize(("guidance_inputs", "chunk_size"), [(1, 0), (2, 4)])
def test_student_sampling_cached_chunked_and_plain_agree(guidance_inputs, chunk_size):
    """A student runs one pass per step with the step's (ramped, capped) weights, on every path alike."""
    model = tiny_denoiser("modulation", guidance_inputs=guidance_inputs)
    with torch.no_grad():
        model.guidance_proj.weight.normal_(0, 0.05)  # a student that hears its weights
    calls = []
    inner_forward = model.forward

    def counted(x_t, t, *args, **kwargs):
        calls.append(kwargs["guidance"][0].tolist())
        return inner_forward(x_t, t, *args, **kwargs)

    model.forward = counted
    cached = ChunkedDenoiser(model, chunk_size) if chunk_size else model
    plain = PlainStudent(model)
    cond = Condition(torch.randn(5, 40, 7), torch.randn(5, 6))
    outs = []
    for d in (cached, plain):
        calls.clear()
        outs.append(edited_sampling(d, cond, "dpmpp_2m", style_guidance=guidance_inputs == 2))
        per_step = calls if not chunk_size or d is plain else calls[::2]  # two chunks of rows per step
        assert len(per_step) == 6  # one pass per step
        # the ramp from 0 over the first half of the steps, then the cap at 1 below t = 400
        assert [w[0] for w in per_step][:3] == pytest.approx([0.0, 1.0, 2.0])
        assert per_step[-1][0] == 1.0 and per_step[2][-1] == pytest.approx(1.2 if guidance_inputs == 2 else 2.0)
    torch.testing.assert_close(outs[0], outs[1], atol=1e-5, rtol=0)
    assert (outs[0] - Sampler(model, GaussianDiffusion(), style_guidance=False).sample(
        (5, 40, 151), cond, method="dpmpp_2m", steps=6, guidance=Guidance(1.0), generator=torch.Generator().manual_seed(0),
    )).abs().max() > 1e-3  # fmt: skip


@pytest.mark.parametrize("injection", ["modulation", "concat"])
@pytest.mark.parametrize("null_music", ["input", "output"])
def test_leading_null_rows_share_one_copy_of_their_keys_and_values(injection, null_music):
    """The unconditional pass's rows come first in a guided batch: their cached keys and values are stored once
    when they are the same (no style enters the null music), and predictions equal the plain forward."""
    model = tiny_denoiser(injection, null_music=null_music)
    b, n = 7, 30
    x, t = torch.randn(b, n, 151), torch.full((b,), 420)
    music, style = torch.randn(b, n, 7), torch.randn(b, 6)
    keep_music = torch.tensor([False, False, False, True, False, True, True])
    keep_style = torch.ones(b, dtype=torch.bool)
    cond = model.condition(music, style, keep_music, keep_style)
    shared = 0 if (injection, null_music) == ("concat", "input") else 3  # concat: the style enters the null music
    assert cond.shared_rows == shared
    if not shared:  # unless the rows' styles are the same, as in one song's windows
        same = style.clone()
        same[:3] = style[0]
        shared_cond = model.condition(music, same, keep_music, keep_style)
        assert shared_cond.shared_rows == 3
        torch.testing.assert_close(model(x, t, cond=shared_cond), model(x, t, music, same, keep_music, keep_style),
                                   atol=2e-6, rtol=0)  # fmt: skip
    assert cond.keys[0].shape[0] == (b - shared + 1 if shared else b)
    for _ in range(2):  # reused across steps
        torch.testing.assert_close(model(x, t, cond=cond), model(x, t, music, style, keep_music, keep_style),
                                   atol=2e-6, rtol=0)  # fmt: skip
        x, t = torch.randn(b, n, 151), torch.full((b,), 17)
    # rows at different steps (predict_x0 of a batch at several steps): a full copy of the shared rows' cache
    t = torch.tensor([1, 200, 3, 999, 5, 6, 7])
    torch.testing.assert_close(model(x, t, cond=cond), model(x, t, music, style, keep_music, keep_style),
                               atol=2e-6, rtol=0)  # fmt: skip
    torch.testing.assert_close(model(x, t.fill_(40), cond=cond), model(x, t, music, style, keep_music, keep_style),
                               atol=2e-6, rtol=0)  # fmt: skip
    # a single leading null row, or a kept first row: nothing to share
    assert (
        model.condition(
            music, style, torch.tensor([False, True, True, False, False, True, True]), keep_style
        ).shared_rows
        == 0
    )
    assert model.condition(music, style, torch.ones(b, dtype=torch.bool), keep_style).shared_rows == 0
