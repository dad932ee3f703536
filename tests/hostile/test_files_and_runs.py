"""Files left behind and files shared: corrupt cache entries, temporaries after a kill, output permissions, run
folders of runs started together, the job log, and a hanging ffmpeg."""

from __future__ import annotations

import logging
import os
import signal
import stat
import subprocess
import sys
import tempfile
import textwrap
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import accepted, refused
from omegaconf import OmegaConf

from dgsdp.errors import DgsdpError
from dgsdp.utils.io import DiskCache, atomic_save_npz, atomic_write_text, remove_stale_temps

REPO = Path(__file__).resolve().parents[2]


def _run(code: str, **env: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)], capture_output=True, text=True, timeout=120,
        env={**os.environ, "PYTHONPATH": str(REPO), **env},
    )  # fmt: skip


# --- corrupt cache entries ----------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "garbage", [b"", b"garbage" * 100, b"PK\x03\x04truncated-zip", b"\x93NUMPY\x01\x00", "npz without the array"]
)
def test_corrupt_cache_entry_is_warned_once_removed_and_recomputed(tmp_path, caplog, garbage):
    cache = DiskCache(tmp_path, "features")
    if isinstance(garbage, bytes):
        cache.dir.mkdir(parents=True)
        cache.path("k").write_bytes(garbage)
    else:
        atomic_save_npz(cache.path("k"), {"other": np.zeros(2)})
    calls = []

    def compute():
        calls.append(1)
        return {"features": np.arange(3.0)}

    with caplog.at_level(logging.WARNING):
        first = cache.get_or_compute("k", compute, required=("features",))
        second = cache.get_or_compute("k", compute, required=("features",))
    assert np.array_equal(first["features"], np.arange(3.0)) and np.array_equal(second["features"], np.arange(3.0))
    assert len(calls) == 1  # recomputed once, then read from the repaired entry
    warnings = [r for r in caplog.records if "corrupt" in r.getMessage()]
    assert len(warnings) == 1 and str(cache.path("k")) in warnings[0].getMessage()
    accepted()


class RmsEncoder:
    """A cheap stand-in encoder: frame RMS at 30 FPS (the cache logic is what is tested here)."""

    def __new__(cls):
        from dgsdp.audio.base import AudioEncoder

        class _Rms(AudioEncoder):
            name = "rms"
            feature_dim = 1
            sample_rate = 8000

            def settings(self):
                return {"name": self.name}

            def _encode(self, waveform, music_id):
                n = len(waveform) // 266
                return np.sqrt((waveform[: n * 266].reshape(n, 266) ** 2).mean(axis=1, keepdims=True))

        return _Rms()


def test_corrupt_audio_feature_entry_through_the_feature_cache(tmp_path, caplog):
    import soundfile as sf

    from dgsdp.audio import FeatureCache

    song = tmp_path / "song.wav"
    sf.write(song, (0.2 * np.sin(np.arange(8000) / 3)).astype(np.float32), 8000)
    cache, encoder = FeatureCache(tmp_path / "cache"), RmsEncoder()
    good = cache.features_for_file(encoder, song)
    entry = cache.disk_cache(encoder).path(cache.key(encoder, song))
    entry.write_bytes(b"PK\x03\x04" + os.urandom(64))  # a BadZipFile, which used to crash every later run
    with caplog.at_level(logging.WARNING):
        again = FeatureCache(tmp_path / "cache").features_for_file(encoder, song)
    np.testing.assert_allclose(again, good)
    assert good.shape == (30, 1) and "corrupt" in caplog.text
    accepted()


