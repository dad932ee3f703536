"""Tempo folding (``sampling.tempo_fold``): a song far faster or slower than the training music is given to the
model in half or double time; the numbers here are worked out by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest
from audio_synth import click_track

from dgsdp.audio import LibrosaEncoder
from dgsdp.audio.base import AudioEncoder, beat_phase_columns
from dgsdp.audio.librosa_encoder import BEAT_COLUMN, ENVELOPE_COLUMN
from dgsdp.audio.tempo import TempoFold, beats_tempo_bpm, fold_beats, fold_octaves, training_tempo_range

SR = 15360


def test_training_range_from_music_ids_widened_by_tempo_augment():
    ids = ["gBR_sBM_cAll_d04_mBR0_ch01", "mKR5", "gHO_sBM_cAll_d19_mHO5_ch02", "not-a-music-id"]
    assert training_tempo_range(ids) == (80.0, 135.0)  # mBR0 80, mKR5 130, mHO5 110 + 5 * 5 = 135
    assert training_tempo_range(ids, (0.8, 1.25)) == pytest.approx((64.0, 168.75))
    assert training_tempo_range(["my_song", "other"]) is None


def test_tempo_of_beat_frames():
    assert beats_tempo_bpm(np.arange(0, 300, 15), 30) == pytest.approx(120.0)  # a beat every half second
    assert beats_tempo_bpm(np.array([3, 14, 25, 36, 47]), 30) == pytest.approx(60 * 30 / 11)
    # 160 BPM falls on frames 11 and 12 apart (11.25 on average); a missed beat (a gap of 23) is left out
    assert beats_tempo_bpm(np.array([0, 11, 23, 34, 45, 68, 79, 90]), 30) == pytest.approx(60 * 30 / (67 / 6))
    assert math.isnan(beats_tempo_bpm(np.array([7]), 30))


@pytest.mark.parametrize(
    ("bpm", "octaves"),
    [
        (100.0, 0),  # inside 80-135
        (135.0, 0),
        (140.0, 0),  # 140 is 0.05 octaves above, 70 is 0.19 below: stays
        (146.0, 0),  # sqrt(2 * 80 * 135) = 146.97 is where half time gets nearer
        (148.0, 1),
        (163.6, 1),  # 81.8: inside
        (300.0, 2),  # 75 (0.09 octaves below 80) beats 150 (0.15 above 135)
        (75.0, 0),  # 0.09 octaves below, 150 would be 0.15 above
        (55.0, -1),  # 110: inside
        (20.0, -2),  # 80
        (2000.0, 2),  # at most two octaves
        (math.nan, 0),
    ],
)
def test_fold_octaves_takes_the_nearest_tempo_to_the_training_range(bpm, octaves):
    assert fold_octaves(bpm, (80.0, 135.0)) == octaves


def test_fold_beats_keeps_the_stronger_half_or_adds_beats_between():
    beats = np.array([10, 20, 30, 40, 50, 60])
    np.testing.assert_array_equal(fold_beats(beats, 0), beats)
    np.testing.assert_array_equal(fold_beats(beats, 1), [10, 30, 50])  # no strength: from the first beat
    strength = np.zeros(70)
    strength[[20, 40, 60]] = 1.0  # the odd beats are the loud ones
    np.testing.assert_array_equal(fold_beats(beats, 1, strength), [20, 40, 60])
    strength[[30]] = 5.0  # every fourth beat from 30 is the loudest of the four offsets
    np.testing.assert_array_equal(fold_beats(beats, 2, strength), [30])
    np.testing.assert_array_equal(fold_beats(np.array([0, 10, 21]), -1), [0, 5, 10, 16, 21])  # 15.5 rounds to 16
    np.testing.assert_array_equal(fold_beats(np.array([0, 12]), -2), [0, 3, 6, 9, 12])


def test_describe_says_what_the_model_was_given():
    assert TempoFold(163.6, 1, (80.0, 135.0)).describe() == (
        "163.6 BPM, given in half time (81.8 BPM; trained on 80-135 BPM)"
    )
    assert TempoFold(100.0).describe() == "100.0 BPM, beats as tracked"
    assert TempoFold(55.0, -1, (80.0, 135.0)).given_bpm == pytest.approx(110.0)


def test_encoders_read_and_rewrite_the_beats_they_give():
    y = click_track(12.0, 160.0, SR)
    encoder = LibrosaEncoder(beat_phase=True)
    feats = encoder.encode(y, SR, music_id="my_song")
    beats = np.flatnonzero(feats[:, BEAT_COLUMN])
    assert beats_tempo_bpm(beats, 30) == pytest.approx(160.0, rel=0.01)
    np.testing.assert_array_equal(encoder.feature_beats(feats), beats)
    # the phase columns alone (what an Encodec or Jukebox model with beat_phase gives) name the same beats, and
    # before the first and after the last the beats at the nearest interval, where the phase runs on through 0
    from_phase = AudioEncoder.feature_beats(encoder, feats)
    inside = (from_phase >= beats[0]) & (from_phase <= beats[-1])
    np.testing.assert_array_equal(from_phase[inside], beats)
    np.testing.assert_array_equal(from_phase[from_phase < beats[0]], beats[0] - (beats[1] - beats[0]) * np.arange(1, 2))
    after = from_phase[from_phase > beats[-1]]
    np.testing.assert_array_equal(after, beats[-1] + (beats[-1] - beats[-2]) * np.arange(1, len(after) + 1))
    halved = fold_beats(beats, 1, encoder.beat_strength(feats))
    folded = encoder.with_beats(feats, halved)
    np.testing.assert_array_equal(np.flatnonzero(folded[:, BEAT_COLUMN]), halved)
    np.testing.assert_array_equal(folded[:, 35:], beat_phase_columns(halved, len(feats)))
    np.testing.assert_array_equal(folded[:, :BEAT_COLUMN], feats[:, :BEAT_COLUMN])  # nothing else changes
    np.testing.assert_array_equal(encoder.beat_strength(feats), feats[:, ENVELOPE_COLUMN])
    assert not np.shares_memory(folded, feats)
    assert LibrosaEncoder().with_beats(feats[:, :35], halved).shape == (len(feats), 35)
