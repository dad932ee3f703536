"""The few-step ODE solvers (DPM-Solver++(2M), UniPC) against closed forms on a Gaussian toy, and with masks,
long-form, guidance and seeds on the tiny model."""

import math

import pytest
import torch
from generation.gen_helpers import AUDIO_DIM, random_motion

from dgsdp.diffusion import GaussianDiffusion
from dgsdp.editing import build_mask
from dgsdp.generation import sample_long
from dgsdp.sampling import Condition, DPMSolverPP2MSDE, Guidance, Sampler, make_solver, solver_timesteps
from dgsdp.sampling.sampler import check_method

SOLVERS = ("dpmpp_2m", "unipc", "unipc_bh1")  # the deterministic ones
MU, STD = 0.3, 0.2  # the toy data: every channel independent N(MU, STD^2), well inside the clamp range


class GaussianPosteriorMean(torch.nn.Module):
    """The exact x0 predictor E[x0 | x_t] for data N(MU, STD^2) under ``diffusion``'s schedule."""

    def __init__(self, diffusion: GaussianDiffusion) -> None:
        super().__init__()
        self.diffusion = diffusion

    def forward(self, x_t, t, music=None, style=None, keep_music=None, keep_style=None):
        ab = self.diffusion.alpha_bar.double()[t].view(-1, 1, 1)
        a, var = ab.sqrt(), 1 - ab
        gain = a * STD**2 / (ab * STD**2 + var)
        return (MU + gain * (x_t.double() - a * MU)).float()


def ode_endpoint(diffusion: GaussianDiffusion, x_start: torch.Tensor, t_start: int) -> torch.Tensor:
    """Where the probability-flow ODE takes x at step ``t_start`` for Gaussian data: it keeps the standardised
    value, x0 = MU + STD (x - a MU) / sqrt(a^2 STD^2 + 1 - a^2)."""
    ab = float(diffusion.alpha_bar.double()[t_start])
    a = math.sqrt(ab)
    return MU + STD * (x_start.double() - a * MU) / math.sqrt(ab * STD**2 + 1 - ab)


@pytest.fixture(scope="module")
def toy() -> tuple[GaussianDiffusion, Sampler]:
    diffusion = GaussianDiffusion(clip_x0=False)
    return diffusion, Sampler(GaussianPosteriorMean(diffusion), diffusion, style_guidance=False)


def sample_toy(sampler: Sampler, method: str, steps: int, seed: int = 0, **kwargs) -> torch.Tensor:
    return sampler.sample((64, 8, 16), Condition(), method=method, steps=steps, eta=0.0,
                          guidance=Guidance(1.0, 1.0), generator=torch.Generator().manual_seed(seed), **kwargs)  # fmt: skip


def test_timestep_spacings():
    diffusion = GaussianDiffusion()
    assert solver_timesteps(diffusion, 10, "time") == [999, 899, 799, 699, 599, 499, 399, 299, 199, 99]
    lam_ts = solver_timesteps(diffusion, 10, "lambda")
    assert lam_ts[:2] == [999, 899] and len(lam_ts) == 10 and lam_ts == sorted(lam_ts, reverse=True)
    ab = diffusion.alpha_bar.double()
    lam = [0.5 * math.log(float(ab[t]) / (1 - float(ab[t]))) for t in [*lam_ts[1:], 0]]
    gaps = [b - a for a, b in zip(lam, lam[1:], strict=False)]
    assert max(gaps) - min(gaps) < 0.1 * max(gaps)  # evenly spaced in lambda up to rounding to integer steps
    with pytest.raises(ValueError, match="spacing"):
        solver_timesteps(diffusion, 10, "karras")
    with pytest.raises(ValueError, match="dpmpp_2m"):
        check_method("dpm")


@pytest.mark.parametrize("method", ["dpmpp_2m", "unipc"])
def test_ten_steps_land_on_the_ode_solution_and_the_data_distribution(toy, method):
    diffusion, sampler = toy
    x_start = torch.randn((64, 8, 16), generator=torch.Generator().manual_seed(0))
    exact = ode_endpoint(diffusion, x_start, 999)
    out = sample_toy(sampler, method, 10).double()
    err = (out - exact).abs().max().item()
    assert err < 0.15 * STD, err  # DDIM with 10 steps: 1.2 STD
    assert abs(out.mean().item() - MU) < 0.01 and abs(out.std().item() - STD) < 0.01


def test_error_shrinks_with_steps_and_all_deterministic_solvers_agree(toy):
    diffusion, sampler = toy
    exact = ode_endpoint(diffusion, torch.randn((64, 8, 16), generator=torch.Generator().manual_seed(0)), 999)
    for method in SOLVERS:
        for spacing in ("time", "lambda"):
            errs = [(sample_toy(sampler, method, n, spacing=spacing).double() - exact).abs().max().item()
                    for n in (5, 10, 25)]  # fmt: skip
            assert errs[0] > errs[1] > errs[2], (method, spacing, errs)
    # with many steps DDIM (eta 0) and the solvers reach the same point, the ODE's
    ddim = sample_toy(sampler, "ddim", 1000).double()
    assert (ddim - exact).abs().max() < 5e-3
    for method in ("dpmpp_2m", "unipc"):
        out = sample_toy(sampler, method, 100).double()
        assert (out - exact).abs().max() < 1e-3
        assert (out - ddim).abs().max() < 5e-3


