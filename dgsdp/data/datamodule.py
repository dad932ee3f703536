"""Training and evaluation windows of (motion, music, style) from an AIST++-layout dataset.

Each item is a window of ``window_seconds`` of normalised motion (pose vectors of the data's skeleton, SMPL-24's
151-d for AIST++) at 30 FPS with the music for the same
frames (encoder features, or the raw waveform), the genre index and the music id. Processed motion and audio
features are cached on disk per file content and settings (see :class:`dgsdp.utils.io.DiskCache`), so a second run
does no processing and a changed setting never reuses stale data.
"""

from __future__ import annotations

import functools
import logging
import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import lightning as L
import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset, Sampler
from tqdm.auto import tqdm

from dgsdp.audio import AudioEncoder, FeatureCache, load_audio
from dgsdp.audio.tempo import training_tempo_range
from dgsdp.data.aistpp import check_root, load_motion_pkl, music_path, parse_name, process_motion, read_split
from dgsdp.data.device import AUTO_LIMIT_BYTES, DeviceLoader, DeviceWindows, check_on_device, host_only_reason
from dgsdp.errors import ConfigError, DataError, DgsdpError
from dgsdp.metrics.attributes import RATE_MEASURES, movement_series
from dgsdp.metrics.speed import SPEED_QUANTILES
from dgsdp.motion import MinMaxNormalizer, Skeleton, measure_floor_height, skeleton_from_config
from dgsdp.motion.representation import CONTACT_CHANNELS
from dgsdp.style.vocab import AISTPP_GENRES, GenreVocab
from dgsdp.utils.io import DiskCache, file_hash

log = logging.getLogger(__name__)

MOTION_CACHE_VERSION = 1


def window_starts(n_frames: int, length: int, stride: int) -> list[int]:
    """Start frames of every window of ``length`` frames lying wholly inside ``n_frames``, ``stride`` apart."""
    if length <= 0 or stride <= 0:
        raise ValueError(f"window length and stride must be positive, got {length} and {stride}")
    if n_frames < length:
        return []
    return list(range(0, n_frames - length + 1, stride))


@dataclass
class Sequence:
    """One processed dance: motion (T, D) unnormalised, z-up (D: the skeleton's pose size), and its music."""

    name: str
    genre: str
    genre_index: int
    music_id: str
    motion: np.ndarray
    audio: np.ndarray | None  # (T_audio, D) features at 30 FPS, or (samples,) waveform, or None
    # each movement channel's series (dgsdp.metrics.attributes: (T-1,) per step or (T,) per frame), in the model's
    # channels' order; with ``movement_channels``
    movement: dict[str, np.ndarray] | None = None


@dataclass(frozen=True)
class SourceItem:
    """One dance to read: its motion file, how that file becomes pose vectors, and its music (a function, so
    that a missing song is reported as this item's error like a bad motion file)."""

    name: str
    genre: str
    genre_index: int
    music_id: str
    motion_file: Path
    read_motion: Callable[[Path], np.ndarray]
    music_file: Callable[[], Path]


