"""Does the dance show the style it was asked for? ``python -m dgsdp.benchmarks.style --checkpoint CKPT``

The raw model (``cleanup=false beat_sync=false``) and the finished dance (generate.py's default finishing of the
same sample) side by side, each judged by the genre classifier of DGSDP's Table I protocol (kinetic and geometric
features of 5 s windows, fitted on the training split's dances):

- **genre accuracy** on the held-out synthetic songs (the test split, 5 s clips every 2.5 s, each asked in its own
  dance's genre, as Table I), with the confusion matrix (printed, and a png with ``--png``);
- **genre speed**: each genre's mean joint speed over its dances against its own training dances' (the ratio; the
  target is within 30%);
- **free text**: the same clips asked with descriptions that are *not* in the training prompts (the held-out list
  ``dgsdp/resources/style_heldout/aistpp.yaml``, which nothing trains on), classified as the genre they describe;
  ``--heldout aistpp_second`` takes a second list, written after generate.py's text-reading temperature was chosen
  on the first, ``--heldout aistpp_third`` a third, of movement and feeling only, written before the router was
  fitted; several lists in one run are each measured on the same clips (the first is the last line's);
- **speed rank**: the Spearman correlation, over the genres, of each genre's training speed with the mean speed of
  the dances asked in it (does a faster genre get a faster dance?);
- **modifier pairs**: for every genre, on one clip of each of its first three held-out dances with one seed, a
  description with a speed or energy word and its opposite (:data:`MODIFIER_PAIRS`: "slow krump" / "fast krump", "gentle krump" /
  "explosive krump", "slow gentle krump" / "fast explosive krump"); a pair is ordered right when the faster word's
  dance has the higher mean joint speed;
- **attribute pairs** (``--attributes aistpp``, the held-out wordings of
  ``dgsdp/resources/style_heldout/attributes/``): for every movement attribute (level, arms, travel, turning), pairs
  of wordings asking for its two ends with a genre's name ("{genre} hugging the ground" / "{genre} stood straight up
  like a soldier"), each pair danced for every genre on one of the modifier check's clips with one seed; a pair is
  ordered right when the dance asked for more measures more (:mod:`dgsdp.metrics.attributes`), and the attribute-asked
  dances' genre accuracy says whether the genre survived the words;
- **a style schedule**: two genres, 10 s each, on held-out songs; the accuracy of each span's 5 s windows (away
  from the 2 s blend) and how many frames the switch takes (2 s windows classified every 5 frames);
- **real songs** (``--songs DIR``, a folder of songs, e.g. one made by ``python -m dgsdp.benchmarks.realsongs
  prepare``): every song in every genre, its 5 s windows classified by the same classifier.

The ground truth's accuracy (the test split's real dances, the same clips) is printed beside. The last line::

    style_acc=<raw genre accuracy> text_acc=<raw free-text accuracy> genre_speed_within_30pct=<n>/10
    speed_spearman=<raw speed rank correlation> modifiers=<raw fraction of pairs ordered right> gt_acc=<gt>

followed, with ``--attributes``, by each attribute's fraction of pairs ordered right and the attribute-asked
dances' genre accuracy (``level=... arms=... travel=... turning=... attribute_genre_acc=...``).

With several checkpoints (one per training seed) each is measured in turn and the last line gives the means.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm.auto import tqdm

from dgsdp.errors import ConfigError, DgsdpError
from dgsdp.metrics.attributes import movement_attributes
from dgsdp.metrics.speed import mean_joint_speed
from dgsdp.motion import SMPL24, Skeleton
from dgsdp.resources import RESOURCES_DIR

HELDOUT_DIR = RESOURCES_DIR / "style_heldout"
HELDOUT_FILE = HELDOUT_DIR / "aistpp.yaml"
"""Held-out free-text descriptions, kept apart from the training prompts (``resources/style_prompts/``)."""
ATTRIBUTE_HELDOUT_DIR = HELDOUT_DIR / "attributes"
"""Held-out wordings of the movement attributes (pairs asking for either end), kept apart from the reader's words."""
ATTRIBUTE_NAMES = ("level", "arms", "travel", "turning")
NAMED_FIRST = {"aistpp": 2, "aistpp_second": 2, "aistpp_third": 0}
"""How many of each genre's descriptions name the genre, first, in each shipped held-out list (another file: 2)."""
SPEED_TOLERANCE = 0.30
CLIP_SECONDS = 5.0
CLIP_STRIDE_SECONDS = 2.5
SCHEDULE_SPAN_SECONDS = 10.0
BLEND_WINDOW_SECONDS = 2.0
BLEND_GRID_FRAMES = 5
VARIANTS = ("raw", "finished")
MODIFIER_PAIRS = (("slow {genre}", "fast {genre}"), ("gentle {genre}", "explosive {genre}"),
                  ("slow gentle {genre}", "fast explosive {genre}"))  # fmt: skip
"""(slower, faster) phrasings of each genre's name: the modifier check's descriptions."""
MODIFIER_SONGS = 3  # the modifier check's clips per genre, each from another held-out dance (and song)


# --- pure measures (tested on hand-made figures) ------------------------------------------------------------------
def confusion_matrix(true: Sequence[int], predicted: Sequence[int], n_classes: int) -> np.ndarray:
    """Counts (n_classes, n_classes): row = the genre asked, column = the genre the classifier saw."""
    out = np.zeros((n_classes, n_classes), dtype=np.int64)
    np.add.at(out, (np.asarray(true, dtype=np.int64), np.asarray(predicted, dtype=np.int64)), 1)
    return out


