"""Sampler determinism, editing masks, the guidance schedule, and Noise with one generator per group of rows."""

import numpy as np
import pytest
import torch

from dgsdp.diffusion import GaussianDiffusion
from dgsdp.model import DanceDenoiser
from dgsdp.sampling import Condition, Guidance, Noise, Sampler

B, N, C = 3, 8, 151
AUDIO, STYLE = 5, 3


@pytest.fixture(scope="module")
def sampler() -> Sampler:
    with torch.random.fork_rng():
        torch.manual_seed(0)
        model = DanceDenoiser(seq_len=N, d_model=16, n_layers=1, n_heads=2, ff_dim=32, dropout=0.0, audio_dim=AUDIO,
                              music_encoder_layers=1, style_dim=STYLE).eval()  # fmt: skip
    return Sampler(model, GaussianDiffusion(num_steps=1000), style_guidance=True)


@pytest.fixture(scope="module")
def cond() -> Condition:
    g = torch.Generator().manual_seed(1)
    return Condition(torch.randn(B, N, AUDIO, generator=g), torch.randn(B, STYLE, generator=g))


def rows(cond: Condition, sl: slice) -> Condition:
    return Condition(cond.music[sl], cond.style[sl])


class FixedStart(Noise):
    """The first draw (the start noise x_T) from seed 0, every later draw from ``later_seed``."""

    def __init__(self, later_seed: int) -> None:
        super().__init__(torch.Generator().manual_seed(later_seed))
        self.first = True

    def randn(self, shape, **kwargs):
        if self.first:
            self.first = False
            return torch.randn(tuple(shape), generator=torch.Generator().manual_seed(0))
        return super().randn(shape, **kwargs)


def test_ddim_eta0_is_deterministic_and_ignores_later_draws(sampler, cond):
    kw = {"method": "ddim", "steps": 10, "eta": 0.0, "guidance": Guidance(2.0, 1.5)}
    a = sampler.sample((B, N, C), cond, generator=FixedStart(1), **kw)
    b = sampler.sample((B, N, C), cond, generator=FixedStart(2), **kw)
    c = sampler.sample((B, N, C), cond, generator=FixedStart(1), **kw)
    assert torch.equal(a, b) and torch.equal(a, c)
    # the same start noise from a plain generator gives the same sample
    d = sampler.sample((B, N, C), cond, generator=torch.Generator().manual_seed(0), **kw)
    assert torch.equal(a, d)
    # with eta = 1 the later draws matter
    kw["eta"] = 1.0
    e = sampler.sample((B, N, C), cond, generator=FixedStart(1), **kw)
    f = sampler.sample((B, N, C), cond, generator=FixedStart(2), **kw)
    assert (e - f).abs().amax() > 1e-3


def test_global_rng_when_no_generator(sampler, cond):
    kw = {"method": "ddim", "steps": 5, "eta": 1.0}
    with torch.random.fork_rng():  # leaves the global RNG as it was for the tests after this one
        torch.manual_seed(123)
        a = sampler.sample((B, N, C), cond, **kw)
        torch.manual_seed(123)
        b = sampler.sample((B, N, C), cond, **kw)
        c = sampler.sample((B, N, C), cond, **kw)
    assert torch.equal(a, b) and (a - c).abs().amax() > 1e-3


def frame_mask() -> torch.Tensor:
    mask = torch.zeros(1, N, C)
    mask[:, :3] = 1  # the first three frames are given
    return mask


def channel_mask() -> torch.Tensor:
    mask = torch.zeros(B, N, C)
    mask[:, :, 4:7] = 1  # the root trajectory is given
    mask[1, :, :] = 0  # row 1 is free
    return mask


class Shrink(torch.nn.Module):
    """A cheap stand-in denoiser for the 1000-step DDPM runs: x0 = 0.5 x_t (plus a little music, so that the
    guidance passes differ)."""

    def forward(self, x_t, t, music, style, keep_music, keep_style):
        return 0.5 * x_t + 0.1 * keep_music.float().view(-1, 1, 1) * music.mean(-1, keepdim=True)


@pytest.mark.parametrize(
    ("method", "eta", "make_mask"),
    [("ddim", 0.0, frame_mask), ("ddim", 1.0, frame_mask), ("ddim", 1.0, channel_mask), ("ddpm", 1.0, frame_mask),
     ("ddpm", 1.0, channel_mask)],
)  # fmt: skip
def test_known_region_equals_the_given_values(sampler, cond, make_mask, method, eta):
    mask = make_mask()
    known = torch.rand(B, N, C, generator=torch.Generator().manual_seed(2)) * 1.6 - 0.8
    steps = 10
    if method == "ddpm":  # 1000 steps: a cheap denoiser
        sampler = Sampler(Shrink(), sampler.diffusion, style_guidance=True)
    ab = sampler.diffusion.alpha_bar.double()
    z_stats = []

    def noised_known(x, t_next):  # the known region at step t_next is sqrt(abar) known + sqrt(1 - abar) z
        if t_next >= 0 and t_next % 100 == 0 or t_next in (899, 499, 99):
            z = (x.double() - ab[t_next].sqrt() * known) / (1 - ab[t_next]).sqrt()
            z_stats.append(z[mask.expand_as(z).bool()])
        return x

    out = sampler.sample((B, N, C), cond, method=method, steps=steps, eta=eta, guidance=Guidance(2.0, 1.5),
                         mask=mask, known=known, step_callback=noised_known,
                         generator=torch.Generator().manual_seed(3))  # fmt: skip
    given = mask.expand_as(out).bool()
    assert torch.equal(out[given], known[given])
    assert (out[~given] - known[~given]).abs().amax() > 0.1
    bound = sampler.diffusion.x0_bound  # x0 is clamped to [-bound, bound]
    assert torch.isfinite(out).all() and out.abs().max() <= bound
    assert z_stats
    z = torch.cat(z_stats)
    se = 1 / np.sqrt(z.numel())
    assert abs(z.mean().item()) < 5 * se and abs(z.std().item() - 1) < 5 * se * np.sqrt(0.5) + 0.01


