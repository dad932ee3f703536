"""How to sample: the settings of ``conf/sampling`` shared by generation, evaluation, training callbacks and the
benchmarks (one dataclass, also the config group's schema)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from dgsdp.errors import ConfigError
from dgsdp.motion.representation import ROTATION_PROJECTIONS
from dgsdp.sampling.sampler import METHODS, Guidance

# How the windows of a long dance are kept in agreement (dgsdp.generation.longform).
LONGFORM_MODES = ("fuse", "edge")
# Which 6D rotations of every x0 prediction are made valid rotations (dgsdp.motion.project_rotations).
ROTATION_PROJECTION_CHOICES = ("none", *ROTATION_PROJECTIONS)


@dataclass
class GuidanceSettings:
    """Classifier-free guidance weights; see :class:`~dgsdp.sampling.Guidance`."""

    # The weight on the music: 1 = plain conditional sampling; above 1 the dance follows the music more strongly, at
    # the risk of exaggerated motion where the song is unlike the training music. 2, the papers' weight, chosen on
    # the quick start's model over 34 + 34 real songs (docs/notes/2026-11-25-the-models-own-timing.md; 2.5 before).
    music: float = 2.0
    style: float = 1.0  # only used by models trained with style dropout (diffusion.style_drop_prob > 0)
    longform_ramp_fraction: float = 0.5  # dances longer than one window: weights rise from 0 over this fraction
    edit_cap_below_t: int = 100  # with an editing mask, weights are capped at 1 below this diffusion step (EDGE)
    # 0..1: the guided prediction's movement over time scaled back to the conditional prediction's (per channel;
    # the mean pose kept): guidance then strengthens what the music asks without making every genre move faster
    # (in neither paper; docs/style.md)
    rescale: float = 0.0


@dataclass
class SamplingSettings:
    """Sampler ``method`` and ``steps``, DDIM ``eta``, guidance, long-form windows and batching.

    window_frames: None = the model's training window. stride_frames: consecutive long-form windows start this
    far apart (None: half the window, at most 75 frames, EDGE's 2.5 s: :meth:`stride`). longform: how the windows
    of a long dance agree (``fuse``: shared initial noise and fused x0 predictions at every step; ``edge``:
    EDGE's overwrite of each window's first half by its neighbour after every step but the last; see
    :mod:`dgsdp.generation.longform`). clip_x0: the bound of x0 predictions in normalised units (None: the run's
    ``diffusion.clip_x0``; the papers: 1). project_rotations: ``root`` (the body's
    orientation) or ``all`` joints' 6D rotations of every x0 prediction are made valid rotations (two orthonormal
    columns, :func:`~dgsdp.motion.project_rotations`) before the solver uses them; ``none``: as the network gives
    them (the papers). tempo_fold: the beats a model is given (a beat column, beat phase columns) are moved by
    octaves toward the tempi of its training songs (``tempo_range_bpm``, else the checkpoint's record;
    :func:`~dgsdp.audio.tempo.fold_octaves`); false: as the beat tracker found them (the papers). chunk_size > 0: at most this many windows per
    denoiser call (memory). batch_size: independent dances sampled together. bf16: bf16 autocast (on CUDA, or on a
    CPU with native bf16 instructions, AVX512-BF16 or AMX, where it is faster; docs/sampling.md)."""

    # The defaults of the sampling config group (conf/sampling/dpmpp_2m.yaml names this class as its schema and
    # writes no value of its own): the one place they are written. docs/sampling.md says why these.
    method: str = "dpmpp_2m"
    steps: int = 10
    eta: float = 1.0  # DDIM only: stochasticity (1 = as stochastic as DDPM, 0 = deterministic)
    guidance: GuidanceSettings = field(default_factory=GuidanceSettings)
    window_frames: int | None = None
    stride_frames: int | None = None
    longform: str = "fuse"
    clip_x0: float | None = None
    # Where a model is unsure which way the body turns, its x0 prediction is the mean of the turns: a short 6D
    # vector, which decodes to the body snapping round within a few frames. Projected at every step, the sampler
    # commits to one turn. root, not all: all joints also slow the dances and cost the quick start's model some of
    # its raw timing (docs/sampling.md, "Rotations kept valid while sampling").
    project_rotations: str = "root"
    # fuse only: before each fusion, every window of a dance is turned about the vertical (and shifted over the
    # floor) to face as its neighbour does on their overlap, so the fusion averages windows that face the same way
    # (dgsdp.generation.longform.align_facings; docs/sampling.md, "Windows turned to agree").
    align_facing: bool = True
    # A song far faster (slower) than the model's training songs is given every other beat (a beat between beats):
    # half (double) time, the nearest the model knows. tempo_range_bpm: the training tempi [lo, hi] (null: as the
    # checkpoint recorded them). docs/sampling.md, "Songs faster than the training music".
    tempo_fold: bool = True
    tempo_range_bpm: list[float] | None = None
    chunk_size: int = 0
    batch_size: int = 64
    bf16: bool = False

    def __post_init__(self) -> None:
        if isinstance(self.guidance, Mapping):
            self.guidance = GuidanceSettings(**self.guidance)
        self.method = str(self.method).lower()
        if self.method not in METHODS:
            raise ConfigError(f"sampling.method={self.method!r} is not a sampler; use one of {', '.join(METHODS)}")
        if int(self.steps) < 1:
            raise ConfigError(f"sampling.steps must be at least 1, got {self.steps}")
        if not 0.0 <= float(self.eta) <= 1.0:
            raise ConfigError(f"sampling.eta must lie in [0, 1], got {self.eta}")
        if self.stride_frames is not None and int(self.stride_frames) < 1:
            raise ConfigError(f"sampling.stride_frames must be at least 1 (or null), got {self.stride_frames}")
        if int(self.batch_size) < 1:
            raise ConfigError(f"sampling.batch_size must be at least 1, got {self.batch_size}")
        if self.window_frames is not None and int(self.window_frames) < 1:
            raise ConfigError(f"sampling.window_frames must be at least 1 (or null), got {self.window_frames}")
        if self.longform not in LONGFORM_MODES:
            raise ConfigError(f"sampling.longform={self.longform!r} is not one of {', '.join(LONGFORM_MODES)}")
        if self.project_rotations not in ROTATION_PROJECTION_CHOICES:
            raise ConfigError(
                f"sampling.project_rotations={self.project_rotations!r} is not one of "
                f"{', '.join(ROTATION_PROJECTION_CHOICES)}"
            )
        if self.tempo_range_bpm is not None:
            from dgsdp.audio.tempo import check_tempo_range

            self.tempo_range_bpm = list(
                check_tempo_range(self.tempo_range_bpm, "sampling.tempo_range_bpm", unknown=False)
            )
        if self.clip_x0 is not None and not float(self.clip_x0) > 0:
            raise ConfigError(f"sampling.clip_x0 must be a positive bound or null (the run's own), got {self.clip_x0}")
        if int(self.chunk_size) < 0:
            raise ConfigError(f"sampling.chunk_size must be >= 0, got {self.chunk_size}")
        if not 0.0 <= float(self.guidance.longform_ramp_fraction) <= 1.0:
            raise ConfigError("sampling.guidance.longform_ramp_fraction must lie in [0, 1]")
        if not 0.0 <= float(self.guidance.rescale) <= 1.0:
            raise ConfigError(f"sampling.guidance.rescale must lie in [0, 1], got {self.guidance.rescale}")

    def stride(self, window: int) -> int:
        """How far apart consecutive long-form windows of ``window`` frames start: ``stride_frames`` (at most the
        window), or by default half the window and at most 75 frames (EDGE's 2.5 s), so that windows shorter
        than 150 frames still overlap by half and a 150-frame window's neighbours start 75 frames apart."""
        if self.stride_frames is not None:
            return min(int(self.stride_frames), window)
        return max(1, min(75, window // 2))

    @classmethod
    def from_config(cls, node: Any) -> SamplingSettings:
        """From the ``sampling`` node of a composed config (or a plain mapping); unknown keys are an error."""
        from omegaconf import OmegaConf

        data = OmegaConf.to_container(node, resolve=True) if OmegaConf.is_config(node) else dict(node)
        known = set(cls.__dataclass_fields__)
        unknown = sorted(set(data) - known)
        if unknown:
            raise ConfigError(f"unknown sampling setting(s) {', '.join(unknown)}; known: {', '.join(sorted(known))}")
        guidance = data.pop("guidance", {}) or {}
        unknown = sorted(set(guidance) - set(GuidanceSettings.__dataclass_fields__))
        if unknown:
            raise ConfigError(f"unknown sampling.guidance setting(s) {', '.join(unknown)}")
        return cls(guidance=GuidanceSettings(**guidance), **data)

    def guidance_for(self, long: bool, music: float | None = None) -> Guidance:
        """The sampler's Guidance: ramped when the dance needs more than one window; ``music`` replaces the music
        weight (evaluation rows that compare weights)."""
        g = self.guidance
        return Guidance(
            g.music if music is None else float(music),
            g.style,
            ramp_fraction=g.longform_ramp_fraction if long else 0.0,
            edit_cap_below_t=g.edit_cap_below_t,
            rescale=g.rescale,
        )
