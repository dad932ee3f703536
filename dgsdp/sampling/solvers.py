"""Few-step solvers of the diffusion ODE for an x0-predicting model: DPM-Solver++(2M) and UniPC.

Both integrate the probability-flow ODE in the data-prediction form, in lambda = log(alpha / sigma) with
alpha = sqrt(alpha_bar_t), sigma = sqrt(1 - alpha_bar_t) of the model's own noise schedule. The first-order step
from s to t is DDIM with eta = 0::

    x_t = (sigma_t / sigma_s) x_s - alpha_t (exp(-h) - 1) x0_s,   h = lambda_t - lambda_s

- DPM-Solver++(2M) (Lu et al. 2022, "DPM-Solver++", Algorithm 2): replaces x0_s by the multistep estimate
  (1 + 1/(2r)) x0_s - 1/(2r) x0_prev with r = h_prev / h.
- DPM-Solver++(2M) SDE (``dpmpp_2m_sde``, the same paper's stochastic variant): each step adds fresh noise,
  x_t = (sigma_t / sigma_s) e^-h x_s + alpha_t (1 - e^-2h) (x0_s + D / 2) + sigma_t sqrt(1 - e^-2h) z with
  D = (x0_s - x0_prev) / r; its first-order step is DDIM with eta = 1.
- UniPC (Zhao et al. 2023, "UniPC"): the predictor UniP-2 and, once the model has been evaluated at the new
  point, the corrector UniC, which redoes the last step with that evaluation included (no extra model call);
  B(h) = exp(-h) - 1 ("bh2", recommended for guided sampling) or -h ("bh1").

The last step goes to sigma = 0 and returns the last x0 prediction, as the DDIM sampler does. Only the SDE
variant draws noise (through the sampler's ``Noise``). Coefficients are computed in float64 from the schedule's alpha_bar.
"""

from __future__ import annotations

import math

import torch

from dgsdp.diffusion import GaussianDiffusion

SOLVERS = ("dpmpp_2m", "dpmpp_2m_sde", "unipc", "unipc_bh1")
STOCHASTIC_SOLVERS = ("dpmpp_2m_sde",)
SPACINGS = ("time", "lambda")


def solver_timesteps(diffusion: GaussianDiffusion, steps: int, spacing: str = "time") -> list[int]:
    """``steps`` descending diffusion steps at which the model is evaluated; the last step goes to x0.

    time: uniform in t, starting at the last training step (999, 899, ..., 99 for 10 of 1000 steps);
    lambda: the same first two steps, then uniform in lambda from the second step to the first training step
    (that end point, t = 0, is replaced by x0), rounded to the nearest training step. (The cosine schedule's last
    beta is clipped, so lambda falls by 3.5 over its last step alone: spacing from there would waste steps.)
    """
    n = diffusion.num_steps
    if not 1 <= steps <= n:
        raise ValueError(f"sampling steps must be in 1..{n}, got {steps}")
    uniform = [int(round(n - 1 - i * n / steps)) for i in range(steps)]
    if spacing == "time":
        return uniform
    if spacing == "lambda":
        if steps <= 2:
            return uniform
        lam = _lambdas(diffusion)
        targets = torch.linspace(float(lam[uniform[1]]), float(lam[0]), steps, dtype=torch.float64)[:-1]
        nearest = (lam[None, :] - targets[:, None]).abs().argmin(dim=1).tolist()  # one read for all the steps
        out = [uniform[0]]
        for k, t in enumerate(nearest, start=2):
            # nearest training step (lambda decreases with t), strictly below the last, leaving room for the rest
            out.append(max(min(t, out[-1] - 1), steps - k))
        return out
    raise ValueError(f"unknown timestep spacing {spacing!r}; use one of {SPACINGS}")


def _lambdas(diffusion: GaussianDiffusion) -> torch.Tensor:
    ab = diffusion.alpha_bar.detach().double().cpu()
    return 0.5 * (ab.log() - (1 - ab).log())


class MultistepSolver:
    """One sampling run of a multistep ODE solver over ``timesteps`` (descending); the state is per run.

    ``step(i, x, x0)`` takes the state at ``timesteps[i]`` and the (guided, clamped, mask-pinned) x0 prediction
    there and returns the state at ``timesteps[i + 1]``, or x0 after the last step.
    ``correct(i, x, x0)`` (UniPC only; identity otherwise) refines the state at ``timesteps[i]`` with the x0
    predicted there, before ``step(i, ...)``.
    """

    def __init__(self, diffusion: GaussianDiffusion, timesteps: list[int]) -> None:
        ab = diffusion.alpha_bar.detach().double().cpu().tolist()  # read once: the coefficients are host numbers
        self.timesteps = list(timesteps)
        # per point: alpha, sigma, lambda; the final point is x0 (alpha 1, sigma 0, lambda +inf)
        self.alpha = [math.sqrt(ab[t]) for t in self.timesteps] + [1.0]
        self.sigma = [math.sqrt(1.0 - ab[t]) for t in self.timesteps] + [0.0]
        self.lam = [math.log(a / s) for a, s in zip(self.alpha[:-1], self.sigma[:-1], strict=True)] + [math.inf]
        self.x0s: list[torch.Tensor] = []  # x0 predictions at the points visited so far (the last two are kept)

    @property
    def n_steps(self) -> int:
        return len(self.timesteps)

    def _remember(self, x0: torch.Tensor) -> None:
        self.x0s = [*self.x0s[-1:], x0]

    def correct(self, i: int, x: torch.Tensor, x0: torch.Tensor) -> torch.Tensor:
        return x

    stochastic = False

    def step(self, i: int, x: torch.Tensor, x0: torch.Tensor, noise=None) -> torch.Tensor:
        """``noise(shape)`` draws Gaussian noise (stochastic solvers only)."""
        raise NotImplementedError


