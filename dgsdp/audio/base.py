"""Common interface of the audio encoders: waveform in, one feature row per 30 FPS motion frame out.

Every encoder works on whole songs of any length; models with a limited context chunk internally. Rows are
aligned so that row ``i`` describes the audio at time ``i / fps`` seconds.

Short and silent audio: anything at least one motion frame long (``1 / fps`` seconds) yields features
(silence gives valid, beat-free features); an empty waveform or one shorter than a frame raises
:class:`AudioError`, because it cannot describe even one motion frame.
"""

from __future__ import annotations

import abc
import math
import warnings
from collections.abc import Sequence
from typing import Any, ClassVar

import numpy as np

from dgsdp.audio.numba_cache import librosa
from dgsdp.audio.tempo import tempo_from_music_id
from dgsdp.errors import AudioError


def default_n_frames(n_samples: int, sample_rate: int, fps: int) -> int:
    """Motion frames covered by ``n_samples`` of audio: ``floor(duration_seconds * fps)``."""
    # Integer arithmetic: floor(n * fps / sr) without float round-off on exact multiples.
    return (int(n_samples) * int(fps)) // int(sample_rate)


def fit_frames(features: np.ndarray, n_frames: int) -> np.ndarray:
    """Truncate ``(T, D)`` features to ``n_frames`` rows, or pad by repeating the last row (edge padding)."""
    if n_frames < 0:
        raise ValueError(f"n_frames must be >= 0, got {n_frames}")
    t = features.shape[0]
    if t >= n_frames:
        return features[:n_frames]
    if t == 0:
        raise AudioError("The encoder produced no feature frames; the audio is too short to encode.")
    pad = np.repeat(features[-1:], n_frames - t, axis=0)
    return np.concatenate([features, pad], axis=0)


def resample_frames(features: np.ndarray, rate_hz: float, fps: float, res_type: str = "fft") -> np.ndarray:
    """Resample ``(T, D)`` frame features from ``rate_hz`` to ``fps`` along time with librosa.

    ``res_type="fft"`` is librosa's FFT (band-limited) resampling, as EDGE uses for Jukebox features;
    ``"soxr_hq"`` is an anti-aliased polyphase filter with less ringing at the ends. Output length is
    ``ceil(T * fps / rate_hz)``.
    """
    if features.ndim != 2:
        raise ValueError(f"expected (T, D) features, got shape {features.shape}")
    if math.isclose(rate_hz, fps):
        return features.astype(np.float32, copy=False)
    out = librosa.resample(
        np.ascontiguousarray(features.T, dtype=np.float32),
        orig_sr=float(rate_hz),
        target_sr=float(fps),
        res_type=res_type,
        axis=-1,
    )
    return np.ascontiguousarray(out.T, dtype=np.float32)


BEAT_PHASE_DIM = 2


def beat_phase_columns(beats: np.ndarray, n_frames: int) -> np.ndarray:
    """``(n_frames, 2)``: sin and cos of 2 pi x the phase of each frame within its beat (0 on a beat frame).

    Between two beats the phase rises linearly from 0 to 1; before the first and after the last beat it runs on
    at the nearest beat interval. With fewer than two beats there is no tempo: both columns are 0.
    """
    beats = np.unique(np.asarray(beats, dtype=np.float64).reshape(-1))
    out = np.zeros((int(n_frames), BEAT_PHASE_DIM), dtype=np.float32)
    if beats.size < 2 or n_frames == 0:
        return out
    t = np.arange(int(n_frames), dtype=np.float64)
    k = np.clip(np.searchsorted(beats, t, side="right") - 1, 0, beats.size - 2)
    phase = (t - beats[k]) / (beats[k + 1] - beats[k])  # < 0 before the first beat, > 1 after the last
    angle = 2.0 * np.pi * phase
    out[:, 0] = np.sin(angle)
    out[:, 1] = np.cos(angle)
    return out


