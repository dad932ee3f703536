"""The second beat tracker (spectral flux, comb-filter tempo, grid phase) against songs whose beats are known, and
the beat measures against answers worked out by hand."""

import math

import numpy as np
import pytest

from dgsdp.audio import beat_tracker as bt
from dgsdp.data.synthetic_music import synthesize_music


def test_beat_f_measure_by_hand():
    ref = np.array([1.0, 2.0, 3.0, 4.0])
    assert bt.beat_f_measure(ref, ref) == 1.0
    # 3 of 4 within 70 ms (one 60 ms late, one 100 ms late: missed), plus one extra beat: P = 3/5, R = 3/4
    est = np.array([1.0, 2.06, 3.1, 4.0, 4.5])
    assert bt.beat_f_measure(est, ref) == pytest.approx(2 * 0.6 * 0.75 / (0.6 + 0.75))
    # one estimated beat between two reference beats matches one of them only
    assert bt.beat_f_measure(np.array([1.5]), np.array([1.45, 1.55])) == pytest.approx(2 * 1 * 0.5 / 1.5)
    assert bt.beat_f_measure(ref + 0.5, ref) == 0.0  # the off-beats find none
    assert bt.beat_f_measure(np.array([]), ref) == 0.0


def test_tempo_agreement_rules():
    assert bt.tempo_agrees(123.0, 120.0) and not bt.tempo_agrees(125.0, 120.0)  # 2.5% in, 4.2% out
    assert not bt.tempo_agrees(240.0, 120.0) and bt.tempo_agrees(240.0, 120.0, octaves=True)
    assert not bt.tempo_agrees(math.nan, 120.0)
    grid = bt.TrackedBeats(120.0, np.arange(0, 600, 15))  # 120 BPM at 30 FPS: every 15 frames
    assert bt.trackers_agree(grid, bt.TrackedBeats(120.0, np.arange(0, 600, 15)))[0]
    assert not bt.trackers_agree(grid, bt.TrackedBeats(120.0, np.arange(7, 600, 15)))[0]  # the off-beats
    three_two = bt.TrackedBeats(180.0, np.arange(0, 600, 10))  # 3:2: every other beat of it lands on one of ours
    agree, f = bt.trackers_agree(grid, three_two)
    assert not agree and 0 < f < 1
    assert not bt.trackers_agree(grid, bt.TrackedBeats(240.0, np.arange(0, 600, 7.5).round().astype(int)))[0]


@pytest.mark.parametrize(("genre", "bpm", "first"), [("BR", 80.0, 0.31), ("HO", 125.0, 0.17), ("JS", 135.0, 0.42)])
def test_tracker_finds_the_known_beats_of_a_synthetic_song(genre, bpm, first):
    audio, beats_s = synthesize_music(genre, bpm, 12.0, first_beat_s=first, sample_rate_hz=bt.SAMPLE_RATE,
                                      rng=np.random.default_rng(3))  # fmt: skip
    found = bt.track_beats(audio)
    assert bt.tempo_agrees(found.bpm, bpm)
    assert bt.beat_f_measure(found.frames / bt.FPS, beats_s) >= 0.9
    # the same song half a beat later: the tracker follows it (its beats are not a fixed grid)
    late = np.concatenate([np.zeros(int(round(30.0 / bpm * bt.SAMPLE_RATE)), dtype=audio.dtype), audio])
    moved = bt.track_beats(late)
    assert bt.beat_f_measure(moved.frames / bt.FPS, beats_s + 30.0 / bpm) >= 0.9


def test_tracker_on_silence_and_a_short_clip():
    assert bt.track_beats(np.zeros(bt.SAMPLE_RATE * 3)).frames.size == 0
    assert bt.track_beats(np.random.default_rng(0).standard_normal(bt.SAMPLE_RATE)).frames.size == 0
    with pytest.raises(ValueError, match="15360 Hz"):
        bt.spectral_flux(np.zeros(1000), 22050)
    novelty, low = bt.spectral_flux(np.zeros(bt.SAMPLE_RATE * 2))
    assert novelty.shape == low.shape == (61,) and not novelty.any()


