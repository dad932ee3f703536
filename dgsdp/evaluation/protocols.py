"""Evaluation protocols as plain settings: which music is danced to, how long, with which guidance and masks.

A protocol yields *rows*: one per (length, guidance weight, editing task) combination, plus one ground-truth row
per length (the real clips through the same feature code). Each is configured in ``conf/protocol/<name>.yaml``.
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from dgsdp.editing.masks import check_task
from dgsdp.errors import ConfigError

METRICS: tuple[str, ...] = ("BeatAlign", "PFC", "FID_k", "FID_g", "Div_k", "Div_g", "StyleAcc")
REFERENCES = ("clips", "dataset")
FEATURE_JOINTS = (24, 22)  # SMPL's 24 joints, or the 22 body joints (LODGE: kinetic features of joints 0-21)
ROW_PARTS = ("length", "guidance", "task")
GROUND_TRUTH = "ground_truth"


@dataclass(frozen=True)
class Variant:
    """One generated row: dances of ``seconds`` with music guidance ``weight`` and editing ``task``."""

    seconds: float
    weight: float
    task: str
    name: str


@dataclass
class ProtocolSpec:
    """Settings of one protocol (see ``conf/protocol/*.yaml`` for the meaning of every field)."""

    name: str
    splits: list[str] = field(default_factory=lambda: ["test"])
    lengths_seconds: list[float] = field(default_factory=lambda: [5.0])
    stride_seconds: float | None = 2.5
    guidance_weights: list[float] = field(default_factory=lambda: [2.0])
    tasks: list[str] = field(default_factory=lambda: ["none"])
    row_by: list[str] = field(default_factory=list)
    trials: int = 1
    clips_per_trial: int | None = None
    max_dances: int | None = None
    reference: str = "clips"
    anchor_root: bool = True
    root_relative: bool = False
    feature_joints: int = 24
    feature_upsample: bool = True
    reference_seconds: float | None = None
    classifier_seconds: float = 5.0
    seed_frames: int = 30
    end_frames: int = 30
    inpaint_fraction: float = 0.7

    @classmethod
    def from_config(cls, cfg: Mapping[str, Any]) -> ProtocolSpec:
        """Build and check a spec from the ``protocol`` config node (a plain mapping)."""
        known = set(cls.__dataclass_fields__)
        unknown = sorted(set(cfg) - known)
        if unknown:
            raise ConfigError(f"unknown protocol setting(s) {unknown}; known: {sorted(known)}")
        values = dict(cfg)
        for key in ("splits", "lengths_seconds", "guidance_weights", "tasks", "row_by"):
            if key in values and not isinstance(values[key], list | tuple):
                values[key] = [values[key]]
            if key in values:
                values[key] = list(values[key])
        spec = cls(**values)
        spec.check()
        return spec

    def check(self) -> None:
        if not self.name:
            raise ConfigError("protocol.name must be set")
        if not self.splits or not self.lengths_seconds or not self.guidance_weights or not self.tasks:
            raise ConfigError("protocol.splits, lengths_seconds, guidance_weights and tasks need at least one entry")
        if any(s <= 0 for s in self.lengths_seconds) or self.classifier_seconds <= 0:
            raise ConfigError(f"protocol lengths must be positive seconds; got {self.lengths_seconds}")
        if self.stride_seconds is not None and self.stride_seconds <= 0:
            raise ConfigError(f"protocol.stride_seconds must be positive or null; got {self.stride_seconds}")
        if self.trials < 1:
            raise ConfigError(f"protocol.trials must be at least 1; got {self.trials}")
        if self.clips_per_trial is not None and self.clips_per_trial < 2:
            raise ConfigError(f"protocol.clips_per_trial must be >= 2 (FID and diversity); got {self.clips_per_trial}")
        if self.feature_joints not in FEATURE_JOINTS:
            raise ConfigError(
                f"protocol.feature_joints must be one of {list(FEATURE_JOINTS)}; got {self.feature_joints}"
            )
        if self.reference_seconds is not None and self.reference_seconds <= 0:
            raise ConfigError(f"protocol.reference_seconds must be positive or null; got {self.reference_seconds}")
        if self.reference not in REFERENCES:
            raise ConfigError(f"protocol.reference must be one of {list(REFERENCES)}; got {self.reference!r}")
        bad = [p for p in self.row_by if p not in ROW_PARTS]
        if bad:
            raise ConfigError(f"protocol.row_by entries must be among {list(ROW_PARTS)}; got {bad}")
        self.tasks = [check_task(t) for t in self.tasks]

    def variants(self) -> list[Variant]:
        """Every generated row, named by the parts that vary or that ``row_by`` names (e.g. ``w=2``, ``7.5s``)."""
        out = []
        for seconds, weight, task in itertools.product(self.lengths_seconds, self.guidance_weights, self.tasks):
            parts = []
            if "length" in self.row_by or len(self.lengths_seconds) > 1:
                parts.append(length_label(seconds))
            if "guidance" in self.row_by or len(self.guidance_weights) > 1:
                parts.append(f"w={weight:g}")
            if "task" in self.row_by or len(self.tasks) > 1:
                parts.append(task)
            out.append(Variant(float(seconds), float(weight), task, ", ".join(parts) or "generated"))
        return out

    def ground_truth_name(self, seconds: float) -> str:
        """Name of the ground-truth row of dances of ``seconds``."""
        if "length" in self.row_by or len(self.lengths_seconds) > 1:
            return f"{GROUND_TRUTH}, {length_label(seconds)}"
        return GROUND_TRUTH


def length_label(seconds: float) -> str:
    """``7.5`` -> ``7.5s``."""
    return f"{seconds:g}s"