def _mono(waveform: np.ndarray) -> np.ndarray:
    """A finite mono float32 waveform from ``(samples,)`` or ``(channels, samples)``, or an AudioError."""
    waveform = np.asarray(waveform, dtype=np.float32)
    if waveform.ndim == 2:
        waveform = waveform.mean(axis=0)
    if waveform.ndim != 1:
        raise AudioError(f"Expected a (samples,) or (channels, samples) waveform, got {waveform.shape}.")
    if not np.all(np.isfinite(waveform)):
        raise AudioError("The waveform contains NaN or infinite samples; check the audio file.")
    return waveform


class AudioEncoder(abc.ABC):
    """Base class of the interchangeable audio encoders (librosa, Encodec, Jukebox).

    Subclasses set ``name``, ``feature_dim`` and ``sample_rate`` (the rate they want) and implement
    :meth:`_encode`. ``uses_music_id`` tells the feature cache that ``music_id`` changes the output.
    """

    name: ClassVar[str] = "base"
    fps: int = 30
    feature_dim: int
    sample_rate: int
    uses_music_id: ClassVar[bool] = False
    # Settings added after runs were first trained, with the value those runs used: a checkpoint whose stored
    # audio config lacks one was trained with that value (the constructor default may differ).
    legacy_settings: ClassVar[dict[str, Any]] = {}
    # EDGE's procedure (its test.py and its training data): every generation window gets features computed from
    # its own audio alone (:meth:`encode_windows`), not cut from the whole song's. Set by ``audio.per_window``.
    per_window: bool = False
    # Two more columns after the encoder's own: sin and cos of the phase within the beat (``audio.beat_phase``,
    # :func:`beat_phase_columns`); the beats are librosa's tracker's, the ones BAS and beat sync use.
    beat_phase: bool = False

    @property
    def output_dim(self) -> int:
        """Width of the rows :meth:`encode` returns: ``feature_dim`` (the encoder's own), plus 2 with beat_phase."""
        return int(self.feature_dim) + (BEAT_PHASE_DIM if self.beat_phase else 0)

    @abc.abstractmethod
    def settings(self) -> dict[str, Any]:
        """Every setting that changes the output (JSON-serialisable), used for cache keys."""

    def output_settings(self) -> dict[str, Any]:
        """:meth:`settings` plus the columns added here (the feature cache's and the data's key)."""
        return {**self.settings(), "beat_phase": True} if self.beat_phase else self.settings()

    def beat_frames(self, waveform: np.ndarray, music_id: str | None, features: np.ndarray) -> np.ndarray:
        """Beat frame indices of mono audio at ``self.sample_rate`` (``features``: this encoder's own rows).

        librosa's tracker on the onset envelope at the motion frame rate, with the AIST++ tempo as prior when the
        music id names one; encoders that track beats themselves return theirs.
        """
        hop = self.sample_rate // self.fps
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)
            envelope = librosa.onset.onset_strength(y=waveform, sr=self.sample_rate, hop_length=hop)
            bpm = tempo_from_music_id(music_id)
            kwargs = {} if bpm is None else {"start_bpm": bpm}
            _, beats = librosa.beat.beat_track(
                onset_envelope=envelope, sr=self.sample_rate, hop_length=hop, tightness=100.0, **kwargs
            )
        return np.asarray(beats, dtype=np.int64)

    # --- the beats the features give a model (tempo folding: dgsdp.audio.tempo) ---------------------------------
    def feature_beats(self, features: np.ndarray) -> np.ndarray | None:
        """The beat frames that features ``(T, output_dim)`` of this encoder give a model (the frames where the
        beat phase columns are at phase 0: before the first and after the last tracked beat, where the phase runs on
        at the nearest interval, the beats it implies), or None where they give none."""
        if not self.beat_phase:
            return None
        sin, cos = np.asarray(features)[:, -BEAT_PHASE_DIM], np.asarray(features)[:, -BEAT_PHASE_DIM + 1]
        return np.flatnonzero((np.abs(sin) < 1e-4) & (cos > 0.99))

    def with_beats(self, features: np.ndarray, beats: np.ndarray) -> np.ndarray:
        """A copy of features ``(T, output_dim)`` whose beat columns give ``beats`` instead."""
        out = np.array(features, dtype=np.float32)
        if self.beat_phase:
            out[:, -BEAT_PHASE_DIM:] = beat_phase_columns(beats, out.shape[0])
        return out

    def beat_strength(self, features: np.ndarray) -> np.ndarray | None:
        """Per frame, how strong the music is (the likelier downbeats), or None where the features do not say."""
        return None

    @abc.abstractmethod
    def _encode(self, waveform: np.ndarray, music_id: str | None) -> np.ndarray:
        """Encode mono audio at ``self.sample_rate``: ``(samples,)`` -> ``(T, feature_dim)`` at ``fps``.

        ``T`` may differ from the requested frame count by a few rows; :meth:`encode` fits it.
        """

    def music_id_key(self, music_id: str | None) -> str:
        """The part of ``music_id`` that changes this encoder's output, for cache keys ("" if none)."""
        return ""

    def encode(
        self,
        waveform: np.ndarray,
        sample_rate: int,
        n_frames: int | None = None,
        music_id: str | None = None,
    ) -> np.ndarray:
        """Features ``(n_frames, output_dim)`` float32; row ``i`` covers time ``i / fps`` s.

        ``waveform`` is ``(samples,)`` or ``(channels, samples)`` at ``sample_rate`` Hz (resampled and
        down-mixed here). ``n_frames`` defaults to ``floor(duration_seconds * fps)``; the features are
        truncated to that song length, then truncated or edge-padded (last frame repeated) to ``n_frames``.
        """
        waveform = _mono(waveform)
        min_samples = math.ceil(sample_rate / self.fps)
        if waveform.shape[0] < min_samples:
            raise AudioError(
                f"Audio is too short for the {self.name} encoder: {waveform.shape[0]} samples at "
                f"{sample_rate} Hz is less than one motion frame (1/{self.fps} s). Use a longer clip."
            )
        song_frames = default_n_frames(waveform.shape[0], sample_rate, self.fps)
        if n_frames is None:
            n_frames = song_frames
        if int(sample_rate) != int(self.sample_rate):
            waveform = librosa.resample(
                waveform, orig_sr=int(sample_rate), target_sr=int(self.sample_rate), res_type="soxr_hq"
            )
        features = self._encode(np.ascontiguousarray(waveform, dtype=np.float32), music_id)
        if features.ndim != 2 or features.shape[1] != self.feature_dim:
            raise RuntimeError(
                f"{type(self).__name__} returned shape {features.shape}, expected (T, {self.feature_dim})"
            )
        if self.beat_phase:
            beats = self.beat_frames(waveform, music_id, features)
            features = np.concatenate([features, beat_phase_columns(beats, features.shape[0])], axis=1)
        # First the song's own length, so that padding repeats the last frame inside the audio.
        features = fit_frames(fit_frames(features, song_frames), int(n_frames))
        return np.ascontiguousarray(features, dtype=np.float32)

    def encode_windows(
        self,
        waveform: np.ndarray,
        sample_rate: int,
        starts: Sequence[int],
        window_frames: int,
        music_id: str | None = None,
    ) -> np.ndarray:
        """Features ``(len(starts), window_frames, output_dim)``: window k's computed from its own audio alone,
        the ``window_frames / fps`` seconds from frame ``starts[k]`` on, as EDGE's test.py encodes each 5 s slice
        file of a song (slices every 2.5 s). Audio past the end of the song is silence."""
        waveform = _mono(waveform)
        length = int(round(window_frames * sample_rate / self.fps))
        out = []
        for start in starts:
            first = int(round(int(start) * sample_rate / self.fps))
            piece = waveform[first : first + length]
            if len(piece) < length:
                piece = np.pad(piece, (0, length - len(piece)))
            out.append(self.encode(piece, sample_rate, n_frames=int(window_frames), music_id=music_id))
        return np.stack(out).astype(np.float32, copy=False)

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.settings()})"
