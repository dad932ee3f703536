"""Beat alignment score (BAS): how close kinematic beats (local minima of joint speed) are to music beats.

All beat positions are frame indices at the motion's frame rate. The reference works at 60 FPS with
a 5-frame smoothing sigma and a 3-frame score sigma; at other rates both sigmas are converted through
time (sigma_frames = sigma_60 * fps / 60, i.e. 2.5 and 1.5 frames at 30 FPS) instead of resampling.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import gaussian_filter1d
from scipy.signal import argrelextrema

from dgsdp.metrics._common import MetricWarning, check_choice, check_joints

REFERENCE_FPS = 60.0
MOTION_SIGMA_FRAMES_60FPS = 5.0  # smoothing of the joint-speed curve
SCORE_SIGMA_FRAMES_60FPS = 3.0  # 50 ms tolerance of the score
BEAT_VARIANTS = ("bailando", "fact")
BEAT_COLUMN = 34  # beat one-hot in the 35-d librosa baseline features


def motion_beats(joints: np.ndarray, fps: float = 60, sigma_frames: float | None = None) -> np.ndarray:
    """Frame indices of kinematic beats: strict local minima of the smoothed mean joint speed.

    joints: (T, 24, 3) metres, T >= 2. Speed v[t] = mean over joints of |p[t+1] - p[t]| (T-1 values),
    smoothed with a Gaussian of ``sigma_frames`` (default 5 frames at 60 FPS scaled by fps / 60;
    scipy's default reflect boundary and 4-sigma truncation, as the reference). Returns (M,) int64.
    """
    return argrelextrema(kinematic_speed(joints, fps, sigma_frames), np.less)[0].astype(np.int64)


def kinematic_speed(joints: np.ndarray, fps: float = 60, sigma_frames: float | None = None) -> np.ndarray:
    """The smoothed mean joint speed whose strict local minima are the kinematic beats (:func:`motion_beats`):
    joints (T, 24, 3) metres, T >= 2 -> (T-1,) metres per frame, entry t between frames t and t + 1."""
    positions = check_joints(joints, min_frames=2)
    if sigma_frames is None:
        sigma_frames = MOTION_SIGMA_FRAMES_60FPS * fps / REFERENCE_FPS
    speed = np.linalg.norm(positions[1:] - positions[:-1], axis=-1).mean(axis=-1)
    return gaussian_filter1d(speed, sigma_frames)


def beat_alignment_from_beats(
    motion_beat_frames: np.ndarray,
    music_beat_frames: np.ndarray,
    fps: float = 60,
    variant: str = "bailando",
    sigma_frames: float | None = None,
) -> float:
    """Beat alignment score from beat frame indices at ``fps``.

    ``"bailando"`` (default): mean over music beats b of exp(-min_m (m - b)^2 / (2 sigma^2));
    ``"fact"``: the same averaged over motion beats m with the nearest music beat. sigma is 3 frames
    at 60 FPS, scaled by fps / 60, unless ``sigma_frames`` gives it in frames. Nothing to average over (no beats of the averaged kind) or nothing
    to match against gives 0.0 with a MetricWarning.
    """
    check_choice(variant, BEAT_VARIANTS, "variant")
    motion = np.asarray(motion_beat_frames, dtype=np.float64).reshape(-1)
    music = np.asarray(music_beat_frames, dtype=np.float64).reshape(-1)
    sigma = SCORE_SIGMA_FRAMES_60FPS * fps / REFERENCE_FPS if sigma_frames is None else float(sigma_frames)
    queries, targets = (music, motion) if variant == "bailando" else (motion, music)
    if queries.size == 0 or targets.size == 0:
        warnings.warn(
            f"beat alignment with {motion.size} motion beat(s) and {music.size} music beat(s): "
            "nothing to align, score set to 0.0.",
            MetricWarning,
            stacklevel=2,
        )
        return 0.0
    nearest_sq = np.min((queries[:, None] - targets[None, :]) ** 2, axis=1)
    return float(np.mean(np.exp(-nearest_sq / (2.0 * sigma**2))))


def beat_alignment(joints: np.ndarray, music_beats: np.ndarray, fps: float = 60, variant: str = "bailando") -> float:
    """Beat alignment score of one dance.

    joints: (T, 24, 3) metres; music_beats: (K,) frame indices at the same ``fps``. As in the reference,
    music beats at or after frame T-1 (beyond the speed curve) are ignored. See
    :func:`beat_alignment_from_beats` for the formula and the variants.
    """
    positions = check_joints(joints, min_frames=2)
    music = np.asarray(music_beats).reshape(-1)
    music = music[(music >= 0) & (music < positions.shape[0] - 1)]
    return beat_alignment_from_beats(motion_beats(positions, fps=fps), music, fps=fps, variant=variant)


def music_beats_from_features(features35: np.ndarray) -> np.ndarray:
    """Frame indices whose beat flag (column 34 of the 35-d librosa features (T, 35), or (T, 37) with the two
    beat-phase columns after them: ``audio.beat_phase``) is non-zero."""
    arr = np.asarray(features35)
    if arr.ndim != 2 or arr.shape[1] not in (BEAT_COLUMN + 1, BEAT_COLUMN + 3):
        raise ValueError(
            f"features35 must have shape (T, {BEAT_COLUMN + 1}) or (T, {BEAT_COLUMN + 3}); got {arr.shape}."
        )
    return np.nonzero(arr[:, BEAT_COLUMN])[0].astype(np.int64)


# The two BAS variants of the shifted-copy test (:func:`beat_scores`), as (motion-speed smoothing sigma, score sigma)
# in frames at 30 FPS.
BAS_VARIANTS = {
    "bas": (2.5, 1.5),  # the project's: the reference's 60 FPS sigmas (5, 3 frames) converted through time: 50 ms
    "bas_edge": (5.0, 3.0),  # Bailando's code as EDGE ran it on 30 FPS joints: the same numbers taken as frames
}


@dataclass
class BeatScores:
    """BAS of a dance and of the same motion shifted later by ``shift_frames`` (half the median beat interval)."""

    bas: float
    shifted: float
    shift_frames: int
    n_music_beats: int

    @property
    def above_shifted(self) -> bool:
        return bool(self.bas > self.shifted)


def beat_scores(joints: np.ndarray, music_beats: Sequence[int], fps: float = 30, variant: str = "bas") -> BeatScores:
    """Beat alignment score (Bailando's formula, the sigmas of ``variant`` in :data:`BAS_VARIANTS`) of a dance and of the same motion shifted later in time by half the median interval of
    the music beats (frame indices at ``fps``).

    Shifting the motion by h frames shifts its kinematic beats by h (those that leave the dance are dropped);
    music beats at or after the last speed sample are ignored, as in :func:`beat_alignment`.
    With fewer than two music beats there is no beat interval: both scores are NaN."""
    motion_sigma, score_sigma = BAS_VARIANTS[variant]
    positions = check_joints(joints, min_frames=2)
    n_frames = positions.shape[0]
    music = np.asarray(music_beats, dtype=np.int64).reshape(-1)
    music = music[(music >= 0) & (music < n_frames - 1)]
    if music.size < 2:
        return BeatScores(math.nan, math.nan, 0, int(music.size))
    shift = int(round(float(np.median(np.diff(np.sort(music)))) / 2.0))
    beats = motion_beats(positions, fps=fps, sigma_frames=motion_sigma)
    shifted = beats + shift
    shifted = shifted[shifted < n_frames - 1]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", MetricWarning)  # no motion beat at all: both scores are 0
        bas = beat_alignment_from_beats(beats, music, fps=fps, sigma_frames=score_sigma)
        bas_shifted = beat_alignment_from_beats(shifted, music, fps=fps, sigma_frames=score_sigma)
    return BeatScores(bas, bas_shifted, shift, int(music.size))
