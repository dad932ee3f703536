"""Dance metrics: kinetic and geometric features, FID, diversity, beat alignment, PFC and style accuracy.

numpy/scipy only; inputs are joint positions (T, 24, 3) in metres from forward kinematics. The kinetic
and geometric features offer ``mode="paper"`` (the reference arithmetic, bugs included, so numbers compare
with published tables) and ``mode="corrected"``.
"""

from dgsdp.metrics._common import MetricError, MetricWarning, anchor_root, y_up_to_z_up, z_up_to_y_up
from dgsdp.metrics.beats import (
    beat_alignment,
    beat_alignment_from_beats,
    motion_beats,
    music_beats_from_features,
)
from dgsdp.metrics.distribution import diversity, fid, frechet_distance, normalise_features
from dgsdp.metrics.geometric import GEOMETRIC_DIM, geometric_features, geometric_features_batch
from dgsdp.metrics.kinetic import KINETIC_DIM, kinetic_features, kinetic_features_batch
from dgsdp.metrics.pfc import pfc
from dgsdp.metrics.style import GenreClassifier, style_accuracy

__all__ = [
    "GEOMETRIC_DIM",
    "KINETIC_DIM",
    "GenreClassifier",
    "MetricError",
    "MetricWarning",
    "anchor_root",
    "beat_alignment",
    "beat_alignment_from_beats",
    "diversity",
    "fid",
    "frechet_distance",
    "geometric_features",
    "geometric_features_batch",
    "kinetic_features",
    "kinetic_features_batch",
    "motion_beats",
    "music_beats_from_features",
    "normalise_features",
    "pfc",
    "style_accuracy",
    "y_up_to_z_up",
    "z_up_to_y_up",
]
