"""The one audio loader: formats, rates, channel counts, bad files."""

from __future__ import annotations

import numpy as np
import pytest
import soundfile as sf
from audio_synth import flac_without_length, write_audio

from dgsdp.audio import audio_duration_seconds, load_audio
from dgsdp.errors import AudioError


def sine(freq_hz: float, seconds: float, rate_hz: int) -> np.ndarray:
    return (0.5 * np.sin(2 * np.pi * freq_hz * np.arange(int(seconds * rate_hz)) / rate_hz)).astype(np.float32)


def dominant_hz(y: np.ndarray, rate_hz: int) -> float:
    spectrum = np.abs(np.fft.rfft(y * np.hanning(len(y))))
    return float(np.argmax(spectrum) * rate_hz / len(y))


@pytest.mark.parametrize("rate_hz", [8000, 96000])
def test_any_rate_is_resampled_and_keeps_pitch(tmp_path, rate_hz):
    path = write_audio(tmp_path / f"s{rate_hz}.wav", sine(440.0, 2.0, rate_hz), rate_hz)
    y, sr = load_audio(path, sample_rate=15360)
    assert sr == 15360 and y.dtype == np.float32 and y.ndim == 1
    assert abs(len(y) - 2 * 15360) <= 1
    assert dominant_hz(y, sr) == pytest.approx(440.0, abs=1.0)
    assert audio_duration_seconds(path) == pytest.approx(2.0)


def test_six_channels_are_averaged(tmp_path):
    rng = np.random.default_rng(0)
    data = (0.1 * rng.standard_normal((6, 4800))).astype(np.float32)
    path = write_audio(tmp_path / "six.flac", data, 48000)
    mono, sr = load_audio(path, sample_rate=None)
    multi, _ = load_audio(path, sample_rate=None, mono=False)
    assert sr == 48000 and multi.shape == (6, 4800)
    # FLAC is 16-bit by default: compare with the quantisation step of 2**-15.
    np.testing.assert_allclose(multi, data, atol=2**-15)
    np.testing.assert_allclose(mono, data.mean(axis=0), atol=2**-15)


@pytest.mark.parametrize("suffix", [".ogg", ".flac", ".wav"])
def test_formats_round_trip(tmp_path, suffix):
    path = write_audio(tmp_path / f"a{suffix}", sine(300.0, 1.0, 22050), 22050)
    y, sr = load_audio(path, sample_rate=22050)
    assert abs(len(y) - 22050) <= 1 and dominant_hz(y, sr) == pytest.approx(300.0, abs=2.0)


def test_mp3_through_fallback_or_soundfile(tmp_path):
    path = tmp_path / "a.mp3"
    try:
        sf.write(str(path), sine(300.0, 1.0, 22050), 22050, format="MP3")
    except (sf.LibsndfileError, TypeError, ValueError):
        pytest.skip("this libsndfile cannot write mp3")
    y, sr = load_audio(path, sample_rate=16000)
    assert sr == 16000 and dominant_hz(y, sr) == pytest.approx(300.0, abs=3.0)


def test_missing_file_names_the_path(tmp_path):
    with pytest.raises(AudioError, match="not found.*nope.wav"):
        load_audio(tmp_path / "nope.wav", 15360)
    with pytest.raises(AudioError, match="not found"):
        audio_duration_seconds(tmp_path / "nope.wav")


def test_corrupt_and_empty_files(tmp_path):
    corrupt = tmp_path / "corrupt.wav"
    corrupt.write_bytes(b"RIFF\x10\x00\x00\x00WAVEjunk" + bytes(range(256)) * 4)
    with pytest.raises(AudioError, match="Cannot decode.*corrupt.wav"):
        load_audio(corrupt, 15360)
    empty = tmp_path / "empty.wav"
    empty.write_bytes(b"")
    with pytest.raises(AudioError, match="empty"):
        load_audio(empty, 15360)
    no_samples = write_audio(tmp_path / "zero.wav", np.zeros(0, np.float32), 22050)
    with pytest.raises(AudioError, match="no samples"):
        load_audio(no_samples, 15360)


def test_flac_without_a_length_in_its_header(tmp_path):
    path = tmp_path / "stream.flac"
    samples = flac_without_length(path, 3.0)
    assert audio_duration_seconds(path) == pytest.approx(3.0, abs=1e-9)  # counted, not the header's 4e14 s
    wave, rate_hz = load_audio(path, sample_rate=None)
    assert rate_hz == 22050 and wave.shape == samples.shape
    np.testing.assert_allclose(wave, samples, atol=1 / 2**15)  # 16-bit quantisation
