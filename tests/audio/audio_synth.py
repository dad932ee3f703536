"""Synthetic songs for the audio tests: click tracks at a known tempo, written in any format."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import soundfile as sf


def click_track(seconds: float, bpm: float, sample_rate: int, first_click_s: float = 0.0) -> np.ndarray:
    """Mono float32 song: a 30 ms decaying 1 kHz burst on every beat, plus a quiet 220 Hz drone."""
    n = int(round(seconds * sample_rate))
    t = np.arange(n) / sample_rate
    y = 0.05 * np.sin(2 * np.pi * 220.0 * t)
    burst_n = int(0.03 * sample_rate)
    tb = np.arange(burst_n) / sample_rate
    burst = 0.8 * np.sin(2 * np.pi * 1000.0 * tb) * np.exp(-tb / 0.008)
    for onset_s in np.arange(first_click_s, seconds, 60.0 / bpm):
        i = int(round(onset_s * sample_rate))
        m = min(burst_n, n - i)
        y[i : i + m] += burst[:m]
    return y.astype(np.float32)


def write_audio(path: Path, data: np.ndarray, sample_rate: int) -> Path:
    """Write ``(samples,)`` or ``(channels, samples)`` audio; the suffix picks the format."""
    path.parent.mkdir(parents=True, exist_ok=True)
    sf.write(str(path), data.T if data.ndim == 2 else data, sample_rate)
    return path


def flac_without_length(path: Path, seconds: float, rate_hz: int = 22050) -> np.ndarray:
    """A FLAC whose STREAMINFO gives 0 total samples ("unknown", as a streamed FLAC may); returns its samples."""
    samples = (np.random.default_rng(0).standard_normal(round(seconds * rate_hz)) * 0.1).astype(np.float32)
    sf.write(path, samples, rate_hz, subtype="PCM_16")
    data = bytearray(path.read_bytes())
    assert data[:4] == b"fLaC" and data[4] & 0x7F == 0  # the first block is STREAMINFO
    # STREAMINFO starts at byte 8; its total-samples field is the low 36 bits of bytes 18-25 (big-endian)
    data[21] &= 0xF0
    data[22:26] = bytes(4)
    path.write_bytes(bytes(data))
    assert sf.info(path).frames == 2**63 - 1  # libsndfile: length unknown
    return samples
