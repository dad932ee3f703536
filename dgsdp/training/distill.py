"""Guidance distillation (Meng et al. 2023, "On Distillation of Guided Diffusion Models", stage one):
``python train.py <the teacher's run config> distill.teacher=<checkpoint>``.

Classifier-free guidance runs the denoiser two or three times per sampling step (with and without the music, and
the style). A student with the teacher's architecture plus the guidance weights as an input (``guidance_inputs``,
see :class:`dgsdp.model.DanceDenoiser`) learns to predict the teacher's guided x0 in one pass, for every weight in
``[0, distill.max_weight]`` (the long-form ramp starts at 0, the editing cap uses 1). It starts from the teacher's
EMA weights with the guidance projection at zero, so it starts as the teacher's conditional model, and trains on the
teacher's data with the loss ``|student(x_t, t, w) - guided_teacher(x_t, t, w)|^2`` at random diffusion steps.

The student is an ordinary checkpoint: generate.py, evaluate.py, the studio and the benchmarks sample it with one
pass per step (:class:`dgsdp.sampling.Sampler` sees its ``guidance_inputs``). docs/distillation.md has the recipe
and what it measured.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import torch

from dgsdp.errors import ConfigError
from dgsdp.sampling.sampler import combine_guided, guidance_passes, pass_masks, repeat_passes
from dgsdp.trained.model import TrainedModel, load_model
from dgsdp.trained.spec import RunSpec
from dgsdp.training.module import DanceDiffusion


@dataclass(frozen=True)
class DistillSettings:
    """``distill`` in conf/train.yaml: the teacher checkpoint (None: ordinary training) and the largest guidance
    weight the student learns."""

    teacher: str | None = None
    max_weight: float = 3.0

    @classmethod
    def from_config(cls, node: Mapping[str, Any] | None) -> DistillSettings:
        node = dict(node or {})
        unknown = sorted(set(node) - {"teacher", "max_weight"})
        if unknown:
            raise ConfigError(f"unknown distill setting(s) {', '.join(unknown)}; known: max_weight, teacher")
        teacher = node.get("teacher")
        max_weight = node.get("max_weight", cls.max_weight)
        if isinstance(max_weight, bool) or not isinstance(max_weight, int | float) or not max_weight > 0:
            raise ConfigError(f"distill.max_weight must be a positive number, got {max_weight!r}")
        return cls(None if teacher in (None, "") else str(teacher), float(max_weight))


def student_guidance_inputs(teacher: TrainedModel) -> int:
    """How many guidance weights a student of ``teacher`` takes: music, and style where the teacher has style
    guidance. A teacher that is itself a student is refused."""
    if getattr(teacher.denoiser, "guidance_inputs", 0):
        raise ConfigError(
            "distill.teacher is itself a guidance-distilled student (it runs one pass per step already); give the "
            "checkpoint of the model it was distilled from"
        )
    return 2 if teacher.spec.conditioning.style_guidance else 1


def check_student_spec(student: RunSpec, teacher: TrainedModel, source: str) -> None:
    """The student must be the teacher's run: the same architecture (but for the guidance input) and diffusion."""
    mine, theirs = student.architecture(), teacher.spec.architecture()
    theirs["model"]["guidance_inputs"] = mine["model"].get("guidance_inputs")
    hint = (
        f"train the student with the teacher's run config (the same experiment and config groups as the run that "
        f"wrote {source}) plus distill.teacher=..."
    )
    if mine != theirs:
        diffs = sorted(
            f"model.{k}" for k in set(mine["model"]) | set(theirs["model"]) if mine["model"].get(k) != theirs["model"].get(k)
        ) + sorted(k for k in mine if k != "model" and mine[k] != theirs[k])  # fmt: skip
        raise ConfigError(f"the student's architecture differs from the teacher's in {', '.join(diffs)}: {hint}")
    if student.diffusion != teacher.spec.diffusion:
        raise ConfigError(f"the student's diffusion settings differ from the teacher's: {hint}")


