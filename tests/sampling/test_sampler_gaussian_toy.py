"""Samplers on a Gaussian toy: data x0 ~ N(mu, s^2) per channel and a "denoiser" returning the exact posterior mean
E[x0 | x_t]. Everything is linear-Gaussian, so the sampled distribution is also computed here in closed form."""

import numpy as np
import pytest
import torch

from dgsdp.diffusion import GaussianDiffusion
from dgsdp.sampling import Condition, Guidance, Sampler

MU = np.array([0.3, -0.2, 0.0, 0.5])
S = np.array([0.5, 0.8, 1.0, 0.25])
N = 12_000  # samples per channel
T = 1000


def cosine_alpha_bar(num_steps: int = T, s: float = 0.008) -> np.ndarray:
    f = np.cos((np.arange(num_steps + 1) / num_steps + s) / (1 + s) * np.pi / 2) ** 2
    betas = np.minimum(1 - f[1:] / f[:-1], 0.999)
    return np.cumprod(1 - betas)


ABAR = cosine_alpha_bar()


def posterior_mean_gain(t: int) -> tuple[np.ndarray, np.ndarray]:
    """E[x0 | x_t] = a x_t + b for x_t = sqrt(abar) x0 + sqrt(1 - abar) e, x0 ~ N(mu, s^2)."""
    ab = ABAR[t]
    a = np.sqrt(ab) * S**2 / (ab * S**2 + 1 - ab)
    return a, MU - a * np.sqrt(ab) * MU


class GaussianToy(torch.nn.Module):
    def __init__(self) -> None:
        super().__init__()
        self.calls = 0

    def forward(self, x_t, t, music, style, keep_music, keep_style):
        self.calls += 1
        step = int(t[0])
        assert bool((t == step).all()), "the samplers run every row at the same step"
        a, b = posterior_mean_gain(step)
        return x_t * torch.from_numpy(a).float() + torch.from_numpy(b).float()


def sampler() -> tuple[Sampler, GaussianToy]:
    toy = GaussianToy()
    return Sampler(toy, GaussianDiffusion(num_steps=T, clip_x0=False), style_guidance=False), toy


def ddpm_moments() -> tuple[np.ndarray, np.ndarray]:
    """Mean and std after ancestral sampling from x_T ~ N(0, 1) with the posterior q(x_{t-1} | x_t, x0_hat)."""
    betas = 1 - ABAR / np.concatenate([[1.0], ABAR[:-1]])
    m, v = np.zeros_like(MU), np.ones_like(S)
    for t in range(T - 1, -1, -1):
        a, b = posterior_mean_gain(t)
        if t == 0:
            return a * m + b, np.sqrt(a * a * v)
        ab, ab_prev = ABAR[t], ABAR[t - 1]
        c0, ct = betas[t] * np.sqrt(ab_prev) / (1 - ab), np.sqrt(1 - betas[t]) * (1 - ab_prev) / (1 - ab)
        gain = c0 * a + ct
        m, v = gain * m + c0 * b, gain**2 * v + betas[t] * (1 - ab_prev) / (1 - ab)


def ddim_map(steps: list[int]) -> tuple[np.ndarray, np.ndarray]:
    """DDIM with eta = 0 is an affine map x_T -> x0 = A x_T + B; returns (A, B) per channel."""
    A, B = np.ones_like(MU), np.zeros_like(MU)
    for i, t in enumerate(steps):
        a, b = posterior_mean_gain(t)
        if i + 1 == len(steps):
            return a * A, a * B + b
        ab, ab_prev = ABAR[t], ABAR[steps[i + 1]]
        # x' = sqrt(ab_prev) x0_hat + sqrt(1 - ab_prev) eps_hat, eps_hat = (x - sqrt(ab) x0_hat) / sqrt(1 - ab)
        k = np.sqrt(1 - ab_prev) / np.sqrt(1 - ab)
        gain_x, gain_1 = np.sqrt(ab_prev) * a + k * (1 - np.sqrt(ab) * a), np.sqrt(ab_prev) * b - k * np.sqrt(ab) * b
        A, B = gain_x * A, gain_x * B + gain_1


def check_moments(x: torch.Tensor, mean: np.ndarray, std: np.ndarray, rel_tol_of_s: float) -> None:
    x = x.double().reshape(-1, len(MU)).numpy()
    se_mean, se_std = S / np.sqrt(len(x)), S / np.sqrt(2 * len(x))
    # against the exact distribution of the sampler (closed form above)
    np.testing.assert_array_less(np.abs(x.mean(0) - mean), 5 * se_mean)
    np.testing.assert_array_less(np.abs(x.std(0) - std), 5 * se_std)
    # and against the data distribution
    np.testing.assert_array_less(np.abs(x.mean(0) - MU), 5 * se_mean + 1e-3)
    np.testing.assert_array_less(np.abs(x.std(0) - S), rel_tol_of_s * S)


def test_ddpm_1000_steps_recovers_data_mean_and_std():
    smp, toy = sampler()
    x = smp.sample((N, 1, len(MU)), Condition(), method="ddpm", guidance=Guidance(1.0, 1.0),
                   generator=torch.Generator().manual_seed(0))  # fmt: skip
    assert toy.calls == T and x.shape == (N, 1, len(MU))
    mean, std = ddpm_moments()
    assert np.all(np.abs(std - S) < 0.01 * S)  # the posterior-variance sampler is within 1 % of s here
    check_moments(x, mean, std, rel_tol_of_s=0.04)


@pytest.mark.parametrize("n_steps", [200, 600])  # 600 does not divide 1000: the steps must still reach t ~ 0
def test_ddim_eta0_is_the_closed_form_affine_map_of_the_start_noise(n_steps):
    smp, toy = sampler()
    steps = smp.timesteps("ddim", n_steps)
    x = smp.sample((N, 1, len(MU)), Condition(), method="ddim", steps=n_steps, eta=0.0, guidance=Guidance(1.0, 1.0),
                   generator=torch.Generator().manual_seed(3))  # fmt: skip
    assert toy.calls == n_steps
    x_start = torch.randn((N, 1, len(MU)), generator=torch.Generator().manual_seed(3)).double().numpy()
    A, B = ddim_map(steps)
    np.testing.assert_allclose(x.double().numpy(), A * x_start + B, rtol=1e-4, atol=1e-4)
    check_moments(x, B, np.abs(A), rel_tol_of_s=0.04)


@pytest.mark.parametrize("method", ["ddim", "ddpm"])
def test_sampling_ends_on_the_denoisers_x0(method):
    """The last step returns the denoiser's x0 prediction at t = 0 (DDPM) or at the last DDIM step."""
    smp, _ = sampler()
    states = []
    x = smp.sample((8, 1, len(MU)), Condition(), method=method, steps=10, guidance=Guidance(1.0, 1.0),
                   generator=torch.Generator().manual_seed(1),
                   step_callback=lambda s, t_next: states.append((s.clone(), t_next)) or s)  # fmt: skip
    last_t = smp.timesteps(method, 10)[-1]
    x_before, t_next = states[-2]
    assert states[-1][1] == -1 and t_next == last_t
    a, b = posterior_mean_gain(last_t)
    np.testing.assert_allclose(x.double().numpy(), a * x_before.double().numpy() + b, rtol=1e-5, atol=1e-6)
