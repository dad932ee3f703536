"""Off-beat layers of the synthetic songs (``data.synthetic.offbeats``) and regeneration of outdated datasets."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from dgsdp.audio.numba_cache import librosa
from dgsdp.data.datamodule import DanceDataModule
from dgsdp.data.synthetic import MANIFEST, generate_synthetic_aistpp, outdated_synthetic, read_manifest
from dgsdp.data.synthetic_music import (
    OFFBEAT_PROB,
    OFFBEAT_RANGE,
    OFFBEAT_SOUNDS,
    Mastering,
    draw_mastering,
    synthesize_music,
)

SR = 22050
HOP = 512
BPM = 100.0
FIRST_BEAT_S = 0.2


def envelope_by_eighth(y: np.ndarray) -> np.ndarray:
    """Mean onset strength in each eighth of the beat (the true beat grid), computed with librosa directly."""
    env = librosa.onset.onset_strength(y=y, sr=SR, hop_length=HOP)
    t = np.arange(len(env)) * HOP / SR
    eighth = np.floor(((t - FIRST_BEAT_S) * BPM / 60.0 % 1.0) * 8).astype(int)
    return np.array([env[eighth == k].mean() for k in range(8)])


@pytest.mark.parametrize("sound", OFFBEAT_SOUNDS)
def test_offbeat_layer_adds_onsets_halfway_between_the_beats(sound):
    # Boom bap has only quiet hats between its beats: with the layer the half beat gets strong onsets (the songs are
    # mastered to one loudness, so the beats' own onsets get weaker); at a middle level the beat tracker (with the
    # music id's tempo, as the features use it) still puts the beats on the beats.
    plain = Mastering(loudness_lufs=-14.0, dynamics="clean", drive_db=0.0, tilt_db=0.0, noise=0.001, sustain=0.0)
    songs = {}
    for level in (0.0, 0.3, 0.5):
        m = replace(plain, offbeat=level, offbeat_sound=sound)
        y, _ = synthesize_music(
            "MH", BPM, 8.0, first_beat_s=FIRST_BEAT_S, sample_rate_hz=SR, rng=np.random.default_rng(0), mastering=m
        )
        songs[level] = y
    without, with_layer = envelope_by_eighth(songs[0.0]), envelope_by_eighth(songs[0.5])
    assert with_layer[4] > 1.4 * without[4], (without, with_layer)  # the eighth that starts at the half beat
    assert np.allclose(with_layer[1:4], without[1:4], rtol=0.25, atol=0.1)  # nothing else between the beats
    _, beats = librosa.beat.beat_track(y=songs[0.3], sr=SR, hop_length=HOP, start_bpm=BPM, tightness=100.0)
    phase = ((beats * HOP / SR - FIRST_BEAT_S) * BPM / 60.0) % 1.0
    assert np.mean((phase < 0.2) | (phase > 0.9)) >= 0.9, phase


def test_offbeat_draws_come_last_so_that_songs_without_them_are_the_earlier_ones():
    for seed in range(20):
        drawn = draw_mastering(np.random.default_rng(seed), offbeats=True)
        assert replace(drawn, offbeat=0.0, offbeat_sound="openhat") == draw_mastering(
            np.random.default_rng(seed), offbeats=False
        )
    rng = np.random.default_rng(3)
    draws = [draw_mastering(rng) for _ in range(400)]
    levels = np.array([d.offbeat for d in draws])
    assert abs(np.mean(levels > 0) - OFFBEAT_PROB) < 0.08
    assert levels[levels > 0].min() >= OFFBEAT_RANGE[0] and levels.max() <= OFFBEAT_RANGE[1]
    assert {d.offbeat_sound for d in draws} == set(OFFBEAT_SOUNDS)
    assert all(d.offbeat == 0.0 for d in (draw_mastering(rng, offbeats=False) for _ in range(50)))


TINY = {"sequences_per_genre": 2, "seconds": 3.0, "genres": ["BR"], "num_ignored": 0, "sample_rate_hz": 22050}


def test_a_dataset_made_with_other_settings_is_outdated(tmp_path: Path):
    root = generate_synthetic_aistpp(tmp_path / "syn", offbeats=False, **TINY)
    assert read_manifest(root)["settings"]["offbeats"] is False
    assert not outdated_synthetic(root, offbeats=False, **TINY)
    assert outdated_synthetic(root, offbeats=True, **TINY)
    # written before the setting existed: the same songs as offbeats=False
    manifest = json.loads((root / MANIFEST).read_text())
    del manifest["settings"]["offbeats"]
    (root / MANIFEST).write_text(json.dumps(manifest))
    assert not outdated_synthetic(root, offbeats=False, **TINY)
    assert outdated_synthetic(root, offbeats=True, **TINY)
    assert not outdated_synthetic(tmp_path / "nothing-here", **TINY)


def test_the_datamodule_regenerates_an_outdated_synthetic_dataset_in_its_own_folder_only(tmp_path: Path):
    root = generate_synthetic_aistpp(tmp_path / "syn", offbeats=False, **TINY)
    before = (root / "wavs" / "mBR0.wav").read_bytes()
    wanted = {**TINY, "offbeats": True}
    # given as data.root elsewhere: used as it is (a dataset made on purpose with its own settings)
    DanceDataModule(str(root), str(tmp_path / "cache"), synthetic=wanted, progress=False).prepare_data()
    assert (root / "wavs" / "mBR0.wav").read_bytes() == before
    assert outdated_synthetic(root, **wanted)
    # the synthetic dataset's own folder: made again with the settings asked for
    own = DanceDataModule(
        str(root), str(tmp_path / "cache"), synthetic=wanted, synthetic_root=str(root), progress=False
    )
    own.prepare_data()
    assert read_manifest(root)["settings"]["offbeats"] is True
    assert not outdated_synthetic(root, **wanted)
    assert (root / "wavs" / "mBR0.wav").read_bytes() != before
