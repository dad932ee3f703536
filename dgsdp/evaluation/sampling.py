"""Dances for a protocol's clips, made through the project's one sampling path (:class:`DanceGenerator`)."""

from __future__ import annotations

import dataclasses

import numpy as np
import torch

from dgsdp.editing.masks import build_mask
from dgsdp.evaluation.clips import Clip, clip_seed
from dgsdp.evaluation.features import MODEL_FPS, motion_to_joints
from dgsdp.evaluation.protocols import ProtocolSpec, Variant
from dgsdp.generation import DanceGenerator, DanceRequest
from dgsdp.sampling import SamplingSettings


def clip_requests(
    generator: DanceGenerator,
    clips: list[Clip],
    variant: Variant,
    spec: ProtocolSpec,
    *,
    seed: int,
    trial: int,
    sampling: SamplingSettings | None = None,
) -> list[DanceRequest]:
    """One request per clip: its music, its genre's style (the style bank's mean, as ``style=<genre>`` in
    generate.py), the variant's editing mask with the real dance as the given motion, and the clip's seed.
    A model whose encoder computes each window's features from its own audio (EDGE's) gets them so, for the
    long-form windows of ``sampling`` over the clip."""
    model = generator.model
    per_window = generator.audio_encoder is not None and generator.audio_encoder.per_window
    requests = []
    for clip in clips:
        s = clip_seed(seed, trial, clip.index)
        genre = torch.tensor([clip.seq.genre_index], device=generator.device)
        style = model.style_for(genre, random=False)
        if per_window and clip.music_file is not None:
            music = generator.music_windows(
                clip.music_file, clip.start, clip.n_frames, sampling, music_id=clip.seq.music_id
            ).float()
        else:
            music = clip.music()
            music = (
                None if music is None else torch.from_numpy(np.array(music, dtype=np.float32))
            )  # a copy: may be read-only
        mask = known = None
        if variant.task != "none":
            mask = build_mask(
                variant.task, clip.n_frames, seed_frames=spec.seed_frames, end_frames=spec.end_frames,
                inpaint_fraction=spec.inpaint_fraction, fps=MODEL_FPS, generator=torch.Generator().manual_seed(s),
                skeleton=generator.skeleton,
            )  # fmt: skip
            known = torch.from_numpy(np.ascontiguousarray(clip.motion)).float()
        requests.append(
            DanceRequest(
                clip.n_frames,
                music=music,
                style=None if style is None else style[0].cpu(),
                mask=mask,
                known=known,
                seed=s,
            )
        )
    return requests


def sample_clips(
    generator: DanceGenerator,
    clips: list[Clip],
    variant: Variant,
    spec: ProtocolSpec,
    sampling: SamplingSettings,
    *,
    seed: int,
    trial: int,
    cleanup: bool = False,
) -> list[np.ndarray]:
    """Generated dances for ``clips`` as 30 FPS z-up joints (T, 24, 3) in SMPL's layout (the metrics' input, see
    :func:`~dgsdp.evaluation.features.motion_to_joints`), with the variant's guidance weight.
    The model's raw output is scored unless ``cleanup`` finishes the dances as generate.py does
    (:meth:`DanceGenerator.finish`: retimed onto the clip's beats where nothing is given, feet on the floor)."""
    settings = dataclasses.replace(sampling, guidance=dataclasses.replace(sampling.guidance, music=variant.weight))
    requests = clip_requests(generator, clips, variant, spec, seed=seed, trial=trial, sampling=settings)
    motions = generator.generate_many(requests, settings)
    if cleanup:
        motions = [generator.finish(m, c.beats_30fps, mask=r.mask) for m, c, r in zip(motions, clips, requests)]
    return [motion_to_joints(m[0].numpy(), generator.skeleton) for m in motions]
