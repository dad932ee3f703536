"""The learning rate over a run: a linear warm-up, then constant or decaying (cosine or linear) to a final fraction.

Configured as ``optimizer.schedule`` (``{warmup_steps: 50, decay: cosine, final_lr_ratio: 0.05}``); without it the
learning rate is the optimiser's ``lr`` throughout, as runs before it trained. The decay spans the run's
``trainer.max_steps``, so a short run ends on its lowest rate instead of stopping mid-stride; the rate is set per
optimiser step (Lightning's ``interval: step``) and resumes with the run.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import torch

from dgsdp.errors import ConfigError

DECAYS = ("constant", "cosine", "linear")


@dataclass(frozen=True)
class LRSchedule:
    """``warmup_steps`` from ``lr / warmup_steps`` up to ``lr``, then ``decay`` down to ``final_lr_ratio * lr`` at
    the last step (constant: stays at ``lr``)."""

    warmup_steps: int = 0
    decay: str = "constant"
    final_lr_ratio: float = 0.0

    def __post_init__(self) -> None:
        if self.decay not in DECAYS:
            raise ConfigError(f"optimizer.schedule.decay must be one of {', '.join(DECAYS)}, got {self.decay!r}")
        if not isinstance(self.warmup_steps, int) or self.warmup_steps < 0:
            raise ConfigError(f"optimizer.schedule.warmup_steps must be an integer >= 0, got {self.warmup_steps!r}")
        if not 0.0 <= self.final_lr_ratio <= 1.0:
            raise ConfigError(f"optimizer.schedule.final_lr_ratio must be in [0, 1], got {self.final_lr_ratio!r}")

    @classmethod
    def from_config(cls, node: Mapping[str, Any] | None) -> LRSchedule:
        if node is None:
            return cls()
        if not isinstance(node, Mapping):
            raise ConfigError(
                f"optimizer.schedule must be a mapping (warmup_steps, decay, final_lr_ratio), got {node!r}"
            )
        unknown = set(node) - {"warmup_steps", "decay", "final_lr_ratio"}
        if unknown:
            raise ConfigError(
                f"optimizer.schedule: unknown keys {sorted(unknown)} (warmup_steps, decay, final_lr_ratio)"
            )
        return cls(**dict(node))

    @property
    def constant(self) -> bool:
        """Whether the rate never changes (no warm-up, no decay): no scheduler is needed."""
        return self.warmup_steps == 0 and self.decay == "constant"

    def factor(self, step: int, total_steps: int) -> float:
        """The multiple of ``lr`` for optimiser step ``step`` (0-based) of a run of ``total_steps``."""
        if step < self.warmup_steps:
            return (step + 1) / self.warmup_steps
        if self.decay == "constant":
            return 1.0
        span = max(total_steps - 1 - self.warmup_steps, 1)
        progress = min(max(step - self.warmup_steps, 0) / span, 1.0)
        shape = 0.5 * (1.0 + math.cos(math.pi * progress)) if self.decay == "cosine" else 1.0 - progress
        return self.final_lr_ratio + (1.0 - self.final_lr_ratio) * shape

    def scheduler(self, optimizer: torch.optim.Optimizer, total_steps: int | None) -> torch.optim.lr_scheduler.LambdaLR:
        """The schedule as a per-step LambdaLR over ``total_steps`` (the run's ``trainer.max_steps``)."""
        if self.decay != "constant" and (total_steps is None or total_steps <= 0):
            raise ConfigError(
                f"a {self.decay} learning-rate decay spans the run: set trainer.max_steps (got {total_steps})"
            )
        total = int(total_steps or 0)
        return torch.optim.lr_scheduler.LambdaLR(optimizer, lambda step: self.factor(step, total))


__all__ = ["DECAYS", "LRSchedule"]