def test_mask_without_known_motion_fails(sampler, cond):
    with pytest.raises(ValueError, match="known motion"):
        sampler.sample((B, N, C), cond, steps=2, mask=frame_mask())


def test_noise_groups_draw_consecutive_rows_from_their_own_generator():
    noise = Noise.seeded([5, 6])
    first, second = noise.randn((4, 2, 3)), noise.randn((4, 2, 3))
    g5, g6 = torch.Generator().manual_seed(5), torch.Generator().manual_seed(6)
    expected_first = torch.cat((torch.randn(2, 2, 3, generator=g5), torch.randn(2, 2, 3, generator=g6)))
    expected_second = torch.cat((torch.randn(2, 2, 3, generator=g5), torch.randn(2, 2, 3, generator=g6)))
    assert torch.equal(first, expected_first) and torch.equal(second, expected_second)
    assert torch.equal(
        Noise(torch.Generator().manual_seed(5)).randn((2, 2)), torch.randn(2, 2, generator=g5.manual_seed(5))
    )
    with pytest.raises(ValueError, match="cannot be split"):
        Noise.seeded([1, 2]).randn((3, 4))
    with pytest.raises(ValueError, match="at least one generator"):
        Noise([])


@pytest.mark.parametrize("as_list", [False, True])
def test_row_sampled_alone_equals_the_row_inside_a_batch(sampler, cond, as_list):
    """One generator per row: each row's noise (start, steps, known-region noise) is its own stream."""
    seeds = [11, 12, 13]
    known = torch.rand(B, N, C, generator=torch.Generator().manual_seed(4)) * 2 - 1
    kw = {"method": "ddim", "steps": 8, "eta": 1.0, "guidance": Guidance(2.0, 1.5), "mask": frame_mask()}

    def gens(s):
        return [torch.Generator().manual_seed(x) for x in s] if as_list else Noise.seeded(s)

    batch = sampler.sample((B, N, C), cond, known=known, generator=gens(seeds), **kw)
    for i in range(B):
        sl = slice(i, i + 1)
        alone = sampler.sample((1, N, C), rows(cond, sl), known=known[sl], generator=gens(seeds[sl]), **kw)
        torch.testing.assert_close(alone, batch[sl], rtol=1e-5, atol=1e-5)
    assert (batch[0] - batch[1]).abs().amax() > 0.1


def test_groups_of_rows_share_a_generator(sampler):
    """Four rows, two generators: rows 2-3 sampled alone with the second seed equal rows 2-3 of the batch."""
    g = torch.Generator().manual_seed(8)
    cond4 = Condition(torch.randn(4, N, AUDIO, generator=g), torch.randn(4, STYLE, generator=g))
    kw = {"method": "ddim", "steps": 6, "eta": 1.0, "guidance": Guidance(2.0, 1.0)}
    batch = sampler.sample((4, N, C), cond4, generator=Noise.seeded([21, 22]), **kw)
    pair = sampler.sample((2, N, C), rows(cond4, slice(2, 4)), generator=Noise.seeded([22]), **kw)
    torch.testing.assert_close(pair, batch[2:], rtol=1e-5, atol=1e-5)
    other = sampler.sample((2, N, C), rows(cond4, slice(2, 4)), generator=Noise.seeded([21]), **kw)
    assert (other - batch[2:]).abs().amax() > 0.1


def test_guidance_schedule():
    g = Guidance(music_weight=3.0, style_weight=2.0, ramp_fraction=0.5, edit_cap_below_t=100)
    # ramp: EDGE's long-form weights, clip(linspace(0, 2 w, n), max=w), computed here as EDGE's code does
    edge_music = np.clip(np.linspace(0, 2 * 3.0, 10), None, 3.0)
    edge_style = np.clip(np.linspace(0, 2 * 2.0, 10), None, 2.0)
    for step in range(10):
        w = g.at(step, 10, t=500, masked=False)
        assert (w.music_weight, w.style_weight) == pytest.approx((edge_music[step], edge_style[step]))
    assert g.at(4, 10, t=500, masked=False).music_weight == pytest.approx(3.0 * 4 / 4.5)
    # cap: with a mask, weights above 1 are capped at 1 below t = 100; not without a mask, not above
    assert (g.at(9, 10, t=99, masked=True).music_weight, g.at(9, 10, t=99, masked=True).style_weight) == (1.0, 1.0)
    assert g.at(9, 10, t=99, masked=False).music_weight == 3.0
    assert g.at(9, 10, t=100, masked=True).music_weight == 3.0
    assert g.at(1, 10, t=50, masked=True).music_weight == pytest.approx(edge_music[1])  # below 1: not raised
    plain = Guidance(2.0, 1.5).at(0, 10, t=999, masked=True)
    assert (plain.music_weight, plain.style_weight) == (2.0, 1.5)


def test_timesteps_and_unknown_method(sampler):
    assert sampler.timesteps("ddpm", None) == list(range(999, -1, -1))
    assert sampler.timesteps("ddim", 4) == [999, 749, 499, 249]
    assert sampler.timesteps("ddim", None) == list(range(999, 0, -20))
    with pytest.raises(ValueError, match="unknown sampler"):
        sampler.timesteps("euler", 10)
