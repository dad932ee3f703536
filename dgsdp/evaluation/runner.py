"""Run an evaluation protocol on a trained model: sample dances, compute every metric per trial, aggregate.

Per row and trial the metrics are: BeatAlign (Bailando's score at 60 FPS against the songs' known beats where the
dataset has them, a synthetic dataset's, else the music's beat track), PFC
(EDGE, 30 FPS z-up), FID_k / FID_g and Div_k / Div_g (against the protocol's reference set, normalised by its
statistics), and StyleAcc (a :class:`~dgsdp.metrics.GenreClassifier` fitted on ground-truth features of the
training split, asked whether each dance shows the genre it was generated for). A metric that cannot be computed
is ``None`` (``n/a`` in tables) and the reason is kept in the results' warnings.

The pieces: :mod:`~dgsdp.evaluation.clips` builds the clips, :mod:`~dgsdp.evaluation.sampling` makes their dances
through the project's one sampling path (:class:`~dgsdp.generation.DanceGenerator`, as generate.py does),
:mod:`~dgsdp.evaluation.scoring` computes the metrics, :mod:`~dgsdp.evaluation.results` writes them.

Randomness: the dance for clip ``i`` in trial ``k`` is seeded :func:`~dgsdp.evaluation.clips.clip_seed` (seed,
k, i), the same for every row of a trial, so rows differ by their settings only; the trial's clip subset is
drawn with ``seed + k``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from tqdm.auto import tqdm

from dgsdp.data.datamodule import Sequence as DanceSequence
from dgsdp.errors import DataError
from dgsdp.evaluation.clips import ALL_SPLITS, ClipSource
from dgsdp.evaluation.features import MODEL_FPS, motion_to_joints
from dgsdp.evaluation.protocols import METRICS, ProtocolSpec
from dgsdp.evaluation.sampling import sample_clips
from dgsdp.evaluation.scoring import Scorer, summarise
from dgsdp.evaluation.warning_log import WarningLog
from dgsdp.generation.pipeline import DanceGenerator
from dgsdp.sampling import SamplingSettings


class Evaluator:
    """Evaluates one trained model, held by a :class:`DanceGenerator`, under a protocol.

    data_root / cache_dir: the dataset (AIST++ or FineDance layout; ``split_scheme``: FineDance's) and the feature
    cache; the model's own audio encoder gives the music features, its skeleton the real dances' pose vectors."""

    def __init__(
        self,
        generator: DanceGenerator,
        spec: ProtocolSpec,
        *,
        data_root: str | Path,
        cache_dir: str | Path,
        sampling: SamplingSettings | None = None,
        metrics_mode: str = "paper",
        classifier_method: str = "logistic",
        seed: int = 0,
        progress: bool = True,
        cleanup: bool = False,
        split_scheme: str = "genre",
    ) -> None:
        self.generator = generator
        self.cleanup = bool(cleanup)  # score the raw model (False) or its dances as generate.py writes them
        self.spec = spec
        self.sampling = sampling or SamplingSettings()
        self.seed = int(seed)
        self.progress = progress
        self.warnings = WarningLog()
        self.source = ClipSource(
            spec, data_root=data_root, cache_dir=cache_dir, audio_encoder=generator.audio_encoder, seed=seed,
            warnings=self.warnings, progress=progress, skeleton=generator.skeleton, split_scheme=split_scheme,
        )  # fmt: skip
        self.skeleton = generator.skeleton  # the dataset's dances are read as this skeleton's pose vectors
        self.scorer = Scorer(
            spec, mode=metrics_mode, classifier_method=classifier_method, warnings=self.warnings, skeleton=self.skeleton
        )

    # --- the protocol --------------------------------------------------------------------------------------
    def run(self) -> dict[str, Any]:
        """Evaluate every row of the protocol; returns the results (rows with per-trial values, warnings)."""
        spec = self.spec
        by_split = {split: self.source.load_split(split) for split in spec.splits}
        music_seqs = [seq for seqs in by_split.values() for seq in seqs]
        if not music_seqs:
            raise DataError(f"no sequences in splits {spec.splits} of {self.source.data_root}")
        train = self.source.load_split("train", with_music=False)
        classifier = self.scorer.fit_classifier(train)

        pool: tuple[np.ndarray, np.ndarray] | None = None
        if spec.reference == "dataset":
            # every sequence of the dataset minus the ignore list, full length
            seen: dict[str, DanceSequence] = {}
            for split in ALL_SPLITS:
                seqs = train if split == "train" else by_split.get(split)
                seen.update(
                    {s.name: s for s in (self.source.load_split(split, with_music=False) if seqs is None else seqs)}
                )
            cut = None if spec.reference_seconds is None else int(round(spec.reference_seconds * MODEL_FPS))
            _, pk, pg = self.scorer.features([motion_to_joints(s.motion[:cut], self.skeleton) for s in seen.values()])
            pool = (pk, pg)

        variants = spec.variants()
        judged_scoring_beats = False  # a retimed dance scored on the beats its judge saw
        by_length = {v.seconds: self.source.clips(music_seqs, v.seconds) for v in variants}
        gt_trials = spec.trials if spec.clips_per_trial is not None else 1
        rows: list[dict[str, Any]] = []
        total = len(variants) * spec.trials + len(by_length) * gt_trials
        bar = tqdm(total=total, desc=f"evaluating {spec.name}", disable=not self.progress)
        gt_rows = []
        references: dict[float, tuple[np.ndarray, np.ndarray]] = {}
        for seconds, clips in by_length.items():
            gt_joints = [motion_to_joints(c.motion, self.skeleton) for c in clips]
            if pool is None:
                _, rk, rg = self.scorer.features(gt_joints)
                references[seconds] = (rk, rg)
            else:
                references[seconds] = pool
            name = spec.ground_truth_name(seconds)
            per_trial = []
            for trial in range(gt_trials):
                idx = self.source.subset(clips, trial)
                same_as_reference = pool is None and len(idx) == len(clips)
                per_trial.append(self.scorer.score(
                    name, [gt_joints[i] for i in idx], [clips[i] for i in idx],
                    None if same_as_reference else references[seconds], classifier,
                ))  # fmt: skip
                bar.update()
            gt_rows.append(self._row(name, "ground_truth", seconds, None, "none", len(clips), per_trial))
        for variant in variants:
            clips = by_length[variant.seconds]
            per_trial = []
            for trial in range(spec.trials):
                idx = self.source.subset(clips, trial)
                chosen = [clips[i] for i in idx]
                bar.set_postfix_str(f"{variant.name} trial {trial + 1}/{spec.trials}")
                joints = sample_clips(
                    self.generator, chosen, variant, spec, self.sampling, seed=self.seed, trial=trial,
                    cleanup=self.cleanup,
                )  # fmt: skip
                per_trial.append(
                    self.scorer.score(variant.name, joints, chosen, references[variant.seconds], classifier)
                )
                # beat sync retimes and judges on the clips' beats (nothing given); BeatAlign scores on known ones
                judged_scoring_beats |= (
                    self.cleanup and variant.task == "none" and any(c.known_beats_30fps is None for c in chosen)
                )
                bar.update()
            rows.append(
                self._row(variant.name, "generated", variant.seconds, variant.weight, variant.task,
                          len(self.source.subset(clips, 0)), per_trial)
            )  # fmt: skip
        bar.close()
        for row in gt_rows:
            if pool is None and spec.clips_per_trial is None:
                row["notes"] = "FID n/a: the reference set is these clips"
        return {
            "protocol": spec.name,
            "metrics": list(METRICS),
            "rows": rows + gt_rows,
            "warnings": self.warnings.items,
            "n_clips": {f"{s:g}": len(c) for s, c in by_length.items()},
            "beats": self.source.beat_source,  # what BeatAlign was scored against
            "finishing": self.finishing(any(v.task == "none" for v in variants), judged_scoring_beats),
            "classifier_fitted": classifier is not None,
        }

    def finishing(self, retimed: bool, judged_scoring_beats: bool) -> dict[str, Any] | None:
        """How the generated dances were finished (None: the model's raw output is scored). ``retimed``: a row
        without an editing task (beat sync retimes only those); ``judged_scoring_beats``: a retimed dance was scored
        on the beats that beat sync's judge saw (the clip's tracker beats: no known beats), so BeatAlign is not
        independent of the judge's choice."""
        if not self.cleanup:
            return None
        text = "the dances as generate.py writes them (cleanup=true): feet on the floor"
        if retimed:
            text += (
                "; where nothing is given, first retimed onto each clip's beats by librosa's tracker, the retime kept "
                "only where a judge on those same beats found the finished dance no worse than in the model's own "
                "timing (docs/beatsync.md)"
            )
            text += (
                "; BeatAlign is scored against the same beats, which the retime aligned to and its judge saw: it "
                "measures the retime and the judge's choice as well as the model, not an independent check"
                if judged_scoring_beats
                else "; BeatAlign is scored against the songs' known beats, which neither the retime nor its judge saw"
            )
        else:
            text += "; no row is retimed (an editing task keeps its timing)"
        return {"cleanup": True, "judge_saw_scoring_beats": judged_scoring_beats, "description": text}

    def _row(
        self, name: str, kind: str, seconds: float, weight: float | None, task: str, n_dances: int,
        per_trial: list[dict[str, float | None]],
    ) -> dict[str, Any]:  # fmt: skip
        return {
            "name": name,
            "kind": kind,
            "seconds": seconds,
            "guidance": weight,
            "task": task,
            "n_dances": n_dances,
            "trials": len(per_trial),
            "metrics": {m: summarise([t[m] for t in per_trial]) for m in METRICS},
        }
