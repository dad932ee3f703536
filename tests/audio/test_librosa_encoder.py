"""EDGE's 35-d librosa features on synthetic click tracks of known tempo."""

from __future__ import annotations

import numpy as np
import pytest
from audio_synth import click_track

from dgsdp.audio import LibrosaEncoder, build_audio_encoder, tempo_from_music_id
from dgsdp.audio.librosa_encoder import BEAT_COLUMN, ENVELOPE_COLUMN, MFCC_COLUMNS, PEAK_COLUMN
from dgsdp.audio.loudness import normalize_loudness
from dgsdp.audio.numba_cache import librosa
from dgsdp.errors import AudioError, ConfigError

SR = 15360


@pytest.mark.parametrize(
    ("music_id", "bpm"),
    [
        ("mBR0", 80.0),
        ("mHO3", 125.0),
        ("mHO0", 110.0),
        ("mJB9", 170.0),
        ("mKR5.wav", 130.0),
        ("gBR_sBM_cAll_d04_mLH1_ch01", 90.0),
        ("mXX1", None),
        ("song", None),
        ("", None),
        (None, None),
    ],
)
def test_tempo_from_music_id(music_id, bpm):
    assert tempo_from_music_id(music_id) == bpm


@pytest.mark.parametrize(("seconds", "n_frames"), [(3.0, 90), (5.0, 150), (240.0, 7200)])
def test_shape_is_30_fps(seconds, n_frames):
    features = LibrosaEncoder().encode(click_track(seconds, 120.0, SR), SR, music_id="mBR4")
    assert features.shape == (n_frames, 35) and features.dtype == np.float32
    assert np.isfinite(features).all()


@pytest.mark.parametrize(("bpm", "music_id"), [(120.0, "mBR4"), (120.0, None), (100.0, "mPO2")])
def test_beat_column_spacing_matches_tempo(bpm, music_id):
    features = LibrosaEncoder().encode(click_track(20.0, bpm, SR), SR, music_id=music_id)
    beats = np.flatnonzero(features[:, BEAT_COLUMN])
    assert set(np.unique(features[:, BEAT_COLUMN])) <= {0.0, 1.0}
    frames_per_beat = 30.0 * 60.0 / bpm  # 15 frames at 120 BPM, 18 at 100 BPM
    assert np.median(np.diff(beats)) == pytest.approx(frames_per_beat, abs=1.0)
    assert len(beats) >= 0.8 * 20.0 * bpm / 60.0


def test_onset_peaks_sit_on_the_clicks():
    features = LibrosaEncoder().encode(click_track(6.0, 120.0, SR), SR)
    peaks = np.flatnonzero(features[:, PEAK_COLUMN])
    clicks = np.arange(15, 180, 15)  # a click every 0.5 s = 15 frames
    # every click after the first is found within one frame, and nothing else is
    distance = np.abs(peaks[:, None] - clicks[None, :]).min(axis=1)
    assert (distance <= 1).all() and len(peaks) >= len(clicks)


def test_envelope_and_mfcc_columns_match_direct_librosa():
    y = click_track(5.0, 120.0, SR)
    features = LibrosaEncoder().encode(y, SR)
    y = normalize_loudness(y, SR, -23.0)  # the default: -23 LUFS, MFCCs of the band below 3.5 kHz
    envelope = librosa.onset.onset_strength(y=y, sr=SR, hop_length=512)
    mfcc = librosa.feature.mfcc(y=y, sr=SR, n_mfcc=20, hop_length=512, fmax=3500.0).T
    # ... and both z-scored over the song (standardize="mean_std")
    envelope = (envelope - envelope.mean()) / envelope.std()
    mfcc = (mfcc - mfcc.mean(axis=0)) / mfcc.std(axis=0)
    np.testing.assert_allclose(features[:, ENVELOPE_COLUMN], envelope[:150], rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(features[:, MFCC_COLUMNS], mfcc[:150], rtol=1e-4, atol=1e-3)


def test_other_rates_and_explicit_length():
    y = click_track(4.0, 120.0, 44100)
    features = LibrosaEncoder().encode(np.stack([y, y]), 44100, n_frames=200)
    assert features.shape == (200, 35)
    np.testing.assert_array_equal(features[120:], np.repeat(features[119:120], 80, axis=0))  # edge padding


def test_silence_gives_features_without_beats():
    features = LibrosaEncoder().encode(np.zeros(3 * SR, np.float32), SR)
    assert features.shape == (90, 35) and np.isfinite(features).all()
    assert features[:, BEAT_COLUMN].sum() == 0 and features[:, PEAK_COLUMN].sum() == 0


def test_very_short_clip_and_too_short_clip():
    assert LibrosaEncoder().encode(click_track(0.2, 120.0, SR), SR).shape == (6, 35)
    with pytest.raises(AudioError, match="too short"):
        LibrosaEncoder().encode(np.zeros(100, np.float32), SR)
    with pytest.raises(AudioError):
        LibrosaEncoder().encode(np.zeros(0, np.float32), SR)


def test_registry_and_bad_settings():
    assert isinstance(build_audio_encoder("librosa"), LibrosaEncoder)
    with pytest.raises(ConfigError, match="Unknown audio encoder"):
        build_audio_encoder("wav2vec")
    with pytest.raises(ValueError, match="30 FPS"):
        LibrosaEncoder(sample_rate=22050)
