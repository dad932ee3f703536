"""ITU-R BS.1770-4 integrated loudness (via pyloudnorm) for short, silent and clipped audio alike."""

from __future__ import annotations

import warnings

import numpy as np
import pyloudnorm

LOUDNESS_BLOCK_S = 0.4  # BS.1770 gating block: pyloudnorm needs at least this much audio


def integrated_loudness(waveform: np.ndarray, sample_rate: int) -> float:
    """ITU-R BS.1770-4 integrated loudness (LUFS) of mono audio; ``-inf`` for silence.

    Clips shorter than one 0.4 s gating block are measured as the clip repeated to fill a block (the loudness
    of a repeated signal is that of the signal).
    """
    waveform = np.asarray(waveform, dtype=np.float64)
    block = int(np.ceil(LOUDNESS_BLOCK_S * sample_rate)) + 1
    if waveform.size == 0 or not np.any(waveform):
        return float("-inf")
    if waveform.size < block:
        waveform = np.tile(waveform, -(-block // waveform.size))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # log10 of a fully gated (silent) signal
        return float(pyloudnorm.Meter(sample_rate).integrated_loudness(waveform))


def normalize_loudness(waveform: np.ndarray, sample_rate: int, target_lufs: float) -> np.ndarray:
    """``waveform`` scaled to ``target_lufs`` integrated loudness (no clipping: peaks may pass 1.0).

    Silence, or audio quieter than BS.1770's absolute gate (-70 LUFS), is returned unchanged.
    """
    loudness = integrated_loudness(waveform, sample_rate)
    if not np.isfinite(loudness):
        return waveform
    gain = 10.0 ** ((float(target_lufs) - loudness) / 20.0)
    return (waveform * gain).astype(np.float32)
