"""EDGE/FACT's hand-crafted 35-d music features, computed with librosa at exactly 30 FPS.

Columns, in order: onset-strength envelope (0), MFCC (1-20), chroma_cens (21-32), onset peaks one-hot (33),
beats one-hot (34: librosa's beat tracker, EDGE's; or with ``beat_tracker="flux"`` the independent tracker of
:mod:`dgsdp.audio.beat_tracker`). 15360 Hz with hop 512 gives exactly 30 frames per second.
"""

from __future__ import annotations

import warnings
from typing import Any, ClassVar

import numpy as np

from dgsdp.audio.base import AudioEncoder
from dgsdp.audio.beat_tracker import SAMPLE_RATE as FLUX_SAMPLE_RATE
from dgsdp.audio.beat_tracker import track_beats
from dgsdp.audio.loudness import normalize_loudness
from dgsdp.audio.numba_cache import librosa
from dgsdp.audio.tempo import tempo_from_music_id
from dgsdp.errors import ConfigError

ENVELOPE_COLUMN = 0
MFCC_COLUMNS = slice(1, 21)
CHROMA_COLUMNS = slice(21, 33)
PEAK_COLUMN = 33
BEAT_COLUMN = 34

STANDARDIZE_MODES = ("none", "mean", "mean_std")
# what finds the beats of the beat column: librosa's tracker (EDGE's features), or the independent one of
# dgsdp.audio.beat_tracker, which finds the synthetic songs' known beats more often (docs/notes/2026-11-26-independent-beats.md)
BEAT_TRACKERS = ("librosa", "flux")
_STD_FLOOR = 1e-3  # a column that does not move (silence) is centred, not blown up


def standardize_song(features: np.ndarray, mode: str) -> np.ndarray:
    """Per-song normalisation of the envelope and MFCC columns of ``(T, 35)`` features (a copy).

    ``"mean"``: MFCCs minus their song mean (cepstral mean normalisation) and the envelope divided by its song
    mean; ``"mean_std"``: both z-scored over the song. Chroma and the binary peak/beat columns are unchanged.
    """
    if mode == "none":
        return features
    out = features.copy()
    mfcc = out[:, MFCC_COLUMNS]
    env = out[:, ENVELOPE_COLUMN]
    if mode == "mean":
        out[:, MFCC_COLUMNS] = mfcc - mfcc.mean(axis=0, keepdims=True)
        out[:, ENVELOPE_COLUMN] = env / max(float(env.mean()), _STD_FLOOR)
    elif mode == "mean_std":
        out[:, MFCC_COLUMNS] = (mfcc - mfcc.mean(axis=0, keepdims=True)) / np.maximum(
            mfcc.std(axis=0, keepdims=True), _STD_FLOOR
        )
        out[:, ENVELOPE_COLUMN] = (env - env.mean()) / max(float(env.std()), _STD_FLOOR)
    else:
        raise ValueError(f"unknown standardize mode {mode!r}; choose from {', '.join(STANDARDIZE_MODES)}")
    return out