def accuracy(true: Sequence[int], predicted: Sequence[int]) -> float:
    true, predicted = np.asarray(true), np.asarray(predicted)
    return float(np.mean(true == predicted)) if true.size else math.nan


def speed_ratios(
    speeds: Sequence[float], genres: Sequence[int], train_speed_by_genre: dict[int, float]
) -> dict[int, float]:
    """Per genre: the mean of its dances' mean joint speeds over its training dances' mean joint speed."""
    speeds_arr, genres_arr = np.asarray(speeds, dtype=np.float64), np.asarray(genres)
    out = {}
    for g, train in sorted(train_speed_by_genre.items()):
        mine = speeds_arr[genres_arr == g]
        if mine.size and train > 0:
            out[g] = float(mine.mean() / train)
    return out


def speed_rank_correlation(
    speeds: Sequence[float], genres: Sequence[int], train_speed_by_genre: dict[int, float]
) -> float:
    """Spearman's rank correlation, over the genres with dances, of each genre's training speed with the mean speed
    of its dances (NaN with fewer than three genres)."""
    from scipy.stats import spearmanr

    speeds_arr, genres_arr = np.asarray(speeds, dtype=np.float64), np.asarray(genres)
    pairs = [(train, float(speeds_arr[genres_arr == g].mean())) for g, train in sorted(train_speed_by_genre.items())
             if (genres_arr == g).any()]  # fmt: skip
    if len(pairs) < 3:
        return math.nan
    return float(spearmanr([a for a, _ in pairs], [b for _, b in pairs]).statistic)


def ordered_right(slower: Sequence[float], faster: Sequence[float]) -> float:
    """The fraction of pairs whose faster-worded dance has the higher mean joint speed."""
    pairs = list(zip(slower, faster, strict=True))
    return float(np.mean([f > s for s, f in pairs])) if pairs else math.nan


def attribute_figures(
    lower: Sequence[float], higher: Sequence[float], asked: Sequence[int], seen: Sequence[int]
) -> dict[str, float]:
    """Of one attribute's pairs (the measured values of the dance asked for less and of the one asked for more) and
    of their dances' genres (asked, seen by the classifier; both dances of every pair): the fraction of pairs ordered
    right and the genre accuracy."""
    return {"right": ordered_right(lower, higher), "genre_acc": accuracy(asked, seen)}


def within(ratio: float, tolerance: float = SPEED_TOLERANCE) -> bool:
    return abs(ratio - 1.0) <= tolerance + 1e-9  # 1.3 is within 30%, floating point aside


def switch_frames(labels: Sequence[int], first: int, second: int, grid_frames: int) -> int | None:
    """Frames a style switch takes, from a sequence of window labels on a grid (``grid_frames`` apart): from the
    last window still labelled ``first`` to the first one from which every window is ``second`` (0 = a clean
    switch from one window to the next; None when the dance never settles in ``second`` or never showed ``first``).
    """
    labels = np.asarray(labels)
    is_second = labels == second
    if not is_second.any() or not is_second[-1]:
        return None
    settled = len(labels) - int(np.argmin(is_second[::-1])) if not is_second.all() else 0
    before = np.flatnonzero(labels[:settled] == first)
    if before.size == 0:
        return None
    return int((settled - before[-1] - 1) * grid_frames)


# --- the benchmark -------------------------------------------------------------------------------------------------
@dataclasses.dataclass
class Judge:
    """The Table I genre classifier (5 s windows) and a 2 s one for the schedule's switch, fitted on the training
    split's dances; both judge 30 FPS z-up joints."""

    scorer: Any
    classifier: Any
    short_classifier: Any
    fps: int

    @classmethod
    def fit(cls, train: list[Any], fps: int) -> Judge:
        from dgsdp.evaluation.protocols import ProtocolSpec
        from dgsdp.evaluation.scoring import Scorer
        from dgsdp.evaluation.warning_log import WarningLog

        def scorer_for(seconds: float) -> Any:
            spec = ProtocolSpec(
                name="style", stride_seconds=min(CLIP_STRIDE_SECONDS, seconds), classifier_seconds=seconds
            )
            return Scorer(spec, mode="paper", classifier_method="logistic", warnings=WarningLog())

        scorer, short = scorer_for(CLIP_SECONDS), scorer_for(BLEND_WINDOW_SECONDS)
        classifier, short_classifier = scorer.fit_classifier(train), short.fit_classifier(train)
        if classifier is None or short_classifier is None:
            raise ConfigError("the genre classifier could not be fitted on the training split (see the warnings)")
        return cls(scorer, classifier, short_classifier, fps)

    def predict(self, joints: Sequence[np.ndarray], short: bool = False) -> np.ndarray:
        """Genre index of each dance ((T, 24, 3) z-up joints at the model's frame rate)."""
        if not len(joints):
            return np.zeros(0, dtype=np.int64)
        _, kin, geo = self.scorer.features(list(joints))
        clf = self.short_classifier if short else self.classifier
        return clf.predict(np.hstack([kin, geo])).astype(np.int64)

    def windows(self, joints: np.ndarray, start_s: float, end_s: float, seconds: float = CLIP_SECONDS) -> list:
        """The ``seconds`` windows of ``joints`` lying within [start_s, end_s], every second."""
        n = int(round(seconds * self.fps))
        starts = range(int(round(start_s * self.fps)), int(round(end_s * self.fps)) - n + 1, self.fps)
        return [joints[s : s + n] for s in starts]