def read_sequences(
    items: list[SourceItem],
    *,
    split: str,
    root: Path,
    cache_dir: str | Path,
    motion_namespace: str,
    audio_encoder: AudioEncoder | None = None,
    waveform_sample_rate: int | None = None,
    progress: bool = True,
    errors: list[tuple[str, str]] | None = None,
) -> list[Sequence]:
    """Process (cached per motion file content under ``cache_dir/motion_namespace``; the namespace names every
    setting the processing depends on) and pair each item with its music: the
    encoder's features (cached per song) or the waveform. The loop behind every dataset layout.

    A sequence whose motion or music file cannot be read does not stop the others: with ``errors`` given, each
    such file's ``(name, message)`` is appended to it and the sequence is left out; without it, one DataError
    listing every bad file is raised after all files were tried."""
    motion_cache = DiskCache(cache_dir, motion_namespace)
    feature_cache = FeatureCache(cache_dir) if audio_encoder is not None else None
    sequences: list[Sequence] = []
    failed: list[tuple[str, str]] = []
    kinds: set[type[DgsdpError]] = set()
    for item in tqdm(items, desc=f"loading {split} ({root.name})", disable=not progress, leave=False):

        def compute(item: SourceItem = item) -> dict[str, np.ndarray]:
            return {"motion": item.read_motion(item.motion_file)}

        try:
            motion = motion_cache.get_or_compute(file_hash(item.motion_file), compute, required=("motion",))
            audio: np.ndarray | None = None
            if audio_encoder is not None:
                audio = feature_cache.features_for_file(audio_encoder, item.music_file(), music_id=item.music_id)
            elif waveform_sample_rate is not None:
                audio, _ = load_audio(item.music_file(), waveform_sample_rate)
        except DgsdpError as e:  # DataError, AudioError: this file is bad, the others may be fine
            failed.append((item.name, str(e).rstrip(".")))
            kinds.add(type(e))
            continue
        sequences.append(Sequence(item.name, item.genre, item.genre_index, item.music_id, motion["motion"], audio))
    if failed:
        for name, message in failed:
            log.error("split %r: %s left out: %s", split, name, message)
        if errors is not None:
            errors.extend(failed)
        else:
            listing = "; ".join(f"{name}: {message}" for name, message in failed)
            error = kinds.pop() if len(kinds) == 1 else DataError  # e.g. AudioError when only songs are bad
            raise error(
                f"{len(failed)} of {len(items)} sequences of split {split!r} in {root} cannot be read: {listing}. "
                "Fix or remove these files (or add their names to the ignore list)"
            )
    return sequences


def load_sequences(
    root: str | Path,
    split: str,
    *,
    fps: int = 30,
    cache_dir: str | Path,
    audio_encoder: AudioEncoder | None = None,
    waveform_sample_rate: int | None = None,
    vocab: GenreVocab = AISTPP_GENRES,
    max_sequences: int | None = None,
    progress: bool = True,
    errors: list[tuple[str, str]] | None = None,
) -> list[Sequence]:
    """Read, process (cached) and pair each sequence of an AIST++-layout split with its music
    (:func:`read_sequences`; ``errors`` as there)."""
    root = check_root(root)
    items = []
    for name in read_split(root, split)[:max_sequences]:
        parsed = parse_name(name)

        def read_motion(pkl: Path) -> np.ndarray:
            poses, trans_m = load_motion_pkl(pkl)
            return process_motion(poses, trans_m, fps=fps)

        items.append(
            SourceItem(
                name,
                parsed.genre,
                vocab.index(parsed.genre),
                parsed.music_id,
                root / "motions" / f"{name}.pkl",
                read_motion,
                functools.partial(music_path, root, parsed.music_id),
            )  # fmt: skip
        )
    return read_sequences(
        items, split=split, root=root, cache_dir=cache_dir, motion_namespace=f"motion-v{MOTION_CACHE_VERSION}-{fps}fps",
        audio_encoder=audio_encoder, waveform_sample_rate=waveform_sample_rate, progress=progress, errors=errors,
    )  # fmt: skip


def count_short(sequences: list[Sequence], length: int) -> int:
    """How many sequences are shorter than one window of ``length`` frames (they give no window)."""
    return sum(len(seq.motion) < length for seq in sequences)


def _same_path(a: Path, b: Path) -> bool:
    return a.expanduser().resolve() == b.expanduser().resolve()


def check_tempo_augment(value: Any, has_features: bool) -> tuple[float, float] | None:
    """``data.tempo_augment`` as (lo, hi) with 0 < lo <= hi, or None; ConfigError otherwise, and where the windows
    carry no frame-rate music features to stretch with the motion (raw waveforms, or no music)."""
    if value is None:
        return None
    try:
        lo, hi = (float(v) for v in value)
    except (TypeError, ValueError):
        raise ConfigError(
            f"data.tempo_augment must be two rates [lo, hi] (e.g. [0.8, 1.25]) or null, got {value!r}"
        ) from None
    if not (0 < lo <= hi) or not math.isfinite(hi):
        raise ConfigError(f"data.tempo_augment=[{lo:g}, {hi:g}] needs 0 < lo <= hi (1 is the recorded tempo)")
    if not has_features:
        raise ConfigError(
            "data.tempo_augment stretches the music features with the motion; it needs an audio encoder that gives "
            "features per frame (audio=librosa, jukebox or encodec), not raw waveforms or no music"
        )
    return lo, hi


