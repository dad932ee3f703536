"""A dance made to a song (:class:`Dance`: motions, joints, SMPL parameters) and the files it is written as
(:func:`write_motion`: AIST++ pickle, BVH, GLB, video with the music, the raw pose vectors)."""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from dgsdp.audio.tempo import TempoFold
from dgsdp.metrics.beats import BAS_VARIANTS
from dgsdp.motion import SMPL24, Skeleton, check_pose_dim, pose_to_joints, unpack_pose
from dgsdp.motion.rotation import matrix_to_axis_angle
from dgsdp.style.reading import TextReading
from dgsdp.utils.io import atomic_path


@dataclass
class Dance:
    """The dances made to one song: ``motion`` (num_samples, T, D), unnormalised, z-up, at ``fps``, on the run's floor
    at ``floor_height`` (z-up metres), pose vectors of the run's ``skeleton`` (D = its pose size, SMPL-24: 151).
    ``joints`` and :meth:`smpl` give them as joint positions and SMPL(-X) parameters; :meth:`save` writes the files
    generate.py writes. ``raw``: the model's own output before the finishing (beat sync and floor cleanup; the same as
    ``motion`` without them), and ``finishing``: one dict per sample of what each finishing step changed
    (:meth:`DanceGenerator.finish`). ``tempo``: the song's tempo and how its beats were given to the model
    (:class:`~dgsdp.audio.tempo.TempoFold`, ``sampling.tempo_fold``)."""

    motion: torch.Tensor
    fps: int
    floor_height: float = 0.0
    song: Path | None = None
    style: str | None = None
    raw: torch.Tensor | None = None
    finishing: list[dict[str, float]] = field(default_factory=list)
    tempo: TempoFold = field(default_factory=TempoFold)
    skeleton: Skeleton = SMPL24
    readings: list[TextReading] = field(default_factory=list)  # how the style (each span's) was read

    def notes(self) -> list[str]:
        """What a user should know about how these dances were made, one line each: how the style was read (the
        genre, or how free text was read and at what speed: :class:`~dgsdp.style.reading.TextReading`), a song
        danced in half or double time (``sampling.tempo_fold``), whether beat sync kept its retime or the model's own
        timing (the retime is kept only where the finished dance is no worse on either tracker's beats:
        docs/beatsync.md), and dances that the floor cleanup left below the model's raw timing on a judged beat
        score (the margin of BAS over the half-beat-shifted copy's) whichever timing was kept, and by how much."""
        notes = list(dict.fromkeys(reading.describe() for reading in self.readings))  # each span's style once
        if self.tempo.octaves:
            notes.append(f"the song: {self.tempo.describe()} (sampling.tempo_fold)")
        judged = [f for f in self.finishing if f.get("judged_beat_sets")]
        kept = sum(bool(f.get("retimed")) for f in judged)
        if judged and kept == len(judged):
            notes.append("beat sync: retimed onto the song's beats")
        elif judged:
            which = "" if len(judged) == 1 else f" in {len(judged) - kept} of {len(judged)} dances"
            notes.append(
                f"beat sync: the model's own timing kept{which} (retimed onto the beats, the finished dance's timing "
                "was worse by one of the trackers' beats)"
            )
        below = [f for f in judged if f.get("below_raw_margins")]
        by = max((f.get("below_raw_by", 0.0) for f in below), default=0.0)
        if len(judged) == 1 and below:
            scores = int(below[0]["judged_beat_sets"]) * len(BAS_VARIANTS)
            notes.append(
                "beat sync: the floor cleanup moved the pauses: the dance's timing is below the model's raw output on "
                f"{below[0]['below_raw_margins']:g} of {scores} judged beat scores, by up to {by:.3f} (beat sync had "
                "no timing that avoided it)"
            )
        elif below:
            notes.append(
                f"beat sync: the floor cleanup moved the pauses: {len(below)} of {len(judged)} dances' timing is below "
                f"the model's raw output on a judged beat score, by up to {by:.3f} (beat sync had no timing that "
                "avoided it)"
            )
        return notes

    @property
    def joints(self) -> np.ndarray:
        """Joint positions (num_samples, T, J, 3), z-up metres (forward kinematics of the run's skeleton)."""
        return pose_to_joints(self.motion.double(), self.skeleton).float().numpy()

    def smpl(self, sample: int = 0) -> dict[str, np.ndarray]:
        """SMPL(-X) parameters of one sample: ``poses`` (T, 3 J) axis-angle per joint in the skeleton's order (SMPL:
        (T, 72)), ``trans`` (T, 3) root translation in metres (both z-up, as the model's vectors)."""
        parts = unpack_pose(self.motion[sample].double(), self.skeleton)
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
                floor_height=self.floor_height, skeleton=self.skeleton,
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
    skeleton: Skeleton = SMPL24,
) -> list[Path]:
    """Write one motion (T, D) of ``skeleton``, unnormalised, as ``base`` + .pkl (AIST++), .bvh, .glb, .mp4/.gif and
    .npy.

    ``floor_height``: the run's floor (z-up metres, :attr:`DanceGenerator.floor_height`). The data files (.npy, .pkl)
    keep the model's coordinates (the pickle records the floor height); the files for viewing show the true floor:
    BVH and GLB are shifted so that it lies at height 0, the video draws its grid at it."""
    from dgsdp.export import check_formats, render_video, save_aistpp_pkl, save_bvh, save_glb

    check_pose_dim(motion, skeleton, "write_motion's motion")
    if motion.ndim != 2:
        raise ValueError(f"write_motion needs one motion (T, {skeleton.pose_dim}), got {tuple(motion.shape)}")
    formats = check_formats(formats)
    base.parent.mkdir(parents=True, exist_ok=True)
    parts = unpack_pose(motion.double(), skeleton)
    written: list[Path] = []
    if "npy" in formats:
        path = base.with_suffix(".npy")
        with atomic_path(path) as tmp, open(tmp, "wb") as f:
            np.save(f, motion.numpy().astype(np.float32))
        written.append(path)
    if "pkl" in formats:
        path = base.with_suffix(".pkl")
        written.append(save_aistpp_pkl(path, parts.rotmats, parts.root_trans, fps, floor_height, skeleton))
    if "bvh" in formats:
        path = base.with_suffix(".bvh")
        written.append(
            save_bvh(path, parts.rotmats, parts.root_trans, fps, floor_height=floor_height, skeleton=skeleton)
        )
    if "glb" in formats:
        path = base.with_suffix(".glb")
        written.append(
            save_glb(path, parts.rotmats, parts.root_trans, fps, floor_height=floor_height, skeleton=skeleton)
        )
    if "video" in formats:
        joints = pose_to_joints(motion.double(), skeleton).float()
        written.append(
            render_video(
                base.with_suffix(".mp4"), joints, fps, audio_path, title=title, floor_z=floor_height, skeleton=skeleton
            )
        )
    return written
