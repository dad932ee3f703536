"""Synthetic music for the synthetic AIST++ dataset: drum-machine loops with a genre's rhythm and timbre.

Every beat carries a strong percussive hit, so a beat tracker finds the tempo the music id encodes; what lies
between the beats (ghost notes, off-beat hats, swung eighths) and the sounds themselves (kick pitch, snare colour,
bass, chords) follow the genre. The genres' own sub-beat events are quiet and a soft noise bed sits under
everything. Most songs also get an off-beat layer (``offbeats``, drawn per song): a hat, chord stab, clap or snare
halfway between the beats at up to 0.6 of a beat hit's level, as real songs have (their onset envelope, averaged
over eighths of the beat, peaks on the beat and again at the half beat); a model trained without it learns that
every onset is a beat.

Each song is then mastered as real recordings are, with settings drawn per song: a loudness between -30 and
-6 LUFS (BS.1770), clean, soft-limited or hard-clipped dynamics, a brighter or darker spectrum, a noise floor and
a sustained distorted chord layer, so that features of the training music span what real songs give.
"""

from __future__ import annotations

import io
import wave
from dataclasses import dataclass, replace

import numpy as np
from scipy.signal import iirpeak, lfilter

from dgsdp.audio.loudness import integrated_loudness


@dataclass(frozen=True)
class Hit:
    """One event of a one-bar (4-beat) pattern: ``instrument`` at ``beat`` (0 <= beat < 4) with ``gain``."""

    instrument: str
    beat: float
    gain: float


@dataclass(frozen=True)
class MusicStyle:
    """A genre's rhythm (events per 4-beat bar) and timbre (kick pitch, decays, bass, chord voicing)."""

    hits: tuple[Hit, ...]
    kick_hz: float = 55.0
    kick_decay_s: float = 0.25
    snare_decay_s: float = 0.12
    snare_band_hz: tuple[float, float] = (1000.0, 5000.0)
    hat_decay_s: float = 0.04
    tone_wave: str = "saw"
    tone_decay_s: float = 0.2
    root_hz: float = 110.0
    pad_gain: float = 0.05
    distortion: float = 0.0


def _on_beats(instrument: str, gain: float, beats: tuple[float, ...] = (0, 1, 2, 3)) -> tuple[Hit, ...]:
    return tuple(Hit(instrument, b, gain) for b in beats)


EIGHTHS_OFF = (0.5, 1.5, 2.5, 3.5)
SIXTEENTHS_OFF = (0.25, 0.75, 1.25, 1.75, 2.25, 2.75, 3.25, 3.75)
SWING_OFF = (2 / 3, 5 / 3, 8 / 3, 11 / 3)

