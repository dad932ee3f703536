"""The project's one audio loader: any format, sample rate and channel count to a float32 array.

wav/flac/ogg (and mp3 on recent libsndfile) are read by soundfile; anything else goes through librosa's
audioread fallback. Resampling uses soxr (via librosa), down-mixing averages the channels.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import soundfile as sf

from dgsdp.audio.numba_cache import librosa
from dgsdp.errors import AudioError

RESAMPLE_TYPE = "soxr_hq"
AUDIO_SUFFIXES = (".wav", ".flac", ".ogg", ".mp3", ".m4a")
"""The song files the project looks for in a folder (mp3 and m4a may need ffmpeg)."""
MAX_PEAK = 1000.0
"""Float files may exceed full scale (1.0) a little; samples past this (60 dB over) mean a broken file."""
UNKNOWN_FRAMES = 2**63 - 1
"""libsndfile's frame count for a stream whose header gives no length (a FLAC may leave it out)."""
BLOCK_FRAMES = 1 << 16


def _blocks(f: sf.SoundFile) -> Iterator[np.ndarray]:
    """An open file of unknown length as (samples, channels) float32 blocks, read until it ends.

    soundfile's ``read`` seeks to its new position after each block, which fails at the end of such a stream,
    so the blocks come from libsndfile's own read call."""
    from soundfile import _ffi, _snd  # noqa: PLC2701 - see above

    while True:
        block = np.empty((BLOCK_FRAMES, f.channels), dtype=np.float32)
        n = int(_snd.sf_readf_float(f._file, _ffi.cast("float *", _ffi.from_buffer(block)), BLOCK_FRAMES))
        if n <= 0:
            return
        yield block[:n]


def _read_native(path: Path) -> tuple[np.ndarray, int]:
    """Decode ``path`` at its own rate; returns ((channels, samples) float32, rate_hz)."""
    try:
        with sf.SoundFile(str(path)) as f:
            if f.frames >= UNKNOWN_FRAMES:
                data = np.concatenate([np.zeros((0, f.channels), np.float32), *_blocks(f)])
            else:
                data = f.read(dtype="float32", always_2d=True)
            return np.ascontiguousarray(data.T), int(f.samplerate)
    except (sf.LibsndfileError, RuntimeError, TypeError, ValueError):
        pass
    try:
        with warnings.catch_warnings():
            # librosa warns that it falls back to audioread; that fallback is the point here.
            warnings.simplefilter("ignore")
            data, rate_hz = librosa.load(str(path), sr=None, mono=False, dtype=np.float32)
    except Exception as err:  # audioread raises many unrelated types (NoBackendError, EOFError, ...)
        raise AudioError(
            f"Cannot decode audio file {path} ({type(err).__name__}: {err}). "
            "Convert it to wav or flac (e.g. `ffmpeg -i in.xyz out.wav`) or install ffmpeg for other formats."
        ) from err
    data = np.asarray(data, dtype=np.float32)
    if data.ndim == 1:
        data = data[None, :]
    return data, int(rate_hz)


def load_audio(path: str | os.PathLike, sample_rate: int | None, mono: bool = True) -> tuple[np.ndarray, int]:
    """Load an audio file as float32 in [-1, 1].

    Returns ``(waveform, rate_hz)``: waveform is ``(samples,)`` when ``mono`` (channels averaged), else
    ``(channels, samples)``. ``sample_rate=None`` keeps the file's rate; otherwise the audio is resampled.
    Raises :class:`AudioError` for a missing, undecodable or empty file.
    """
    path = Path(path)
    if not path.is_file():
        raise AudioError(f"Audio file not found: {path}. Check the path (and the data folder setting).")
    if path.stat().st_size == 0:
        raise AudioError(f"Audio file {path} is empty (0 bytes). Re-copy or re-download it.")
    data, rate_hz = _read_native(path)
    if data.size == 0 or data.shape[-1] == 0:
        raise AudioError(f"Audio file {path} contains no samples. Re-export it with audio content.")
    if not np.all(np.isfinite(data)):
        raise AudioError(f"Audio file {path} contains NaN or infinite samples. Re-export it.")
    peak = float(np.abs(data).max())
    if peak > MAX_PEAK:
        raise AudioError(
            f"Audio file {path} has samples up to {peak:.3g}, where full scale is 1.0: it is corrupt or wrongly "
            "scaled. Re-export it normalised (e.g. as 16-bit PCM wav)."
        )
    if mono:
        data = data.mean(axis=0)
    if sample_rate is not None and int(sample_rate) != rate_hz:
        data = librosa.resample(data, orig_sr=rate_hz, target_sr=int(sample_rate), res_type=RESAMPLE_TYPE)
        rate_hz = int(sample_rate)
    return np.ascontiguousarray(data, dtype=np.float32), rate_hz


def audio_duration_seconds(path: str | os.PathLike) -> float:
    """Duration of an audio file in seconds, read from its header when possible (no decoding)."""
    path = Path(path)
    if not path.is_file():
        raise AudioError(f"Audio file not found: {path}. Check the path (and the data folder setting).")
    try:
        with sf.SoundFile(str(path)) as f:
            if f.samplerate > 0 and 0 < f.frames < UNKNOWN_FRAMES:
                return float(f.frames) / float(f.samplerate)
            if f.samplerate > 0 and f.frames == UNKNOWN_FRAMES:  # no length in the header: count the samples
                return sum(len(block) for block in _blocks(f)) / float(f.samplerate)
    except (sf.LibsndfileError, RuntimeError, TypeError, ValueError):
        pass
    data, rate_hz = load_audio(path, sample_rate=None, mono=True)
    return data.shape[-1] / float(rate_hz)
