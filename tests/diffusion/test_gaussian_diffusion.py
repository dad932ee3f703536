"""GaussianDiffusion against closed forms computed here in numpy float64 (Nichol & Dhariwal's cosine schedule,
DDPM's forward marginal and posterior, DDIM's update)."""

import math

import numpy as np
import pytest
import torch

from dgsdp.diffusion import GaussianDiffusion, cosine_betas

T = 1000


def closed_form(num_steps: int = T, s: float = 0.008, max_beta: float = 0.999) -> dict[str, np.ndarray]:
    """Cosine schedule: alpha_bar(t) = f(t) / f(0), f(t) = cos^2(((t / T) + s) / (1 + s) * pi / 2),
    beta_t = min(1 - alpha_bar(t) / alpha_bar(t - 1), max_beta); index i holds diffusion step i + 1 of the paper."""
    f = np.cos((np.arange(num_steps + 1) / num_steps + s) / (1 + s) * np.pi / 2) ** 2
    abar_exact = f / f[0]
    betas = np.minimum(1 - abar_exact[1:] / abar_exact[:-1], max_beta)
    abar = np.cumprod(1 - betas)
    abar_prev = np.concatenate([[1.0], abar[:-1]])
    return {"betas": betas, "abar": abar, "abar_prev": abar_prev, "abar_exact": abar_exact[1:]}


def gaussian_posterior(x0: np.ndarray, x_t: np.ndarray, t: int, cf: dict) -> tuple[np.ndarray, float]:
    """q(x_{t-1} | x_t, x0) by conditioning the joint Gaussian of (x_{t-1}, x_t) given x0:
    x_{t-1} = sqrt(abar_{t-1}) x0 + sqrt(1 - abar_{t-1}) e1, x_t = sqrt(1 - beta_t) x_{t-1} + sqrt(beta_t) e2."""
    beta, abar, abar_prev = cf["betas"][t], cf["abar"][t], cf["abar_prev"][t]
    var_prev = 1 - abar_prev
    cov = np.sqrt(1 - beta) * var_prev  # Cov(x_{t-1}, x_t | x0)
    var_t = (1 - beta) * var_prev + beta  # Var(x_t | x0)
    mean = np.sqrt(abar_prev) * x0 + cov / var_t * (x_t - np.sqrt(abar) * x0)
    return mean, var_prev - cov**2 / var_t


@pytest.fixture(scope="module")
def diffusion() -> GaussianDiffusion:
    return GaussianDiffusion(num_steps=T, schedule="cosine", clip_x0=False)


@pytest.mark.parametrize(("num_steps", "s"), [(1000, 0.008), (100, 0.008), (50, 0.02)])
def test_cosine_betas_match_closed_form(num_steps, s):
    cf = closed_form(num_steps, s)
    betas = cosine_betas(num_steps, s)
    assert betas.dtype == torch.float64 and betas.shape == (num_steps,)
    np.testing.assert_allclose(betas.numpy(), cf["betas"], rtol=1e-12, atol=1e-15)
    # f(T) = 0: the last beta would be 1 and is clipped at max_beta; every other step is below it
    assert betas[-1].item() == 0.999
    assert (betas[:-1] < 0.999).all()


def test_schedule_buffers_match_closed_form(diffusion):
    cf = closed_form()
    np.testing.assert_allclose(diffusion.betas.numpy(), cf["betas"], rtol=1e-6)
    np.testing.assert_allclose(diffusion.alpha_bar.numpy(), cf["abar"], rtol=1e-5, atol=1e-12)
    np.testing.assert_allclose(diffusion.alpha_bar_prev.numpy(), cf["abar_prev"], rtol=1e-5, atol=1e-12)
    # before the clipped last step the cumulative product telescopes to f(t) / f(0)
    np.testing.assert_allclose(cf["abar"][:-1], cf["abar_exact"][:-1], rtol=1e-9)
    assert diffusion.alpha_bar.dtype == torch.float32