class WindowDataset(Dataset):
    """Fixed-length windows over a list of sequences; motion normalised by ``normalizer``. With ``tempo_range``
    (training, ``data.tempo_augment``) each window is played at a random tempo (:meth:`_stretched`)."""

    def __init__(
        self,
        sequences: list[Sequence],
        normalizer: MinMaxNormalizer,
        *,
        length: int,
        stride: int,
        fps: int = 30,
        waveform_sample_rate: int | None = None,
        tempo_range: tuple[float, float] | None = None,
    ) -> None:
        self.sequences = sequences
        self.tempo_range = tempo_range
        self.normalizer = normalizer
        self.length = length
        self.fps = fps
        self.waveform_sample_rate = waveform_sample_rate
        self.index = [(i, s) for i, seq in enumerate(sequences) for s in window_starts(len(seq.motion), length, stride)]

    def __len__(self) -> int:
        return len(self.index)

    def _audio_window(self, audio: np.ndarray, start: int) -> np.ndarray:
        if self.waveform_sample_rate is not None:
            per_frame = self.waveform_sample_rate / self.fps
            a, n = int(round(start * per_frame)), int(round(self.length * per_frame))
            chunk = audio[a : a + n]
            return np.pad(chunk, (0, n - len(chunk)))
        chunk = audio[start : start + self.length]
        if len(chunk) == 0:
            raise DataError("the music is shorter than the motion start; check the dataset's wavs")
        if len(chunk) < self.length:  # song shorter than the dance: hold the last feature frame
            chunk = np.concatenate([chunk, np.repeat(chunk[-1:], self.length - len(chunk), axis=0)])
        return chunk

    def __getitem__(self, i: int) -> dict[str, Any]:
        seq_i, start = self.index[i]
        seq = self.sequences[seq_i]
        audio, rate = None, 1.0
        if self.tempo_range is not None and seq.audio is not None and self.waveform_sample_rate is None:
            start, motion, audio, rate = self._stretched(seq, start)
        else:
            motion = torch.from_numpy(seq.motion[start : start + self.length])
        item: dict[str, Any] = {
            "motion": self.normalizer.normalize(motion),
            "genre": seq.genre_index,
            "music_id": seq.music_id,
            "name": seq.name,
            "start": start,
        }
        if seq.movement is not None:  # the window's movement values (model.movement_channels)
            item["movement"] = torch.tensor(self.window_movement(seq, start, rate), dtype=torch.float32)
        if audio is not None:
            item["audio"] = audio
        elif seq.audio is not None:
            # a copy of the window: the song's features may be a read-only memory map
            item["audio"] = torch.from_numpy(np.array(self._audio_window(seq.audio, start), dtype=np.float32))
        return item

    def window_movement(self, seq: Sequence, start: int, rate: float = 1.0) -> list[float]:
        """The movement values of the window at ``start`` played at ``rate``, one per channel of ``seq.movement``:
        the mean of each series over the window's source span, the rates (speed, travel, turning) ``rate`` times
        faster."""
        steps = max(1, math.ceil((self.length - 1) * rate))
        out = []
        for name, series in seq.movement.items():
            if name in RATE_MEASURES:
                out.append(float(series[start : start + steps].mean()) * rate)
            else:
                out.append(float(series[start : start + steps + 1].mean()))
        return out

    def _stretched(self, seq: Sequence, start: int) -> tuple[int, torch.Tensor, torch.Tensor, float]:
        """The window at ``start`` played at a random tempo: ``rate`` in ``tempo_range`` drawn log-uniformly from
        torch's generator (seeded with the run), and ``(length - 1) * rate`` source frames resampled to ``length``
        (rate 1.25: the dance and its music 25% faster). Motion and continuous feature columns are interpolated
        linearly between neighbouring frames (6D rotations too: neighbouring frames are close), the foot contacts
        rounded back to 0/1, and each binary feature column (onset peaks, beats) keeps its events, each moved to
        its nearest new frame. A window that would run past the end of its sequence starts earlier; a sequence
        too short for the rate keeps rate 1. Returns (start, motion (length, 151), features (length, F), rate)."""
        lo, hi = self.tempo_range
        rate = lo * (hi / lo) ** float(torch.rand(()))
        audio = np.asarray(seq.audio)
        n = min(len(seq.motion), len(audio))
        span = (self.length - 1) * rate
        if span > n - 1:
            rate, span = 1.0, float(self.length - 1)
        start = int(min(start, n - 1 - math.ceil(span)))
        t = start + np.arange(self.length) * rate
        i0 = np.minimum(np.floor(t).astype(np.int64), n - 1)
        i1 = np.minimum(i0 + 1, n - 1)
        w = (t - i0)[:, None]
        motion = seq.motion[i0] * (1 - w) + seq.motion[i1] * w
        motion[:, CONTACT_CHANNELS] = np.round(motion[:, CONTACT_CHANNELS])
        features = audio[i0] * (1 - w) + audio[i1] * w
        binary = np.all((audio == 0) | (audio == 1), axis=0) & np.any(audio == 1, axis=0)
        if binary.any():
            source = np.arange(start, min(n, start + math.ceil(span) + 1))
            target = np.round((source - start) / rate).astype(np.int64)
            keep = target < self.length
            for column in np.flatnonzero(binary):
                features[:, column] = 0.0
                features[target[keep & (audio[source, column] == 1)], column] = 1.0
        motion_t, features_t = (
            torch.from_numpy(motion.astype(np.float32)),
            torch.from_numpy(features.astype(np.float32)),
        )
        return start, motion_t, features_t, rate


