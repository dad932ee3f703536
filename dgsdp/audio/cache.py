"""On-disk cache of whole-song audio features, keyed by file content and encoder settings.

Entries live in ``<cache_dir>/<encoder name>-<settings hash>/<content hash>[-<music id part>].npz`` and are
written atomically by :class:`dgsdp.utils.io.DiskCache`, so a killed extraction never leaves a readable
partial entry. Whole songs are cached; callers slice windows by frame index.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from dgsdp.audio.base import AudioEncoder, fit_frames
from dgsdp.audio.io import audio_duration_seconds, load_audio
from dgsdp.errors import AudioError
from dgsdp.utils.io import DiskCache, file_hash, stable_hash

FEATURES_KEY = "features"


class FeatureCache:
    """Whole-song features of one or more encoders under ``cache_dir``."""

    def __init__(self, cache_dir: str | os.PathLike) -> None:
        self.cache_dir = Path(cache_dir)
        self._caches: dict[str, DiskCache] = {}
        self._mapped: dict[tuple[str, str], np.ndarray] = {}  # one memory map per cached song

    @staticmethod
    def namespace(encoder: AudioEncoder) -> str:
        """Folder name of an encoder's entries: a changed setting gives a new folder (a miss)."""
        return f"{encoder.name}-{stable_hash(encoder.output_settings())}"

    def disk_cache(self, encoder: AudioEncoder) -> DiskCache:
        ns = self.namespace(encoder)
        if ns not in self._caches:
            self._caches[ns] = DiskCache(self.cache_dir, ns)
        return self._caches[ns]

    @staticmethod
    def key(encoder: AudioEncoder, audio_path: str | os.PathLike, music_id: str | None = None) -> str:
        """Content hash of the file, plus the part of ``music_id`` that changes this encoder's output."""
        if not Path(audio_path).is_file():
            raise AudioError(f"Audio file not found: {audio_path}. Check the path (and the data folder setting).")
        key = file_hash(audio_path)
        extra = encoder.music_id_key(music_id) if encoder.uses_music_id else ""
        return f"{key}-{extra}" if extra else key

    def contains(self, encoder: AudioEncoder, audio_path: str | os.PathLike, music_id: str | None = None) -> bool:
        return self.key(encoder, audio_path, music_id) in self.disk_cache(encoder)

    def features_for_file(
        self,
        encoder: AudioEncoder,
        audio_path: str | os.PathLike,
        n_frames: int | None = None,
        music_id: str | None = None,
    ) -> np.ndarray:
        """Features ``(n_frames, feature_dim)`` of a whole file; encodes only on a cache miss.

        ``n_frames=None`` returns the whole song (``floor(duration * fps)`` rows); otherwise the cached
        whole-song features are truncated or edge-padded to ``n_frames``.
        """
        cache = self.disk_cache(encoder)
        key = self.key(encoder, audio_path, music_id)

        def compute() -> dict[str, np.ndarray]:
            return {FEATURES_KEY: _encode_file(audio_path, encoder.sample_rate, encoder.encode, music_id=music_id)}

        mapped = self._mapped.get((cache.dir.name, key))
        if mapped is None:
            # a hit is memory-mapped: pages load on first touch and are shared by loader workers and ranks
            mapped = cache.get_or_compute(key, compute, required=(FEATURES_KEY,), mmap=True)[FEATURES_KEY]
            self._mapped[(cache.dir.name, key)] = mapped
        features = mapped
        if n_frames is not None:
            features = fit_frames(features, int(n_frames))
        return features.astype(np.float32, copy=False)

    def windows_for_file(
        self,
        encoder: AudioEncoder,
        audio_path: str | os.PathLike,
        starts: list[int],
        window_frames: int,
        music_id: str | None = None,
    ) -> np.ndarray:
        """Per-window features ``(len(starts), window_frames, feature_dim)`` of a file
        (:meth:`AudioEncoder.encode_windows`), cached like whole-song features under a key of the layout too."""
        cache = self.disk_cache(encoder)
        layout = stable_hash({"starts": [int(s) for s in starts], "window_frames": int(window_frames)})
        key = f"{self.key(encoder, audio_path, music_id)}-windows-{layout}"

        def compute() -> dict[str, np.ndarray]:
            encode = encoder.encode_windows
            return {
                FEATURES_KEY: _encode_file(audio_path, encoder.sample_rate, encode, starts, window_frames, music_id)
            }

        return cache.get_or_compute(key, compute, required=(FEATURES_KEY,))[FEATURES_KEY].astype(np.float32)


def _encode_file(audio_path: str | os.PathLike, sample_rate: int, encode: Any, *args: Any, **kwargs: Any) -> np.ndarray:
    """``encode(waveform, rate, *args, **kwargs)`` of a file read at ``sample_rate``; its errors name the file."""
    waveform, rate_hz = load_audio(audio_path, sample_rate=sample_rate, mono=True)
    try:
        return encode(waveform, rate_hz, *args, **kwargs)
    except AudioError as e:  # the encoder does not know the file: name it
        raise AudioError(f"{audio_path}: {e}") from e


@dataclass
class ExtractionSummary:
    """What :func:`extract_dataset` did: songs encoded now, songs already cached, audio seconds seen."""

    n_songs: int
    n_computed: int
    n_cached: int
    audio_seconds: float


def extract_dataset(
    encoder: AudioEncoder,
    wav_paths: Iterable[str | os.PathLike],
    cache_dir: str | os.PathLike,
    music_id_from_name: bool = True,
    progress: bool = True,
) -> ExtractionSummary:
    """Fill the cache for every file in ``wav_paths``; resumes by skipping files already cached.

    With ``music_id_from_name`` the file stem is passed as music id (AIST++ songs are named ``mBR0.wav``),
    so encoders that read the tempo from it get it.
    """
    cache = FeatureCache(cache_dir)
    paths = [Path(p) for p in wav_paths]
    n_computed = n_cached = 0
    audio_seconds = 0.0
    bar = tqdm(paths, desc=f"{encoder.name} features", unit="song", disable=not progress)
    for path in bar:
        music_id = path.stem if music_id_from_name else None
        audio_seconds += audio_duration_seconds(path)
        if cache.contains(encoder, path, music_id):
            n_cached += 1
        else:
            cache.features_for_file(encoder, path, music_id=music_id)
            n_computed += 1
        bar.set_postfix(computed=n_computed, cached=n_cached)
    return ExtractionSummary(len(paths), n_computed, n_cached, audio_seconds)
