"""generate.py end to end on a tiny checkpoint trained here: files written, bad inputs reported clearly."""

import os
import pickle
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf
from gen_helpers import train_tiny_checkpoint, write_click_song

from dgsdp.cli.config import compose_config
from dgsdp.cli.generate import generate
from dgsdp.editing import load_motion_file
from dgsdp.errors import ConfigError, DataError


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory) -> str:
    return train_tiny_checkpoint(tmp_path_factory.mktemp("tiny"))


@pytest.fixture(scope="module")
def songs(tmp_path_factory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("songs")
    paths = {"good": d / "good.wav", "one_second": d / "one_second.flac", "broken": d / "broken.wav",
             "long": d / "twenty_minutes.wav", "missing": d / "missing.mp3"}  # fmt: skip
    write_click_song(paths["good"], 3.0)
    write_click_song(paths["one_second"], 1.0)
    paths["broken"].write_bytes(b"RIFF this is not audio at all" * 50)
    sf.write(paths["long"], np.zeros(1200 * 1000, dtype=np.int16), 1000, subtype="PCM_16")
    return paths


def gen_config(tmp: Path, checkpoint: str, music, *overrides: str):
    def value(v) -> str:
        return "[" + ",".join(str(x) for x in v) + "]" if isinstance(v, list) else str(v)

    return compose_config(
        "generate",
            [
                f"checkpoint={checkpoint}", f"music={value(music)}", "style=krump", "sampling.steps=2", "progress=false",
                f"output_dir={tmp / 'out'}", f"paths.output_dir={tmp / 'out'}", f"paths.cache_dir={tmp / 'cache'}",
                "device=cpu", *overrides,
            ]
        )  # fmt: skip


def test_generate_writes_every_format_and_reports_bad_songs(tmp_path, checkpoint, songs):
    music = [songs[k] for k in ("good", "broken", "long", "one_second", "missing")]
    report = generate(gen_config(tmp_path, checkpoint, music, "max_song_seconds=600", "num_samples=2"))
    out = tmp_path / "out"
    for stem, seconds in (("good", 3.0), ("one_second", 1.0)):
        for k in range(2):
            names = {p.name for p in report.written[str(songs[stem if stem == "good" else "one_second"])]}
            base = f"{stem}_sample{k}"
            assert {f"{base}.pkl", f"{base}.bvh", f"{base}.npy"} <= names
            assert f"{base}.mp4" in names or f"{base}.gif" in names
            motion = np.load(out / f"{base}.npy")
            assert motion.shape == (int(seconds * 30), 151)
            with open(out / f"{base}.pkl", "rb") as f:
                data = pickle.load(f)
            assert data["smpl_poses"].shape == (int(seconds * 30), 72) and data["fps"] == 30
            assert load_motion_file(out / f"{base}.pkl").shape == (int(seconds * 30), 151)
            assert (out / f"{base}.bvh").read_text().startswith("HIERARCHY")
    errors = report.errors
    assert set(errors) == {str(songs[k]) for k in ("broken", "long", "missing")}
    assert "Cannot decode audio file" in errors[str(songs["broken"])]
    assert "1200 s long; the limit is max_song_seconds=600" in errors[str(songs["long"])]
    assert "not found" in errors[str(songs["missing"])]
    assert not report.ok


def test_editing_from_files_and_run_wide_errors(tmp_path, checkpoint, songs):
    # keyframes from a file, at given seconds: the written motion holds the keyframes' rotations and root
    key = np.load(_first_motion(tmp_path, checkpoint, songs))
    np.save(tmp_path / "keys.npy", key[[0, 45]])
    cfg = gen_config(tmp_path, checkpoint, songs["good"], "task=keyframes",
                     f"keyframes_file={tmp_path / 'keys.npy'}", "keyframe_seconds=[0,1.5]", "formats=[npy]")  # fmt: skip
    report = generate(cfg)
    assert report.ok
    motion = np.load(tmp_path / "out" / "good.npy")
    np.testing.assert_allclose(motion[[0, 45], 4:], key[[0, 45], 4:], atol=1e-5)
    np.save(tmp_path / "wrong.npy", np.zeros((2, 150), np.float32))
    bad = gen_config(tmp_path, checkpoint, songs["good"], "task=keyframes", f"keyframes_file={tmp_path / 'wrong.npy'}",
                     "keyframe_seconds=[0,1.5]")  # fmt: skip
    with pytest.raises(DataError, match=r"shape \(2, 150\).*\(N, 151\)"):
        generate(bad)
    with pytest.raises(ConfigError, match="one-hot.*Known genres"):
        generate(gen_config(tmp_path, checkpoint, songs["good"], "style=slow graceful moonwalk"))
    with pytest.raises(ConfigError, match="does not exist"):
        generate(gen_config(tmp_path, str(tmp_path / "nope.ckpt"), songs["good"]))
    with pytest.raises(ConfigError, match="task=seed_motion needs the given motion"):
        generate(gen_config(tmp_path, checkpoint, songs["good"], "task=seed_motion"))
    with pytest.raises(ConfigError, match="unknown editing task"):
        generate(gen_config(tmp_path, checkpoint, songs["good"], "task=dance_off"))


def _first_motion(tmp_path, checkpoint, songs) -> Path:
    report = generate(gen_config(tmp_path / "first", checkpoint, songs["good"], "formats=[npy]"))
    return report.written[str(songs["good"])][0]


def test_command_line_exit_codes_and_messages(tmp_path, checkpoint, songs, repo_root):
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "WANDB_MODE": "offline", "PYTHONPATH": str(repo_root)}
    cmd = [sys.executable, str(repo_root / "generate.py"), f"checkpoint={checkpoint}",
           f"music=[{songs['good']},{songs['broken']}]", "style=BR", "sampling.steps=2", "formats=[npy,pkl]",
           f"output_dir={tmp_path / 'out'}", f"paths.cache_dir={tmp_path / 'cache'}", f"hydra.run.dir={tmp_path}"]  # fmt: skip
    run = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=300)
    assert run.returncode == 1, run.stderr
    assert "Traceback" not in run.stderr + run.stdout
    assert "1 song(s) failed" in run.stdout and "Cannot decode audio file" in run.stdout
    assert (tmp_path / "out" / "good.pkl").is_file() and (tmp_path / "out" / "good.npy").is_file()
    assert str(tmp_path / "out" / "good.pkl") in run.stdout  # where the files are


