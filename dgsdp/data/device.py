"""Training windows kept on the training device (``data.on_device``).

A small dataset (the synthetic set is tens of MB) fits on a GPU many times over. Assembling each batch on the host
from Python items, collating it and copying it to the card costs a fixed few milliseconds per step, which on a GPU is
a large share of a small model's step. :class:`DeviceWindows` instead holds each sequence's normalised motion and
music features once, as two tensors on the device, and cuts a batch of windows out of them with one gather per
tensor. :class:`DeviceLoader` serves those batches in exactly the order, with exactly the sharding and the mid-epoch
resume state, of the host loader (:class:`~dgsdp.data.datamodule.ResumableLoader`), and every tensor of a batch is
equal to the host loader's to the last bit: the same seed trains the same weights either way.

Windows stretched to a random tempo (``data.tempo_augment``) and raw waveform windows are made on the host only.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import Any

import numpy as np
import torch
from torch.utils.data import Dataset, Sampler, SequentialSampler

from dgsdp.errors import ConfigError, DataError

ON_DEVICE_CHOICES = ("auto", "true", "false")
# data.on_device=auto keeps the windows on a GPU when their sequences take at most this much of its memory
AUTO_LIMIT_BYTES = 2 * 1024**3


def check_on_device(value: Any) -> str:
    """``data.on_device`` as one of auto/true/false (YAML may give a bool)."""
    text = str(value).lower() if isinstance(value, bool) else str(value)
    if text not in ON_DEVICE_CHOICES:
        raise ConfigError(
            f"data.on_device={value!r}: choose auto (on a GPU, when the data fits), true or false (docs/benchmarks.md)"
        )
    return text


def host_only_reason(dataset: Dataset) -> str | None:
    """Why the windows of ``dataset`` (a :class:`~dgsdp.data.datamodule.WindowDataset`) can only be made on the host,
    or None when they can be cut on the device."""
    if dataset.tempo_range is not None:
        return "windows played at a random tempo (data.tempo_augment) are resampled on the host"
    if dataset.waveform_sample_rate is not None:
        return "raw waveform windows (a waveform audio encoder) are cut on the host"
    return None


def _fitted_audio(audio: np.ndarray, frames: int, starts: list[int], name: str) -> np.ndarray:
    """A sequence's feature frames cut or padded to ``frames`` rows, the last frame held as the host windows hold it
    (a song shorter than its dance)."""
    if len(audio) == 0 or max(starts) >= len(audio):
        raise DataError(f"{name}: the music is shorter than the motion start; check the dataset's wavs")
    audio = np.asarray(audio[:frames], dtype=np.float32)
    if len(audio) < frames:
        audio = np.concatenate([audio, np.repeat(audio[-1:], frames - len(audio), axis=0)])
    return audio


class DeviceWindows:
    """Every window of a :class:`~dgsdp.data.datamodule.WindowDataset`, held as whole sequences on ``device``.

    The sequences with at least one window are concatenated once (motion normalised, features fitted to the motion's
    frames); a window is then its first frame's row in that store, and :meth:`batch` gathers ``(B, length)`` rows.
    """

    def __init__(self, dataset: Dataset, device: torch.device | str) -> None:
        reason = host_only_reason(dataset)
        if reason is not None:
            raise ConfigError(f"data.on_device=true: {reason}; set data.on_device=auto or false")
        self.device = torch.device(device)
        self.length = dataset.length
        windows: dict[int, list[int]] = {}
        for seq_i, start in dataset.index:
            windows.setdefault(seq_i, []).append(start)
        offsets: dict[int, int] = {}
        motion, audio, total = [], [], 0
        has_audio = None
        for seq_i, starts in windows.items():
            seq = dataset.sequences[seq_i]
            offsets[seq_i] = total
            motion.append(np.asarray(seq.motion, dtype=np.float32))
            if has_audio is None:
                has_audio = seq.audio is not None
            elif has_audio != (seq.audio is not None):
                raise DataError(f"{seq.name}: some sequences have music features and some do not")
            if seq.audio is not None:
                audio.append(_fitted_audio(seq.audio, len(seq.motion), starts, seq.name))
            total += len(seq.motion)
        self.motion = dataset.normalizer.normalize(torch.from_numpy(np.concatenate(motion))).to(self.device)
        self.audio = torch.from_numpy(np.concatenate(audio)).to(self.device) if has_audio else None
        index = dataset.index
        self.rows = torch.tensor([offsets[i] + s for i, s in index], dtype=torch.int64, device=self.device)
        self.genre = torch.tensor([dataset.sequences[i].genre_index for i, _ in index], device=self.device)
        self.start = torch.tensor([s for _, s in index], device=self.device)
        self.movement = None  # (N, C) each window's movement values (model.movement_channels)
        if all(dataset.sequences[i].movement is not None for i in windows):
            values = [dataset.window_movement(dataset.sequences[i], s) for i, s in index]
            self.movement = torch.tensor(values, dtype=torch.float32, device=self.device)
        self.names = [dataset.sequences[i].name for i, _ in index]
        self.music_ids = [dataset.sequences[i].music_id for i, _ in index]
        self.frames = torch.arange(self.length, device=self.device)

    def __len__(self) -> int:
        return len(self.names)

    @property
    def nbytes(self) -> int:
        """The bytes the store holds on its device."""
        tensors = [self.motion, self.audio, self.rows, self.genre, self.start, self.movement, self.frames]
        return sum(t.numel() * t.element_size() for t in tensors if t is not None)

    def batch(self, items: list[int]) -> dict[str, Any]:
        """The windows ``items`` as one batch, with the keys, dtypes and values the host loader's batch has."""
        pick = torch.tensor(items, dtype=torch.int64).to(self.device, non_blocking=True)
        frames = self.rows[pick][:, None] + self.frames  # (B, length) rows of the store
        batch: dict[str, Any] = {
            "motion": self.motion[frames],
            "genre": self.genre[pick],
            "music_id": [self.music_ids[i] for i in items],
            "name": [self.names[i] for i in items],
            "start": self.start[pick],
        }
        if self.movement is not None:
            batch["movement"] = self.movement[pick]
        if self.audio is not None:
            batch["audio"] = self.audio[frames]
        return batch


