"""The clips a protocol dances to: stretches of real dances with their music and beats, and each trial's subset."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dgsdp.audio import AudioEncoder, FeatureCache
from dgsdp.data.aistpp import music_path
from dgsdp.data.datamodule import Sequence as DanceSequence
from dgsdp.data.datamodule import load_sequences, window_starts
from dgsdp.data.finedance import SPLIT_SCHEMES, is_finedance, load_finedance_sequences, wav_path
from dgsdp.data.synthetic import MANIFEST as SYNTHETIC_MANIFEST
from dgsdp.data.synthetic import music_beat_times_s, read_manifest
from dgsdp.errors import DataError
from dgsdp.evaluation.features import MODEL_FPS
from dgsdp.evaluation.protocols import ProtocolSpec
from dgsdp.evaluation.warning_log import WarningLog
from dgsdp.generation.beatsync import fed_beat_tracker
from dgsdp.metrics import music_beats_from_features
from dgsdp.motion import SMPL24, Skeleton
from dgsdp.resources import CONFIG_DIR

ALL_SPLITS = ("train", "val", "test")


def clip_seed(seed: int, trial: int, index: int) -> int:
    """The seed of the dance made for clip ``index`` (its place among the protocol's clips of its length) in
    trial ``trial``: ``generate.py seed=<this>`` on the clip's song makes the same dance."""
    return int(seed) + 1_000_003 * int(trial) + int(index)


@dataclass
class Clip:
    """A stretch of one real dance and its music: frames ``start .. start + n_frames`` at 30 FPS."""

    seq: DanceSequence
    start: int
    n_frames: int
    beats_30fps: np.ndarray  # (K,) music beat frames relative to ``start``: the tracker's, what generation uses
    index: int = 0  # place among the protocol's clips of this length (decides the clip's seed)
    music_file: Path | None = None  # the song (for encoders that compute each window's features from its audio)
    known_beats_30fps: np.ndarray | None = None  # the song's own beats where the dataset knows them (synthetic)

    @property
    def scoring_beats_30fps(self) -> np.ndarray:
        """The beats BeatAlign scores against: the song's known beats where the dataset has them (a synthetic
        dataset's ``synthetic.json``), else the tracker's (:attr:`beats_30fps`)."""
        return self.beats_30fps if self.known_beats_30fps is None else self.known_beats_30fps

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


class ClipSource:
    """Reads a protocol's splits and cuts them into clips with their beats; draws each trial's subset."""

    def __init__(
        self,
        spec: ProtocolSpec,
        *,
        data_root: str | Path,
        cache_dir: str | Path,
        audio_encoder: AudioEncoder | None,
        seed: int,
        warnings: WarningLog,
        progress: bool = True,
        skeleton: Skeleton = SMPL24,
        split_scheme: str = "genre",
    ) -> None:
        self.spec = spec
        self.skeleton = skeleton
        self.split_scheme = split_scheme  # FineDance's split scheme (genre or dancer)
        self.data_root = Path(data_root).expanduser()
        self.cache_dir = Path(cache_dir).expanduser()
        self.audio_encoder = audio_encoder
        self.seed = int(seed)
        self.warnings = warnings
        self.progress = progress
        self._beat_encoder: AudioEncoder | None = None
        self._beats: dict[str, np.ndarray] = {}
        self.finedance = is_finedance(self.data_root)
        manifest = self.data_root / SYNTHETIC_MANIFEST
        self._manifest = read_manifest(self.data_root) if manifest.is_file() else None

    @property
    def fed_beat_tracker(self) -> str | None:
        """The beat tracker whose beats the model is fed (its librosa features' beat column), or None."""
        return fed_beat_tracker(self.audio_encoder)

    @property
    def beat_source(self) -> str:
        """What BeatAlign is scored against, in words (for the results)."""
        if self._manifest is not None:
            return f"the synthetic songs' known beats ({SYNTHETIC_MANIFEST})"
        text = "librosa's beat tracker on the songs (column 34 of the 35-d librosa features): no known beats"
        if self.fed_beat_tracker not in (None, "librosa"):
            text += (
                f"; the model was fed the {self.fed_beat_tracker!r} tracker's beats (audio.beat_tracker), so it is "
                "scored against librosa's, which it was not fed"
            )
        return text

    def known_beats(self, seq: DanceSequence) -> np.ndarray | None:
        """Beat frames (K,) at 30 FPS of a sequence's music as the dataset made them (a synthetic dataset's
        ``synthetic.json``: the nearest frame to each beat time), or None where the dataset does not know them."""
        if self._manifest is None or seq.music_id not in self._manifest.get("music", {}):
            return None
        return np.unique(np.round(music_beat_times_s(self._manifest, seq.music_id) * MODEL_FPS).astype(np.int64))

    def load_split(self, split: str, with_music: bool = True) -> list[DanceSequence]:
        """Sequences of a split (with the model's music features), or [] with a warning when the dataset has no such
        split; unreadable files are one DataError listing them all."""
        bad: list[tuple[str, str]] = []
        encoder = self.audio_encoder if with_music else None
        try:
            if self.finedance:
                if split not in SPLIT_SCHEMES[self.split_scheme][1]:
                    raise DataError(f"FineDance's {self.split_scheme!r} split scheme has no split {split!r}")
                sequences = load_finedance_sequences(
                    self.data_root, split, skeleton=self.skeleton, scheme=self.split_scheme,
                    cache_dir=self.cache_dir, audio_encoder=encoder, progress=self.progress, errors=bad,
                )  # fmt: skip
            else:
                sequences = load_sequences(
                    self.data_root, split, fps=MODEL_FPS, cache_dir=self.cache_dir, audio_encoder=encoder,
                    progress=self.progress, errors=bad,
                )  # fmt: skip
        except DataError as e:  # no such split in this dataset
            self.warnings.add("data", "-", f"split {split!r} skipped: {e}")
            return []
        if bad:  # a table computed without some of its dances would not be the protocol's
            listing = "; ".join(f"{name}: {message}" for name, message in bad)
            raise DataError(
                f"{len(bad)} sequence(s) of split {split!r} in {self.data_root} cannot be read: {listing}. Fix or "
                "remove these files (or add their names to the dataset's ignore list) and evaluate again"
            )
        return sequences

    def music_beats(self, seq: DanceSequence) -> np.ndarray:
        """Beat frames (K,) at 30 FPS of a sequence's music by librosa's beat tracker: column 34 of the 35-d librosa
        features (the model's own features when they hold librosa's beats, else the librosa encoder of
        ``conf/audio/librosa.yaml``: a model fed another tracker's beats is not scored against the beats it was
        fed)."""
        if seq.music_id in self._beats:
            return self._beats[seq.music_id]
        if self.fed_beat_tracker == "librosa" and seq.audio is not None:
            feats = seq.audio
        else:
            if self._beat_encoder is None:
                from omegaconf import OmegaConf

                from dgsdp.registry import build

                node = OmegaConf.to_container(OmegaConf.load(CONFIG_DIR / "audio" / "librosa.yaml"))
                self._beat_encoder = build(node, "audio", where="audio")
            path = self.music_file(seq)
            feats = FeatureCache(self.cache_dir).features_for_file(self._beat_encoder, path, music_id=seq.music_id)
        self._beats[seq.music_id] = music_beats_from_features(feats)
        return self._beats[seq.music_id]

    def music_file(self, seq: DanceSequence) -> Path:
        """The song of a sequence: FineDance's ``music_wav/<id>.wav``, AIST++'s ``wavs/<music id>.wav``."""
        return wav_path(self.data_root, seq.music_id) if self.finedance else music_path(self.data_root, seq.music_id)

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
            beats, known = self.music_beats(seq), self.known_beats(seq)
            song = self.music_file(seq)
            for s in starts:
                rel = beats[(beats >= s) & (beats < s + n)] - s
                known_rel = None if known is None else known[(known >= s) & (known < s + n)] - s
                out.append(Clip(seq, s, n, rel, index=len(out), music_file=song, known_beats_30fps=known_rel))
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