def test_cleanup_is_on_by_default_and_switches_off(tmp_path, checkpoint, songs):
    """generate.py writes the dance retimed onto the song's beats with its feet on the run's floor; beat_sync=false
    keeps the model's timing; cleanup=false writes the model's raw dance."""
    import torch

    from dgsdp.audio import FeatureCache
    from dgsdp.audio.beat_tracker import beats_of_song
    from dgsdp.generation.beatsync import song_beats, sync_to_beats
    from dgsdp.motion import clean_motion, pose_to_joints
    from dgsdp.trained import load_model

    floor = float(load_model(checkpoint).floor_height)
    finished = np.load(_first_motion(tmp_path, checkpoint, songs))
    raw_cfg = gen_config(tmp_path / "raw", checkpoint, songs["good"], "formats=[npy]", "cleanup=false")
    raw = torch.from_numpy(np.load(generate(raw_cfg).written[str(songs["good"])][0]))
    timed_cfg = gen_config(tmp_path / "timed", checkpoint, songs["good"], "formats=[npy]", "beat_sync=false")
    own_timing = np.load(generate(timed_cfg).written[str(songs["good"])][0])
    np.testing.assert_allclose(own_timing, clean_motion(raw, 30, floor).numpy(), atol=1e-5)
    beats = song_beats(songs["good"], FeatureCache(tmp_path / "first" / "cache"))
    assert len(beats) >= 4  # the click song's beats
    other = [beats_of_song(songs["good"]).frames]  # the retime is judged by the independent tracker's beats too

    def clean(m: torch.Tensor, stats: list) -> torch.Tensor:  # the judge decides on the dances with feet on the floor
        return clean_motion(m, 30, floor, stats=stats)

    stats: list[dict] = []
    expected = sync_to_beats(raw, beats, 30.0, check_beats=other, finish=clean, stats=stats).numpy()
    np.testing.assert_allclose(finished, expected, atol=1e-5)
    assert stats[0]["anchored_beats"] > 0 and stats[0]["judged_beat_sets"] == 2  # a retime was made and judged
    if stats[0]["retimed"]:
        assert np.abs(finished - own_timing).max() > 1e-3  # the retiming moved something
    else:  # the judge kept the model's own timing: the dance beat_sync=false writes
        np.testing.assert_allclose(finished, own_timing, atol=1e-5)
    raw_low = pose_to_joints(raw.double())[..., 2].min()
    assert pose_to_joints(torch.from_numpy(finished).double())[..., 2].min() >= floor - 0.01
    assert np.abs(own_timing - raw.numpy()).max() > 1e-3 or raw_low >= floor - 0.01  # did something, or nothing to do
    with pytest.raises(ConfigError, match="beat_sync must be true or false"):
        generate(gen_config(tmp_path, checkpoint, songs["good"], "beat_sync=often"))
    with pytest.raises(ConfigError, match="cleanup must be true or false"):
        generate(gen_config(tmp_path, checkpoint, songs["good"], "cleanup=sometimes"))


