"""Evaluation protocols of the papers' tables: clips, their dances through the one sampling path, every metric,
results files."""

from dgsdp.evaluation.clips import Clip, ClipSource, clip_seed
from dgsdp.evaluation.features import dance_features, feature_joints, motion_to_joints, upsample_joints
from dgsdp.evaluation.protocols import GROUND_TRUTH, METRICS, ProtocolSpec, Variant
from dgsdp.evaluation.results import read_results, results_markdown, write_results
from dgsdp.evaluation.runner import Evaluator
from dgsdp.evaluation.sampling import clip_requests, sample_clips
from dgsdp.evaluation.scoring import Scorer, summarise
from dgsdp.evaluation.warning_log import WarningLog

__all__ = [
    "GROUND_TRUTH", "METRICS", "Clip", "ClipSource", "Evaluator", "ProtocolSpec", "Scorer", "Variant", "WarningLog",
    "clip_requests", "clip_seed", "dance_features", "feature_joints", "motion_to_joints", "read_results",
    "results_markdown", "sample_clips", "summarise", "upsample_joints", "write_results",
]  # fmt: skip