class DeviceLoader:
    """Batches of :class:`DeviceWindows`, served as :class:`~dgsdp.data.datamodule.ResumableLoader` serves the host
    windows: in the order of ``sampler`` (the datamodule's :class:`~dgsdp.data.datamodule.EpochShuffleSampler`,
    which also shards the windows across ranks) with full batches only when a rank's share holds more than one, and
    the number of batches served this epoch as the state a resumed run skips; with ``sampler`` None, every window in
    order (validation and testing, and training under ``trainer.overfit_batches``: the datamodule asks for that
    order, as it does of the host loader)."""

    def __init__(self, windows: DeviceWindows, *, batch_size: int, sampler: Sampler[int] | None = None) -> None:
        self.windows = windows
        self.batch_size = batch_size
        self.shuffled = sampler is not None
        self.sampler: Sampler[int] = sampler if sampler is not None else SequentialSampler(range(len(windows)))
        self.batch_sampler = None  # read by Lightning, as a DataLoader's
        self.drop_last = self.shuffled and len(self.sampler) > batch_size
        self.served = 0

    def __len__(self) -> int:
        n = len(self.sampler)
        return n // self.batch_size if self.drop_last else math.ceil(n / self.batch_size)

    def __iter__(self) -> Iterator[dict[str, Any]]:
        self.served = self.sampler.skip // self.batch_size if self.shuffled else 0
        order = list(self.sampler)
        for i in range(0, len(order), self.batch_size):
            items = order[i : i + self.batch_size]
            if self.drop_last and len(items) < self.batch_size:
                return
            self.served += 1
            yield self.windows.batch(items)

    def state_dict(self) -> dict[str, int]:
        return {"served": self.served}

    def load_state_dict(self, state: dict[str, int]) -> None:
        if self.shuffled:
            self.sampler.skip = int(state.get("served", 0)) * self.batch_size