MUSIC_STYLES: dict[str, MusicStyle] = {
    # Break: breakbeat (kick 1 & 3, snare 2 & 4, a ghost kick), scratchy noise, funky stab.
    "BR": MusicStyle(
        hits=_on_beats("kick", 1.0, (0, 2)) + _on_beats("snare", 1.0, (1, 3)) + _on_beats("hat", 0.5)
        + (Hit("kick", 2.5, 0.2),) + _on_beats("hat", 0.12, EIGHTHS_OFF) + (Hit("tone", 0, 0.5),),
        kick_hz=60, snare_band_hz=(1500, 6000), tone_wave="square", tone_decay_s=0.12, root_hz=98,
    ),
    # Pop: electro funk, kick on every beat, clap on 2 & 4, zappy synth on the one.
    "PO": MusicStyle(
        hits=_on_beats("kick", 1.0) + _on_beats("clap", 0.8, (1, 3)) + _on_beats("zap", 0.6, (0, 2)),
        kick_hz=50, kick_decay_s=0.18, hat_decay_s=0.02, tone_wave="square", root_hz=123,
    ),
    # Lock: funk with brass stabs on the beats.
    "LO": MusicStyle(
        hits=_on_beats("kick", 1.0, (0, 2)) + _on_beats("snare", 1.0, (1, 3)) + _on_beats("tone", 0.7)
        + _on_beats("hat", 0.12, EIGHTHS_OFF),
        kick_hz=65, snare_decay_s=0.15, tone_wave="saw", tone_decay_s=0.15, root_hz=147,
    ),
    # Middle hip-hop: boom bap, heavy kick and snare, a bass note per beat.
    "MH": MusicStyle(
        hits=_on_beats("kick", 1.0, (0, 2)) + _on_beats("snare", 1.0, (1, 3)) + _on_beats("bass", 0.6)
        + (Hit("kick", 2.75, 0.2),) + _on_beats("hat", 0.1, EIGHTHS_OFF),
        kick_hz=52, kick_decay_s=0.3, snare_band_hz=(800, 4000), tone_wave="sine", root_hz=73,
    ),
    # LA-style hip-hop: 808 sub kick, claps, light 16th hats.
    "LH": MusicStyle(
        hits=_on_beats("kick", 1.0, (0, 2)) + _on_beats("clap", 1.0, (1, 3)) + _on_beats("hat", 0.4)
        + _on_beats("hat", 0.08, SIXTEENTHS_OFF) + _on_beats("bass", 0.5, (0, 2)),
        kick_hz=45, kick_decay_s=0.5, tone_wave="sine", root_hz=65,
    ),
    # House: four on the floor, open hat on the off-beats, chord stabs, pad.
    "HO": MusicStyle(
        hits=_on_beats("kick", 1.0) + _on_beats("clap", 0.6, (1, 3)) + _on_beats("openhat", 0.12, EIGHTHS_OFF)
        + _on_beats("tone", 0.4),
        kick_hz=50, kick_decay_s=0.2, hat_decay_s=0.08, tone_wave="square", tone_decay_s=0.1, root_hz=110,
        pad_gain=0.08,
    ),
    # Waack: disco, four on the floor, off-beat hats, octave bass, strings.
    "WA": MusicStyle(
        hits=_on_beats("kick", 1.0) + _on_beats("snare", 0.6, (1, 3)) + _on_beats("openhat", 0.1, EIGHTHS_OFF)
        + _on_beats("bass", 0.6) + _on_beats("bass", 0.12, EIGHTHS_OFF),
        kick_hz=58, kick_decay_s=0.2, tone_wave="saw", root_hz=82, pad_gain=0.1,
    ),
    # Krump: slow heavy distorted hits on every beat, low rumble, nothing in between.
    "KR": MusicStyle(
        hits=_on_beats("kick", 1.0) + _on_beats("snare", 0.9) + _on_beats("bass", 0.5, (0, 2)),
        kick_hz=42, kick_decay_s=0.45, snare_decay_s=0.25, snare_band_hz=(400, 3000), tone_wave="saw",
        root_hz=55, distortion=3.0,
    ),
    # Street jazz: swing, ride on the beats plus quiet swung eighths, walking bass.
    "JS": MusicStyle(
        hits=_on_beats("kick", 0.8, (0, 2)) + _on_beats("snare", 0.8, (1, 3)) + _on_beats("ride", 0.6)
        + _on_beats("ride", 0.1, SWING_OFF) + _on_beats("bass", 0.6),
        kick_hz=62, snare_decay_s=0.1, hat_decay_s=0.15, tone_wave="triangle", root_hz=87,
    ),
    # Ballet jazz: piano chords on the beats over strings, soft kick, swung ride.
    "JB": MusicStyle(
        hits=_on_beats("piano", 1.0) + _on_beats("kick", 0.6) + _on_beats("ride", 0.06, SWING_OFF),
        kick_hz=70, kick_decay_s=0.15, tone_wave="triangle", tone_decay_s=0.5, root_hz=196, pad_gain=0.12,
    ),
}  # fmt: skip


def _decay(n: int, decay_s: float, sample_rate_hz: int) -> np.ndarray:
    return np.exp(-np.arange(n) / (decay_s * sample_rate_hz))


def _wave(kind: str, phase: np.ndarray) -> np.ndarray:
    """Periodic waveform of ``phase`` (cycles)."""
    frac = phase % 1.0
    if kind == "sine":
        return np.sin(2 * np.pi * phase)
    if kind == "square":
        return np.tanh(4 * np.sin(2 * np.pi * phase))
    if kind == "triangle":
        return 4 * np.abs(frac - 0.5) - 1
    return 2 * frac - 1  # saw


