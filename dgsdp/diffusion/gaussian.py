"""Gaussian diffusion over pose sequences, kept apart from the denoiser (x0 prediction).

The process owns the noise schedule and the single-step updates (forward noising, DDPM posterior step, DDIM step);
the training loss and samplers call it with any denoiser.
"""

from __future__ import annotations

import math

import torch
from torch import nn


def cosine_betas(num_steps: int, s: float = 0.008, max_beta: float = 0.999) -> torch.Tensor:
    """Cosine schedule (Nichol & Dhariwal): betas (num_steps,) float64, clipped at ``max_beta``."""
    steps = torch.arange(num_steps + 1, dtype=torch.float64) / num_steps
    alpha_bar = torch.cos((steps + s) / (1 + s) * math.pi / 2) ** 2
    betas = 1 - alpha_bar[1:] / alpha_bar[:-1]
    return betas.clamp(max=max_beta)


def linear_betas(num_steps: int, start: float = 1e-4, end: float = 0.02) -> torch.Tensor:
    return torch.linspace(start * 1000 / num_steps, end * 1000 / num_steps, num_steps, dtype=torch.float64)


def x0_bound(clip_x0: bool | float) -> float | None:
    """The bound of a ``clip_x0`` setting: True = 1 (EDGE), False = None (no clamp), or a positive number."""
    if isinstance(clip_x0, bool):
        return 1.0 if clip_x0 else None
    if isinstance(clip_x0, int | float) and float(clip_x0) > 0:
        return float(clip_x0)
    raise ValueError(f"clip_x0 must be true, false or a positive bound, got {clip_x0!r}")