def test_finishing_limits_are_config_keys(tmp_path, checkpoint, songs):
    """generate.py's finishing keys set the cleanup's limits: null lifts one, a bad value is one clear error."""
    import torch

    from dgsdp.audio import FeatureCache
    from dgsdp.audio.beat_tracker import beats_of_song
    from dgsdp.cli.generate import generate_settings
    from dgsdp.generation import Finishing
    from dgsdp.generation.beatsync import BeatSync, song_beats, sync_to_beats
    from dgsdp.motion import FloorCleanup, clean_motion
    from dgsdp.trained import load_model

    settings = generate_settings(gen_config(tmp_path, checkpoint, songs["good"]))
    assert settings.finishing == Finishing()
    assert settings.finishing.floor() == FloorCleanup() and settings.finishing.beat_sync() == BeatSync()
    lifted = ["finishing.max_turn_rate=null", "finishing.max_tilt_rate=null", "finishing.max_air_seconds=null",
              "finishing.beat_sync_reach=0.4"]  # fmt: skip
    cfg = gen_config(tmp_path / "lifted", checkpoint, songs["good"], "formats=[npy]", *lifted)
    floor = generate_settings(cfg).finishing.floor()
    assert floor.max_turn_rate is None and floor.max_tilt_rate is None and floor.max_air_seconds is None
    assert generate_settings(cfg).finishing.beat_sync().max_shift_beats == 0.4
    # the dance written is the raw one finished with exactly those limits
    written = np.load(generate(cfg).written[str(songs["good"])][0])
    raw_cfg = gen_config(tmp_path / "raw", checkpoint, songs["good"], "formats=[npy]", "cleanup=false")
    raw = torch.from_numpy(np.load(generate(raw_cfg).written[str(songs["good"])][0]))
    beats = song_beats(songs["good"], FeatureCache(tmp_path / "lifted" / "cache"))
    height = float(load_model(checkpoint).floor_height)
    expected = sync_to_beats(raw, beats, 30.0, settings=BeatSync(max_shift_beats=0.4),
                             check_beats=[beats_of_song(songs["good"]).frames],
                             finish=lambda m, stats: clean_motion(m, 30, height, settings=floor, stats=stats))  # fmt: skip
    np.testing.assert_allclose(written, expected.numpy(), atol=1e-5)
    for bad, message in [
        ("finishing.max_turn_rate=-1", "max_turn_rate must be a positive number"),
        ("finishing.max_tilt_rate=fast", "finishing.max_tilt_rate must be a number"),
        ("finishing.beat_sync_reach=0.9", "max_shift_beats must lie in"),
        ("finishing.beat_sync_reach=null", "beat_sync=false keeps the model's timing"),
        ("+finishing.max_spin=3", "finishing has no key max_spin"),
    ]:
        with pytest.raises(ConfigError, match=message):
            generate_settings(gen_config(tmp_path, checkpoint, songs["good"], bad))


def test_studio_takes_the_same_limits():
    from dgsdp.generation import Finishing
    from dgsdp.studio.app import parse_args

    assert parse_args([]).finishing == Finishing()
    config = parse_args(["--max-turn-rate", "none", "--max-air-seconds", "1.5", "--beat-sync-reach", "0.3"])
    assert config.finishing == Finishing(max_turn_rate=None, max_air_seconds=1.5, beat_sync_reach=0.3)
    with pytest.raises(SystemExit):
        parse_args(["--max-tilt-rate", "0"])