def add_movement(
    sequences: list[Sequence], skeleton: Skeleton, fps: int, channels: tuple[str, ...], floor_m: float = 0.0
) -> None:
    """Give each sequence (that has none yet) the series of each movement channel (:mod:`dgsdp.metrics.attributes`),
    measured on its joints: the speed as the style benchmark measures it (SMPL's 24-joint layout), the level above
    the training data's floor ``floor_m``."""
    from dgsdp.motion import pose_to_joints

    for seq in sequences:
        if seq.movement is None and len(seq.motion) >= 2:
            joints = pose_to_joints(torch.from_numpy(np.asarray(seq.motion, dtype=np.float32)), skeleton).numpy()
            series = movement_series(joints, skeleton, fps, floor_m, channels)
            seq.movement = {name: values.astype(np.float32) for name, values in series.items()}


def movement_statistics(dataset: WindowDataset, n_genres: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Of each movement channel of the training windows (at their own tempo), in the sequences' channels' order:
    the quantiles 0, 0.1, ..., 1 of each genre's windows, (C, n_genres, SPEED_QUANTILES) with NaN for a genre
    without windows; the median of all windows (C,); and their 10th-to-90th percentile spread (C,)."""
    by_genre: dict[int, list[list[float]]] = {}
    channels = 0
    for seq_i, start in dataset.index:
        seq = dataset.sequences[seq_i]
        by_genre.setdefault(seq.genre_index, []).append(dataset.window_movement(seq, start))
        channels = len(seq.movement)
    out = np.full((channels, n_genres, SPEED_QUANTILES), np.nan, dtype=np.float32)
    levels = np.linspace(0.0, 1.0, SPEED_QUANTILES)
    for genre, values in by_genre.items():
        if 0 <= genre < n_genres:
            out[:, genre] = np.quantile(np.asarray(values, dtype=np.float64), levels, axis=0).T
    every = np.asarray([v for values in by_genre.values() for v in values], dtype=np.float64).reshape(-1, channels)
    if not len(every):
        return out, np.full(channels, math.nan), np.full(channels, math.nan)
    q10, q90 = np.quantile(every, [0.1, 0.9], axis=0)
    return out, np.median(every, axis=0), q90 - q10


def distributed_rank_world() -> tuple[int, int]:
    """(rank, world size) of this process: from ``torch.distributed`` once initialised, else (0, 1)."""
    if torch.distributed.is_available() and torch.distributed.is_initialized():
        return torch.distributed.get_rank(), torch.distributed.get_world_size()
    return 0, 1


class EpochShuffleSampler(Sampler[int]):
    """This rank's share of a shuffle whose order depends only on (seed, epoch).

    A resumed run therefore sees the same batches as an uninterrupted one (Lightning calls ``set_epoch`` at the
    start of every epoch), on every rank. Under data parallelism (``world_size`` processes; read from
    ``torch.distributed`` when not given) every rank draws the same permutation of the ``length`` items and takes
    every ``world_size``-th item from position ``rank``, so the ranks' shards are disjoint. The permutation is
    cut to ``world_size * (length // world_size)`` items first, so every rank has the same number of items and
    of batches (DDP needs that); the few items cut (fewer than ``world_size``) differ from epoch to epoch.
    With the loader's ``drop_last``, an epoch serves each item of a prefix of the permutation exactly once.

    ``skip`` drops the first items of this rank's next pass (a run resumed mid-epoch).
    """

    def __init__(self, length: int, seed: int, *, rank: int | None = None, world_size: int | None = None) -> None:
        if rank is None or world_size is None:
            found_rank, found_world = distributed_rank_world()
            rank = found_rank if rank is None else rank
            world_size = found_world if world_size is None else world_size
        if not 0 <= rank < world_size:
            raise ValueError(f"rank {rank} is not in [0, {world_size})")
        if length < world_size:
            raise DataError(
                f"{length} training windows cannot be shared by {world_size} processes; use fewer devices or more data"
            )
        self.length = length
        self.seed = seed
        self.rank = rank
        self.world_size = world_size
        self.epoch = 0
        self.skip = 0

    def set_epoch(self, epoch: int) -> None:
        self.epoch = epoch

    def __len__(self) -> int:
        """Items per rank per epoch (before ``skip``)."""
        return self.length // self.world_size

    def order(self) -> list[int]:
        """The whole epoch's permutation (the same on every rank)."""
        g = torch.Generator().manual_seed(self.seed * 100_003 + self.epoch)
        return torch.randperm(self.length, generator=g).tolist()

    def __iter__(self) -> Iterator[int]:
        shard = self.order()[self.rank : len(self) * self.world_size : self.world_size]
        skip, self.skip = self.skip, 0
        return iter(shard[skip:])


class ResumableLoader(DataLoader):
    """A DataLoader over an :class:`EpochShuffleSampler` that Lightning can checkpoint mid-epoch: its state is the
    number of batches already served this epoch (the same on every rank), which a resumed run skips.

    Keep Lightning from replacing the sampler (``Trainer(use_distributed_sampler=False)``, as in
    ``conf/trainer/default.yaml``): the sampler shards the data across ranks itself, and a
    ``DistributedSampler`` wrapped around it would split an order already shortened by a resume a second time.
    """

    def __init__(
        self,
        dataset: Dataset,
        *,
        batch_size: int,
        seed: int,
        rank: int | None = None,
        world_size: int | None = None,
        **kwargs: Any,
    ) -> None:
        if "sampler" in kwargs or "shuffle" in kwargs:
            raise ConfigError(
                "the training loader shards the data across processes itself and cannot take another sampler: "
                "keep trainer.use_distributed_sampler=false (conf/trainer/default.yaml)"
            )
        sampler = EpochShuffleSampler(len(dataset), seed, rank=rank, world_size=world_size)
        if "drop_last" not in kwargs:  # full batches only, unless a rank's share is smaller than one batch
            kwargs["drop_last"] = len(sampler) > batch_size
        super().__init__(dataset, batch_size=batch_size, sampler=sampler, **kwargs)
        self.served = 0

    def __iter__(self) -> Iterator[Any]:
        self.served = self.sampler.skip // self.batch_size
        for batch in super().__iter__():
            self.served += 1
            yield batch

    def state_dict(self) -> dict[str, int]:
        return {"served": self.served}

    def load_state_dict(self, state: dict[str, int]) -> None:
        self.sampler.skip = int(state.get("served", 0)) * self.batch_size


class DanceDataModule(L.LightningDataModule):
    """Windows of AIST++-layout data for training (stride 0.5 s) and validation/testing (stride 2.5 s).

    ``num_workers`` loader processes (kept alive across epochs with ``persistent_workers``) and ``pin_memory``
    (page-locked batches, for asynchronous copies to a GPU) are the data-loading speed settings of the host loader.
    ``on_device`` (auto, true, false) keeps the windows on the training device instead and cuts each batch there
    (:mod:`dgsdp.data.device`; the same batches to the last bit): auto does so on a GPU when the sequences take at
    most 2 GiB and need no host processing per window (no tempo augmentation, no raw waveforms). Under the
    trainer's ``overfit_batches`` the training windows come in order, as the validation windows do, from either
    loader: every epoch, and every process, trains on the same first batches.
    ``audio_encoder`` None with ``waveform_sample_rate`` set yields raw waveform windows; both None yields motion
    only. If ``root`` has no dataset and ``synthetic`` is set, the synthetic dataset is generated there first, but
    only when asked: ``root`` is the synthetic dataset's own folder (``synthetic_root``) or ``generate_synthetic``
    is true. A mistyped ``data.root`` is an error, not a new dataset.
    The normaliser is fitted on every frame of the training sequences. ``skeleton`` names the motion's skeleton
    (:func:`dgsdp.motion.skeleton_from_config`; SMPL-X ones read ``smplx_file``), recorded in the run spec.
    """

    # the skeletons this data comes in (data.skeleton must be one): AIST++ pickles hold SMPL's 24 joints
    skeletons: tuple[str, ...] = ("smpl24",)

    def __init__(
        self,
        root: str,
        cache_dir: str,
        *,
        audio_encoder: AudioEncoder | None = None,
        waveform_sample_rate: int | None = None,
        fps: int = 30,
        window_seconds: float = 5.0,
        train_stride_seconds: float = 0.5,
        test_stride_seconds: float = 2.5,
        train_split: str = "train",
        val_split: str = "test",
        test_split: str = "test",
        batch_size: int = 64,
        num_workers: int = 0,
        pin_memory: bool = False,
        persistent_workers: bool = True,
        max_sequences: int | None = None,
        synthetic: dict[str, Any] | None = None,
        vocab: GenreVocab | str = AISTPP_GENRES,
        progress: bool = True,
        shuffle_seed: int = 0,
        synthetic_root: str | None = None,
        generate_synthetic: bool = False,
        tempo_augment: tuple[float, float] | None = None,
        skeleton: str = "smpl24",
        smplx_file: str | None = None,
        movement_channels: tuple[str, ...] | list[str] = (),
        on_device: str | bool = "auto",
    ) -> None:
        super().__init__()
        self.on_device = check_on_device(on_device)
        self._device_windows: dict[str, Any] = {}  # DeviceWindows by split name, built by the first loader
        self.skeleton = skeleton_from_config(skeleton, smplx_file, option="data.smplx_file")
        # each window's movement values in its batch, for a model conditioned on them (train.py passes the model's
        # channels, dgsdp.style.movement); the training windows' values per genre are measured in setup()
        self.movement_channels = tuple(movement_channels)
        self.movement_quantiles: np.ndarray | None = None  # (C, genres, SPEED_QUANTILES), in setup()
        self.movement_reference: np.ndarray | None = None  # (C,) the median window's values, in setup()
        self.movement_spread: np.ndarray | None = None  # (C,) their 10th-to-90th percentile spread, in setup()
        if self.skeleton.name not in self.skeletons:
            raise ConfigError(
                f"data.skeleton={skeleton}: {type(self).__name__} reads {' or '.join(self.skeletons)} motion "
                "(the AIST++ layout holds SMPL poses); choose a dataset recorded on that skeleton"
            )
        self.tempo_augment = check_tempo_augment(tempo_augment, has_features=audio_encoder is not None)
        self.synthetic_root = None if synthetic_root is None else Path(synthetic_root).expanduser()
        self.generate_synthetic = bool(generate_synthetic)
        self.shuffle_seed = shuffle_seed
        self.root = Path(root).expanduser()
        self.cache_dir = Path(cache_dir).expanduser()
        self.audio_encoder = audio_encoder
        self.waveform_sample_rate = waveform_sample_rate
        self.fps = fps
        self.length = int(round(window_seconds * fps))
        self.train_stride = int(round(train_stride_seconds * fps))
        self.test_stride = int(round(test_stride_seconds * fps))
        self.splits = {"train": train_split, "val": val_split, "test": test_split}
        self.batch_size = batch_size
        self.num_workers = num_workers
        self.pin_memory = pin_memory
        self.persistent_workers = persistent_workers
        self.max_sequences = max_sequences
        self.synthetic = dict(synthetic) if synthetic else None
        self.vocab = GenreVocab.named(vocab) if isinstance(vocab, str) else vocab  # a GenreVocab or a dataset's name
        self.progress = progress
        self.normalizer = MinMaxNormalizer(self.skeleton.pose_dim)
        self.floor_height: float | None = None  # z-up metres, measured on the training motions in setup()
        # (lowest, highest) BPM of the training songs from their music ids, widened by tempo_augment; in setup()
        self.tempo_range_bpm: tuple[float, float] | None = None
        self._sequences: dict[str, list[Sequence]] = {}
        self.datasets: dict[str, WindowDataset] = {}

    @property
    def audio_dim(self) -> int:
        return 0 if self.audio_encoder is None else self.audio_encoder.output_dim

    def settings(self) -> dict[str, Any]:
        """What shapes the data, for run records and cache keys."""
        return {
            "root": str(self.root),
            "fps": self.fps,
            "window_frames": self.length,
            "train_stride": self.train_stride,
            "test_stride": self.test_stride,
            "splits": self.splits,
            "audio": None if self.audio_encoder is None else self.audio_encoder.output_settings(),
        }

    def prepare_data(self) -> None:
        if self.synthetic is not None:
            from dgsdp.data.synthetic import generate_synthetic_aistpp, outdated_synthetic

            at_default = self.synthetic_root is not None and _same_path(self.root, self.synthetic_root)
            missing = not (self.root / "motions").is_dir()
            if missing and not (at_default or self.generate_synthetic):
                raise DataError(
                    f"no dataset at data.root={self.root} (no 'motions/' folder there). Check the path; to generate "
                    f"the synthetic dataset in that folder on purpose, add data.generate_synthetic=true "
                    f"(or run 'python -m dgsdp.data.synthetic --out {self.root}')"
                )
            # in its own folder, a synthetic dataset made with other settings (e.g. before data.synthetic.offbeats)
            # is made again; a dataset anywhere else is used as it is
            if missing or (at_default and outdated_synthetic(self.root, **self.synthetic)):
                log.info(
                    "%s the synthetic AIST++ dataset in %s", "generating" if missing else "regenerating", self.root
                )
                generate_synthetic_aistpp(self.root, **self.synthetic)
        check_root(self.root)

    def sequences(self, stage: str) -> list[Sequence]:
        split = self.splits[stage]
        if split not in self._sequences:
            self._sequences[split] = self.load_split(split)
        return self._sequences[split]

    def reading_options(self) -> dict[str, Any]:
        """The settings every layout's reader takes from this datamodule (cache, music features, genres, limits)."""
        return {
            "cache_dir": self.cache_dir,
            "audio_encoder": self.audio_encoder,
            "waveform_sample_rate": self.waveform_sample_rate,
            "vocab": self.vocab,
            "max_sequences": self.max_sequences,
            "progress": self.progress,
        }

    def load_split(self, split: str) -> list[Sequence]:
        """The processed sequences of one split of this dataset (subclasses read other layouts)."""
        return load_sequences(self.root, split, fps=self.fps, **self.reading_options())

    def setup(self, stage: str | None = None) -> None:
        train = self.sequences("train")
        wrong = [s.name for s in train if s.motion.shape[-1] != self.skeleton.pose_dim]
        if wrong:
            raise DataError(
                f"{len(wrong)} training sequences (e.g. {wrong[0]}) are not {self.skeleton.name} pose vectors "
                f"({self.skeleton.pose_dim} channels); check data.skeleton"
            )
        if not bool(self.normalizer.fitted):
            self.normalizer.fit(torch.from_numpy(np.concatenate([s.motion for s in train])))
        if self.floor_height is None:
            self.floor_height = measure_floor_height([s.motion for s in train], skeleton=self.skeleton)
            log.info("floor height of the training motions: %.3f m", self.floor_height)
        if self.tempo_range_bpm is None:
            self.tempo_range_bpm = training_tempo_range([s.music_id for s in train], self.tempo_augment)
        if self.movement_channels:
            for name in ("train", "val", "test"):
                add_movement(self.sequences(name), self.skeleton, self.fps, self.movement_channels, self.floor_height)
        wanted = {
            "fit": ("train", "val"),
            "validate": ("val",),
            "test": ("test",),
            None: ("train", "val", "test"),
        }
        for name in wanted.get(stage, ("train", "val", "test")):
            if name in self.datasets:
                continue
            stride = self.train_stride if name == "train" else self.test_stride
            ds = WindowDataset(
                self.sequences(name),
                self.normalizer,
                length=self.length,
                stride=stride,
                fps=self.fps,
                waveform_sample_rate=self.waveform_sample_rate if self.audio_encoder is None else None,
                tempo_range=self.tempo_augment if name == "train" else None,
            )
            short = count_short(ds.sequences, self.length)
            if short:
                log.warning(
                    "split %r: %d of %d sequences are shorter than one window (%.1f s) and are left out",
                    self.splits[name], short, len(ds.sequences), self.length / self.fps,
                )  # fmt: skip
            if len(ds) == 0:
                raise DataError(
                    f"split {self.splits[name]!r} of {self.root} has no sequence of at least "
                    f"{self.length / self.fps:.1f} s; use shorter windows (data.window_seconds)"
                )
            self.datasets[name] = ds
            if name == "train" and self.movement_channels and self.movement_quantiles is None:
                stats = movement_statistics(ds, len(self.vocab))
                self.movement_quantiles, self.movement_reference, self.movement_spread = stats

    def _windows_device(self, name: str) -> torch.device | None:
        """The device whose memory holds split ``name``'s windows (``on_device``), or None for the host loader."""
        if self.on_device == "false":
            return None
        device = torch.device("cpu") if self.trainer is None else self.trainer.strategy.root_device
        if self.on_device == "true":
            return device
        dataset = self.datasets[name]
        if device.type != "cuda" or host_only_reason(dataset) is not None:
            return None
        used = {i for i, _ in dataset.index}
        frames = sum(len(dataset.sequences[i].motion) for i in used)
        width = self.skeleton.pose_dim + self.audio_dim
        if frames * width * 4 > AUTO_LIMIT_BYTES:
            log.info("split %r: %.1f GiB of windows is too much to keep on %s; loading on the host",
                     self.splits[name], frames * width * 4 / 1024**3, device)  # fmt: skip
            return None
        return device

    def _loader(self, name: str, shuffle: bool) -> DataLoader | DeviceLoader:
        dataset = self.datasets[name]
        device = self._windows_device(name)
        if device is not None:
            windows = self._device_windows.get(name)
            if windows is None or windows.device != device:
                windows = self._device_windows[name] = DeviceWindows(dataset, device)
                log.info("split %r: %d windows kept on %s (%.1f MB)",
                         self.splits[name], len(windows), device, windows.nbytes / 1e6)  # fmt: skip
            sampler = EpochShuffleSampler(len(windows), self.shuffle_seed) if shuffle else None
            return DeviceLoader(windows, batch_size=self.batch_size, sampler=sampler)
        kwargs = {
            "num_workers": self.num_workers,
            "persistent_workers": self.persistent_workers and self.num_workers > 0,
            "pin_memory": self.pin_memory,
        }
        if shuffle:
            return ResumableLoader(dataset, batch_size=self.batch_size, seed=self.shuffle_seed, **kwargs)
        return DataLoader(dataset, batch_size=self.batch_size, shuffle=False, **kwargs)

    def overfitting(self) -> bool:
        """Whether the trainer trains on its first few batches over and over (``trainer.overfit_batches``)."""
        return self.trainer is not None and self.trainer.overfit_batches > 0

    def train_dataloader(self) -> DataLoader | DeviceLoader:
        """The training windows, shuffled anew every epoch; under ``trainer.overfit_batches`` in order, as the
        validation windows are served (host or device alike), so that every epoch trains on the same first batches.
        Lightning's own remedy, a SequentialSampler swapped into the loader, works on neither: the host loader
        shards the data itself and refuses another sampler, and the device loader has no ``dataset`` to sample."""
        return self._loader("train", shuffle=not self.overfitting())

    def val_dataloader(self) -> DataLoader:
        return self._loader("val", shuffle=False)

    def test_dataloader(self) -> DataLoader:
        return self._loader("test", shuffle=False)
