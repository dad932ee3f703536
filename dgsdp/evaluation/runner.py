"""Run an evaluation protocol on a trained model: sample dances, compute every metric per trial, aggregate.

Per row and trial the metrics are: BeatAlign (Bailando's score at 60 FPS against the music's beat track), PFC
(EDGE, 30 FPS z-up), FID_k / FID_g and Div_k / Div_g (against the protocol's reference set, normalised by its
statistics), and StyleAcc (a :class:`~dgsdp.metrics.GenreClassifier` fitted on ground-truth features of the
training split, asked whether each dance shows the genre it was generated for). A metric that cannot be computed
is ``None`` (``n/a`` in tables) and the reason is kept in the results' warnings.

Randomness: trial ``k`` samples every row with a generator seeded ``seed + k`` (the same noise for every row of a
trial, so rows differ by their settings only) and draws its clip subset with the same seed.
"""

from __future__ import annotations

import logging
import math
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from omegaconf import OmegaConf
from tqdm.auto import tqdm

from dgsdp.audio import AudioEncoder, FeatureCache, LibrosaEncoder
from dgsdp.data.aistpp import music_path
from dgsdp.data.datamodule import Sequence as DanceSequence
from dgsdp.data.datamodule import load_sequences, window_starts
from dgsdp.editing.masks import build_mask
from dgsdp.errors import ConfigError, DataError
from dgsdp.evaluation.features import (
    FEATURE_FPS,
    MODEL_FPS,
    beats_to_feature_fps,
    feature_joints,
    motion_to_joints,
)
from dgsdp.evaluation.protocols import METRICS, ProtocolSpec, Variant
from dgsdp.generation.longform import sample_long
from dgsdp.metrics import (
    GenreClassifier,
    MetricError,
    MetricWarning,
    beat_alignment,
    diversity,
    fid,
    geometric_features_batch,
    kinetic_features_batch,
    music_beats_from_features,
    pfc,
)
from dgsdp.resources import CONFIG_DIR
from dgsdp.sampling import Guidance

log = logging.getLogger(__name__)

LIBROSA_CONFIG = CONFIG_DIR / "audio" / "librosa.yaml"
ALL_SPLITS = ("train", "val", "test")


@dataclass
class SamplingSettings:
    """How dances are sampled for evaluation (see ``conf/evaluate.yaml``)."""

    method: str = "ddim"
    steps: int = 50
    eta: float = 1.0
    style_weight: float = 1.0
    batch_size: int = 64
    longform_ramp_fraction: float = 0.5
    longform_stride_frames: int = 75
    edit_cap_below_t: int = 100
    chunk_size: int = 0


@dataclass
class Clip:
    """A stretch of one real dance and its music: frames ``start .. start + n_frames`` at 30 FPS."""

    seq: DanceSequence
    start: int
    n_frames: int
    beats_30fps: np.ndarray  # (K,) music beat frames relative to ``start``

    @property
    def motion(self) -> np.ndarray:
        """(n_frames, 151) unnormalised, z-up."""
        return self.seq.motion[self.start : self.start + self.n_frames]

    def music(self) -> np.ndarray | None:
        """(n_frames, Da) features, the song's last frame held if it ends early; None without features."""
        if self.seq.audio is None or self.seq.audio.ndim != 2:
            return None
        chunk = self.seq.audio[self.start : self.start + self.n_frames]
        if len(chunk) == 0:
            raise DataError(f"the music of {self.seq.name} ends before frame {self.start}")
        if len(chunk) < self.n_frames:
            chunk = np.concatenate([chunk, np.repeat(chunk[-1:], self.n_frames - len(chunk), axis=0)])
        return chunk


@dataclass
class WarningLog:
    """Messages of metrics that fell back to a defined value, per row (deduplicated)."""

    items: list[dict[str, str]] = field(default_factory=list)

    def add(self, row: str, metric: str, message: str) -> None:
        entry = {"row": row, "metric": metric, "message": message}
        if entry not in self.items:
            self.items.append(entry)
            log.warning("%s / %s: %s", row, metric, message)

    def guard(self, row: str, metric: str, fn: Callable[[], float]) -> float | None:
        """``fn()``, or None when it raises MetricError; MetricWarnings it raises are recorded."""
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", MetricWarning)
            try:
                value: float | None = float(fn())
            except MetricError as e:
                self.add(row, metric, f"not computable ({e}); reported as n/a")
                value = None
        for w in caught:
            if issubclass(w.category, MetricWarning):
                self.add(row, metric, str(w.message))
            else:
                warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
        if value is not None and not math.isfinite(value):
            self.add(row, metric, f"non-finite value {value}; reported as n/a")
            value = None
        return value