def test_songs_far_faster_than_the_training_music_are_given_in_half_time(tmp_path, checkpoint, caplog):
    """train.py records the training songs' tempi (the tiny data: mBR0 and mKR2, 80 and 100 BPM); a 170 BPM song
    is then given to the model with every other beat (85 BPM), unless sampling.tempo_fold=false."""
    import logging

    from dgsdp.audio.librosa_encoder import BEAT_COLUMN, ENVELOPE_COLUMN
    from dgsdp.audio.tempo import fold_beats
    from dgsdp.generation import DanceGenerator
    from dgsdp.sampling import SamplingSettings
    from dgsdp.trained import load_model

    assert load_model(checkpoint).tempo_range == (80.0, 100.0)
    fast, steady = tmp_path / "fast_mBR9.wav", tmp_path / "steady.wav"  # mBR9: the tracker is told 170 BPM
    write_click_song(fast, 8.0, bpm=170.0)
    write_click_song(steady, 8.0, bpm=120.0)  # 0.26 octaves above 100, 60 BPM would be 0.42 below 80: as it is
    gen = DanceGenerator.from_checkpoint(checkpoint, cache_dir=tmp_path / "cache")
    tracked = gen.cache.features_for_file(gen.audio_encoder, fast, music_id=fast.stem)
    beats = np.flatnonzero(tracked[:, BEAT_COLUMN])
    fold = gen.tempo_fold(fast)
    assert fold.octaves == 1 and fold.range_bpm == (80.0, 100.0) and fold.bpm == pytest.approx(170.0, rel=0.02)
    given = gen.music_features(fast)[0].numpy()
    half = fold_beats(beats, 1, tracked[:, ENVELOPE_COLUMN])
    assert len(half) == (len(beats) + 1) // 2 or len(half) == len(beats) // 2
    np.testing.assert_array_equal(np.flatnonzero(given[:, BEAT_COLUMN]), half)
    np.testing.assert_array_equal(np.delete(given, BEAT_COLUMN, axis=1), np.delete(tracked, BEAT_COLUMN, axis=1))
    off = SamplingSettings(tempo_fold=False)
    np.testing.assert_array_equal(gen.music_features(fast, sampling=off)[0].numpy(), tracked)
    assert gen.tempo_fold(fast, off).octaves == 0
    assert gen.tempo_fold(fast, SamplingSettings(tempo_range_bpm=[150, 200])).octaves == 0  # 170 is inside
    assert gen.tempo_fold(steady).octaves == 0
    dance = gen.dance_to_song(fast, "krump", sampling=SamplingSettings(steps=1), seconds=3.0)
    assert dance.tempo == fold
    # a checkpoint that recorded no tempi: one warning, the beats as tracked
    gen.model.set_tempo_range(None)
    with caplog.at_level(logging.WARNING, logger="dgsdp.generation.pipeline"):
        np.testing.assert_array_equal(gen.music_features(fast)[0].numpy(), tracked)
        gen.music_features(fast)
    assert sum("records no training tempi" in r.getMessage() for r in caplog.records) == 1
    assert gen.tempo_fold(fast, SamplingSettings(tempo_range_bpm=[80, 100])) == fold


@pytest.mark.parametrize("bad", ["[100]", "[120,80]", "[0,100]", "[80,100,120]"])
def test_a_bad_tempo_range_is_one_clear_error(tmp_path, checkpoint, bad):
    from dgsdp.cli.generate import generate_settings

    with pytest.raises(ConfigError, match=r"sampling.tempo_range_bpm must be \[lowest, highest\]"):
        generate_settings(gen_config(tmp_path, checkpoint, "x.wav", f"sampling.tempo_range_bpm={bad}"))


def test_generate_says_which_songs_it_gave_in_half_time(tmp_path, checkpoint, caplog):
    import logging

    fast = tmp_path / "fast_mBR9.wav"  # 170 BPM; the tiny checkpoint was trained on 80-100 BPM
    write_click_song(fast, 4.0, bpm=170.0)
    with caplog.at_level(logging.INFO, logger="dgsdp.generation.songs"):
        generate(gen_config(tmp_path, checkpoint, fast, "formats=[npy]"))
    said = [r.getMessage() for r in caplog.records if "sampling.tempo_fold" in r.getMessage()]
    assert len(said) == 1 and "fast_mBR9.wav: " in said[0] and "given in half time" in said[0]
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="dgsdp.generation.songs"):
        generate(gen_config(tmp_path / "off", checkpoint, fast, "formats=[npy]", "sampling.tempo_fold=false"))
    assert not any("sampling.tempo_fold" in r.getMessage() for r in caplog.records)
