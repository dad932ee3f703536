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
