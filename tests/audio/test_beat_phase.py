"""The beat-phase columns (``audio.beat_phase``): sin and cos of the phase within the beat after any encoder's own."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from audio_synth import click_track
from transformers import EncodecConfig

from dgsdp.audio import EncodecEncoder, FeatureCache, LibrosaEncoder
from dgsdp.audio.base import beat_phase_columns
from dgsdp.audio.librosa_encoder import BEAT_COLUMN

SR = 15360


def phase_of(columns: np.ndarray) -> np.ndarray:
    return np.mod(np.arctan2(columns[:, 0], columns[:, 1]) / (2 * math.pi), 1.0)


def test_phase_rises_from_each_beat_to_the_next():
    beats = np.array([10, 20, 40])
    columns = beat_phase_columns(beats, 50)
    assert columns.shape == (50, 2) and columns.dtype == np.float32
    np.testing.assert_allclose(np.hypot(columns[:, 0], columns[:, 1]), 1.0, atol=1e-6)
    expected = []
    for t in range(50):  # written out: before the first beat and after the last, the nearest interval runs on
        if t < 20:
            expected.append((t - 10) / 10)
        else:
            expected.append((t - 20) / 20)
    expected = np.mod(expected, 1.0)
    distance = np.abs(phase_of(columns) - expected)
    np.testing.assert_allclose(np.minimum(distance, 1 - distance), 0.0, atol=1e-6)
    assert np.allclose(columns[[10, 20, 40]], [[0.0, 1.0]] * 3, atol=1e-6)  # on a beat: phase 0
    assert np.allclose(columns[30], [0.0, -1.0], atol=1e-6)  # half way between 20 and 40
    # no tempo without two beats: both columns 0
    assert not beat_phase_columns(np.array([5]), 20).any() and not beat_phase_columns(np.array([]), 20).any()


def test_librosa_encoder_appends_the_phase_of_its_own_beats():
    y = click_track(12.0, 120.0, SR)
    plain = LibrosaEncoder().encode(y, SR, music_id="mBR4")
    phased_encoder = LibrosaEncoder(beat_phase=True)
    phased = phased_encoder.encode(y, SR, music_id="mBR4")
    assert phased_encoder.feature_dim == 35 and phased_encoder.output_dim == 37
    assert phased.shape == (360, 37)
    np.testing.assert_array_equal(phased[:, :35], plain)  # the encoder's own columns are unchanged
    beats = np.flatnonzero(plain[:, BEAT_COLUMN])
    np.testing.assert_array_equal(phased[:, 35:], beat_phase_columns(beats, 360))
    # a click every 15 frames: half way between two beats the phase is 1/2
    middle = beats[2] + (beats[3] - beats[2]) // 2
    assert beats[3] - beats[2] == 15 and phase_of(phased[[middle], 35:])[0] == pytest.approx(7 / 15, abs=1e-6)
    # the cache keeps the two apart; settings() (the encoder's own) does not change
    assert FeatureCache.namespace(phased_encoder) != FeatureCache.namespace(LibrosaEncoder())
    assert phased_encoder.settings() == LibrosaEncoder().settings()


def test_other_encoders_track_the_beats_with_librosa():
    torch.manual_seed(0)
    config = EncodecConfig(num_filters=4, num_residual_layers=1, hidden_size=16, codebook_size=32, codebook_dim=16,
                           num_lstm_layers=1)  # fmt: skip
    encoder = EncodecEncoder.from_config(config, device="cpu", beat_phase=True)
    y = click_track(10.0, 100.0, 24000)
    features = encoder.encode(y, 24000)
    assert encoder.output_dim == 18 and features.shape == (300, 18)
    on_beat = np.flatnonzero(np.isclose(features[:, 16], 0.0, atol=1e-6) & (features[:, 17] > 0.99))
    assert np.median(np.diff(on_beat)) == pytest.approx(18, abs=1)  # 100 BPM: a beat every 18 frames