# --- kill anywhere: temporaries ------------------------------------------------------------------------------------
def test_write_killed_midway_leaves_no_entry_and_its_temp_is_cleaned(tmp_path):
    target = tmp_path / "cache" / "ns" / "entry.npz"
    proc = _run(f"""
        import os, signal
        from dgsdp.utils.io import atomic_path
        with atomic_path({str(target)!r}) as tmp:
            tmp.write_bytes(b"half of an entry")
            os.kill(os.getpid(), signal.SIGKILL)
    """)
    assert proc.returncode == -signal.SIGKILL
    leftovers = list(target.parent.glob(".*.tmp"))
    assert not target.exists() and len(leftovers) == 1  # nothing half-written under the real name
    DiskCache(tmp_path / "cache", "ns")  # the next run opening the cache removes it
    assert not leftovers[0].exists()
    accepted()


def test_temp_of_a_live_process_is_kept(tmp_path):
    """Another process still writing (its pid is alive) keeps its temporary file."""
    from dgsdp.utils.io import temp_tag

    live = tmp_path / f".entry.npz.{temp_tag()}-0123abcd.tmp"
    live.write_bytes(b"being written")
    assert remove_stale_temps(tmp_path) == 0 and live.exists()


def test_checkpoint_writes_nothing_to_the_temp_folder_and_is_world_readable(tmp_path, monkeypatch):
    """Lightning's default saving stages the whole checkpoint in the system temp folder (mkstemp, 0600)."""
    from dgsdp.training.checkpoint import AtomicCheckpointIO

    tmpdir = tmp_path / "system-temp"
    tmpdir.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(tmpdir))
    old = os.umask(0o022)
    try:
        path = tmp_path / "run" / "last.ckpt"
        AtomicCheckpointIO().save_checkpoint({"state_dict": {"w": torch.ones(3)}}, path)
    finally:
        os.umask(old)
    assert list(tmpdir.iterdir()) == []
    assert stat.S_IMODE(path.stat().st_mode) == 0o644
    assert torch.equal(torch.load(path, weights_only=True)["state_dict"]["w"], torch.ones(3))
    assert list(path.parent.glob(".*.tmp")) == []


def test_outputs_get_normal_permissions(tmp_path):
    from dgsdp.export import save_aistpp_pkl

    old = os.umask(0o022)
    try:
        atomic_write_text(tmp_path / "report.md", "x")
        pkl = save_aistpp_pkl(tmp_path / "dance.pkl", torch.eye(3).expand(4, 24, 3, 3), torch.zeros(4, 3), 30)
    finally:
        os.umask(old)
    for path in (tmp_path / "report.md", pkl):
        assert stat.S_IMODE(path.stat().st_mode) == 0o644, path


# --- run folders and the job log -----------------------------------------------------------------------------------
def test_runs_started_in_the_same_second_get_their_own_folders(tmp_path):
    """Two processes resolve conf/hydra's run folder at the same moment: different folders, each stable."""
    code = f"""
        import hydra.core.utils
        hydra.core.utils.setup_globals()  # registers ${{now:}} as a Hydra app does
        from omegaconf import OmegaConf
        import dgsdp.cli.runtime  # registers ${{dgsdp_run_suffix:}}
        node = OmegaConf.load({str(REPO / "dgsdp" / "conf" / "hydra" / "default.yaml")!r})
        cfg = OmegaConf.create({{"paths": {{"log_dir": "/logs"}}, "task_name": "generate", "hydra": node}})
        print(cfg.hydra.run.dir, cfg.hydra.run.dir)
    """
    procs = [subprocess.Popen([sys.executable, "-c", textwrap.dedent(code)], stdout=subprocess.PIPE, text=True,
                              env={**os.environ, "PYTHONPATH": str(REPO)}) for _ in range(2)]  # fmt: skip
    dirs = [p.communicate(timeout=120)[0].split() for p in procs]
    assert all(len(d) == 2 and d[0] == d[1] and d[0].startswith("/logs/generate/runs/") for d in dirs), dirs
    assert dirs[0][0] != dirs[1][0]


