"""Scoring generated or real dances: features, the style classifier, every metric, and their warnings."""

from __future__ import annotations

import logging
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from dgsdp.data.datamodule import window_starts
from dgsdp.evaluation.features import (
    FEATURE_FPS,
    MODEL_FPS,
    beats_to_feature_fps,
    feature_joints,
    motion_to_joints,
    root_relative,
)
from dgsdp.evaluation.protocols import ProtocolSpec
from dgsdp.evaluation.warning_log import WarningLog
from dgsdp.metrics import (
    GenreClassifier,
    beat_alignment,
    diversity,
    fid,
    geometric_features_batch,
    kinetic_features_batch,
    pfc,
)
from dgsdp.motion import SMPL24, Skeleton

if TYPE_CHECKING:
    from dgsdp.data.datamodule import Sequence as DanceSequence
    from dgsdp.evaluation.clips import Clip

log = logging.getLogger(__name__)


def summarise(values: Sequence[float | None]) -> dict[str, Any]:
    """Mean and sample std (ddof 1; 0 for one value) of the computable values; None when there are none."""
    finite = [float(v) for v in values if v is not None]
    if not finite:
        return {"mean": None, "std": None, "n": 0, "values": list(values)}
    arr = np.asarray(finite)
    std = float(arr.std(ddof=1)) if len(arr) > 1 else 0.0
    return {"mean": float(arr.mean()), "std": std, "n": len(arr), "values": list(values)}


class Scorer:
    """Every metric of a set of dances (30 FPS z-up joints) made for a protocol's clips.

    mode: paper (the reference arithmetic) or corrected; classifier_method: logistic or centroid."""

    def __init__(
        self, spec: ProtocolSpec, *, mode: str, classifier_method: str, warnings: WarningLog,
        skeleton: Skeleton = SMPL24,
    ) -> None:  # fmt: skip
        self.spec = spec
        self.skeleton = skeleton  # of the real dances' pose vectors (the classifier's training windows)
        self.mode = mode
        self.classifier_method = classifier_method
        self.warnings = warnings

    def features(self, joints: Sequence[np.ndarray]) -> tuple[list[np.ndarray], np.ndarray, np.ndarray]:
        """y-up joints as BeatAlign reads them (60 FPS, or the 30 FPS frames where ``feature_upsample`` is off) and
        kinetic (N, 72; N, 66 with ``feature_joints`` 22: the first 22 joints' columns) and geometric (N, 32)
        features of 30 FPS z-up joints (made root-relative first where ``root_relative`` is on). The feature code
        always runs with its 60 FPS constants."""
        spec = self.spec
        prepared = [feature_joints(j, anchor=spec.anchor_root, upsample=spec.feature_upsample) for j in joints]
        measured = [root_relative(p) for p in prepared] if spec.root_relative else prepared
        kin = kinetic_features_batch(measured, fps=FEATURE_FPS, up_axis="y", mode=self.mode)
        geo = geometric_features_batch(measured, fps=FEATURE_FPS, up_axis="y", mode=self.mode)
        return prepared, kin[:, : 3 * spec.feature_joints], geo

    def beats(self, clip: Clip) -> np.ndarray:
        """The clip's music beats as frame indices of :meth:`features`' joints."""
        beats = clip.scoring_beats_30fps
        return beats_to_feature_fps(beats) if self.spec.feature_upsample else np.asarray(beats, dtype=np.int64)

    def fit_classifier(self, train: list[DanceSequence]) -> GenreClassifier | None:
        """Genre classifier on kinetic + geometric features of training-split windows; None if it cannot be fitted."""
        n = int(round(self.spec.classifier_seconds * MODEL_FPS))
        stride = int(round((self.spec.stride_seconds or self.spec.classifier_seconds) * MODEL_FPS))
        joints, labels = [], []
        for seq in train:
            starts = window_starts(len(seq.motion), n, stride) or [0]
            for s in starts:
                joints.append(motion_to_joints(seq.motion[s : s + n], self.skeleton))
                labels.append(seq.genre_index)
        if not joints:
            self.warnings.add("classifier", "StyleAcc", "no training sequences; StyleAcc reported as n/a")
            return None
        _, kin, geo = self.features(joints)
        clf = GenreClassifier(method=self.classifier_method)

        def fit() -> float:
            clf.fit(np.hstack([kin, geo]), np.asarray(labels))
            return 0.0

        return None if self.warnings.guard("classifier", "StyleAcc", fit) is None else clf

    def score(
        self,
        row: str,
        joints: list[np.ndarray],
        clips: list[Clip],
        reference: tuple[np.ndarray, np.ndarray] | None,
        classifier: GenreClassifier | None,
    ) -> dict[str, float | None]:
        """Every metric of one set of dances (30 FPS z-up joints) made for ``clips``."""
        guard = self.warnings.guard
        prepared, kin, geo = self.features(joints)
        out: dict[str, float | None] = {}
        out["BeatAlign"] = guard(
            row, "BeatAlign",
            lambda: np.mean([beat_alignment(p, self.beats(c), fps=FEATURE_FPS) for p, c in zip(prepared, clips)]),
        )  # fmt: skip
        out["PFC"] = guard(row, "PFC", lambda: np.mean([pfc(j, fps=MODEL_FPS, up_axis="z") for j in joints]))
        if reference is None:
            out["FID_k"] = out["FID_g"] = None
            ref_k, ref_g = kin, geo
        else:
            ref_k, ref_g = reference
            out["FID_k"] = guard(row, "FID_k", lambda: fid(ref_k, kin))
            out["FID_g"] = guard(row, "FID_g", lambda: fid(ref_g, geo))
        out["Div_k"] = guard(row, "Div_k", lambda: diversity(kin, ref_k))
        out["Div_g"] = guard(row, "Div_g", lambda: diversity(geo, ref_g))
        if classifier is None:
            out["StyleAcc"] = None
        else:
            labels = [c.seq.genre_index for c in clips]
            out["StyleAcc"] = guard(row, "StyleAcc", lambda: classifier.accuracy(np.hstack([kin, geo]), labels))
        return out
