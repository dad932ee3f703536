"""``audio.rhythm_only``: the librosa features without their timbre (MFCC) and harmony (chroma) columns."""

from __future__ import annotations

import numpy as np
from audio_synth import click_track

from dgsdp.audio import LibrosaEncoder
from dgsdp.audio.librosa_encoder import BEAT_COLUMN, CHROMA_COLUMNS, ENVELOPE_COLUMN, MFCC_COLUMNS, PEAK_COLUMN

SR = 15360


def test_rhythm_only_zeroes_mfcc_and_chroma_and_keeps_the_rhythm_columns():
    y = click_track(8.0, 100.0, SR) + 0.05 * np.sin(2 * np.pi * 440.0 * np.arange(8 * SR) / SR)
    full = LibrosaEncoder().encode(y, SR)
    rhythm = LibrosaEncoder(rhythm_only=True).encode(y, SR)
    assert rhythm.shape == full.shape == (240, 35)
    assert np.abs(full[:, MFCC_COLUMNS]).max() > 0.1 and np.abs(full[:, CHROMA_COLUMNS]).max() > 0.1
    assert not rhythm[:, MFCC_COLUMNS].any() and not rhythm[:, CHROMA_COLUMNS].any()
    for column in (ENVELOPE_COLUMN, PEAK_COLUMN, BEAT_COLUMN):
        np.testing.assert_array_equal(rhythm[:, column], full[:, column])
    assert full[:, BEAT_COLUMN].sum() >= 10  # a click track at 100 BPM: the beats are there to keep


def test_rhythm_only_is_a_setting_only_when_on():
    # full-feature runs keep their settings, so their feature caches and checkpoints are unchanged
    assert "rhythm_only" not in LibrosaEncoder().settings()
    assert LibrosaEncoder(rhythm_only=True).settings()["rhythm_only"] is True
