"""Evaluation protocols of the papers' tables: sampling dances from a checkpoint, every metric, results files."""

from dgsdp.evaluation.features import dance_features, feature_joints, motion_to_joints, upsample_joints
from dgsdp.evaluation.protocols import GROUND_TRUTH, METRICS, ProtocolSpec, Variant
from dgsdp.evaluation.results import read_results, results_markdown, write_results
from dgsdp.evaluation.runner import Evaluator, SamplingSettings, summarise

__all__ = [
    "GROUND_TRUTH", "METRICS", "Evaluator", "ProtocolSpec", "SamplingSettings", "Variant", "dance_features",
    "feature_joints", "motion_to_joints", "read_results", "results_markdown", "summarise", "upsample_joints",
    "write_results",
]  # fmt: skip
