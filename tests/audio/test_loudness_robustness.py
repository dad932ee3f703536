"""Librosa features are robust to gain, clipping and sample rate (loudness normalisation, band-limited MFCCs).

Each test computes the features both with the default normalisation and with the settings the encoder had
before it (no loudness normalisation, MFCCs up to Nyquist), so it shows that the normalisation is what makes
the difference. Distances are mean absolute differences in units of the original song's per-column std.
"""

from __future__ import annotations

import numpy as np
import pytest

from dgsdp.audio.librosa_encoder import (
    BEAT_COLUMN,
    CHROMA_COLUMNS,
    ENVELOPE_COLUMN,
    MFCC_COLUMNS,
    PEAK_COLUMN,
    LibrosaEncoder,
)
from dgsdp.audio.loudness import integrated_loudness, normalize_loudness
from dgsdp.audio.numba_cache import librosa
from dgsdp.data.synthetic_music import Mastering, synthesize_music
from dgsdp.errors import ConfigError

SR = 22050
MFCC0 = slice(MFCC_COLUMNS.start, MFCC_COLUMNS.start + 1)
GROUPS = {"env": slice(ENVELOPE_COLUMN, ENVELOPE_COLUMN + 1), "mfcc0": MFCC0, "mfcc": MFCC_COLUMNS}
GROUPS["chroma"] = CHROMA_COLUMNS


@pytest.fixture(scope="module")
def song() -> np.ndarray:
    """6 s of a clean synthetic house loop with a melody and a sustained layer, at -20 LUFS."""
    m = Mastering(loudness_lufs=-20.0, dynamics="clean", drive_db=0.0, tilt_db=0.0, noise=0.01, sustain=0.2, lead=0.3)
    y, _ = synthesize_music(
        "HO", 120.0, 6.0, first_beat_s=0.2, sample_rate_hz=SR, rng=np.random.default_rng(3), mastering=m
    )
    return y


@pytest.fixture(scope="module")
def encoders() -> dict[str, LibrosaEncoder]:
    return {"new": LibrosaEncoder(), "old": LibrosaEncoder(**LibrosaEncoder.legacy_settings)}


def distances(encoder: LibrosaEncoder, original: np.ndarray, variant: np.ndarray, rate: int) -> dict[str, float]:
    ref = encoder.encode(original, SR)
    feats = encoder.encode(variant, rate)
    assert feats.shape == ref.shape
    scale = np.maximum(ref.std(axis=0), 1e-3)
    d = np.abs(feats - ref) / scale
    return {group: float(d[:, cols].mean()) for group, cols in GROUPS.items()}


def test_quieter_copy_gives_the_same_features(song, encoders):
    quiet = song * 0.1  # -20 dB
    new = distances(encoders["new"], song, quiet, SR)
    old = distances(encoders["old"], song, quiet, SR)
    assert max(new.values()) < 0.01, new
    assert old["mfcc0"] > 3.0, old  # without normalisation the first MFCC moves by several stds


def test_loud_clipped_copy_stays_close(song, encoders):
    loud = np.clip(song * 10.0, -1.0, 1.0)  # +20 dB into hard clipping
    assert np.mean(np.abs(loud) >= 1.0) > 0.2  # a heavily clipped master
    new = distances(encoders["new"], song, loud, SR)
    old = distances(encoders["old"], song, loud, SR)
    # Loudness normalisation undoes the gain; what is left is the distortion clipping adds to the spectrum.
    assert new["mfcc0"] < 1.0 and new["mfcc"] < 1.0 and new["env"] < 0.5 and new["chroma"] < 0.6, new
    assert old["mfcc0"] > 3.0, old


def test_8khz_copy_stays_close(song, encoders):
    low = librosa.resample(song, orig_sr=SR, target_sr=8000, res_type="soxr_hq")
    new = distances(encoders["new"], song, low, 8000)
    old = distances(encoders["old"], song, low, 8000)
    # MFCCs from the band below 3.5 kHz that an 8 kHz file still holds.
    assert new["mfcc"] < 0.3 and new["mfcc0"] < 0.3 and new["env"] < 0.3 and new["chroma"] < 0.1, new
    assert old["mfcc"] > 2.0, old


@pytest.mark.parametrize("seconds", [0.1, 3.0])
@pytest.mark.parametrize("kind", ["silence", "noise"])
def test_silence_and_short_clips(seconds, kind):
    n = int(seconds * SR)
    y = np.zeros(n, np.float32) if kind == "silence" else np.random.default_rng(0).normal(0, 0.1, n).astype(np.float32)
    for standardize in ("none", "mean", "mean_std"):
        features = LibrosaEncoder(standardize=standardize).encode(y, SR)
        assert features.shape == (int(seconds * 30), 35) and np.isfinite(features).all()
        assert set(np.unique(features[:, [PEAK_COLUMN, BEAT_COLUMN]])) <= {0.0, 1.0}


def test_loudness_of_short_and_silent_audio():
    t = np.arange(int(2.0 * SR)) / SR
    sine = 0.1 * np.sin(2 * np.pi * 997.0 * t)
    # A full-scale 1 kHz sine reads about -3.01 LUFS (BS.1770's reference); 0.1 of it 20 dB less.
    assert integrated_loudness(sine, SR) == pytest.approx(-23.0, abs=0.3)
    assert integrated_loudness(sine[: int(0.1 * SR)], SR) == pytest.approx(-23.0, abs=0.3)  # shorter than a block
    assert integrated_loudness(np.zeros(SR), SR) == float("-inf")
    assert integrated_loudness(np.zeros(10), SR) == float("-inf")
    assert np.array_equal(normalize_loudness(np.zeros(SR, np.float32), SR, -23.0), np.zeros(SR))
    assert integrated_loudness(normalize_loudness(sine * 0.01, SR, -14.0), SR) == pytest.approx(-14.0, abs=0.05)


def test_settings_change_the_cache_key_and_are_checked():
    default, legacy = LibrosaEncoder(), LibrosaEncoder(**LibrosaEncoder.legacy_settings)
    assert default.settings() != legacy.settings()
    assert default.settings()["loudness_lufs"] == -23.0 and legacy.settings()["loudness_lufs"] is None
    for bad in ({"loudness_lufs": 3.0}, {"standardize": "zscore"}, {"mfcc_fmax_hz": 20000.0}):
        with pytest.raises(ConfigError):
            LibrosaEncoder(**bad)


def test_checkpoints_trained_before_normalisation_keep_their_features():
    import dataclasses

    from dgsdp.trained import RunSpec

    spec = RunSpec.from_groups(
        model="small", audio_dim=35, style_dim=10, style_kind="onehot", style_bank_size=10, n_genres=10,
        d_model=32, n_layers=1, n_heads=2, ff_dim=64, music_encoder_layers=1, dropout=0.0,
    )  # fmt: skip
    old_audio = {"_target_": "dgsdp.audio.LibrosaEncoder", "sample_rate": 15360, "use_music_id_tempo": True}
    spec = dataclasses.replace(spec, audio=old_audio)
    # A stored run without the new settings was trained without them ...
    assert (
        spec.build_audio_encoder("checkpoint").settings() == LibrosaEncoder(**LibrosaEncoder.legacy_settings).settings()
    )
    # ... while a new config gets the normalised default, and a stored setting wins over the legacy value.
    assert spec.build_audio_encoder("config").settings() == LibrosaEncoder().settings()
    stored = dataclasses.replace(spec, audio={**old_audio, "standardize": "mean"})
    assert stored.build_audio_encoder("checkpoint").standardize == "mean"
