"""Samplers over a denoiser and a diffusion process: DDPM (every step), DDIM (N steps, eta) and the few-step ODE
solvers DPM-Solver++(2M) and UniPC (:mod:`dgsdp.sampling.solvers`), with classifier-free guidance on music and
style, and editing masks (DGSDP Algorithm 2 / EDGE Eq. 8).

Guidance (x are x0 predictions; passes are batched into one forward):
- models trained with style dropout: ``x_u + w_music (x_m - x_u) + w_style (x_ms - x_m)`` where x_u has neither
  condition, x_m music only, x_ms both;
- models whose style is never dropped (the official DGSDP setting) or without style: ``x_u + w_music (x_m - x_u)``
  with the style kept in both passes.
With all weights 1 a single conditional pass is run. A guidance-distilled student (a denoiser with
``guidance_inputs``, :mod:`dgsdp.training.distill`) takes the weights as an input and runs one conditional pass.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import torch
from tqdm.auto import tqdm

from dgsdp.diffusion import GaussianDiffusion
from dgsdp.diffusion.gaussian import x0_bound
from dgsdp.sampling.noise import Noise
from dgsdp.sampling.solvers import SOLVERS, make_solver, solver_timesteps
from dgsdp.utils.deadline import check_time

# Sampler methods by name (``sampling.method``).
METHODS = ("ddim", "ddpm", *SOLVERS)
DEFAULT_SOLVER_STEPS = 10

StepCallback = Callable[[torch.Tensor, int], torch.Tensor]


def check_method(method: str) -> None:
    """Raise one clear error for an unknown sampler name."""
    if method not in METHODS:
        raise ValueError(f"unknown sampler {method!r}; use one of {', '.join(METHODS)}")


@dataclass
class Guidance:
    """Guidance weights, optionally ramped up over the first steps and capped near the end when editing.

    ramp_fraction: the weights rise linearly from 0 and reach their value at this fraction of the way from the
    first sampling step to the last, EDGE's long-form schedule (0.5: ``clip(linspace(0, 2 w, n), max=w)``). edit_cap_below_t: with a mask, weights above 1 are capped at 1 for
    diffusion steps t below this value (EDGE's inpainting: 100); 0 = off.
    """

    music_weight: float = 2.0
    style_weight: float = 1.0
    ramp_fraction: float = 0.0
    edit_cap_below_t: int = 0
    rescale: float = 0.0

    def at(self, step: int, n_steps: int, t: int, masked: bool) -> Guidance:
        """The plain weights used at sampling step ``step`` (0-based) of ``n_steps``, diffusion step ``t``."""
        scale = 1.0
        if self.ramp_fraction > 0:
            scale = min(1.0, step / max(self.ramp_fraction * (n_steps - 1), 1e-9))
        music, style = self.music_weight * scale, self.style_weight * scale
        if masked and t < self.edit_cap_below_t:
            music, style = min(music, 1.0), min(style, 1.0)
        return Guidance(music, style, rescale=self.rescale)


@dataclass
class Condition:
    """What the denoiser is conditioned on: music (B, T, Da) or None, style (B, ds) / (B, T, ds) or None."""

    music: torch.Tensor | None = None
    style: torch.Tensor | None = None


Passes = tuple[tuple[bool, bool], ...]


class PreparedCondition:
    """The condition of one sampling run, laid out once per set of guidance passes and reused at every step.

    For each set of passes (keep_music, keep_style) it holds the keep masks and the condition repeated over the
    passes, and, for denoisers with a ``condition(music, style, keep_music, keep_style)`` method, the denoiser's
    own conditioning (music encoder output, style, cross-attention keys and values) computed once.

    ``same_step``: every call of the run has all its rows at one diffusion step with the same guidance weights (a
    sampler's loop); the denoiser is told so with its conditioning (``same_step=True``), which spares it a read
    back from the device per step.
    """

    def __init__(
        self,
        denoiser: Callable,
        cond: Condition,
        batch: int,
        n_frames: int,
        device: torch.device | str,
        same_step: bool = False,
    ) -> None:
        self.denoiser = denoiser
        self.cond = cond
        self.batch = batch
        self.n_frames = n_frames
        self.device = device
        self.same_step = same_step
        self._by_passes: dict[Passes, dict] = {}

    def inputs(self, passes: Passes) -> dict:
        """Keyword arguments of the denoiser for a batch laid out pass after pass (x_t repeated per pass)."""
        if passes not in self._by_passes:
            self._by_passes[passes] = self._prepare(passes)
        return self._by_passes[passes]

    def _prepare(self, passes: Passes) -> dict:
        k, b = len(passes), self.batch
        keep_music, keep_style = pass_masks(passes, b, self.device)
        style = repeat_passes(self.cond.style, k)
        condition = getattr(self.denoiser, "condition", None)
        if condition is not None:
            # the music is not repeated over the passes: each row names its row of the run's music
            rows = torch.arange(b, device=self.device).repeat(k) if self.cond.music is not None else None
            cached = condition(self.cond.music, style, keep_music, keep_style, n_frames=self.n_frames, batch=k * b,
                               music_rows=rows)  # fmt: skip
            if cached is not None:
                return {"cond": cached, "same_step": True} if self.same_step else {"cond": cached}
        music = repeat_passes(self.cond.music, k)
        return {"music": music, "style": style, "keep_music": keep_music, "keep_style": keep_style}


def guidance_passes(style_guidance: bool) -> Passes:
    """(keep_music, keep_style) of each guided pass, the fully conditional pass last: with style guidance
    (a model trained with style dropout, and a style given) the unconditional, music-only and full passes, else
    the pass without music and the full one (the style kept in both)."""
    return ((False, False), (True, False), (True, True)) if style_guidance else ((False, True), (True, True))


def pass_masks(passes: Passes, batch: int, device: torch.device | str) -> tuple[torch.Tensor, torch.Tensor]:
    """keep_music and keep_style (len(passes) * batch,) of a batch laid out pass after pass."""
    keep_music = torch.tensor([p[0] for p in passes], device=device).repeat_interleave(batch)
    keep_style = torch.tensor([p[1] for p in passes], device=device).repeat_interleave(batch)
    return keep_music, keep_style


def repeat_passes(v: torch.Tensor | None, k: int) -> torch.Tensor | None:
    """``v`` (B, ...) repeated for ``k`` passes laid out one after the other (None stays None)."""
    return None if v is None else v.repeat(k, *([1] * (v.ndim - 1)))


def combine_guided(
    outs: Sequence[torch.Tensor], music_weight: float | torch.Tensor, style_weight: float | torch.Tensor
) -> torch.Tensor:
    """The guided x0 from the passes of :func:`guidance_passes` (in its order); weights are numbers or tensors
    that broadcast against the predictions (per-row weights: (B, 1, 1))."""
    if len(outs) == 2:
        return outs[0] + music_weight * (outs[1] - outs[0])
    x_u, x_m, x_ms = outs
    return x_u + music_weight * (x_m - x_u) + style_weight * (x_ms - x_m)


def rescale_guided(guided: torch.Tensor, conditional: torch.Tensor, amount: float) -> torch.Tensor:
    """The guided x0 (B, T, C) with each channel's movement over time scaled back to the fully conditional
    prediction's: per row and channel, the deviation from its mean over the frames is multiplied by the ratio of the
    two predictions' standard deviations over the frames, blended with the guided x0 by ``amount`` (0: unchanged;
    1: fully rescaled). The mean pose, which carries most of a style's posture, is kept; the guidance's extra
    movement is what goes. The rescaling of Lin et al. (2024, "Common diffusion noise schedules and sample steps are
    flawed") taken over time, per channel, for motion."""
    if guided.shape[-2] < 2:
        return guided
    mean = guided.mean(dim=-2, keepdim=True)
    ratio = conditional.std(dim=-2, keepdim=True) / guided.std(dim=-2, keepdim=True).clamp_min(1e-6)
    rescaled = mean + (guided - mean) * ratio
    return amount * rescaled + (1.0 - amount) * guided


def guidance_weights(denoiser: torch.nn.Module, guidance: Guidance, batch: int, like: torch.Tensor) -> dict:
    """The ``guidance=`` input of a guidance-distilled student (B, guidance_inputs), or no argument. Filled on the
    device (a tensor made from a list would be copied from the host, which waits for the device, every step)."""
    n = getattr(denoiser, "guidance_inputs", 0)
    if not n:
        return {}
    columns = [like.new_full((batch, 1), w) for w in (guidance.music_weight, guidance.style_weight)[:n]]
    return {"guidance": columns[0] if n == 1 else torch.cat(columns, dim=1)}


class Sampler:
    """Generates x0 (normalised) from noise with any denoiser ``fn(x_t, t, music, style, keep_music, keep_style)``.

    Denoisers that also offer ``condition(music, style, keep_music, keep_style)`` and accept its result as
    ``fn(x_t, t, cond=...)`` get their conditioning computed once per sampling run instead of once per step.

    ``clip_x0``: the bound of every x0 prediction in normalised units, replacing the run's own
    (``diffusion.clip_x0``) when given: ``True`` = 1 (EDGE), ``False`` = none, or a positive number.
    """

    def __init__(
        self,
        denoiser: torch.nn.Module,
        diffusion: GaussianDiffusion,
        *,
        style_guidance: bool,
        clip_x0: bool | float | None = None,
    ) -> None:
        self.denoiser = denoiser
        self.diffusion = diffusion
        self.style_guidance = style_guidance
        self.x0_bound = diffusion.x0_bound if clip_x0 is None else x0_bound(clip_x0)

    def _passes(self, cond: Condition, guidance: Guidance) -> Passes:
        """(keep_music, keep_style) of each pass, the fully conditional pass last."""
        if getattr(self.denoiser, "guidance_inputs", 0):  # a student: the weights are its input
            return ((True, True),)
        if guidance.music_weight == 1 and (guidance.style_weight == 1 or not self.style_guidance):
            return ((True, True),)
        return guidance_passes(self.style_guidance and cond.style is not None)

    @torch.no_grad()
    def predict_x0(
        self,
        x_t: torch.Tensor,
        t: torch.Tensor,
        cond: Condition,
        guidance: Guidance,
        prepared: PreparedCondition | None = None,
    ) -> torch.Tensor:
        """The guided, clamped x0 prediction (B, T, D). ``prepared`` (for ``cond``) reuses the conditioning
        of earlier steps."""
        passes = self._passes(cond, guidance)
        k = len(passes)
        if prepared is None:
            prepared = PreparedCondition(self.denoiser, cond, x_t.shape[0], x_t.shape[1], x_t.device)
        xs = x_t if k == 1 else x_t.repeat(k, *([1] * (x_t.ndim - 1)))
        weights = guidance_weights(self.denoiser, guidance, xs.shape[0], x_t)
        out = self.denoiser(xs, t.repeat(k), **prepared.inputs(passes), **weights)
        outs = out.chunk(k)
        x0 = outs[0] if k == 1 else combine_guided(outs, guidance.music_weight, guidance.style_weight)
        if k > 1 and guidance.rescale > 0:
            x0 = rescale_guided(x0, outs[-1], guidance.rescale)
        return x0 if self.x0_bound is None else x0.clamp(-self.x0_bound, self.x0_bound)

    def timesteps(self, method: str, steps: int | None, spacing: str = "lambda") -> list[int]:
        """The diffusion steps at which the model is evaluated, descending (the last step goes to x0)."""
        check_method(method)
        if method == "ddpm":
            return list(range(self.diffusion.num_steps - 1, -1, -1))
        if method == "ddim":
            return self.diffusion.ddim_timesteps(steps or 50)
        return solver_timesteps(self.diffusion, steps or DEFAULT_SOLVER_STEPS, spacing)

    @torch.no_grad()
    def sample(
        self,
        shape: tuple[int, int, int],
        cond: Condition,
        *,
        method: str = "ddim",
        steps: int | None = 50,
        eta: float = 1.0,
        guidance: Guidance | None = None,
        mask: torch.Tensor | None = None,
        known: torch.Tensor | None = None,
        step_callback: StepCallback | None = None,
        x0_callback: Callable[[torch.Tensor], torch.Tensor] | None = None,
        generator: torch.Generator | Sequence[torch.Generator] | Noise | None = None,
        device: torch.device | str = "cpu",
        progress: bool = False,
        spacing: str = "lambda",
    ) -> torch.Tensor:
        """Sample x0 of ``shape`` (B, T, D), normalised.

        method: ``ddim`` (``steps``, ``eta``), ``ddpm`` (every diffusion step), or a few-step solver
        (``dpmpp_2m``, ``unipc``: deterministic ODE solvers; ``dpmpp_2m_sde``: stochastic; ``eta`` is not used) evaluated at ``steps`` diffusion steps placed by
        ``spacing`` (``time`` or ``lambda``, see :func:`solver_timesteps`).

        generator: one generator for the batch, one per group of rows (see :class:`Noise`), or a Noise; every
        Gaussian draw of the sampler comes from it.

        mask (B or 1, T, D) with 1 where ``known`` (normalised, same shape as the output) is given. DDPM/DDIM:
        after every step the known region is replaced by ``known`` noised to the new step with fresh noise.
        ODE solvers: the known region of every x0 prediction is replaced by ``known`` before the update, and that
        of the state by ``known`` on its own ODE path, alpha_t known + sigma_t z with the initial noise z (the
        SDE solver pins the start only: its update with x0 = known keeps the known region on a path of that
        form). All end with ``known`` itself. ``step_callback(x, t_next)`` may rewrite the state after every step
        (long-form consistency uses it); UniPC also calls it after each correction, ``step_callback(x, t)``, and
        every sampler calls it on the initial noise, ``step_callback(x, first t)``. ``x0_callback(x0)`` may
        rewrite every guided x0 prediction before it is used (long-form windows fuse their predictions).
        """
        guidance = guidance or Guidance()
        ts = self.timesteps(method, steps, spacing)
        noise = generator if isinstance(generator, Noise) else Noise(generator)
        x = noise.randn(shape, device=device)
        b = shape[0]
        if mask is not None:
            if known is None:
                raise ValueError("a mask needs the known motion it refers to")
            mask = mask.to(device=device, dtype=x.dtype)
            known = known.to(device=device, dtype=x.dtype)
        prepared = PreparedCondition(self.denoiser, cond, b, shape[1], device, same_step=True)  # t: one step per call
        solver = make_solver(method, self.diffusion, ts) if method in SOLVERS else None
        z = x  # the initial noise: the known region's ODE path for the solvers

        def draw(shape: Sequence[int]) -> torch.Tensor:
            return noise.randn(shape, device=device, dtype=x.dtype)

        def pin_state(x: torch.Tensor, i: int) -> torch.Tensor:
            """The solver's state at point i with the known region on its ODE path."""
            if mask is None:
                return x
            if i >= len(ts):
                target = known
            elif solver.stochastic and i > 0:  # the SDE step with x0 = known keeps the known region on its own path
                return x
            else:
                target = solver.alpha[i] * known + solver.sigma[i] * z
            return mask * target + (1 - mask) * x

        if step_callback is not None:
            x = step_callback(x, ts[0])
        if solver is not None:
            x = pin_state(x, 0)
        for i, t_now in enumerate(tqdm(ts, desc="sampling", leave=False, disable=not progress)):
            check_time()  # a request's time limit (dgsdp.utils.deadline), when one is set
            t_next = ts[i + 1] if i + 1 < len(ts) else -1
            t = torch.full((b,), t_now, device=device, dtype=torch.long)
            at = guidance.at(i, len(ts), t_now, masked=mask is not None)
            x0 = self.predict_x0(x, t, cond, at, prepared)
            if x0_callback is not None:
                x0 = x0_callback(x0)
            if solver is not None:
                if mask is not None:
                    x0 = mask * known + (1 - mask) * x0
                if i > 0:
                    corrected = solver.correct(i, x, x0)
                    if corrected is not x:
                        x = pin_state(corrected, i)
                        if step_callback is not None:
                            x = step_callback(x, t_now)
                x = pin_state(solver.step(i, x, x0, noise=draw), i + 1)
            else:
                if t_next < 0:
                    x = x0
                elif method == "ddpm":
                    x = self.diffusion.ddpm_step(x, t, x0, noise=noise.randn(x.shape, device=device, dtype=x.dtype))
                else:
                    t_prev = torch.full_like(t, t_next)
                    step_noise = noise.randn(x.shape, device=device, dtype=x.dtype)
                    x = self.diffusion.ddim_step(x, t, t_prev, x0, eta=eta, noise=step_noise)
                if mask is not None:
                    if t_next < 0:
                        target = known
                    else:
                        known_noise = noise.randn(x.shape, device=device, dtype=x.dtype)
                        target = self.diffusion.q_sample(known, torch.full_like(t, t_next), known_noise)
                    x = mask * target + (1 - mask) * x
            if step_callback is not None:
                x = step_callback(x, t_next)
        return x