def test_job_log_holds_what_the_run_printed(tmp_path, capsys):
    from dgsdp.cli.runtime import LogPrintedOutput

    hydra_node = OmegaConf.load(REPO / "dgsdp" / "conf" / "hydra" / "default.yaml")
    targets = [c["_target_"] for c in hydra_node.callbacks.values()]
    assert "dgsdp.cli.runtime.LogPrintedOutput" in targets  # every entry point's Hydra config installs it
    config = OmegaConf.create({"hydra": {"runtime": {"output_dir": str(tmp_path)}, "job": {"name": "generate"}}})
    callback = LogPrintedOutput()
    callback.on_job_start(config=config)
    print("song.wav:\n  out/song.mp4")
    callback.on_job_end(config=config, job_return=None)
    print("after the job")
    assert "song.wav:\n  out/song.mp4" in (tmp_path / "generate.log").read_text()
    assert "after the job" not in (tmp_path / "generate.log").read_text()
    assert "out/song.mp4" in capsys.readouterr().out  # still printed too


# --- subprocesses ---------------------------------------------------------------------------------------------------
@pytest.fixture
def hanging_ffmpeg(tmp_path, monkeypatch):
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    fake = bin_dir / "ffmpeg"
    fake.write_text(f"#!/bin/sh\necho started > {tmp_path / 'ffmpeg_started'}\nsleep 300\n")
    fake.chmod(0o755)
    monkeypatch.setenv("PATH", f"{bin_dir}{os.pathsep}{os.environ['PATH']}")
    monkeypatch.setenv("DGSDP_FFMPEG_TIMEOUT", "1")
    return tmp_path


def test_hanging_ffmpeg_is_stopped_with_a_clear_error(hanging_ffmpeg):
    from dgsdp.export import render_video

    out = hanging_ffmpeg / "dance.mp4"
    with pytest.raises(DgsdpError) as exc:
        render_video(out, np.random.default_rng(0).standard_normal((20, 24, 3)), size=(64, 64))
    refused(exc, "ffmpeg stopped responding", "DGSDP_FFMPEG_TIMEOUT")
    assert (hanging_ffmpeg / "ffmpeg_started").exists() and not out.exists()
    assert list(hanging_ffmpeg.glob(".*.tmp")) == []  # no half-written video


def test_bad_ffmpeg_timeout_setting(monkeypatch):
    from dgsdp.export.render import ffmpeg_timeout_seconds

    monkeypatch.setenv("DGSDP_FFMPEG_TIMEOUT", "soon")
    with pytest.raises(DgsdpError) as exc:
        ffmpeg_timeout_seconds()
    refused(exc, "DGSDP_FFMPEG_TIMEOUT", "soon")


@pytest.mark.parametrize("trainer", ["default", "cpu", "gpu", "ddp"])
def test_every_trainer_saves_checkpoints_atomically(trainer):
    """Checkpoints saved by any trainer config (also Lightning's own, with callbacks=none) use AtomicCheckpointIO."""
    from dgsdp.cli.config import compose_config

    cfg = compose_config("train", [f"trainer={trainer}"], output_dir="/unused")
    assert [p["_target_"] for p in cfg.trainer.plugins] == ["dgsdp.training.checkpoint.AtomicCheckpointIO"]


def test_render_folders_of_killed_runs_are_removed(tmp_path, monkeypatch):
    """The video step stages the song as float wav in the temp folder; a killed run's copy goes on the next render."""
    from dgsdp.export.render import RENDER_TEMP_PREFIX, _remove_stale_render_dirs
    from dgsdp.utils.io import temp_tag

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    host = temp_tag().rsplit("-", 1)[0]
    killed = tmp_path / f"{RENDER_TEMP_PREFIX}{host}-{dead.pid}-abc123"
    live = tmp_path / f"{RENDER_TEMP_PREFIX}{temp_tag()}-def456"
    for folder in (killed, live):
        folder.mkdir()
        (folder / "audio.wav").write_bytes(b"\0" * 1000)
    _remove_stale_render_dirs()
    assert not killed.exists() and live.exists()