def summarise(values: Sequence[float | None]) -> dict[str, Any]:
    """Mean and sample std (ddof 1; 0 for one value) of the computable values; None when there are none."""
    finite = [float(v) for v in values if v is not None]
    if not finite:
        return {"mean": None, "std": None, "n": 0, "values": list(values)}
    arr = np.asarray(finite)
    std = float(arr.std(ddof=1)) if len(arr) > 1 else 0.0
    return {"mean": float(arr.mean()), "std": std, "n": len(arr), "values": list(values)}


class Evaluator:
    """Evaluates one trained model (:class:`~dgsdp.training.module.DanceDiffusion`) under a protocol.

    data_root / cache_dir: the AIST++-layout dataset and the feature cache; the model's own audio encoder
    (rebuilt from its config) gives the music features.
    """

    def __init__(
        self,
        model: Any,
        spec: ProtocolSpec,
        *,
        data_root: str | Path,
        cache_dir: str | Path,
        sampling: SamplingSettings | None = None,
        metrics_mode: str = "paper",
        classifier_method: str = "logistic",
        seed: int = 0,
        device: str | torch.device = "cpu",
        progress: bool = True,
    ) -> None:
        self.model = model.to(device).eval()
        self.spec = spec
        self.data_root = Path(data_root).expanduser()
        self.cache_dir = Path(cache_dir).expanduser()
        self.sampling = sampling or SamplingSettings()
        self.mode = metrics_mode
        self.classifier_method = classifier_method
        self.seed = int(seed)
        self.device = torch.device(device)
        self.progress = progress
        self.warnings = WarningLog()
        data = model.hparams.get("data", {})
        self.window = int(data.get("window_frames", model.denoiser.seq_len))
        self._beat_encoder: AudioEncoder | None = None
        self._beats: dict[str, np.ndarray] = {}

    # --- data ----------------------------------------------------------------------------------------------
    def audio_encoder(self) -> AudioEncoder | None:
        """The model's audio encoder from its training config, or None for a model without music."""
        cond = self.model.hparams["conditioning"]
        if not int(cond.get("audio_dim", 0)):
            return None
        audio_cfg = (self.model.hparams.get("config") or {}).get("audio")
        if not audio_cfg or not audio_cfg.get("_target_"):
            raise ConfigError("the checkpoint's config does not say which audio encoder it was trained with")
        from hydra.utils import instantiate

        encoder = instantiate(audio_cfg)
        if int(encoder.feature_dim) != int(cond["audio_dim"]):
            raise ConfigError(
                f"the checkpoint's audio encoder gives {encoder.feature_dim}-d features but the model was "
                f"trained on {cond['audio_dim']}-d features"
            )
        return encoder

    def load_split(self, split: str, audio_encoder: AudioEncoder | None) -> list[DanceSequence]:
        """Sequences of a split, or [] (with a warning) when the dataset has no such split."""
        try:
            return load_sequences(
                self.data_root, split, fps=MODEL_FPS, cache_dir=self.cache_dir, audio_encoder=audio_encoder,
                progress=self.progress,
            )  # fmt: skip
        except DataError as e:
            self.warnings.add("data", "-", f"split {split!r} skipped: {e}")
            return []

    def music_beats(self, seq: DanceSequence) -> np.ndarray:
        """Beat frames (K,) at 30 FPS of a sequence's music: column 34 of the 35-d librosa features (the model's
        own features when it was trained on them, else the librosa encoder of ``conf/audio/librosa.yaml``)."""
        if seq.music_id in self._beats:
            return self._beats[seq.music_id]
        if self.model.hparams["conditioning"].get("audio") == LibrosaEncoder.name and seq.audio is not None:
            feats = seq.audio
        else:
            if self._beat_encoder is None:
                from hydra.utils import instantiate

                self._beat_encoder = instantiate(OmegaConf.load(LIBROSA_CONFIG))
            path = music_path(self.data_root, seq.music_id)
            feats = FeatureCache(self.cache_dir).features_for_file(self._beat_encoder, path, music_id=seq.music_id)
        self._beats[seq.music_id] = music_beats_from_features(feats)
        return self._beats[seq.music_id]

    def clips(self, sequences: list[DanceSequence], seconds: float) -> list[Clip]:
        """Clips of ``seconds`` from the protocol's music: every window ``stride_seconds`` apart, or (stride
        null) the start of each dance, at most ``seconds`` long; capped at ``max_dances``."""
        n_frames = int(round(seconds * MODEL_FPS))
        out: list[Clip] = []
        for seq in sequences:
            if self.spec.stride_seconds is None:
                starts, n = [0], min(n_frames, len(seq.motion))
            else:
                starts = window_starts(len(seq.motion), n_frames, int(round(self.spec.stride_seconds * MODEL_FPS)))
                n = n_frames
            beats = self.music_beats(seq)
            for s in starts:
                rel = beats[(beats >= s) & (beats < s + n)] - s
                out.append(Clip(seq, s, n, rel))
        if self.spec.max_dances is not None:
            out = out[: self.spec.max_dances]
        if len(out) < 2:
            raise DataError(
                f"protocol {self.spec.name!r} found {len(out)} clip(s) of {seconds:g} s in splits {self.spec.splits} "
                f"of {self.data_root}; FID and diversity need at least 2. Use a dataset with longer or more "
                "sequences, or shorter protocol.lengths_seconds."
            )
        return out

    def subset(self, clips: list[Clip], trial: int) -> list[int]:
        """Indices of the clips of one trial: all of them, or ``clips_per_trial`` drawn round-robin over genres."""
        k = self.spec.clips_per_trial
        if k is None or k >= len(clips):
            return list(range(len(clips)))
        rng = np.random.default_rng(self.seed + trial)
        by_genre: dict[int, list[int]] = {}
        for i, clip in enumerate(clips):
            by_genre.setdefault(clip.seq.genre_index, []).append(i)
        queues = [list(rng.permutation(v)) for _, v in sorted(by_genre.items())]
        order = [int(q[i]) for i in range(max(len(q) for q in queues)) for q in queues if i < len(q)]
        return sorted(order[:k])

    # --- metrics -------------------------------------------------------------------------------------------
    def features(self, joints: Sequence[np.ndarray]) -> tuple[list[np.ndarray], np.ndarray, np.ndarray]:
        """60 FPS y-up joints and kinetic (N, 72) and geometric (N, 32) features of 30 FPS z-up joints."""
        prepared = [feature_joints(j, anchor=self.spec.anchor_root) for j in joints]
        kin = kinetic_features_batch(prepared, fps=FEATURE_FPS, up_axis="y", mode=self.mode)
        geo = geometric_features_batch(prepared, fps=FEATURE_FPS, up_axis="y", mode=self.mode)
        return prepared, kin, geo

    def fit_classifier(self, train: list[DanceSequence]) -> GenreClassifier | None:
        """Genre classifier on kinetic + geometric features of training-split windows; None if it cannot be fitted."""
        n = int(round(self.spec.classifier_seconds * MODEL_FPS))
        stride = int(round((self.spec.stride_seconds or self.spec.classifier_seconds) * MODEL_FPS))
        joints, labels = [], []
        for seq in train:
            starts = window_starts(len(seq.motion), n, stride) or [0]
            for s in starts:
                joints.append(motion_to_joints(seq.motion[s : s + n]))
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
            lambda: np.mean([beat_alignment(p, beats_to_feature_fps(c.beats_30fps), fps=FEATURE_FPS)
                             for p, c in zip(prepared, clips)]),
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

    # --- sampling ------------------------------------------------------------------------------------------
    def sample(self, clips: list[Clip], variant: Variant, trial: int) -> list[np.ndarray]:
        """Generated dances for ``clips`` as 30 FPS z-up joints (T, 24, 3) each."""
        s = self.sampling
        generator = torch.Generator(device=self.device).manual_seed(self.seed + trial)
        mask_generator = torch.Generator().manual_seed(self.seed + trial)
        n_frames = clips[0].n_frames
        long = any(c.n_frames > self.window for c in clips)
        guidance = Guidance(
            variant.weight, s.style_weight,
            ramp_fraction=s.longform_ramp_fraction if long else 0.0,
            edit_cap_below_t=s.edit_cap_below_t,
        )  # fmt: skip
        genres = torch.tensor([c.seq.genre_index for c in clips], device=self.device)
        styles = self.model.style_for(genres, random=False)
        masks = known = None
        if variant.task != "none":
            masks = torch.stack([
                build_mask(variant.task, c.n_frames, seed_frames=self.spec.seed_frames,
                           end_frames=self.spec.end_frames, inpaint_fraction=self.spec.inpaint_fraction,
                           fps=MODEL_FPS, generator=mask_generator)
                for c in clips
            ]) if len({c.n_frames for c in clips}) == 1 else None  # fmt: skip
            if masks is None:
                raise ConfigError("editing protocols need clips of one length (set protocol.stride_seconds)")
            known = torch.stack([torch.from_numpy(np.ascontiguousarray(c.motion)).float() for c in clips])
        music = [c.music() for c in clips]
        motions: list[torch.Tensor] = []
        if not long and len({c.n_frames for c in clips}) == 1:
            for lo in range(0, len(clips), s.batch_size):
                hi = min(lo + s.batch_size, len(clips))
                batch_music = None
                if music[0] is not None:
                    batch_music = torch.from_numpy(np.stack(music[lo:hi])).float().to(self.device)
                kwargs: dict[str, Any] = {}
                if masks is not None:
                    kwargs["mask"] = masks[lo:hi]
                    kwargs["known"] = self.model.normalizer.normalize(known[lo:hi].to(self.device))
                out = self.model.sample_batch(
                    batch_music, None if styles is None else styles[lo:hi], n_frames=n_frames, batch=hi - lo,
                    guidance=guidance, steps=s.steps, method=s.method, eta=s.eta, generator=generator, **kwargs,
                )  # fmt: skip
                if masks is not None:  # the given channels exactly as given
                    given = known[lo:hi].to(out)
                    out = torch.where(masks[lo:hi].to(out.device).bool(), given, out)
                motions.extend(out.float().cpu())
        else:
            for i, clip in enumerate(clips):
                out = sample_long(
                    self.model.sampler(), self.model.normalizer, clip.n_frames,
                    music=None if music[i] is None else torch.from_numpy(music[i]).float(),
                    style=None if styles is None else styles[i],
                    window=self.window, stride=min(s.longform_stride_frames, self.window),
                    mask=None if masks is None else masks[i], known=None if known is None else known[i],
                    method=s.method, steps=s.steps, eta=s.eta, guidance=guidance, chunk_size=s.chunk_size,
                    generator=generator, device=self.device,
                )  # fmt: skip
                motions.append(out[0].float().cpu())
        return [motion_to_joints(m.numpy()) for m in motions]

    # --- the protocol --------------------------------------------------------------------------------------
    def run(self) -> dict[str, Any]:
        """Evaluate every row of the protocol; returns the results (rows with per-trial values, warnings)."""
        spec = self.spec
        encoder = self.audio_encoder()
        by_split = {split: self.load_split(split, encoder) for split in spec.splits}
        music_seqs = [seq for seqs in by_split.values() for seq in seqs]
        if not music_seqs:
            raise DataError(f"no sequences in splits {spec.splits} of {self.data_root}")
        train = self.load_split("train", None)
        classifier = self.fit_classifier(train)

        pool: tuple[np.ndarray, np.ndarray] | None = None
        if spec.reference == "dataset":
            # every sequence of the dataset minus the ignore list, full length
            seen: dict[str, DanceSequence] = {}
            for split in ALL_SPLITS:
                seqs = train if split == "train" else by_split.get(split)
                seen.update({s.name: s for s in (self.load_split(split, None) if seqs is None else seqs)})
            _, pk, pg = self.features([motion_to_joints(s.motion) for s in seen.values()])
            pool = (pk, pg)

        variants = spec.variants()
        by_length = {v.seconds: self.clips(music_seqs, v.seconds) for v in variants}
        gt_trials = spec.trials if spec.clips_per_trial is not None else 1
        rows: list[dict[str, Any]] = []
        total = len(variants) * spec.trials + len(by_length) * gt_trials
        bar = tqdm(total=total, desc=f"evaluating {spec.name}", disable=not self.progress)
        gt_rows = []
        references: dict[float, tuple[np.ndarray, np.ndarray]] = {}
        for seconds, clips in by_length.items():
            gt_joints = [motion_to_joints(c.motion) for c in clips]
            if pool is None:
                _, rk, rg = self.features(gt_joints)
                references[seconds] = (rk, rg)
            else:
                references[seconds] = pool
            name = spec.ground_truth_name(seconds)
            per_trial = []
            for trial in range(gt_trials):
                idx = self.subset(clips, trial)
                same_as_reference = pool is None and len(idx) == len(clips)
                per_trial.append(self.score(
                    name, [gt_joints[i] for i in idx], [clips[i] for i in idx],
                    None if same_as_reference else references[seconds], classifier,
                ))  # fmt: skip
                bar.update()
            gt_rows.append(self._row(name, "ground_truth", seconds, None, "none", len(clips), per_trial))
        for variant in variants:
            clips = by_length[variant.seconds]
            per_trial = []
            for trial in range(spec.trials):
                idx = self.subset(clips, trial)
                chosen = [clips[i] for i in idx]
                bar.set_postfix_str(f"{variant.name} trial {trial + 1}/{spec.trials}")
                joints = self.sample(chosen, variant, trial)
                per_trial.append(self.score(variant.name, joints, chosen, references[variant.seconds], classifier))
                bar.update()
            rows.append(
                self._row(variant.name, "generated", variant.seconds, variant.weight, variant.task,
                          len(self.subset(clips, 0)), per_trial)
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
            "classifier_fitted": classifier is not None,
        }

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