def test_linear_schedule_matches_ddpm_range():
    d = GaussianDiffusion(num_steps=200, schedule="linear")
    expected = np.linspace(1e-4 * 1000 / 200, 0.02 * 1000 / 200, 200)
    np.testing.assert_allclose(d.betas.numpy(), expected, rtol=1e-6)
    with pytest.raises(ValueError, match="unknown noise schedule"):
        GaussianDiffusion(schedule="quadratic")


@pytest.mark.parametrize("t", [0, 1, 17, 500, 998, 999])
def test_q_sample_is_closed_form_affine_map(diffusion, t):
    cf = closed_form()
    g = torch.Generator().manual_seed(t)
    x0, noise = torch.randn(3, 5, 7, generator=g), torch.randn(3, 5, 7, generator=g)
    tt = torch.full((3,), t)
    out = diffusion.q_sample(x0, tt, noise).double().numpy()
    expected = np.sqrt(cf["abar"][t]) * x0.double().numpy() + np.sqrt(1 - cf["abar"][t]) * noise.double().numpy()
    np.testing.assert_allclose(out, expected, rtol=1e-5, atol=1e-6)


def test_q_sample_moments_per_row(diffusion):
    """Each row its own step: the empirical mean and variance over many noise draws are sqrt(abar) x0 and 1 - abar."""
    cf = closed_form()
    steps = [0, 100, 600, 999]
    n = 200_000
    x0 = torch.tensor([0.7, -0.4, 1.0, 0.3]).repeat_interleave(n)[:, None]
    t = torch.tensor(steps).repeat_interleave(n)
    noise = torch.randn(x0.shape, generator=torch.Generator().manual_seed(0))
    x_t = diffusion.q_sample(x0, t, noise).double().view(len(steps), n)
    for i, step in enumerate(steps):
        abar = cf["abar"][step]
        mean, var = np.sqrt(abar) * x0[i * n].item(), 1 - abar
        se = np.sqrt(var / n)
        assert abs(x_t[i].mean().item() - mean) < 5 * se + 1e-6
        assert abs(x_t[i].var().item() - var) < 5 * var * np.sqrt(2 / n) + 1e-9


