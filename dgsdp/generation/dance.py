"""A dance made to a song (:class:`Dance`: motions, joints, SMPL parameters) and the files it is written as
(:func:`write_motion`: AIST++ pickle, BVH, GLB, video with the music, the raw 151-d array)."""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from dgsdp.audio.tempo import TempoFold
from dgsdp.motion import POSE_DIM, pose_to_joints, unpack_pose
from dgsdp.motion.rotation import matrix_to_axis_angle
from dgsdp.utils.io import atomic_path


@dataclass
class Dance:
    """The dances made to one song: ``motion`` (num_samples, T, 151), unnormalised, z-up, at ``fps``, on the run's
    floor at ``floor_height`` (z-up metres). ``joints`` and :meth:`smpl` give them as joint positions and SMPL
    parameters; :meth:`save` writes the files generate.py writes. ``raw``: the model's own output before the
    finishing (beat sync and floor cleanup; the same as ``motion`` without them), and ``finishing``: one dict per
    sample of what each finishing step changed (:meth:`DanceGenerator.finish`). ``tempo``: the song's tempo and how its
    beats were given to the model (:class:`~dgsdp.audio.tempo.TempoFold`, ``sampling.tempo_fold``)."""

    motion: torch.Tensor
    fps: int
    floor_height: float = 0.0
    song: Path | None = None
    style: str | None = None
    raw: torch.Tensor | None = None
    finishing: list[dict[str, float]] = field(default_factory=list)
    tempo: TempoFold = field(default_factory=TempoFold)

    @property
    def joints(self) -> np.ndarray:
        """Joint positions (num_samples, T, 24, 3), z-up metres (forward kinematics of the SMPL skeleton)."""
        return pose_to_joints(self.motion.double()).float().numpy()

    def smpl(self, sample: int = 0) -> dict[str, np.ndarray]:
        """SMPL parameters of one sample: ``poses`` (T, 72) axis-angle per joint in SMPL order, ``trans`` (T, 3)
        root translation in metres (both z-up, as the model's vectors)."""
        parts = unpack_pose(self.motion[sample].double())
        poses = matrix_to_axis_angle(parts.rotmats).reshape(len(self.motion[sample]), -1)
        return {"poses": poses.float().numpy(), "trans": parts.root_trans.float().numpy()}

    def save(
        self, path: str | os.PathLike, formats: Sequence[str] = ("npy", "pkl", "bvh"), sample: int | None = None
    ) -> list[Path]:
        """Write the dances as ``path`` + .npy / .pkl / .bvh / .glb / .mp4 (see :func:`write_motion`); with several
        samples (and ``sample`` None) each gets ``_sample<k>`` appended to its name."""
        base = Path(path)
        samples = range(len(self.motion)) if sample is None else [sample]
        written: list[Path] = []
        for k in samples:
            name = base if len(samples) == 1 else base.with_name(f"{base.name}_sample{k}")
            written += write_motion(
                self.motion[k], name, fps=self.fps, audio_path=self.song, formats=formats, title=self.style,
                floor_height=self.floor_height,
            )  # fmt: skip
        return written


def write_motion(
    motion: torch.Tensor,
    base: Path,
    *,
    fps: float,
    audio_path: Path | None = None,
    formats: Sequence[str] = ("pkl", "bvh", "video", "npy"),
    title: str | None = None,
    floor_height: float = 0.0,
) -> list[Path]:
    """Write one motion (T, 151), unnormalised, as ``base`` + .pkl (AIST++), .bvh, .glb, .mp4/.gif and .npy.

    ``floor_height``: the run's floor (z-up metres, :attr:`DanceGenerator.floor_height`). The data files (.npy, .pkl)
    keep the model's coordinates (the pickle records the floor height); the files for viewing show the true floor:
    BVH and GLB are shifted so that it lies at height 0, the video draws its grid at it."""
    from dgsdp.export import check_formats, render_video, save_aistpp_pkl, save_bvh, save_glb

    if motion.ndim != 2 or motion.shape[-1] != POSE_DIM:
        raise ValueError(f"write_motion needs one motion (T, {POSE_DIM}), got {tuple(motion.shape)}")
    formats = check_formats(formats)
    base.parent.mkdir(parents=True, exist_ok=True)
    parts = unpack_pose(motion.double())
    written: list[Path] = []
    if "npy" in formats:
        path = base.with_suffix(".npy")
        with atomic_path(path) as tmp, open(tmp, "wb") as f:
            np.save(f, motion.numpy().astype(np.float32))
        written.append(path)
    if "pkl" in formats:
        written.append(save_aistpp_pkl(base.with_suffix(".pkl"), parts.rotmats, parts.root_trans, fps, floor_height))
    if "bvh" in formats:
        written.append(
            save_bvh(base.with_suffix(".bvh"), parts.rotmats, parts.root_trans, fps, floor_height=floor_height)
        )
    if "glb" in formats:
        written.append(
            save_glb(base.with_suffix(".glb"), parts.rotmats, parts.root_trans, fps, floor_height=floor_height)
        )
    if "video" in formats:
        joints = pose_to_joints(motion.double()).float()
        written.append(
            render_video(base.with_suffix(".mp4"), joints, fps, audio_path, title=title, floor_z=floor_height)
        )
    return written