def test_the_librosa_features_can_take_their_beats_from_the_independent_tracker():
    from dgsdp.audio import LibrosaEncoder
    from dgsdp.audio.librosa_encoder import BEAT_COLUMN
    from dgsdp.errors import ConfigError

    audio, beats_s = synthesize_music("HO", 125.0, 10.0, first_beat_s=0.2, sample_rate_hz=bt.SAMPLE_RATE,
                                      rng=np.random.default_rng(5))  # fmt: skip
    flux = LibrosaEncoder(beat_tracker="flux")
    features = flux.encode(audio, bt.SAMPLE_RATE)
    beat_column = np.flatnonzero(features[:, BEAT_COLUMN])
    assert np.array_equal(beat_column, bt.track_beats(audio).frames[bt.track_beats(audio).frames < len(features)])
    assert bt.beat_f_measure(beat_column / bt.FPS, beats_s) >= 0.9
    default = LibrosaEncoder()
    assert np.array_equal(default.encode(audio, bt.SAMPLE_RATE)[:, :BEAT_COLUMN], features[:, :BEAT_COLUMN])
    # the setting is part of the features' identity only when it is not the default (EDGE's features unchanged)
    assert flux.settings()["beat_tracker"] == "flux" and "beat_tracker" not in default.settings()
    with pytest.raises(ConfigError, match="beat_tracker must be one of"):
        LibrosaEncoder(beat_tracker="madmom")
    with pytest.raises(ConfigError, match="sample_rate=15360"):
        LibrosaEncoder(beat_tracker="flux", sample_rate=30720, hop_length=1024)


def test_the_tracker_benchmark_measures_both_trackers_on_known_beats(tmp_path, capsys):
    import json

    from dgsdp.benchmarks.beat_trackers import main
    from dgsdp.data.synthetic import generate_synthetic_aistpp

    root = generate_synthetic_aistpp(tmp_path / "data", sequences_per_genre=2, seconds=8.0, genres=["HO"],
                                     num_ignored=0, sample_rate_hz=bt.SAMPLE_RATE)  # fmt: skip
    songs = tmp_path / "songs"
    songs.mkdir()
    (songs / "a.wav").symlink_to(next((root / "wavs").glob("*.wav")))
    assert main([str(root), "--songs", str(songs), "--json", str(tmp_path / "t.json")]) == 0
    printed = capsys.readouterr().out
    figures = json.loads((tmp_path / "t.json").read_text())
    n = figures["synthetic"]["flux"]["songs"]
    assert n == len(json.loads((root / "synthetic.json").read_text())["music"]) >= 2
    assert set(figures["synthetic"]) == {"flux", "librosa", "librosa_id_prior"}
    from dgsdp.audio.io import load_audio
    from dgsdp.data.synthetic import music_beat_times_s, read_manifest

    manifest, fs, tempi = read_manifest(root), [], 0
    for music_id, info in manifest["music"].items():  # the flux row recomputed song by song
        found = bt.track_beats(load_audio(root / "wavs" / f"{music_id}.wav", bt.SAMPLE_RATE)[0])
        fs.append(bt.beat_f_measure(found.frames / bt.FPS, music_beat_times_s(manifest, music_id)))
        tempi += bt.tempo_agrees(found.bpm, info["bpm"])
    assert figures["synthetic"]["flux"]["f_measure"] == pytest.approx(np.mean(fs))
    assert figures["synthetic"]["flux"]["tempo_within_4pct"] == tempi
    assert f"synthetic flux: songs={n} f_measure_70ms=" in printed
    assert figures["songs"][0]["song"].endswith("a.wav") and "real songs: the trackers agree on " in printed