class LibrosaEncoder(AudioEncoder):
    """35-d librosa features; ``start_bpm`` for the beat tracker comes from the AIST++ music id when known."""

    name: ClassVar[str] = "librosa"
    uses_music_id: ClassVar[bool] = True
    # Runs trained before the features were normalised stored no normalisation settings.
    legacy_settings: ClassVar[dict[str, Any]] = {"loudness_lufs": None, "standardize": "none", "mfcc_fmax_hz": None}

    def __init__(
        self,
        sample_rate: int = 15360,
        hop_length: int = 512,
        n_mfcc: int = 20,
        n_chroma: int = 12,
        beat_tightness: float = 100.0,
        use_music_id_tempo: bool = True,
        loudness_lufs: float | None = -23.0,
        standardize: str = "mean_std",
        mfcc_fmax_hz: float | None = 3500.0,
        per_window: bool = False,
        beat_phase: bool = False,
        rhythm_only: bool = False,
        beat_tracker: str = "librosa",
    ) -> None:
        if sample_rate % hop_length != 0 or sample_rate // hop_length != self.fps:
            raise ValueError(f"sample_rate / hop_length must equal {self.fps} FPS, got {sample_rate} / {hop_length}")
        self.sample_rate = int(sample_rate)
        self.hop_length = int(hop_length)
        self.n_mfcc = int(n_mfcc)
        self.n_chroma = int(n_chroma)
        self.beat_tightness = float(beat_tightness)
        self.use_music_id_tempo = bool(use_music_id_tempo)
        if loudness_lufs is not None and not -70.0 < float(loudness_lufs) <= 0.0:
            raise ConfigError(f"loudness_lufs must lie in (-70, 0] LUFS or be null (off), got {loudness_lufs}")
        if standardize not in STANDARDIZE_MODES:
            raise ConfigError(f"standardize must be one of {', '.join(STANDARDIZE_MODES)}, got {standardize!r}")
        self.loudness_lufs = None if loudness_lufs is None else float(loudness_lufs)
        self.standardize = str(standardize)
        if mfcc_fmax_hz is not None and not 1000.0 <= float(mfcc_fmax_hz) <= sample_rate / 2:
            raise ConfigError(f"mfcc_fmax_hz must lie in [1000, {sample_rate / 2:g}] Hz or be null, got {mfcc_fmax_hz}")
        self.mfcc_fmax_hz = None if mfcc_fmax_hz is None else float(mfcc_fmax_hz)
        self.feature_dim = 1 + self.n_mfcc + self.n_chroma + 2
        self.per_window = bool(per_window)  # not a settings() key: whole-song features are the same
        self.beat_phase = bool(beat_phase)
        self.rhythm_only = bool(rhythm_only)
        if beat_tracker not in BEAT_TRACKERS:
            raise ConfigError(f"beat_tracker must be one of {', '.join(BEAT_TRACKERS)}, got {beat_tracker!r}")
        if beat_tracker == "flux" and self.sample_rate != FLUX_SAMPLE_RATE:
            raise ConfigError(f"beat_tracker=flux works at sample_rate={FLUX_SAMPLE_RATE}, got {self.sample_rate}")
        self.beat_tracker = str(beat_tracker)

    def settings(self) -> dict[str, Any]:
        return {
            "sample_rate": self.sample_rate,
            "hop_length": self.hop_length,
            "n_mfcc": self.n_mfcc,
            "n_chroma": self.n_chroma,
            "beat_tightness": self.beat_tightness,
            "use_music_id_tempo": self.use_music_id_tempo,
            "loudness_lufs": self.loudness_lufs,
            "standardize": self.standardize,
            "mfcc_fmax_hz": self.mfcc_fmax_hz,
            "librosa": librosa.__version__,
            # only when on: the features (and caches, and checkpoints) of full-feature runs stay as they were
            **({"rhythm_only": True} if self.rhythm_only else {}),
            **({"beat_tracker": self.beat_tracker} if self.beat_tracker != "librosa" else {}),
        }

    def start_bpm(self, music_id: str | None) -> float | None:
        """Tempo prior for the beat tracker from the music id (None: estimate from the audio)."""
        return tempo_from_music_id(music_id) if self.use_music_id_tempo else None

    def music_id_key(self, music_id: str | None) -> str:
        bpm = self.start_bpm(music_id)
        return "" if bpm is None else f"bpm{bpm:g}"

    def beat_frames(self, waveform: np.ndarray, music_id: str | None, features: np.ndarray) -> np.ndarray:
        """The beats of the beat column: the phase then agrees with the beats these features flag."""
        return self.feature_beats(features)

    def feature_beats(self, features: np.ndarray) -> np.ndarray:
        return np.flatnonzero(np.asarray(features)[:, BEAT_COLUMN])

    def with_beats(self, features: np.ndarray, beats: np.ndarray) -> np.ndarray:
        out = super().with_beats(features, beats)
        beats = np.asarray(beats, dtype=np.int64)
        out[:, BEAT_COLUMN] = 0.0
        out[beats[(beats >= 0) & (beats < len(out))], BEAT_COLUMN] = 1.0
        return out

    def beat_strength(self, features: np.ndarray) -> np.ndarray | None:
        return np.asarray(features)[:, ENVELOPE_COLUMN]  # the onset envelope

    def _encode(self, waveform: np.ndarray, music_id: str | None) -> np.ndarray:
        sr, hop = self.sample_rate, self.hop_length
        if self.loudness_lufs is not None:
            waveform = normalize_loudness(waveform, sr, self.loudness_lufs)
        with warnings.catch_warnings():
            # Short clips make librosa warn that n_fft exceeds the signal and silence that tuning is
            # undefined; both are handled (zero padding, default tuning) and expected here.
            warnings.simplefilter("ignore", UserWarning)
            envelope = librosa.onset.onset_strength(y=waveform, sr=sr, hop_length=hop)  # (T,)
            mfcc = librosa.feature.mfcc(y=waveform, sr=sr, n_mfcc=self.n_mfcc, hop_length=hop, fmax=self.mfcc_fmax_hz).T
            chroma = librosa.feature.chroma_cens(y=waveform, sr=sr, hop_length=hop, n_chroma=self.n_chroma).T
            peaks = librosa.onset.onset_detect(onset_envelope=envelope, sr=sr, hop_length=hop)
            if self.beat_tracker == "flux":  # the independent tracker (dgsdp.audio.beat_tracker)
                beats = track_beats(waveform, sr).frames
            else:
                start_bpm = self.start_bpm(music_id)
                if start_bpm is None:
                    start_bpm = float(librosa.feature.tempo(onset_envelope=envelope, sr=sr, hop_length=hop)[0])
                _, beats = librosa.beat.beat_track(
                    onset_envelope=envelope,
                    sr=sr,
                    hop_length=hop,
                    start_bpm=start_bpm,
                    tightness=self.beat_tightness,
                )
        n = min(len(envelope), len(mfcc), len(chroma))
        peak_onehot = np.zeros(n, dtype=np.float32)
        peak_onehot[peaks[peaks < n]] = 1.0
        beat_onehot = np.zeros(n, dtype=np.float32)
        beat_onehot[beats[beats < n]] = 1.0
        features = np.concatenate(
            [envelope[:n, None], mfcc[:n], chroma[:n], peak_onehot[:, None], beat_onehot[:, None]], axis=1
        ).astype(np.float32)
        features = standardize_song(features, self.standardize)
        if self.rhythm_only:  # timbre and harmony out; the 35-column layout (and its beat column) stays
            features[:, MFCC_COLUMNS] = 0.0
            features[:, CHROMA_COLUMNS] = 0.0
        return features