class GuidanceDistillation(DanceDiffusion):
    """Trains a guidance-distilled student of ``teacher`` (see the module docstring). ``spec`` is the student's:
    the teacher's run with ``model.guidance_inputs`` set."""

    def __init__(self, spec: RunSpec, teacher: TrainedModel, max_weight: float) -> None:
        super().__init__(spec)
        if self.denoiser.guidance_inputs != student_guidance_inputs(teacher):
            raise ConfigError(f"the student needs model.guidance_inputs={student_guidance_inputs(teacher)}")
        self.max_weight = float(max_weight)
        self.style_guidance = teacher.spec.conditioning.style_guidance
        frozen = teacher.ema.module.eval().requires_grad_(False)
        self._teacher = (frozen,)  # a tuple: not a submodule, so never in the student's checkpoint
        weights = frozen.state_dict()
        for denoiser in (self.denoiser, self.ema.module):
            missing, unexpected = denoiser.load_state_dict(weights, strict=False)
            if unexpected or any(not k.startswith("guidance_proj.") for k in missing):
                raise ConfigError(
                    f"the teacher's weights do not fit the student (missing {missing}, extra {unexpected})"
                )
        # the teacher's normalisation, floor, tempo range and style bank: the student predicts in the teacher's units
        self.normalizer.load_state_dict(teacher.normalizer.state_dict())
        self.floor_height.copy_(teacher.floor_height)
        self.tempo_range_bpm.copy_(teacher.tempo_range_bpm)
        self.style_vectors.copy_(teacher.style_vectors)
        self.style_genre_index.copy_(teacher.style_genre_index)

    @property
    def teacher(self) -> torch.nn.Module:
        return self._teacher[0]

    def on_fit_start(self) -> None:
        self.teacher.to(self.device)
        super().on_fit_start()

    def _weights(self, b: int, device: torch.device, generator: torch.Generator | None) -> torch.Tensor:
        """Guidance weights (B, guidance_inputs), uniform in [0, max_weight]."""
        n = self.denoiser.guidance_inputs
        return torch.rand(b, n, device=device, generator=generator) * self.max_weight

    @torch.no_grad()
    def guided_teacher(
        self, x_t: torch.Tensor, t: torch.Tensor, music: torch.Tensor | None, style: torch.Tensor | None,
        weights: torch.Tensor,
    ) -> torch.Tensor:  # fmt: skip
        """The teacher's guided x0 (B, T, D) with per-row weights (B, guidance_inputs), as the sampler forms it
        (without the x0 bound, which the sampler applies to the student's prediction)."""
        passes = guidance_passes(self.style_guidance and style is not None)
        k = len(passes)
        keep_music, keep_style = pass_masks(passes, x_t.shape[0], x_t.device)
        rep = [repeat_passes(v, k) for v in (x_t, music, style)]
        outs = self.teacher(rep[0], t.repeat(k), rep[1], rep[2], keep_music, keep_style).chunk(k)
        w = weights[:, :, None, None]  # (B, n, 1, 1): one weight per row
        return combine_guided(outs, w[:, 0], w[:, -1] if weights.shape[1] > 1 else 1.0)

    def _loss(
        self, denoiser: torch.nn.Module, batch: dict[str, Any], train: bool, generator=None
    ) -> dict[str, torch.Tensor]:
        t, x_t, style = self._noised(batch, train, generator)
        music = batch.get("audio")
        weights = self._weights(x_t.shape[0], x_t.device, generator)
        target = self.guided_teacher(x_t, t, music, style, weights)
        pred = denoiser(x_t, t, music, style, guidance=weights)
        return {"loss": torch.nn.functional.mse_loss(pred.float(), target.float())}


def check_same_data(teacher: TrainedModel, normalizer: torch.nn.Module, bank: Any, source: str) -> None:
    """The student's data must be the teacher's: the same normalisation statistics and style bank."""
    hint = f"train the student on the data and style config of the run that wrote {source}"
    ours, theirs = normalizer.state_dict(), teacher.normalizer.state_dict()
    if ours.keys() != theirs.keys() or not all(torch.allclose(ours[k], theirs[k], atol=1e-5) for k in ours):
        raise ConfigError(f"the training data's normalisation differs from the teacher's: {hint}")
    vectors = torch.zeros(0, teacher.style_dim) if bank is None else bank.vectors
    if vectors.shape != teacher.style_vectors.shape or not torch.allclose(vectors, teacher.style_vectors, atol=1e-4):
        raise ConfigError(f"the style bank differs from the teacher's: {hint}")


def load_teacher(settings: DistillSettings) -> TrainedModel | None:
    """The teacher of a distillation run, read once before any work starts (None: ordinary training)."""
    return None if settings.teacher is None else load_model(settings.teacher)