def _bandpass_noise(n: int, low_hz: float, high_hz: float, sample_rate_hz: int, rng: np.random.Generator):
    """White noise through a one-pole high-pass and low-pass (cheap, good enough for drums)."""
    noise = rng.standard_normal(n)
    a_hp = np.exp(-2 * np.pi * low_hz / sample_rate_hz)
    hp = lfilter([1 - a_hp, -(1 - a_hp)], [1, -a_hp], noise) if low_hz > 0 else noise
    a_lp = np.exp(-2 * np.pi * high_hz / sample_rate_hz)
    return lfilter([1 - a_lp], [1, -a_lp], hp)


def _instrument_sounds(style: MusicStyle, sample_rate_hz: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """One sample per instrument, peak-normalised; each starts with a sharp attack (the onset)."""
    sr = sample_rate_hz
    sounds: dict[str, np.ndarray] = {}

    n = int(sr * max(0.6, 3 * style.kick_decay_s))
    t = np.arange(n) / sr
    # Pitch falls from about 4x to the base frequency within ~30 ms: the "thump".
    freq = style.kick_hz * (1 + 3 * np.exp(-t / 0.03))
    phase = np.cumsum(freq) / sr
    kick = np.sin(2 * np.pi * phase) * _decay(n, style.kick_decay_s, sr)
    kick[: int(0.003 * sr)] += rng.standard_normal(int(0.003 * sr)) * 0.5  # beater click
    sounds["kick"] = kick

    n = int(sr * 4 * style.snare_decay_s)
    body = np.sin(2 * np.pi * 190 * np.arange(n) / sr) * _decay(n, style.snare_decay_s * 0.5, sr)
    noise = _bandpass_noise(n, *style.snare_band_hz, sr, rng)
    sounds["snare"] = 0.4 * body + noise / np.abs(noise).max() * _decay(n, style.snare_decay_s, sr)

    n = int(sr * 0.3)
    clap = _bandpass_noise(n, 900, 3000, sr, rng)
    env = _decay(n, 0.06, sr)
    for delay_s in (0.008, 0.016):  # a clap is several hands a few ms apart
        d = int(delay_s * sr)
        env[d:] += 0.6 * _decay(n - d, 0.01, sr)
    sounds["clap"] = clap / np.abs(clap).max() * env

    for name, decay_s, low_hz in (
        ("hat", style.hat_decay_s, 6000),
        ("openhat", 0.15, 5000),
        ("ride", 0.4, 3000),
    ):
        n = int(sr * 4 * decay_s)
        hat = _bandpass_noise(n, low_hz, 16000, sr, rng)
        if name == "ride":
            ring = np.arange(n) / sr
            hat = hat / np.abs(hat).max() + 0.3 * np.sin(2 * np.pi * 3200 * ring) * np.sin(2 * np.pi * 4700 * ring)
        sounds[name] = hat / np.abs(hat).max() * _decay(n, decay_s, sr)

    n = int(sr * 3 * style.tone_decay_s)
    t = np.arange(n) / sr
    chord = sum(_wave(style.tone_wave, f * style.root_hz * t) for f in (2.0, 2.52, 3.0))
    sounds["tone"] = chord / 3 * _decay(n, style.tone_decay_s, sr)

    n = int(sr * 0.25)
    t = np.arange(n) / sr
    zap_freq = 1500 * np.exp(-t / 0.04) + 100
    sounds["zap"] = np.sin(2 * np.pi * np.cumsum(zap_freq) / sr) * _decay(n, 0.08, sr)

    n = int(sr * 1.5)
    t = np.arange(n) / sr
    piano = sum(np.sin(2 * np.pi * f * style.root_hz * t) / k for k, f in enumerate((1.0, 1.26, 1.5, 2.0), 1))
    sounds["piano"] = piano * _decay(n, style.tone_decay_s, sr) * (1 - np.exp(-t / 0.002))

    n = int(sr * 0.4)
    t = np.arange(n) / sr
    sounds["bass"] = _wave(style.tone_wave, style.root_hz / 2 * t) * _decay(n, 0.15, sr)

    for name, s in sounds.items():
        s = s / (np.abs(s).max() + 1e-12)
        if style.distortion > 0 and name in ("kick", "snare"):
            s = np.tanh(style.distortion * s) / np.tanh(style.distortion)
        sounds[name] = s
    return sounds


# Mastering of the synthetic songs, drawn per song so that the training music spans what real recordings do.
LOUDNESS_RANGE_LUFS = (-30.0, -6.0)  # quiet ambient to loud modern masters (BS.1770 integrated loudness)
DYNAMICS = ("clean", "limited", "clipped")
DYNAMICS_PROBS = (0.4, 0.35, 0.25)
TILT_HZ = 2000.0  # brightness: gain of everything above this, relative to below
TILT_RANGE_DB = (-15.0, 9.0)
EQ_RANGE_HZ = (150.0, 4000.0)  # one broad resonance (a room, a cabinet, a voice) boosted or cut
EQ_RANGE_DB = (-9.0, 12.0)
NOISE_RANGE = (0.001, 0.1)  # broadband noise (hiss, distortion, crowd) relative to full scale
SUSTAIN_PROB = 0.5  # songs with a sustained, distorted chord layer (guitars, synths) filling the gaps
SUSTAIN_RANGE = (0.05, 0.35)  # its level against the drums' peak
LEAD_PROB = 0.6  # songs with a melody: one note per beat or two, from the key's pentatonic scale
LEAD_RANGE = (0.1, 0.5)
TRANSPOSE_RANGE = (-5, 6)  # semitones: the genre's key moved per song, so chroma covers every pitch class
OFFBEAT_PROB = 0.7  # songs with an off-beat layer (with ``offbeats``): one hit halfway between every two beats
OFFBEAT_RANGE = (0.15, 0.6)  # its level against a beat's hit (1.0)
OFFBEAT_SOUNDS = ("openhat", "tone", "clap", "snare")  # hats, a chord stab (a skank), claps, a snare


@dataclass(frozen=True)
class Mastering:
    """How one synthetic song is mixed and mastered after its instruments are played."""

    loudness_lufs: float
    dynamics: str  # "clean", "limited" (soft limiter, tanh) or "clipped" (driven into hard clipping)
    drive_db: float  # gain into the limiter or the clipper
    tilt_db: float  # spectral tilt above TILT_HZ: > 0 brighter, < 0 darker
    noise: float
    sustain: float
    transpose: int = 0
    lead: float = 0.0
    lead_wave: str = "sine"
    eq_hz: float = 1000.0
    eq_db: float = 0.0
    offbeat: float = 0.0  # level of the off-beat layer (0: none)
    offbeat_sound: str = "openhat"


def draw_mastering(rng: np.random.Generator, offbeats: bool = True) -> Mastering:
    """One song's mastering; with ``offbeats`` also its off-beat layer (drawn last: without it the draws, and so
    the songs, are those of the dataset before the layer existed)."""
    dynamics = str(rng.choice(DYNAMICS, p=DYNAMICS_PROBS))
    m = Mastering(
        loudness_lufs=float(rng.uniform(*LOUDNESS_RANGE_LUFS)),
        dynamics=dynamics,
        drive_db=float(rng.uniform(3.0, 18.0)) if dynamics != "clean" else 0.0,
        tilt_db=float(rng.uniform(*TILT_RANGE_DB)),
        noise=float(np.exp(rng.uniform(*np.log(NOISE_RANGE)))),
        sustain=float(rng.uniform(*SUSTAIN_RANGE)) if rng.random() < SUSTAIN_PROB else 0.0,
        transpose=int(rng.integers(TRANSPOSE_RANGE[0], TRANSPOSE_RANGE[1] + 1)),
        lead=float(rng.uniform(*LEAD_RANGE)) if rng.random() < LEAD_PROB else 0.0,
        lead_wave=str(rng.choice(["sine", "triangle", "saw", "square"])),
        eq_hz=float(np.exp(rng.uniform(*np.log(EQ_RANGE_HZ)))),
        eq_db=float(rng.uniform(*EQ_RANGE_DB)),
    )
    if not offbeats:
        return m
    level = float(rng.uniform(*OFFBEAT_RANGE)) if rng.random() < OFFBEAT_PROB else 0.0
    return replace(m, offbeat=level, offbeat_sound=str(rng.choice(OFFBEAT_SOUNDS)))


def _one_pole_lowpass(x: np.ndarray, cutoff_hz: float, sample_rate_hz: int) -> np.ndarray:
    a = np.exp(-2 * np.pi * cutoff_hz / sample_rate_hz)
    return lfilter([1 - a], [1, -a], x)


def master(audio: np.ndarray, sample_rate_hz: int, m: Mastering, rng: np.random.Generator | None = None) -> np.ndarray:
    """Colour, compress or clip ``audio`` (peak about 0.9) and set its loudness to ``m.loudness_lufs``.

    Samples past full scale after the loudness gain are clipped, as a 16-bit master would be, so the loudest
    songs measure a little below their target.
    """
    sr = sample_rate_hz
    rng = rng if rng is not None else np.random.default_rng(0)
    n = len(audio)
    x = audio.astype(np.float64)
    x = x + m.noise * rng.standard_normal(n)
    low = _one_pole_lowpass(x, TILT_HZ, sr)
    x = low + 10.0 ** (m.tilt_db / 20.0) * (x - low)
    if m.eq_db != 0.0 and m.eq_hz < sr / 2:
        b, a = iirpeak(m.eq_hz, 1.0, fs=sr)
        x = x + (10.0 ** (m.eq_db / 20.0) - 1.0) * lfilter(b, a, x)
    x = x / (np.abs(x).max() + 1e-12)
    drive = 10.0 ** (m.drive_db / 20.0)
    if m.dynamics == "limited":
        x = np.tanh(drive * x)
    elif m.dynamics == "clipped":
        x = np.clip(drive * x, -1.0, 1.0)
    loudness = integrated_loudness(x, sr)
    if np.isfinite(loudness):
        x = x * 10.0 ** ((m.loudness_lufs - loudness) / 20.0)
    return np.clip(x, -1.0, 1.0)


def _melody(
    root_hz: float, kind: str, beat_times: np.ndarray, total: int, sample_rate_hz: int, rng: np.random.Generator
) -> np.ndarray:
    """A lead line: notes from the pentatonic scale over two octaves above ``root_hz``, each starting on a beat
    (so it adds pitch and timbre, not off-beat onsets) and lasting one or two beats, with a little vibrato."""
    sr = sample_rate_hz
    scale = np.array([0, 2, 4, 7, 9, 12, 14, 16, 19, 21, 24])
    freq = np.zeros(total)
    env = np.zeros(total)
    starts = [int(round(b * sr)) for b in beat_times[:: int(rng.integers(1, 3))]] + [total]
    for begin, end in zip(starts[:-1], starts[1:], strict=False):
        if begin >= total or rng.random() < 0.2:  # a rest now and then
            continue
        n = end - begin
        freq[begin:end] = 2 * root_hz * 2.0 ** (rng.choice(scale) / 12)
        k = np.arange(n) / sr
        env[begin:end] = (1 - np.exp(-k / 0.02)) * np.exp(-k / float(rng.uniform(0.3, 2.0)))
    t = np.arange(total) / sr
    phase = np.cumsum(freq * (1 + 0.004 * np.sin(2 * np.pi * 5.5 * t))) / sr
    return _wave(kind, phase) * env


def beat_period_s(bpm: float) -> float:
    return 60.0 / bpm


def synthesize_music(
    genre: str,
    bpm: float,
    seconds: float,
    *,
    first_beat_s: float,
    sample_rate_hz: int,
    rng: np.random.Generator,
    mastering: Mastering | None = None,
    offbeats: bool = True,
) -> tuple[np.ndarray, np.ndarray]:
    """A genre's drum-machine loop at ``bpm``, mixed and mastered (see :func:`master`).

    Returns audio (S,) float32 in [-1, 1] and the beat times (B,) in seconds: one beat every 60 / bpm seconds
    from ``first_beat_s``. ``rng`` varies the sounds, the chord progression and, unless ``mastering`` is given,
    the mastering (loudness, dynamics, brightness, noise, a sustained layer and, with ``offbeats``, an off-beat
    layer: :func:`draw_mastering`).
    """
    m = mastering if mastering is not None else draw_mastering(rng, offbeats)
    style = MUSIC_STYLES[genre]
    style = replace(style, root_hz=style.root_hz * 2.0 ** (m.transpose / 12))
    sr = sample_rate_hz
    total = int(round(seconds * sr))
    period_s = beat_period_s(bpm)
    beat_times = np.arange(first_beat_s, seconds, period_s)
    sounds = _instrument_sounds(style, sr, rng)
    # Every beat also gets a short broadband click, so that the beats, not quieter off-beat cymbals, carry the
    # strongest onsets in every frequency band.
    hits = style.hits + _on_beats("hat", 0.5)
    if m.offbeat > 0:
        hits = hits + _on_beats(m.offbeat_sound, m.offbeat, EIGHTHS_OFF)
    out = np.zeros(total + max(len(s) for s in sounds.values()), dtype=np.float64)  # tail room for the last hits

    # Bars start one beat-pattern before the first beat so that pickup events fill the start.
    bar_starts = np.arange(first_beat_s - 4 * period_s, seconds, 4 * period_s)
    for hit in hits:
        sound = sounds[hit.instrument]
        for bar_start in bar_starts:
            start = int(round((bar_start + hit.beat * period_s) * sr))
            if start < 0 or start >= total:
                continue
            # Small per-hit loudness variation, like a human on a drum machine's velocity knob.
            gain = hit.gain * (1.0 + 0.05 * rng.standard_normal())
            out[start : start + len(sound)] += gain * sound

    # A pad changing chord on every bar's downbeat, with a slow attack (no extra onsets), and a soft noise bed
    # so that quiet sub-beat events make small onsets.
    t = np.arange(total) / sr
    progression = rng.choice([1.0, 1.335, 1.5, 1.122, 0.891], size=len(bar_starts) + 1)
    bar_index = np.clip(((t - bar_starts[0]) // (4 * period_s)).astype(int), 0, len(progression) - 1)
    root = style.root_hz * progression[bar_index]
    pad_phase = np.cumsum(root) / sr
    pad = sum(np.sin(2 * np.pi * k * pad_phase) for k in (1.0, 1.5, 2.0)) / 3
    out[:total] += style.pad_gain * pad * (1 - np.exp(-t / 0.5))
    if m.sustain > 0:
        # A distorted power chord (root, fifth, octave) following the pad: sustained energy between the hits.
        chord = sum(_wave("saw", k * pad_phase) for k in (0.5, 0.75, 1.0))
        out[:total] += m.sustain * np.tanh(2.0 * chord) * (1 - np.exp(-t / 0.3))
    if m.lead > 0:
        out[:total] += m.lead * _melody(style.root_hz, m.lead_wave, beat_times, total, sr, rng)
    out[:total] += 0.015 * _bandpass_noise(total, 100, 16000, sr, rng)

    audio = out[:total]
    audio = audio / (np.abs(audio).max() + 1e-12) * 0.9
    audio = master(audio, sr, m, rng)
    return audio.astype(np.float32), beat_times


def wav_bytes(audio: np.ndarray, sample_rate_hz: int) -> bytes:
    """Mono 16-bit PCM WAV file contents for ``audio`` (S,) in [-1, 1] (deterministic bytes)."""
    pcm = np.clip(np.round(audio * 32767.0), -32768, 32767).astype("<i2")
    buffer = io.BytesIO()
    with wave.open(buffer, "wb") as w:
        w.setnchannels(1)
        w.setsampwidth(2)
        w.setframerate(sample_rate_hz)
        w.writeframes(pcm.tobytes())
    return buffer.getvalue()
