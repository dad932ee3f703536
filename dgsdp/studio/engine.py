"""The studio's one link to the generation pipeline: requests from the page in, dance files out.

Everything the studio does with a model goes through :class:`dgsdp.generation.DanceGenerator` and
:func:`dgsdp.generation.write_motion` here (the same path as ``python generate.py``); the page code only builds
:class:`DanceRequest` objects and shows :class:`Dance` results.

Edits of the current dance map to the editing tasks of :mod:`dgsdp.editing.masks`:

- ``upper_body`` / ``lower_body``: regenerate that half, keep the other half of the current dance;
- ``keyframes``: keep the current dance's poses at the given seconds, regenerate everything else;
- ``continue``: ``seed_motion`` with the last ``seed_seconds`` of the current dance as the new dance's start;
- ``range``: regenerate the frames between two times and keep every frame outside them (an in-between over
  frames: the ``keyframes`` task with every frame outside the range given).
"""

from __future__ import annotations

import math
import threading
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

import dgsdp.export
from dgsdp.audio.io import audio_duration_seconds
from dgsdp.audio.tempo import TempoFold
from dgsdp.errors import AudioError, ConfigError
from dgsdp.generation import DanceGenerator, EditSettings, Finishing, write_motion
from dgsdp.motion import SMPL24, Skeleton, pose_to_joints
from dgsdp.sampling import GuidanceSettings, SamplingSettings

EDITS = ("none", "upper_body", "lower_body", "keyframes", "continue", "range")


def glb_available() -> bool:
    """Whether this install can write GLB files (``write_motion(..., formats=[..., "glb"])``)."""
    return "glb" in dgsdp.export.MOTION_FORMATS


def output_formats(video: bool = True) -> list[str]:
    """The files written for every dance: AIST++ pkl, BVH, GLB when available, video (optional) and npy."""
    formats = ["pkl", "bvh"]
    if glb_available():
        formats.append("glb")
    if video:
        formats.append("video")
    return formats + ["npy"]


@dataclass
class Edit:
    """An edit of an existing dance (``motion`` (T, D), unnormalised): one of :data:`EDITS`."""

    kind: str
    motion: torch.Tensor
    keyframe_seconds: Sequence[float] = ()
    seed_seconds: float = 1.0
    start_seconds: float = 0.0
    end_seconds: float = 0.0


@dataclass
class DanceRequest:
    """One generation: a song, a style (genre, free text or schedule string), sampling settings, an edit."""

    checkpoint: str
    song: Path
    style: str | None
    music_weight: float = GuidanceSettings.music
    style_weight: float = GuidanceSettings.style
    sampler: str = SamplingSettings.method
    steps: int = SamplingSettings.steps
    seed: int = 0
    blend_seconds: float = 2.0
    edit: Edit | None = None
    video: bool = True
    cleanup: bool = True  # beat sync and feet on the floor (DanceGenerator.finish); False: the model's raw output


@dataclass
class Dance:
    """A generated dance: the motion (T, D), its joints (T, J, 3) z-up metres on the run's ``skeleton``, and the
    files written."""

    motion: torch.Tensor
    joints: np.ndarray
    fps: int
    song: Path
    style: str | None
    files: list[Path] = field(default_factory=list)
    tempo: TempoFold = field(default_factory=TempoFold)  # how the song's beats were given to the model
    skeleton: Skeleton = SMPL24
    notes: list[str] = field(default_factory=list)  # what the user should know (:meth:`dgsdp.generation.Dance.notes`)