def _to_joints(motions: Sequence[torch.Tensor], skeleton: Skeleton = SMPL24) -> list[np.ndarray]:
    """Joints in SMPL's layout (the metrics' input) of motions of ``skeleton`` (the dataset's clips: SMPL-24)."""
    from dgsdp.evaluation.features import motion_to_joints

    return [motion_to_joints(m[0].numpy() if m.ndim == 3 else m.numpy(), skeleton) for m in motions]


def resolve_heldout(heldout: str | None) -> Path:
    """The held-out descriptions file: ``None`` (the first list, ``style_heldout/aistpp.yaml``), a shipped list's name
    in ``dgsdp/resources/style_heldout/`` or a yaml path."""
    from dgsdp.style.embeddings import resolve_prompts_file

    if heldout is None:
        return HELDOUT_FILE
    path = resolve_prompts_file(heldout, shipped_dir=HELDOUT_DIR)
    if not path.is_file():
        shipped = ", ".join(sorted(p.stem for p in HELDOUT_DIR.glob("aistpp*.yaml")))
        raise ConfigError(f"--heldout {heldout}: no such file; give a yaml path or a shipped list's name ({shipped})")
    return path


def resolve_attribute_wordings(name: str) -> Path:
    """The held-out attribute wordings: a shipped list's name in ``dgsdp/resources/style_heldout/attributes/`` or a
    yaml path."""
    path = Path(name).expanduser()
    if not path.suffix:
        path = ATTRIBUTE_HELDOUT_DIR / f"{name}.yaml"
    if not path.is_file():
        shipped = ", ".join(sorted(p.stem for p in ATTRIBUTE_HELDOUT_DIR.glob("*.yaml")))
        raise ConfigError(f"--attributes {name}: no such file; give a yaml path or a shipped list's name ({shipped})")
    return path


def load_attribute_pairs(path: Path) -> dict[str, list[tuple[str, str]]]:
    """The pairs (asking for less, asking for more) of each movement attribute in a wordings file (see the shipped
    one), each with a ``{genre}`` placeholder."""
    import yaml

    try:
        data = yaml.safe_load(Path(path).read_text(encoding="utf-8"))
    except (OSError, yaml.YAMLError) as e:
        raise ConfigError(f"{path}: cannot read the attribute wordings ({e})") from e
    if not isinstance(data, dict) or not data:
        raise ConfigError(f"{path} must map movement attributes ({', '.join(ATTRIBUTE_NAMES)}) to pairs of wordings")
    out: dict[str, list[tuple[str, str]]] = {}
    for name, pairs in data.items():
        if name not in ATTRIBUTE_NAMES:
            raise ConfigError(f"{path}: unknown attribute {name!r}; use {', '.join(ATTRIBUTE_NAMES)}")
        if not isinstance(pairs, list) or not pairs:
            raise ConfigError(f"{path}: {name} must list pairs [asking for less, asking for more]")
        for pair in pairs:
            if (
                not isinstance(pair, list)
                or len(pair) != 2
                or not all(isinstance(t, str) and "{genre}" in t for t in pair)
            ):
                raise ConfigError(f"{path}: {name}: {pair!r} is not a pair of two wordings, each with {{genre}}")
        out[name] = [(a, b) for a, b in pairs]
    return out