def test_posterior_coefficients_and_variance(diffusion):
    cf = closed_form()
    betas, abar, abar_prev = cf["betas"], cf["abar"], cf["abar_prev"]
    c0 = betas * np.sqrt(abar_prev) / (1 - abar)
    ct = np.sqrt(1 - betas) * (1 - abar_prev) / (1 - abar)
    var = betas * (1 - abar_prev) / (1 - abar)
    np.testing.assert_allclose(diffusion.posterior_c0.numpy(), c0, rtol=1e-5)
    np.testing.assert_allclose(diffusion.posterior_ct.numpy(), ct, rtol=1e-5, atol=1e-12)
    np.testing.assert_allclose(diffusion.posterior_var.numpy(), var, rtol=1e-5, atol=1e-12)
    assert diffusion.posterior_var[0].item() == 0  # x_0 given x_1 and x0 is x0
    # the log variance is finite at step 0 (it holds step 1's value there; no noise is added at step 0)
    np.testing.assert_allclose(diffusion.posterior_log_var[1:].numpy(), np.log(var[1:]), rtol=1e-5, atol=1e-6)
    assert np.isfinite(diffusion.posterior_log_var.numpy()).all()
    # the coefficients are those of the conditioned joint Gaussian
    x0, x_t = np.array([0.3, -1.2]), np.array([1.5, 0.2])
    for t in (1, 10, 300, 999):
        mean, v = gaussian_posterior(x0, x_t, t, cf)
        np.testing.assert_allclose(c0[t] * x0 + ct[t] * x_t, mean, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(var[t], v, rtol=1e-9, atol=1e-15)


@pytest.mark.parametrize("t", [1, 10, 500, 999])
def test_ddpm_step_mean_and_variance(diffusion, t):
    cf = closed_form()
    x0 = torch.tensor([[0.5, -0.25, 0.9]])
    x_t = torch.tensor([[1.2, 0.1, -0.7]])
    mean, var = gaussian_posterior(x0.double().numpy(), x_t.double().numpy(), t, cf)
    tt = torch.full((1,), t)
    # the step is mean + std * noise, exactly
    no_noise = diffusion.ddpm_step(x_t, tt, x0, noise=torch.zeros_like(x_t))
    np.testing.assert_allclose(no_noise.double().numpy(), mean, rtol=1e-5, atol=1e-6)
    # statistics over draws from a generator
    n = 100_000
    g = torch.Generator().manual_seed(t)
    draws = diffusion.ddpm_step(x_t.expand(n, 3), tt.expand(n), x0.expand(n, 3), generator=g).double()
    se = np.sqrt(var / n)
    np.testing.assert_array_less(np.abs(draws.mean(0).numpy() - mean[0]), 5 * se + 1e-6)
    np.testing.assert_allclose(draws.var(0).numpy(), var, rtol=5 * np.sqrt(2 / n))


def test_ddpm_step_at_zero_returns_x0_without_noise(diffusion):
    x0, x_t = torch.randn(4, 6), torch.randn(4, 6)
    t = torch.zeros(4, dtype=torch.long)
    out = diffusion.ddpm_step(x_t, t, x0, noise=torch.full_like(x_t, 5.0))
    torch.testing.assert_close(out, x0, rtol=1e-6, atol=1e-6)


def test_ddim_eta0_is_deterministic_and_recovers_x0(diffusion):
    cf = closed_form()
    g = torch.Generator().manual_seed(1)
    x0, eps = torch.randn(5, 4, 3, generator=g), torch.randn(5, 4, 3, generator=g)
    t = torch.tensor([999, 700, 300, 50, 1])
    x_t = diffusion.q_sample(x0, t, eps)
    # final step (t_prev < 0): x0 itself, exactly
    final = diffusion.ddim_step(x_t, t, torch.full_like(t, -1), x0, eta=0.0, noise=torch.randn(5, 4, 3))
    assert torch.equal(final, x0)
    # to an intermediate step: x_{t_prev} is built from the same x0 and the noise implied by x_t
    t_prev = torch.tensor([900, 650, 100, 10, 0])
    a = diffusion.ddim_step(x_t, t, t_prev, x0, eta=0.0, generator=torch.Generator().manual_seed(7))
    b = diffusion.ddim_step(x_t, t, t_prev, x0, eta=0.0, generator=torch.Generator().manual_seed(8))
    c = diffusion.ddim_step(x_t, t, t_prev, x0, eta=0.0, noise=torch.full_like(x_t, 3.0))
    assert torch.equal(a, b) and torch.equal(a, c)
    abar = torch.from_numpy(cf["abar"][t_prev.numpy()])[:, None, None]
    expected = abar.sqrt() * x0.double() + (1 - abar).sqrt() * eps.double()
    np.testing.assert_allclose(a.double().numpy(), expected.numpy(), rtol=1e-4, atol=2e-4)


@pytest.mark.parametrize("t", [1, 20, 600, 999])
def test_ddim_eta1_single_step_is_the_ddpm_posterior(diffusion, t):
    """With eta = 1 and t_prev = t - 1, DDIM's sigma^2 is the posterior variance and its mean the posterior mean."""
    cf = closed_form()
    x0 = torch.tensor([[0.4, -0.8]])
    x_t = torch.tensor([[-0.3, 1.1]])
    tt, t_prev = torch.tensor([t]), torch.tensor([t - 1])
    mean, var = gaussian_posterior(x0.double().numpy(), x_t.double().numpy(), t, cf)
    # DDIM works from the float32 alpha_bar buffer: at t = 1, beta ~ 5e-5 is the gap between two float32 numbers
    # near 1 (spacing 6e-8), so the step carries a ~1e-3 relative error there (float64 arithmetic on the same
    # float32-rounded alpha_bar gives the same error; on float64 alpha_bar the formulas agree to 1e-12).
    tol = {"rtol": 5e-3, "atol": 1e-4} if t < 10 else {"rtol": 1e-4, "atol": 1e-5}
    zero = diffusion.ddim_step(x_t, tt, t_prev, x0, eta=1.0, noise=torch.zeros_like(x_t)).double().numpy()
    np.testing.assert_allclose(zero, mean, **tol)
    one = diffusion.ddim_step(x_t, tt, t_prev, x0, eta=1.0, noise=torch.ones_like(x_t)).double().numpy()
    np.testing.assert_allclose(one - zero, np.full_like(zero, np.sqrt(var)), **tol)


def test_ddim_timesteps():
    d = GaussianDiffusion(num_steps=1000)
    steps = d.ddim_timesteps(50)
    assert steps == list(range(999, 18, -20)) and len(steps) == 50
    assert d.ddim_timesteps(1000) == list(range(999, -1, -1))
    assert d.ddim_timesteps(1) == [999]
    for bad in (0, 1001):
        with pytest.raises(ValueError, match="sampling steps"):
            d.ddim_timesteps(bad)


@pytest.mark.parametrize("n", [3, 7, 30, 300, 501, 600, 750, 999])
def test_ddim_timesteps_span_the_whole_schedule(n):
    """Any number of sampling steps covers 999 .. ~0 evenly: the gaps are floor or ceil of 1000 / n and the last
    step is within one gap of 0 (the final update goes from it to x0)."""
    steps = GaussianDiffusion(num_steps=1000).ddim_timesteps(n)
    assert len(steps) == n and steps[0] == 999
    gaps = {a - b for a, b in zip(steps, steps[1:])}
    assert gaps <= {1000 // n, -(-1000 // n)}
    assert 0 <= steps[-1] < -(-1000 // n)


@pytest.mark.parametrize(("setting", "bound"), [(True, 1.0), (False, None), (1.5, 1.5)])
def test_x0_clamp_bound(setting, bound):
    diffusion = GaussianDiffusion(num_steps=10, clip_x0=setting)
    x0 = torch.tensor([-3.0, -1.2, 0.3, 1.2, 3.0])
    expected = x0 if bound is None else torch.tensor([max(-bound, min(bound, v)) for v in x0.tolist()])
    torch.testing.assert_close(diffusion.clamp(x0), expected)


def test_x0_clamp_bound_must_be_positive():
    with pytest.raises(ValueError, match="positive bound"):
        GaussianDiffusion(num_steps=10, clip_x0=0.0)


def test_uniform_timesteps_are_the_draws_of_randint():
    """The default draws exactly what training drew before the sampling was a setting (same checkpoints)."""
    drawn = GaussianDiffusion().sample_timesteps(64, torch.device("cpu"), torch.Generator().manual_seed(3))
    assert torch.equal(drawn, torch.randint(0, T, (64,), generator=torch.Generator().manual_seed(3)))


@pytest.mark.parametrize(("mean", "std"), [(0.0, 1.0), (0.7, 0.5)])
def test_logit_normal_timesteps_follow_their_distribution(mean, std):
    """P(t <= k) = P(sigmoid(z) < (k + 1) / T) = Phi((logit((k + 1) / T) - mean) / std), z ~ N(mean, std)."""
    d = GaussianDiffusion(timesteps="logit_normal", timestep_mean=mean, timestep_std=std)
    t = d.sample_timesteps(200_000, torch.device("cpu"), torch.Generator().manual_seed(0)).numpy()
    assert t.dtype == np.int64 and t.min() >= 0 and t.max() <= T - 1
    for k in (49, 249, 499, 749, 949):
        u = (k + 1) / T
        expected = 0.5 * (1 + math.erf((math.log(u / (1 - u)) - mean) / (std * math.sqrt(2))))
        assert abs((t <= k).mean() - expected) < 0.005, k


@pytest.mark.parametrize("kwargs", [{"timesteps": "lognormal"}, {"timesteps": "logit_normal", "timestep_std": 0.0}])
def test_bad_timestep_sampling_is_refused(kwargs):
    with pytest.raises(ValueError, match="timestep"):
        GaussianDiffusion(**kwargs)