class GaussianDiffusion(nn.Module):
    """Noise schedule and update rules. Buffers are float32 copies of float64 computations."""

    def __init__(
        self,
        num_steps: int = 1000,
        schedule: str = "cosine",
        cosine_s: float = 0.008,
        max_beta: float = 0.999,
        clip_x0: bool | float = 1.5,
        timesteps: str = "uniform",
        timestep_mean: float = 0.0,
        timestep_std: float = 1.0,
    ) -> None:
        super().__init__()
        if timesteps not in ("uniform", "logit_normal"):
            raise ValueError(f"unknown timestep sampling {timesteps!r}; use 'uniform' or 'logit_normal'")
        if not float(timestep_std) > 0:
            raise ValueError(f"timestep_std must be positive, got {timestep_std!r}")
        # training draws each window's step uniformly (EDGE), or t / num_steps = sigmoid(N(mean, std)) (the
        # logit-normal of Esser et al. 2024, SD3): more of the steps where the noise is neither small nor total,
        # and with mean > 0 more of the noisy ones, where a dance's genre is decided
        self.timesteps = timesteps
        self.timestep_mean = float(timestep_mean)
        self.timestep_std = float(timestep_std)
        if schedule == "cosine":
            betas = cosine_betas(num_steps, cosine_s, max_beta)
        elif schedule == "linear":
            betas = linear_betas(num_steps)
        else:
            raise ValueError(f"unknown noise schedule {schedule!r}; use 'cosine' or 'linear'")
        self.num_steps = num_steps
        # x0 predictions are clamped to [-bound, bound] (normalised units; the training data spans [-1, 1]) while
        # sampling: True is EDGE's bound 1 (it pins every channel inside the training range), a larger bound lets
        # a dance leave that range a little (bounce, deeper levels) and still stops runaway guidance.
        self.x0_bound = x0_bound(clip_x0)
        alphas = 1 - betas
        alpha_bar = torch.cumprod(alphas, dim=0)
        alpha_bar_prev = torch.cat([torch.ones(1, dtype=torch.float64), alpha_bar[:-1]])
        post_var = betas * (1 - alpha_bar_prev) / (1 - alpha_bar)
        buffers = {
            "betas": betas,
            "alpha_bar": alpha_bar,
            "alpha_bar_prev": alpha_bar_prev,
            "sqrt_alpha_bar": alpha_bar.sqrt(),
            "sqrt_one_minus_alpha_bar": (1 - alpha_bar).sqrt(),
            "posterior_var": post_var,
            "posterior_log_var": torch.log(torch.cat([post_var[1:2], post_var[1:]])),
            "posterior_c0": betas * alpha_bar_prev.sqrt() / (1 - alpha_bar),
            "posterior_ct": (1 - alpha_bar_prev) * alphas.sqrt() / (1 - alpha_bar),
        }
        for name, value in buffers.items():
            self.register_buffer(name, value.float(), persistent=False)

    @staticmethod
    def _at(values: torch.Tensor, t: torch.Tensor, ndim: int) -> torch.Tensor:
        return values[t].view(-1, *([1] * (ndim - 1)))

    def sample_timesteps(
        self, batch: int, device: torch.device, generator: torch.Generator | None = None
    ) -> torch.Tensor:
        if self.timesteps == "uniform":
            return torch.randint(0, self.num_steps, (batch,), device=device, generator=generator)
        z = torch.randn(batch, device=device, generator=generator) * self.timestep_std + self.timestep_mean
        return (torch.sigmoid(z) * self.num_steps).long().clamp_(0, self.num_steps - 1)

    def q_sample(self, x0: torch.Tensor, t: torch.Tensor, noise: torch.Tensor) -> torch.Tensor:
        """Noise x0 (B, ...) to step t (B,): sqrt(abar) x0 + sqrt(1 - abar) noise."""
        return (
            self._at(self.sqrt_alpha_bar, t, x0.ndim) * x0 + self._at(self.sqrt_one_minus_alpha_bar, t, x0.ndim) * noise
        )

    def predict_noise(self, x_t: torch.Tensor, t: torch.Tensor, x0: torch.Tensor) -> torch.Tensor:
        return (x_t - self._at(self.sqrt_alpha_bar, t, x_t.ndim) * x0) / self._at(
            self.sqrt_one_minus_alpha_bar, t, x_t.ndim
        )

    def clamp(self, x0: torch.Tensor) -> torch.Tensor:
        return x0 if self.x0_bound is None else x0.clamp(-self.x0_bound, self.x0_bound)

    def ddpm_step(
        self,
        x_t: torch.Tensor,
        t: torch.Tensor,
        x0: torch.Tensor,
        generator: torch.Generator | None = None,
        noise: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """One ancestral step x_t -> x_{t-1} from the posterior q(x_{t-1} | x_t, x0); no noise at t = 0.

        ``noise`` (like x_t) is drawn from ``generator`` when not given."""
        nd = x_t.ndim
        mean = self._at(self.posterior_c0, t, nd) * x0 + self._at(self.posterior_ct, t, nd) * x_t
        if noise is None:
            noise = torch.randn(x_t.shape, device=x_t.device, dtype=x_t.dtype, generator=generator)
        nonzero = (t > 0).float().view(-1, *([1] * (nd - 1)))
        return mean + nonzero * (0.5 * self._at(self.posterior_log_var, t, nd)).exp() * noise

    def ddim_step(
        self,
        x_t: torch.Tensor,
        t: torch.Tensor,
        t_prev: torch.Tensor,
        x0: torch.Tensor,
        eta: float = 1.0,
        generator: torch.Generator | None = None,
        noise: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """One DDIM step x_t -> x_{t_prev} (t_prev < 0 means: return x0); ``noise`` drawn from ``generator`` when
        not given."""
        nd = x_t.ndim
        eps = self.predict_noise(x_t, t, x0)
        final = t_prev < 0
        ab = self._at(self.alpha_bar, t, nd)
        ab_prev = self._at(self.alpha_bar, t_prev.clamp(min=0), nd)
        ab_prev = torch.where(final.view(-1, *([1] * (nd - 1))), torch.ones_like(ab_prev), ab_prev)
        sigma = eta * ((1 - ab_prev) / (1 - ab) * (1 - ab / ab_prev)).clamp(min=0).sqrt()
        if noise is None:
            noise = torch.randn(x_t.shape, device=x_t.device, dtype=x_t.dtype, generator=generator)
        direction = (1 - ab_prev - sigma**2).clamp(min=0).sqrt() * eps
        return ab_prev.sqrt() * x0 + direction + sigma * noise

    def ddim_timesteps(self, num_sampling_steps: int) -> list[int]:
        """Evenly spaced descending steps over the whole schedule, e.g. 1000 steps and 50 sampling steps: 999, 979,
        ..., 19 (EDGE's ``linspace(-1, T - 1, n + 1)`` without its -1); gaps are floor or ceil of T / n when n
        does not divide T, so the last step is always within one gap of 0."""
        if not 1 <= num_sampling_steps <= self.num_steps:
            raise ValueError(f"sampling steps must be in 1..{self.num_steps}, got {num_sampling_steps}")
        n = num_sampling_steps
        return [k * self.num_steps // n - 1 for k in range(n, 0, -1)]
