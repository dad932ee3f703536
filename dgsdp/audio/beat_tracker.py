"""A second beat tracker, independent of librosa's: spectral flux, a comb filter on its autocorrelation for the
tempo, and a constant-tempo grid whose period and phase are picked by exhaustive search (no dynamic programming).

librosa's tracker (``librosa.beat.beat_track``, the beat column of the 35-d features) finds a tempo from its onset
envelope and then follows the onsets beat by beat with dynamic programming. A song whose strongest pulse is not the
beat a listener hears (a 3:2 or 4:3 pulse, the off-beats) fools it silently, and every figure scored against its
beats (BAS, the speed by beat phase) inherits the error. This tracker shares no code with it (numpy FFTs only) and
is of another family, so that where the two agree the beat is likely right, and where they disagree the report can
say so rather than score.

Also here: the measures of a tracker against known beats (:func:`beat_f_measure`, 70 ms window; :func:`tempo_agrees`)
and of two trackers against each other (:func:`trackers_agree`); ``python -m dgsdp.benchmarks.beat_trackers`` measures
both trackers with them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

FPS = 30  # beat frames are at the model's 30 FPS
SAMPLE_RATE = 15360  # hop 512 gives exactly 30 frames per second (the 35-d features' rate)
HOP = SAMPLE_RATE // FPS
N_FFT = 1024
LOW_BAND_HZ = 300.0  # the low band's onsets (kicks) weigh as much as the whole spectrum's in the phase
BPM_RANGE = (60.0, 200.0)  # the tempi a beat is looked for in
PRIOR_BPM, PRIOR_OCTAVES = 110.0, 1.0  # a broad log-normal preference between octaves of one pulse
COMB_HARMONICS = 4  # lags k * period, k = 1 .. this, summed
F_MEASURE_WINDOW_S = 0.07  # a tracked beat within 70 ms of a known one counts as found (the MIREX window)
TEMPO_TOLERANCE = 0.04  # two tempi agree within 4%
AGREE_F_MEASURE = 0.5  # two trackers agree on a song: tempi within 4% and at least this F-measure between them


@dataclass(frozen=True)
class TrackedBeats:
    """A tracker's answer on one song: its tempo (BPM) and beat frames at 30 FPS."""

    bpm: float
    frames: np.ndarray


