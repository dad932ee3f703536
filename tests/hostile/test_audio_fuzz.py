"""Fuzzed audio through the loader and the librosa encoder path: each input ends in one AudioError that says
what is wrong, or in valid finite features of the right length."""

from __future__ import annotations

import numpy as np
import pytest
import soundfile as sf
from conftest import accepted, refused

from dgsdp.audio import FeatureCache, load_audio
from dgsdp.audio.librosa_encoder import LibrosaEncoder
from dgsdp.errors import AudioError


def write(path, data: np.ndarray, rate_hz: int, subtype: str = "FLOAT"):
    sf.write(str(path), data, rate_hz, subtype=subtype)
    return path


def features(path, tmp_path):
    """The encoder path that training and generation use: the feature cache over the one audio loader."""
    return FeatureCache(tmp_path / "cache").features_for_file(LibrosaEncoder(), path)


@pytest.mark.parametrize(
    "case, fragment",
    [("empty", "empty"), ("one sample", "too short"), ("truncated header", "cannot decode"), ("nan", "nan"),
     ("inf", "infinite"), ("1e30", "full scale"), ("text named .wav", "cannot decode"), ("missing", "not found"),
     ("zero channels of data", "cannot decode")],
)  # fmt: skip
def test_bad_audio_gets_one_audio_error(tmp_path, case, fragment):
    path = tmp_path / "song.wav"
    noise = (0.1 * np.random.default_rng(0).standard_normal(4000)).astype(np.float32)
    if case == "empty":
        path.write_bytes(b"")
    elif case == "one sample":
        write(path, noise[:1], 8000)
    elif case == "truncated header":
        path.write_bytes(write(tmp_path / "full.wav", noise, 8000).read_bytes()[:30])
    elif case == "nan":
        write(path, np.where(np.arange(4000) == 100, np.nan, noise).astype(np.float32), 8000)
    elif case == "inf":
        write(path, np.where(np.arange(4000) == 7, np.inf, noise).astype(np.float32), 8000)
    elif case == "1e30":
        write(path, np.full(4000, 1e30, np.float32), 8000)
    elif case == "text named .wav":
        path.write_text("this is not audio\n" * 20)
    elif case == "zero channels of data":
        path.write_bytes(b"RIFF\x24\x00\x00\x00WAVEfmt \x10\x00\x00\x00\x01\x00\x00\x00" + b"\x00" * 40)
    with pytest.raises(AudioError) as exc:
        features(path, tmp_path)
    refused(exc, str(path.name), fragment)


@pytest.mark.parametrize(
    "rate_hz, channels, subtype",
    [(8000, 1, "PCM_16"), (11025, 2, "PCM_U8"), (44100, 2, "PCM_24"), (48000, 1, "DOUBLE"), (192000, 6, "FLOAT")],
)
def test_unusual_but_valid_formats_give_features(tmp_path, rate_hz, channels, subtype):
    seconds = 0.5
    t = np.arange(int(seconds * rate_hz)) / rate_hz
    data = np.stack([0.3 * np.sin(2 * np.pi * (220 + 50 * c) * t) for c in range(channels)], axis=1)
    path = write(tmp_path / "song.wav", data, rate_hz, subtype)
    wave, sr = load_audio(path, sample_rate=22050, mono=True)
    assert sr == 22050 and wave.ndim == 1 and abs(len(wave) - seconds * 22050) <= 2
    feats = features(path, tmp_path)
    assert feats.shape == (int(seconds * 30), 35) and np.isfinite(feats).all()
    accepted()


def test_loud_float_file_within_limits_is_kept(tmp_path):
    """A float file a little over full scale (a hot master) is valid audio, not an error."""
    data = (3.0 * np.sin(np.arange(8000) / 5)).astype(np.float32)
    wave, _ = load_audio(write(tmp_path / "hot.wav", data, 8000), sample_rate=None)
    assert np.isclose(np.abs(wave).max(), 3.0, rtol=1e-3)
    accepted()