class DPMSolverPP2M(MultistepSolver):
    """DPM-Solver++(2M): second order from the second step on, first order on the first and the last step."""

    def step(self, i: int, x: torch.Tensor, x0: torch.Tensor, noise=None) -> torch.Tensor:
        self._remember(x0)
        if i == self.n_steps - 1:  # to sigma = 0: the first-order step returns x0 itself
            return x0
        s, t = i, i + 1
        h = self.lam[t] - self.lam[s]
        d = x0
        if i > 0:
            r = (self.lam[s] - self.lam[s - 1]) / h
            d = (1 + 1 / (2 * r)) * x0 - (1 / (2 * r)) * self.x0s[0]
        return (self.sigma[t] / self.sigma[s]) * x - (self.alpha[t] * math.expm1(-h)) * d


class DPMSolverPP2MSDE(MultistepSolver):
    """DPM-Solver++(2M) SDE: second order from the second step on; ``noise(shape)`` draws each step's z."""

    stochastic = True

    def step(self, i: int, x: torch.Tensor, x0: torch.Tensor, noise=None) -> torch.Tensor:
        self._remember(x0)
        if i == self.n_steps - 1:
            return x0
        s, t = i, i + 1
        h = self.lam[t] - self.lam[s]
        d = x0
        if i > 0:
            r = (self.lam[s] - self.lam[s - 1]) / h
            d = x0 + (0.5 / r) * (x0 - self.x0s[0])
        decay = -math.expm1(-2 * h)  # 1 - e^-2h
        z = noise(x.shape)
        return (
            (self.sigma[t] / self.sigma[s] * math.exp(-h)) * x
            + (self.alpha[t] * decay) * d
            + (self.sigma[t] * math.sqrt(decay)) * z
        )


class UniPC(MultistepSolver):
    """UniPC with the order-2 predictor (UniP-2) and the corrector UniC of the previous step's order."""

    def __init__(self, diffusion: GaussianDiffusion, timesteps: list[int], variant: str = "bh2") -> None:
        super().__init__(diffusion, timesteps)
        if variant not in ("bh1", "bh2"):
            raise ValueError(f"unknown UniPC variant {variant!r}; use 'bh1' or 'bh2'")
        self.variant = variant
        self.last_x: torch.Tensor | None = None  # the (corrected) state the last step started from
        self.last_order = 0

    def _coefficients(self, s: int, t: int) -> tuple[float, float, list[float]]:
        """h phi_1 = exp(-h) - 1, B(h), and b_k = g_k(h) / B(h) for k = 1, 2 (the right-hand side of UniPC's
        order conditions, with hh = -h for data prediction)."""
        hh = -(self.lam[t] - self.lam[s])
        h_phi_1 = math.expm1(hh)
        b_h = hh if self.variant == "bh1" else h_phi_1
        h_phi_k = h_phi_1 / hh - 1
        b, factorial = [], 1
        for k in range(1, 3):
            b.append(h_phi_k * factorial / b_h)
            factorial *= k + 1
            h_phi_k = h_phi_k / hh - 1 / factorial
        return h_phi_1, b_h, b

    def correct(self, i: int, x: torch.Tensor, x0: torch.Tensor) -> torch.Tensor:
        if i == 0 or self.last_x is None:
            return x
        s, t = i - 1, i  # redo the step s -> t with x0 at t included
        h_phi_1, b_h, b = self._coefficients(s, t)
        m0 = self.x0s[-1]
        base = (self.sigma[t] / self.sigma[s]) * self.last_x - (self.alpha[t] * h_phi_1) * m0
        d_t = x0 - m0
        if self.last_order == 1:
            res = 0.5 * d_t
        else:  # order 2: solve [[1, 1], [r1, 1]] rho = b
            r1 = (self.lam[s - 1] - self.lam[s]) / (self.lam[t] - self.lam[s])
            rho_1 = (b[0] - b[1]) / (1 - r1)
            rho_t = b[0] - rho_1
            res = rho_1 * (self.x0s[0] - m0) / r1 + rho_t * d_t
        return base - (self.alpha[t] * b_h) * res

    def step(self, i: int, x: torch.Tensor, x0: torch.Tensor, noise=None) -> torch.Tensor:
        self._remember(x0)
        self.last_x = x
        if i == self.n_steps - 1:
            return x0
        s, t = i, i + 1
        order = min(2, i + 1, self.n_steps - i)
        self.last_order = order
        h_phi_1, b_h, _ = self._coefficients(s, t)
        out = (self.sigma[t] / self.sigma[s]) * x - (self.alpha[t] * h_phi_1) * x0
        if order == 2:
            r1 = (self.lam[s - 1] - self.lam[s]) / (self.lam[t] - self.lam[s])
            out = out - (self.alpha[t] * b_h * 0.5) * (self.x0s[0] - x0) / r1
        return out


def make_solver(method: str, diffusion: GaussianDiffusion, timesteps: list[int]) -> MultistepSolver:
    if method == "dpmpp_2m":
        return DPMSolverPP2M(diffusion, timesteps)
    if method == "dpmpp_2m_sde":
        return DPMSolverPP2MSDE(diffusion, timesteps)
    if method == "unipc":
        return UniPC(diffusion, timesteps, "bh2")
    if method == "unipc_bh1":
        return UniPC(diffusion, timesteps, "bh1")
    raise ValueError(f"unknown solver {method!r}; use one of {SOLVERS}")