@pytest.mark.parametrize("method", SOLVERS)
def test_masked_region_is_known_and_the_rest_is_on_its_ode_path(toy, method):
    diffusion, sampler = toy
    known = torch.full((64, 8, 16), -0.5)
    mask = torch.zeros(1, 8, 16)
    mask[:, :3] = 1
    out = sample_toy(sampler, method, 10, mask=mask, known=known)
    assert torch.equal(out[:, :3], known[:, :3])
    # channels are independent in the toy: the unmasked part is the unconstrained ODE solution
    torch.testing.assert_close(out[:, 3:], sample_toy(sampler, method, 10)[:, 3:], atol=1e-5, rtol=0)


@pytest.mark.parametrize("method", ["dpmpp_2m", "unipc"])
def test_solvers_on_the_model_with_guidance_masks_and_seeds(tiny_model, method):
    sampler = tiny_model.sampler()
    b, n = 3, 60
    music, style = torch.randn(b, n, AUDIO_DIM), torch.eye(10)[:b]
    known = tiny_model.normalizer.normalize(torch.stack([random_motion(n, seed=s) for s in range(b)]))
    mask = build_mask("inbetween", n, seed_frames=10, end_frames=10)[None].expand(b, n, 151)
    runs = [
        sampler.sample(
            (b, n, 151),
            Condition(music, style),
            method=method,
            steps=6,
            mask=mask,
            known=known,
            guidance=Guidance(2.0, 1.0, edit_cap_below_t=100),
            generator=torch.Generator().manual_seed(seed),
        )  # fmt: skip
        for seed in (0, 0, 1)
    ]
    assert torch.equal(runs[0], runs[1])  # same seed, same dance
    assert (runs[0] - runs[2]).abs().max() > 1e-2
    assert torch.equal(runs[0][mask.bool()], known[mask.bool()])
    assert runs[0].abs().max() <= sampler.diffusion.x0_bound and torch.isfinite(runs[0]).all()


@pytest.mark.parametrize("method", ["dpmpp_2m", "unipc"])
def test_longform_with_solvers(tiny_model, method):
    n = 2 * 150 + 37
    music, style = torch.randn(n, AUDIO_DIM), torch.eye(10)[torch.arange(n) * 10 // n]
    outs = [
        sample_long(
            tiny_model.sampler(),
            tiny_model.normalizer,
            n,
            music=music,
            style=style,
            method=method,
            steps=5,
            guidance=Guidance(2.0, 1.0, ramp_fraction=0.5),
            chunk_size=2,
            generator=torch.Generator().manual_seed(0),
        )  # fmt: skip
        for _ in range(2)
    ]
    assert outs[0].shape == (1, n, 151) and torch.isfinite(outs[0]).all()
    assert torch.equal(outs[0], outs[1])


def test_longform_overlaps_agree_after_every_solver_update(tiny_model):
    """The state handed to the model has equal overlaps in neighbouring windows, also after UniPC's corrector."""
    seen = []
    inner = tiny_model.sampler()

    def spy(x_t, t, *args, **kwargs):
        seen.append(x_t.clone())
        return inner.denoiser(x_t, t, *args, **kwargs)

    spy.condition = None
    sampler = Sampler(spy, inner.diffusion, style_guidance=inner.style_guidance)
    n = 300  # 3 windows, 75 frames apart
    sample_long(sampler, tiny_model.normalizer, n, music=torch.randn(n, AUDIO_DIM), style=torch.eye(10)[2],
                method="unipc", steps=5, guidance=Guidance(1.0, 1.0), generator=torch.Generator().manual_seed(0))  # fmt: skip
    assert len(seen) == 5
    for x in seen[1:]:
        assert torch.equal(x[1:, :75], x[:-1, 75:])


def test_sde_solver_first_step_is_ddim_eta_one_and_lands_on_the_data_distribution(toy):
    diffusion, sampler = toy
    solver = make_solver("dpmpp_2m_sde", diffusion, [999, 600, 300, 100])
    x, x0, z = torch.randn(4, 5), 0.3 * torch.randn(4, 5), torch.randn(4, 5)
    solver.step(0, x, x0, noise=lambda shape: z)  # 999 -> 600
    first = DPMSolverPP2MSDE(diffusion, [600, 300]).step(0, x, x0, noise=lambda shape: z)
    ddim = diffusion.ddim_step(x, torch.full((4,), 600), torch.full((4,), 300), x0, eta=1.0, noise=z)
    torch.testing.assert_close(first, ddim, atol=1e-5, rtol=0)
    outs = [sample_toy(sampler, "dpmpp_2m_sde", 10, seed=s) for s in (0, 0, 1)]
    assert torch.equal(outs[0], outs[1]) and not torch.equal(outs[0], outs[2])
    assert abs(outs[0].mean().item() - MU) < 0.01 and abs(outs[0].std().item() - STD) < 0.01
    known = torch.full((64, 8, 16), -0.5)
    mask = torch.zeros(1, 8, 16)
    mask[:, :3] = 1
    assert torch.equal(sample_toy(sampler, "dpmpp_2m_sde", 10, mask=mask, known=known)[:, :3], known[:, :3])