class Engine:
    """Loads checkpoints once (one model in memory per path) and runs requests one at a time."""

    def __init__(
        self,
        cache_dir: str | Path,
        device: str = "auto",
        max_song_seconds: float | None = 600,
        finishing: Finishing | None = None,
    ) -> None:
        self.cache_dir = Path(cache_dir)
        self.finishing = finishing or Finishing()  # the limits of the finishing (beat sync, floor cleanup)
        self.device = device
        self.max_song_seconds = max_song_seconds
        self._generators: dict[str, DanceGenerator] = {}
        self._lock = threading.Lock()

    def generator(self, checkpoint: str) -> DanceGenerator:
        """The DanceGenerator of a checkpoint (loaded on first use; ConfigError for a bad checkpoint)."""
        if not checkpoint or not str(checkpoint).strip():
            raise ConfigError("choose a checkpoint: a run under the outputs folder or the path of a .ckpt file")
        key = str(Path(str(checkpoint).strip()).expanduser().resolve())
        with self._lock:
            if key not in self._generators:
                self._generators.clear()  # keep one model in memory
                self._generators[key] = DanceGenerator.from_checkpoint(
                    key, cache_dir=self.cache_dir, device=self.device, max_song_seconds=self.max_song_seconds
                )
            return self._generators[key]

    def genres(self, checkpoint: str) -> list[str]:
        """Genre names the checkpoint knows (empty for a model without style)."""
        gen = self.generator(checkpoint)
        if not gen.style_dim:
            return []
        return list(gen.embedder().vocab.names)

    def song_seconds(self, song: Path) -> float:
        """The song's length (AudioError for an unreadable song, or one longer than the studio's --max-seconds)."""
        seconds = audio_duration_seconds(song)
        if self.max_song_seconds is not None and seconds > self.max_song_seconds:
            raise AudioError(
                f"{song.name} is {seconds:.0f} s long; this studio takes songs up to {self.max_song_seconds:g} s "
                "(its --max-seconds setting): cut the song shorter"
            )
        return seconds

    def run(self, request: DanceRequest, out_base: Path, progress: bool = False) -> Dance:
        """Generate (or edit) one dance and write its files as ``out_base`` + suffixes."""
        gen = self.generator(request.checkpoint)
        sampling = SamplingSettings(  # checks the sampler name and steps (ConfigError)
            method=request.sampler,
            steps=int(request.steps),
            guidance=GuidanceSettings(music=float(request.music_weight), style=float(request.style_weight)),
        )
        plan = gen.resolve_style(request.style)
        _, n_frames = gen.music_features(request.song)  # the edit's frames depend on the song's length
        edit = edit_settings(request.edit, n_frames, gen.fps)
        danced = gen.dance_to_song(
            request.song, plan, edit=edit, blend_seconds=float(request.blend_seconds), sampling=sampling,
            seed=int(request.seed), progress=progress,
            cleanup=bool(request.cleanup) and self.finishing.floor(), beat_sync=self.finishing.beat_sync(),
        )  # fmt: skip
        motion = danced.motion[0]
        title = f"{request.song.stem} | {plan.text}" if plan.text else request.song.stem
        files = write_motion(
            motion,
            out_base,
            fps=gen.fps,
            audio_path=request.song,
            formats=output_formats(request.video),
            title=title,
            floor_height=gen.floor_height,
            skeleton=gen.skeleton,
        )
        joints = pose_to_joints(motion.double(), gen.skeleton).float().numpy()
        return Dance(
            motion, joints, gen.fps, request.song, plan.text, files, tempo=danced.tempo, skeleton=gen.skeleton,
            notes=danced.notes(),
        )  # fmt: skip


def edit_settings(edit: Edit | None, n_frames: int, fps: int) -> EditSettings:
    """The editing task for an edit of the current dance on a song of ``n_frames`` frames."""
    if edit is None or edit.kind == "none":
        return EditSettings()
    if edit.kind not in EDITS:
        raise ConfigError(f"unknown edit {edit.kind!r}; use one of: {', '.join(EDITS)}")
    motion = torch.as_tensor(edit.motion, dtype=torch.float32)
    if edit.kind == "continue":
        seed = int(round(float(edit.seed_seconds) * fps))
        if not 1 <= seed <= len(motion):
            raise ConfigError(
                f"continue from the last {edit.seed_seconds:g} s: give between {1 / fps:.2f} s and the current "
                f"dance's length ({len(motion) / fps:.1f} s)"
            )
        return EditSettings(task="seed_motion", motion=motion[-seed:], seed_frames=min(seed, n_frames))
    if len(motion) < n_frames:
        raise ConfigError(
            f"the current dance has {len(motion)} frames but the song has {n_frames}: edits keep the current "
            "dance's song; generate a new dance for another song"
        )
    if edit.kind in ("upper_body", "lower_body"):
        return EditSettings(task=edit.kind, motion=motion)
    if edit.kind == "keyframes":
        seconds = [float(s) for s in edit.keyframe_seconds]
        if not seconds:
            raise ConfigError("give keyframe times in seconds, e.g. 1.5, 4, 8")
        return EditSettings(task="keyframes", motion=motion, keyframe_seconds=seconds)
    # range: regenerate [start, end), keep every other frame
    start, end = float(edit.start_seconds), float(edit.end_seconds)
    first, last = int(round(start * fps)), int(round(end * fps))
    if not (0 <= first < last <= n_frames):
        raise ConfigError(
            f"the range {start:g}-{end:g} s must lie inside the song (0-{n_frames / fps:.1f} s) with start < end"
        )
    kept = [f for f in range(n_frames) if f < first or f >= last]
    if not kept:
        raise ConfigError("the range covers the whole dance: press Generate for a new dance instead")
    return EditSettings(task="keyframes", motion=motion, keyframes=kept)


def parse_seconds(text: str) -> list[float]:
    """Times in seconds from text such as ``"1.5, 4 8"``; ConfigError naming the first bad entry."""
    values: list[float] = []
    for item in str(text or "").replace(";", ",").replace(",", " ").split():
        try:
            value = float(item)
        except ValueError:
            value = math.nan
        if not math.isfinite(value):
            raise ConfigError(f"{item!r} is not a time in seconds; write keyframe times like 1.5, 4, 8")
        values.append(value)
    return values