class StyleBenchmark:
    """Measures one checkpoint. ``overrides``: generate.py settings (e.g. ``sampling=edge``,
    ``sampling.guidance.music=2.5``); the finished dances use its finishing settings."""

    def __init__(
        self,
        checkpoint: str,
        overrides: Sequence[str] = (),
        *,
        data_root: str | None = None,
        max_clips: int | None = None,
        raw_only: bool = False,
        progress: bool = True,
        heldout: str | Sequence[str] | None = None,
        attributes: str | None = None,
    ) -> None:
        from dgsdp.cli.config import compose_config
        from dgsdp.cli.generate import generate_settings
        from dgsdp.generation.songs import SongDancer

        cfg = compose_config("generate", [f"checkpoint={checkpoint}", *overrides])
        self.job = SongDancer.from_settings(generate_settings(cfg))
        self.generator = self.job.generator
        if not self.generator.style_dim:
            raise ConfigError(f"{checkpoint} was trained without style (style=none): there is no style to measure")
        self.checkpoint = checkpoint
        self.cache_dir = Path(cfg.paths.cache_dir)
        self.data_root = Path(data_root) if data_root else self._training_root(cfg)
        if max_clips is not None and max_clips < 2:
            raise ConfigError(f"--max-clips must be at least 2, got {max_clips}")
        self.max_clips = max_clips
        self.raw_only = bool(raw_only)  # quick screening: the finished clips are not made
        lists = [heldout] if heldout is None or isinstance(heldout, str) else list(heldout)
        self.heldout_files = [resolve_heldout(h) for h in lists]
        self.attribute_file = None if attributes is None else resolve_attribute_wordings(attributes)
        self.attribute_pairs = None if self.attribute_file is None else load_attribute_pairs(self.attribute_file)
        self.progress = progress
        self.vocab = self.generator.embedder().vocab
        self.fps = self.generator.fps

    def _training_root(self, cfg: Any) -> Path:
        recorded = ((self.generator.spec.record or {}).get("data") or {}).get("root")
        for root in (recorded, Path(cfg.paths.data_dir) / "synthetic"):
            if root and (Path(root) / "motions").is_dir():
                return Path(root)
        raise ConfigError(
            f"the checkpoint's training data ({recorded}) is not here; give --data-root <AIST++-layout folder> "
            "(the synthetic one: python -m dgsdp.data.synthetic --out data/synthetic)"
        )

    # --- pieces ------------------------------------------------------------------------------------------------
    def _finish(self, motions: list[torch.Tensor], beats: list[np.ndarray | None]) -> list[torch.Tensor]:
        s = self.job.settings
        cleanup = s.cleanup and s.finishing.floor()
        beat_sync = s.beat_sync and s.finishing.beat_sync()
        return [self.generator.finish(m, b, cleanup=cleanup, beat_sync=beat_sync) for m, b in zip(motions, beats)]

    def _sample(self, requests: list[Any], beats: list[np.ndarray | None]) -> dict[str, list[np.ndarray]]:
        raw = self.generator.generate_many(requests, self.job.sampling, progress=False)
        if self.raw_only:
            return {"raw": _to_joints(raw, self.generator.skeleton)}
        finished = self._finish(raw, beats)
        return {
            "raw": _to_joints(raw, self.generator.skeleton),
            "finished": _to_joints(finished, self.generator.skeleton),
        }

    def run(self, songs: Sequence[Path] = (), song_seconds: float = 10.0) -> dict[str, Any]:
        from dgsdp.evaluation.clips import ClipSource
        from dgsdp.evaluation.protocols import ProtocolSpec, Variant
        from dgsdp.evaluation.sampling import clip_requests
        from dgsdp.evaluation.warning_log import WarningLog

        spec = ProtocolSpec(
            name="style", stride_seconds=CLIP_STRIDE_SECONDS, classifier_seconds=CLIP_SECONDS,
            clips_per_trial=self.max_clips,  # at most this many clips, taken from the genres in turn
        )  # fmt: skip
        source = ClipSource(
            spec, data_root=self.data_root, cache_dir=self.cache_dir, audio_encoder=self.generator.audio_encoder,
            seed=0, warnings=WarningLog(), progress=self.progress,
        )  # fmt: skip
        train = source.load_split("train", with_music=False)
        judge = Judge.fit(train, self.fps)
        train_speed = self._train_speeds(train)
        test = source.load_split("test")
        clips = source.clips(test, CLIP_SECONDS)
        clips = [clips[i] for i in source.subset(clips, trial=0)]
        genres = [c.seq.genre_index for c in clips]
        beats = [c.beats_30fps for c in clips]
        seed = self.job.settings.seed
        variant = Variant(CLIP_SECONDS, self.job.sampling.guidance.music, "none", "style")
        requests = clip_requests(self.generator, clips, variant, spec, seed=seed, trial=0, sampling=self.job.sampling)
        steps = 4 + (1 if songs else 0)
        bar = tqdm(total=steps, desc="style benchmark", disable=not self.progress)

        def stage(name: str) -> None:
            bar.set_postfix_str(name)

        stage(f"{len(clips)} held-out clips in their genre")
        gt = judge.predict(_to_joints([torch.from_numpy(np.asarray(c.motion)) for c in clips]))
        dances = self._sample(requests, beats)
        bar.update()
        result: dict[str, Any] = {
            "checkpoint": self.checkpoint,
            "data_root": str(self.data_root),
            "sampling": dataclasses.asdict(self.job.sampling),
            # how free text was read (generate.py's style_text_reading, _temperature and _descriptions)
            "text_reading": dataclasses.asdict(self.generator.text_choice),
            "heldout_descriptions": self.heldout_files[0].name,
            "genres": list(self.vocab.codes),
            "n_clips": len(clips),
            "gt_acc": accuracy(genres, gt),
            "train_speed_by_genre": {self.vocab.codes[g]: v for g, v in train_speed.items()},
            "finished": None,
        }
        for name, joints in dances.items():
            predicted = judge.predict(joints)
            speeds = [mean_joint_speed(j, self.fps) for j in joints]
            ratios = speed_ratios(speeds, genres, train_speed)
            result[name] = {
                "genre_acc": accuracy(genres, predicted),
                "confusion": confusion_matrix(genres, predicted, len(self.vocab)).tolist(),
                "speed_ratio": {self.vocab.codes[g]: r for g, r in ratios.items()},
                "genre_speed_within": sum(within(r) for r in ratios.values()),
                "speed_spearman": speed_rank_correlation(speeds, genres, train_speed),
            }

        stage("held-out descriptions")
        if self.generator.embedder().kind not in ("genre", "prompt"):  # one-hot: genre codes only, no free text
            for name in dances:
                result[name].update(
                    text_acc=math.nan, text_acc_named=math.nan, text_acc_unnamed=math.nan, modifiers_right=math.nan
                )
        else:
            self._free_text(result, requests, genres, beats, judge)
            stage("modifier pairs")
            self._modifiers(result, requests, genres, beats, clips)
            if self.attribute_pairs is not None:
                stage("attribute pairs")
                result["attribute_wordings"] = self.attribute_file.name
                self._attributes(result, requests, genres, beats, clips, judge)
        bar.update()

        stage("style schedules")
        result["schedule"] = self._schedules(test, judge)
        bar.update()
        if songs:
            stage(f"{len(songs)} real songs in every genre")
            result["real_songs"] = self._real_songs(songs, judge, song_seconds)
            bar.update()
        bar.update()
        bar.close()
        return result

    def _free_text(
        self, result: dict[str, Any], requests: list[Any], genres: list[int], beats: list[Any], judge: Judge
    ) -> None:
        """The held-out clips asked with the descriptions of each held-out list, of their genres in turn: per list
        (``text_by_list``), and the first list's as ``text_acc``."""
        for i, path in enumerate(self.heldout_files):
            texts = self._heldout_texts(path)
            text_requests, named = [], []
            for k, (request, genre) in enumerate(zip(requests, genres)):
                options = texts[genre]
                pick = k % len(options)
                style = self.generator.embed_style(f"text: {options[pick]}")
                text_requests.append(dataclasses.replace(request, style=style))
                named.append(pick < NAMED_FIRST.get(path.stem, 2))  # those that name the genre come first
            text_dances = self._sample(text_requests, beats)
            named_arr, genres_arr = np.asarray(named), np.asarray(genres)
            for name, joints in text_dances.items():
                predicted = judge.predict(joints)
                figures = {
                    "text_acc": accuracy(genres, predicted),
                    "text_acc_named": accuracy(genres_arr[named_arr], predicted[named_arr]),
                    "text_acc_unnamed": accuracy(genres_arr[~named_arr], predicted[~named_arr]),
                }
                result[name].setdefault("text_by_list", {})[path.stem] = figures
                if i == 0:
                    result[name].update(figures)

    @staticmethod
    def _chosen_clips(genres: list[int], clips: list[Any]) -> dict[int, dict[str, int]]:
        """genre -> the first clip (its index) of each of its first :data:`MODIFIER_SONGS` held-out dances."""
        chosen: dict[int, dict[str, int]] = {}
        for k, (g, clip) in enumerate(zip(genres, clips)):
            dances = chosen.setdefault(g, {})
            if clip.seq.name not in dances and len(dances) < MODIFIER_SONGS:
                dances[clip.seq.name] = k
        return chosen

    def _modifiers(
        self, result: dict[str, Any], requests: list[Any], genres: list[int], beats: list[Any], clips: list[Any]
    ) -> None:
        """Each genre's first clip of each of its first :data:`MODIFIER_SONGS` held-out dances, asked with each of
        :data:`MODIFIER_PAIRS`, one seed: the fraction of pairs whose faster-worded dance moves faster, and each
        pair's speeds."""
        chosen = self._chosen_clips(genres, clips)
        pair_requests, pair_beats, rows = [], [], []
        for g, k in sorted((g, k) for g, dances in chosen.items() for k in dances.values()):
            name = self.vocab.names[g].lower()
            for slow, fast in MODIFIER_PAIRS:
                texts = (slow.format(genre=name), fast.format(genre=name))
                for text in texts:
                    pair_requests.append(
                        dataclasses.replace(requests[k], style=self.generator.embed_style(f"text: {text}"))
                    )
                    pair_beats.append(beats[k])
                rows.append({"genre": self.vocab.codes[g], "dance": clips[k].seq.name, "slower": texts[0],
                             "faster": texts[1]})  # fmt: skip
        dances = self._sample(pair_requests, pair_beats)
        for name, joints in dances.items():
            speeds = [mean_joint_speed(j, self.fps) for j in joints]
            slower, faster = speeds[0::2], speeds[1::2]
            result[name]["modifiers_right"] = ordered_right(slower, faster)
            result[name]["modifier_pairs"] = [
                {**row, "slower_m_s": a, "faster_m_s": b} for row, a, b in zip(rows, slower, faster, strict=True)
            ]

    def _attributes(
        self,
        result: dict[str, Any],
        requests: list[Any],
        genres: list[int],
        beats: list[Any],
        clips: list[Any],
        judge: Judge,
    ) -> None:
        """Every pair of held-out attribute wordings, with every genre's name, danced on one of the genre's modifier
        clips (the pairs in turn), one seed for both: per attribute the fraction of pairs whose dance asked for
        more measures more, the genre accuracy of its dances, and each pair's measured values."""
        chosen = {g: list(dances.values()) for g, dances in self._chosen_clips(genres, clips).items()}
        pair_requests, pair_beats, rows = [], [], []
        for attribute, pairs in self.attribute_pairs.items():
            for i, (less, more) in enumerate(pairs):
                for g in sorted(chosen):
                    k = chosen[g][i % len(chosen[g])]
                    name = self.vocab.names[g].lower()
                    texts = (less.format(genre=name), more.format(genre=name))
                    for text in texts:
                        style = self.generator.embed_style(f"text: {text}")
                        pair_requests.append(dataclasses.replace(requests[k], style=style))
                        pair_beats.append(beats[k])
                    rows.append({"attribute": attribute, "genre": g, "dance": clips[k].seq.name, "less": texts[0],
                                 "more": texts[1]})  # fmt: skip
        floor_m = float(self.generator.model.floor_height)
        dances = self._sample(pair_requests, pair_beats)
        for variant, joints in dances.items():
            seen = judge.predict(joints)
            measured = [movement_attributes(j, SMPL24, self.fps, floor_m, ATTRIBUTE_NAMES) for j in joints]
            right, genre_acc, out_rows = {}, {}, []
            for attribute in self.attribute_pairs:
                picks = [r for r, row in enumerate(rows) if row["attribute"] == attribute]
                lower = [measured[2 * r][attribute] for r in picks]
                higher = [measured[2 * r + 1][attribute] for r in picks]
                asked = [rows[r]["genre"] for r in picks for _ in (0, 1)]
                got = [int(seen[2 * r + side]) for r in picks for side in (0, 1)]
                figures = attribute_figures(lower, higher, asked, got)
                right[attribute], genre_acc[attribute] = figures["right"], figures["genre_acc"]
                out_rows += [
                    {**rows[r], "genre": self.vocab.codes[rows[r]["genre"]], "less_value": a, "more_value": b}
                    for r, a, b in zip(picks, lower, higher, strict=True)
                ]
            result[variant].update(
                attributes_right=right,
                attribute_genre_acc=accuracy([row["genre"] for row in rows for _ in (0, 1)], seen),
                attribute_genre_acc_by_attribute=genre_acc,
                attribute_pairs=out_rows,
            )

    def _train_speeds(self, train: list[Any]) -> dict[int, float]:
        """Mean joint speed over every frame of each genre's training dances."""
        from dgsdp.evaluation.features import motion_to_joints

        total: dict[int, float] = {}
        frames: dict[int, int] = {}
        for seq in train:
            joints = motion_to_joints(seq.motion)
            n = len(joints) - 1
            total[seq.genre_index] = total.get(seq.genre_index, 0.0) + mean_joint_speed(joints, self.fps) * n
            frames[seq.genre_index] = frames.get(seq.genre_index, 0) + n
        return {g: total[g] / frames[g] for g in sorted(total) if frames[g] > 0}

    def _heldout_texts(self, path: Path) -> list[list[str]]:
        from dgsdp.style.embeddings import load_prompts

        return load_prompts(path, self.vocab)

    def _schedules(self, test: list[Any], judge: Judge) -> dict[str, Any]:
        """Each of the first half of the genres followed by the genre half the vocabulary away, 10 s each, on the
        held-out songs in turn (looped to 20 s where shorter); raw and finished."""
        import tempfile

        from dgsdp.data.aistpp import music_path

        n = len(self.vocab)
        span = SCHEDULE_SPAN_SECONDS
        blend = self.job.settings.blend_seconds
        paths = list(dict.fromkeys(music_path(self.data_root, seq.music_id) for seq in test))
        if not paths:
            return {"error": "no held-out songs"}
        with tempfile.TemporaryDirectory(prefix="dgsdp-style-") as tmp:
            songs = [_looped(path, 2 * span, Path(tmp)) for path in paths]
            return self._schedule_rows(songs, judge, n, span, blend)

    def _schedule_rows(self, songs: list[Path], judge: Judge, n: int, span: float, blend: float) -> dict[str, Any]:
        rows = []
        for k in range(max(1, n // 2)):
            first, second = k, (k + n // 2) % n
            a, b = self.vocab.codes[first], self.vocab.codes[second]
            song = songs[k % len(songs)]
            dance = self.generator.dance_to_song(
                song, f"0-{span:g}: {a}; {span:g}-{2 * span:g}: {b}", seconds=2 * span, blend_seconds=blend,
                sampling=self.job.sampling, seed=self.job.settings.seed,
                cleanup=self.job.settings.finishing.floor(), beat_sync=self.job.settings.finishing.beat_sync(),
            )  # fmt: skip
            row: dict[str, Any] = {"song": song.name, "first": a, "second": b}
            for name, motion in (("raw", dance.raw), ("finished", dance.motion)):
                joints = _to_joints([motion], self.generator.skeleton)[0]
                first_windows = judge.windows(joints, 0.0, span - blend / 2)
                second_windows = judge.windows(joints, span + blend / 2, 2 * span)
                grid = BLEND_GRID_FRAMES
                short_n = int(round(BLEND_WINDOW_SECONDS * self.fps))
                short = [joints[s : s + short_n] for s in range(0, len(joints) - short_n + 1, grid)]
                labels = judge.predict(short, short=True)
                row[name] = {
                    "first_acc": accuracy([first] * len(first_windows), judge.predict(first_windows)),
                    "second_acc": accuracy([second] * len(second_windows), judge.predict(second_windows)),
                    "switch_frames": switch_frames(labels, first, second, grid),
                }
            rows.append(row)
        summary = {}
        for name in VARIANTS:
            switches = [r[name]["switch_frames"] for r in rows]
            settled = [s for s in switches if s is not None]
            summary[name] = {
                "first_acc": float(np.mean([r[name]["first_acc"] for r in rows])),
                "second_acc": float(np.mean([r[name]["second_acc"] for r in rows])),
                "switch_frames_median": float(np.median(settled)) if settled else None,
                "switched": len(settled),
            }
        return {"span_seconds": span, "blend_seconds": blend, "rows": rows, "summary": summary}

    def _real_songs(self, songs: Sequence[Path], judge: Judge, seconds: float) -> dict[str, Any]:
        """Every song in every genre, its first ``seconds``; each dance's 5 s windows classified."""
        per_genre: dict[str, dict[str, list[int]]] = {v: {} for v in VARIANTS}
        errors = []
        total = len(songs) * len(self.vocab)
        bar = tqdm(total=total, desc="real songs x genres", disable=not self.progress, leave=False)
        for song in songs:
            for g, code in enumerate(self.vocab.codes):
                try:
                    dance = self.generator.dance_to_song(
                        song, code, seconds=seconds, sampling=self.job.sampling, seed=self.job.settings.seed,
                        cleanup=self.job.settings.finishing.floor(), beat_sync=self.job.settings.finishing.beat_sync(),
                    )  # fmt: skip
                except DgsdpError as e:
                    errors.append(f"{song.name} ({code}): {e}")
                    for name in VARIANTS:
                        per_genre[name].setdefault(code, []).append(0)  # an error is a miss
                    bar.update()
                    continue
                for name, motion in (("raw", dance.raw), ("finished", dance.motion)):
                    joints = _to_joints([motion], self.generator.skeleton)[0]
                    windows = judge.windows(joints, 0.0, len(joints) / self.fps) or [joints]
                    predicted = judge.predict(windows)
                    per_genre[name].setdefault(code, []).extend(int(p == g) for p in predicted)
                bar.update()
        bar.close()
        out: dict[str, Any] = {"songs": [s.name for s in songs], "seconds": seconds, "errors": errors}
        for name in VARIANTS:
            hits = [h for v in per_genre[name].values() for h in v]
            out[name] = {
                "acc": float(np.mean(hits)) if hits else math.nan,
                "by_genre": {code: float(np.mean(v)) for code, v in per_genre[name].items()},
            }
        return out


def _looped(path: Path, seconds: float, folder: Path) -> Path:
    """``path`` itself when it lasts ``seconds``, else a copy played over and over up to ``seconds`` in ``folder``
    (same file name, so an AIST++ music id in it still names the tempo)."""
    import soundfile

    from dgsdp.audio.io import load_audio

    audio, rate = load_audio(path, None)
    if len(audio) >= seconds * rate:
        return path
    repeats = math.ceil(seconds * rate / max(len(audio), 1))
    out = folder / f"{path.stem}.wav"
    soundfile.write(out, np.tile(audio, repeats)[: int(math.ceil(seconds * rate))], rate)
    return out


# --- report ---------------------------------------------------------------------------------------------------------
_ATTRIBUTE_ENDS = {"level": "crouched / upright", "arms": "arms down / raised", "travel": "on the spot / across the floor",
                   "turning": "facing ahead / turning"}  # fmt: skip


def _pct(x: float | None) -> str:
    return "n/a" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{x:.2f}"


def report_lines(result: dict[str, Any]) -> list[str]:
    """The printed report of one checkpoint (everything but the last line)."""
    codes = result["genres"]
    raw, fin = result["raw"], result["finished"] or {}  # no finished figures with --raw-only

    def both(key: str) -> str:
        return f"{_pct(raw.get(key)):>8s}{_pct(fin.get(key)):>10s}"

    def count(figures: dict[str, Any]) -> str:
        return f"{figures['genre_speed_within']}/{len(figures['speed_ratio'])}" if figures else "n/a"

    def ratio(figures: dict[str, Any], code: str) -> str:
        value = (figures.get("speed_ratio") or {}).get(code)
        return "n/a" if value is None else f"{value:.2f}"

    lines = [
        f"checkpoint {result['checkpoint']}: {result['n_clips']} held-out 5 s clips of {result['data_root']}; "
        f"sampling {result['sampling']['method']}-{result['sampling']['steps']} "
        f"guidance music={result['sampling']['guidance']['music']:g} style={result['sampling']['guidance']['style']:g}",
        f"{'':28s}{'raw':>8s}{'finished':>10s}",
        f"{'genre accuracy':28s}{both('genre_acc')}   (ground truth {_pct(result['gt_acc'])})",
        f"{'free text (held out)':28s}{both('text_acc')}   ({result['heldout_descriptions']})",
        f"{'  naming the genre':28s}{both('text_acc_named')}",
        f"{'  movement only':28s}{both('text_acc_unnamed')}",
        *(
            f"{'free text, ' + stem:28s}{_pct(figures['text_acc']):>8s}"
            f"{_pct(((fin.get('text_by_list') or {}).get(stem) or {}).get('text_acc')):>10s}"
            for stem, figures in list((raw.get("text_by_list") or {}).items())[1:]
        ),
        f"{'genres within 30% of speed':28s}{count(raw):>8s}{count(fin):>10s}",
        f"{'speed rank correlation':28s}{both('speed_spearman')}   (Spearman, genres' training speed vs danced)",
        f"{'modifier pairs right':28s}{both('modifiers_right')}   (slow/fast, gentle/explosive: faster word faster)",
        *(
            f"{'attribute pairs right, ' + name:28s}{_pct(value):>8s}"
            f"{_pct((fin.get('attributes_right') or {}).get(name)):>10s}   ({_ATTRIBUTE_ENDS[name]})"
            for name, value in (raw.get("attributes_right") or {}).items()
        ),
        *(
            [f"{'genre acc., attribute words':28s}{both('attribute_genre_acc')}   ({result['attribute_wordings']})"]
            if raw.get("attributes_right")
            else []
        ),
        "speed over the genre's own training dances (raw/finished): "
        + "  ".join(f"{c} {ratio(raw, c)}/{ratio(fin, c)}" for c in codes),
    ]
    for name in VARIANTS:
        if not result[name]:
            continue
        lines.append(f"confusion matrix, {name} (rows: genre asked; columns: genre seen)")
        lines.append("      " + "".join(f"{c:>4s}" for c in codes))
        for c, row in zip(codes, result[name]["confusion"]):
            lines.append(f"  {c:>3s} " + "".join(f"{v:>4d}" for v in row))
    sched = result.get("schedule", {})
    if "summary" in sched:
        for name in VARIANTS:
            s = sched["summary"][name]
            lines.append(
                f"schedule ({len(sched['rows'])} pairs, {sched['span_seconds']:g} s each, blend "
                f"{sched['blend_seconds']:g} s), {name}: first span {_pct(s['first_acc'])}, second span "
                f"{_pct(s['second_acc'])}, switched {s['switched']}/{len(sched['rows'])}, median switch "
                f"{'n/a' if s['switch_frames_median'] is None else format(s['switch_frames_median'], 'g')} frames"
            )
    elif sched:
        lines.append(f"schedule: {sched.get('error')}")
    real = result.get("real_songs")
    if real:
        lines.append(
            f"real songs ({len(real['songs'])} songs x {len(codes)} genres, first {real['seconds']:g} s): "
            f"accuracy raw {_pct(real['raw']['acc'])}, finished {_pct(real['finished']['acc'])}"
            + (f"; {len(real['errors'])} errors (counted as misses)" if real["errors"] else "")
        )
        lines.append(
            "  by genre (raw/finished): "
            + "  ".join(f"{c} {_pct(real['raw']['by_genre'].get(c))}/{_pct(real['finished']['by_genre'].get(c))}"
                        for c in codes)
        )  # fmt: skip
    return lines


def last_line(results: Sequence[dict[str, Any]]) -> str:
    """``style_acc=... text_acc=... genre_speed_within_30pct=n/10 speed_spearman=... modifiers=... gt_acc=...`` of
    the raw model (means over the checkpoints; the genre count rounded down), then, where the attribute pairs were
    measured, ``level=... arms=... travel=... turning=... attribute_genre_acc=...``."""
    raw = [r["raw"] for r in results]
    n_genres = len(results[0]["genres"])
    within_mean = float(np.mean([r["genre_speed_within"] for r in raw]))

    def mean(key: str) -> float:
        return float(np.mean([r.get(key, math.nan) for r in raw]))

    line = (
        f"style_acc={mean('genre_acc'):.3f} text_acc={mean('text_acc'):.3f} "
        f"genre_speed_within_30pct={math.floor(within_mean)}/{n_genres} "
        f"speed_spearman={mean('speed_spearman'):.3f} modifiers={mean('modifiers_right'):.3f} "
        f"gt_acc={np.mean([r['gt_acc'] for r in results]):.3f}"
    )
    measured = [r.get("attributes_right") or {} for r in raw]
    names = [name for name in ATTRIBUTE_NAMES if all(name in m for m in measured)]
    if names:
        line += "".join(f" {name}={np.mean([m[name] for m in measured]):.3f}" for name in names)
        line += f" attribute_genre_acc={mean('attribute_genre_acc'):.3f}"
    return line


def save_confusion_png(results: Sequence[dict[str, Any]], path: Path) -> None:
    """The raw and finished confusion matrices (summed over the checkpoints) as one png."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    codes = results[0]["genres"]
    fig, axes = plt.subplots(1, 2, figsize=(11, 5))
    for ax, name in zip(axes, VARIANTS):
        if not results[0][name]:
            ax.set_axis_off()
            continue
        matrix = np.sum([np.asarray(r[name]["confusion"]) for r in results], axis=0)
        shares = matrix / np.maximum(matrix.sum(axis=1, keepdims=True), 1)
        ax.imshow(shares, vmin=0, vmax=1, cmap="Blues")
        for i in range(len(codes)):
            for j in range(len(codes)):
                if matrix[i, j]:
                    ax.text(j, i, str(matrix[i, j]), ha="center", va="center", fontsize=7,
                            color="white" if shares[i, j] > 0.5 else "black")  # fmt: skip
        acc = np.trace(matrix) / max(matrix.sum(), 1)
        ax.set(xticks=range(len(codes)), yticks=range(len(codes)), xticklabels=codes, yticklabels=codes,
               xlabel="genre seen by the classifier", ylabel="genre asked", title=f"{name} (accuracy {acc:.2f})")  # fmt: skip
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp.png")
    fig.savefig(tmp, dpi=110)
    plt.close(fig)
    tmp.replace(path)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m dgsdp.benchmarks.style",
        description="Does the dance show the asked style? Genre accuracy (raw and finished), each genre's speed "
        "against its training dances, held-out free-text descriptions, a style schedule and, with --songs, real "
        "songs in every genre.",
    )
    parser.add_argument("--checkpoint", nargs="+", required=True, help="one or more checkpoints (e.g. one per seed)")
    parser.add_argument("--data-root", default=None, help="AIST++-layout dataset (default: the checkpoint's)")
    parser.add_argument("--songs", default=None, help="a folder of real songs: each danced in every genre")
    parser.add_argument("--song-seconds", type=float, default=10.0, help="seconds of each real song (default 10)")
    parser.add_argument("--max-clips", type=int, default=None, help="at most this many held-out clips (balanced)")
    parser.add_argument("--raw-only", action="store_true", help="quick screening: skip the finished clips")
    parser.add_argument(
        "--heldout", action="append", default=None,
        help="the held-out descriptions: a shipped list's name (aistpp, the default; aistpp_second, aistpp_third) or "
        "a yaml path; repeat it to measure several lists on the same clips",
    )  # fmt: skip
    parser.add_argument(
        "--attributes", default=None,
        help="also measure the movement attributes' held-out wording pairs: a shipped list's name (aistpp) or a yaml "
        "path (400 more dances for the 10 AIST++ genres)",
    )  # fmt: skip
    parser.add_argument("--json", default=None, help="write every figure to this JSON file")
    parser.add_argument("--png", default=None, help="write the confusion matrices to this png")
    parser.add_argument("--no-progress", action="store_true")
    parser.add_argument("overrides", nargs="*", help="generate.py settings, e.g. sampling=edge seed=1")
    args = parser.parse_args(argv)
    try:
        songs: list[Path] = []
        if args.songs:
            from dgsdp.generation import find_songs

            songs = find_songs(args.songs)
        results = []
        for checkpoint in args.checkpoint:
            bench = StyleBenchmark(
                checkpoint, args.overrides, data_root=args.data_root, max_clips=args.max_clips,
                raw_only=args.raw_only, progress=not args.no_progress, heldout=args.heldout,
                attributes=args.attributes,
            )  # fmt: skip
            result = bench.run(songs, args.song_seconds)
            print("\n".join(report_lines(result)), flush=True)
            results.append(result)
        if args.png:
            save_confusion_png(results, Path(args.png))
            print(f"confusion matrices: {args.png}")
        if args.json:
            from dgsdp.utils.io import atomic_write_text

            atomic_write_text(Path(args.json), json.dumps(results, indent=2, default=_json_default) + "\n")
        print(last_line(results), flush=True)
    except DgsdpError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    return 0


def _json_default(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")


if __name__ == "__main__":
    sys.exit(main())