def spectral_flux(waveform: np.ndarray, sample_rate: int = SAMPLE_RATE) -> tuple[np.ndarray, np.ndarray]:
    """The onset novelty of a mono waveform at 30 FPS, over the whole spectrum and below :data:`LOW_BAND_HZ` (the
    kick drum's band, where the beat usually is and the off-beat hats are not), each (T,): the half-wave rectified
    frame-to-frame rise of the log-compressed magnitude spectrum (Hann window of 1024 samples at 15360 Hz), summed
    over its bins, minus its half-second moving average and rectified again."""
    y = np.asarray(waveform, dtype=np.float64).reshape(-1)
    if sample_rate != SAMPLE_RATE:
        raise ValueError(f"spectral_flux expects {SAMPLE_RATE} Hz audio; got {sample_rate}")
    n_frames = 1 + len(y) // HOP
    padded = np.pad(y, (N_FFT // 2, N_FFT // 2 + N_FFT))
    idx = np.arange(N_FFT)[None, :] + HOP * np.arange(n_frames)[:, None]
    spectrum = np.abs(np.fft.rfft(padded[idx] * np.hanning(N_FFT)[None, :], axis=1))
    log_spec = np.log1p(1000.0 * spectrum / max(float(spectrum.max()), 1e-12))
    rise = np.maximum(np.diff(log_spec, axis=0, prepend=log_spec[:1]), 0.0)
    low_bins = int(LOW_BAND_HZ * N_FFT / SAMPLE_RATE)
    width = FPS // 2
    kernel = np.ones(2 * width + 1) / (2 * width + 1)
    out = []
    for band in (rise.sum(axis=1), rise[:, :low_bins].sum(axis=1)):
        out.append(np.maximum(band - np.convolve(band, kernel, mode="same"), 0.0))
    return out[0], out[1]


def _comb_tempo(novelty: np.ndarray) -> float:
    """The tempo (BPM) whose period and its multiples carry the most autocorrelation of the novelty, weighted by a
    broad log-normal preference around :data:`PRIOR_BPM`."""
    n = novelty - novelty.mean()
    size = 1 << int(np.ceil(np.log2(2 * len(n))))
    spectrum = np.fft.rfft(n, size)
    acf = np.fft.irfft(spectrum * np.conj(spectrum), size)[: len(n)]
    acf = acf / max(float(acf[0]), 1e-12)
    bpms = np.arange(BPM_RANGE[0], BPM_RANGE[1] + 1e-9, 0.5)
    periods = 60.0 * FPS / bpms
    score = np.zeros(len(bpms))
    for k in range(1, COMB_HARMONICS + 1):
        lags = k * periods
        score += np.interp(lags, np.arange(len(acf)), acf, right=0.0) / k
    prior = np.exp(-0.5 * (np.log2(bpms / PRIOR_BPM) / PRIOR_OCTAVES) ** 2)
    return float(bpms[int(np.argmax(np.maximum(score, 0.0) * prior))])


def _grid_fit(novelty: np.ndarray, bpm: float) -> tuple[float, float]:
    """The period (frames) within 2% of ``bpm``'s and the phase (frames) of the constant-tempo beat grid that lands
    on the most novelty (mean of the novelty, smoothed over +-1 frame, at the grid's frames)."""
    smooth = np.convolve(novelty, [0.25, 0.5, 0.25], mode="same")
    n = len(smooth)
    best = (-math.inf, 60.0 * FPS / bpm, 0.0)
    for period in 60.0 * FPS / (bpm * np.linspace(0.98, 1.02, 81)):
        phases = np.arange(0.0, period, 0.5)
        k = np.arange(int(n / period) + 1)
        positions = np.rint(phases[:, None] + period * k[None, :]).astype(np.int64)
        inside = positions < n
        values = np.where(inside, smooth[np.minimum(positions, n - 1)], 0.0)
        score = values.sum(axis=1) / np.maximum(inside.sum(axis=1), 1)
        j = int(np.argmax(score))
        if score[j] > best[0]:
            best = (float(score[j]), float(period), float(phases[j]))
    return best[1], best[2]


def track_beats(waveform: np.ndarray, sample_rate: int = SAMPLE_RATE) -> TrackedBeats:
    """The tempo and beats (30 FPS frames) of a mono waveform at 15360 Hz: :func:`spectral_flux`, the comb-filter
    tempo on the whole spectrum's novelty, then the constant-tempo grid near it that lands on the most novelty of
    the whole spectrum and of the low band together. Silence or a clip shorter than two beats gives no beats."""
    novelty, low = spectral_flux(waveform, sample_rate)
    if len(novelty) < 2 * FPS or not novelty.any():
        return TrackedBeats(math.nan, np.zeros(0, dtype=np.int64))
    coarse = _comb_tempo(novelty)
    # the grid's phase: the whole spectrum's onsets and the low band's, equally weighted, so that loud off-beat
    # hats do not win over the kicks
    both = novelty / max(float(novelty.mean()), 1e-12) + low / max(float(low.mean()), 1e-12)
    period, phase = _grid_fit(both, coarse)
    frames = np.rint(np.arange(phase, len(novelty), period)).astype(np.int64)
    return TrackedBeats(60.0 * FPS / period, frames[frames < len(novelty)])


def bpm_of_beats(frames: np.ndarray) -> float:
    """The tempo (BPM) of beat frames at 30 FPS: from their median interval (NaN with fewer than two beats)."""
    frames = np.sort(np.asarray(frames, dtype=np.float64).reshape(-1))
    return 60.0 * FPS / float(np.median(np.diff(frames))) if frames.size >= 2 else math.nan


def beats_of_song(path: str | Path) -> TrackedBeats:
    """:func:`track_beats` on an audio file (read with the project's loader at 15360 Hz, mono)."""
    from dgsdp.audio.io import load_audio

    waveform, rate = load_audio(path, SAMPLE_RATE, mono=True)
    return track_beats(waveform, rate)


# --- measures ----------------------------------------------------------------------------------------------------
def beat_f_measure(estimated_s: np.ndarray, reference_s: np.ndarray, window_s: float = F_MEASURE_WINDOW_S) -> float:
    """F-measure of beat times (seconds) against reference beat times: each reference beat matches at most one
    estimated beat within ``window_s``, matched nearest first; 0 when either is empty."""
    est = np.sort(np.asarray(estimated_s, dtype=np.float64).reshape(-1))
    ref = np.sort(np.asarray(reference_s, dtype=np.float64).reshape(-1))
    if est.size == 0 or ref.size == 0:
        return 0.0
    pairs = sorted(
        (abs(e - r), i, j)
        for j, r in enumerate(ref)
        for i in np.flatnonzero(np.abs(est - r) <= window_s)
        for e in [est[i]]
    )
    used_e, used_r, hits = set(), set(), 0
    for _, i, j in pairs:
        if i not in used_e and j not in used_r:
            used_e.add(i)
            used_r.add(j)
            hits += 1
    precision, recall = hits / est.size, hits / ref.size
    return 0.0 if hits == 0 else 2 * precision * recall / (precision + recall)


def tempo_ratio(bpm: float, reference_bpm: float) -> float:
    """``bpm / reference_bpm`` (NaN for a missing tempo)."""
    return bpm / reference_bpm if reference_bpm > 0 and bpm > 0 else math.nan


def tempo_agrees(bpm: float, reference_bpm: float, octaves: bool = False) -> bool:
    """Whether a tempo is within 4% of a reference tempo (with ``octaves``: of it, its double or its half)."""
    ratio = tempo_ratio(bpm, reference_bpm)
    targets = (1.0, 2.0, 0.5) if octaves else (1.0,)
    return any(abs(ratio / t - 1.0) <= TEMPO_TOLERANCE for t in targets)


def trackers_agree(a: TrackedBeats, b: TrackedBeats) -> tuple[bool, float]:
    """Whether two trackers agree on a song's beat, and the F-measure of one's beats against the other's: tempi
    within 4% of each other (a double or half tempo is a disagreement: half a beat of one is a whole beat of the
    other, so the shifted-copy test means nothing there) and at least half the beats matching within 70 ms (the
    same tempo on the off-beats is a disagreement too)."""
    f = beat_f_measure(np.asarray(a.frames) / FPS, np.asarray(b.frames) / FPS)
    return bool(tempo_agrees(a.bpm, b.bpm) and f >= AGREE_F_MEASURE), f


def librosa_beats(waveform: np.ndarray, sample_rate: int = SAMPLE_RATE, start_bpm: float | None = None) -> TrackedBeats:
    """librosa's tracker as the 35-d features run it (its onset envelope, its tempo estimate unless ``start_bpm``
    is given, tightness 100), for the comparison."""
    from dgsdp.audio.numba_cache import librosa

    envelope = librosa.onset.onset_strength(y=np.asarray(waveform, dtype=np.float32), sr=sample_rate, hop_length=HOP)
    if start_bpm is None:
        start_bpm = float(librosa.feature.tempo(onset_envelope=envelope, sr=sample_rate, hop_length=HOP)[0])
    tempo, frames = librosa.beat.beat_track(
        onset_envelope=envelope, sr=sample_rate, hop_length=HOP, start_bpm=start_bpm
    )
    return TrackedBeats(float(np.atleast_1d(tempo)[0]), np.asarray(frames, dtype=np.int64))
