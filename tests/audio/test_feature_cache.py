"""Feature cache: content keys, hits without encoder work, misses on changed settings, atomic writes."""

from __future__ import annotations

import shutil
from typing import Any

import numpy as np
import pytest
from audio_synth import click_track, write_audio

import dgsdp.utils.io as dio
from dgsdp.audio import FeatureCache, LibrosaEncoder, extract_dataset
from dgsdp.audio.base import AudioEncoder
from dgsdp.audio.extract import main as extract_main
from dgsdp.errors import AudioError


class CountingEncoder(AudioEncoder):
    """A cheap encoder (per-frame RMS times ``gain``) that counts how often it really encodes."""

    name = "counting"

    def __init__(self, gain: float = 1.0) -> None:
        self.gain = gain
        self.sample_rate = 3000
        self.feature_dim = 1
        self.calls = 0

    def settings(self) -> dict[str, Any]:
        return {"gain": self.gain}

    def _encode(self, waveform: np.ndarray, music_id: str | None) -> np.ndarray:
        self.calls += 1
        frames = waveform[: len(waveform) // 100 * 100].reshape(-1, 100)  # 100 samples = 1/30 s
        return (self.gain * np.sqrt((frames**2).mean(axis=1)))[:, None].astype(np.float32)


class CountingLibrosa(LibrosaEncoder):
    calls = 0

    def _encode(self, waveform, music_id):
        type(self).calls += 1
        return super()._encode(waveform, music_id)


def test_second_extraction_does_no_encoder_work_and_content_is_the_key(tmp_path):
    song = write_audio(tmp_path / "a.wav", click_track(2.0, 120.0, 3000), 3000)
    encoder, cache = CountingEncoder(), FeatureCache(tmp_path / "cache")
    first = cache.features_for_file(encoder, song)
    assert first.shape == (60, 1) and encoder.calls == 1
    # Independent value: frame 0 holds the first click; RMS of those 100 samples computed here.
    y = click_track(2.0, 120.0, 3000)
    assert first[0, 0] == pytest.approx(np.sqrt((y[:100] ** 2).mean()), rel=1e-3)
    again = cache.features_for_file(encoder, song)
    renamed = shutil.copy(song, tmp_path / "renamed.wav")
    moved = cache.features_for_file(encoder, renamed, n_frames=75)
    assert encoder.calls == 1
    np.testing.assert_array_equal(again, first)
    assert moved.shape == (75, 1) and (moved[60:] == first[59]).all()
    # a fresh cache object on the same folder also hits
    assert FeatureCache(tmp_path / "cache").features_for_file(encoder, song).shape == (60, 1)
    assert encoder.calls == 1


def test_changed_setting_misses(tmp_path):
    song = write_audio(tmp_path / "a.wav", click_track(1.0, 120.0, 3000), 3000)
    cache = FeatureCache(tmp_path / "cache")
    base = cache.features_for_file(CountingEncoder(gain=1.0), song)
    louder_encoder = CountingEncoder(gain=2.0)
    louder = cache.features_for_file(louder_encoder, song)
    assert louder_encoder.calls == 1
    np.testing.assert_allclose(louder, 2.0 * base, rtol=1e-6)
    assert len(list((tmp_path / "cache").iterdir())) == 2  # one namespace per settings


def test_music_id_is_part_of_the_key_only_when_it_changes_the_output(tmp_path):
    song = write_audio(tmp_path / "s.wav", click_track(2.0, 120.0, 15360), 15360)
    cache, encoder = FeatureCache(tmp_path / "cache"), CountingLibrosa()
    CountingLibrosa.calls = 0
    cache.features_for_file(encoder, song, music_id="mBR4")  # 120 BPM
    cache.features_for_file(encoder, song, music_id="mPO4")  # also 120 BPM: same output, hit
    assert CountingLibrosa.calls == 1
    cache.features_for_file(encoder, song, music_id="mBR0")  # 80 BPM prior: miss
    cache.features_for_file(encoder, song, music_id=None)  # estimated tempo: miss
    cache.features_for_file(encoder, song, music_id="not_an_id")  # also estimated: hit
    assert CountingLibrosa.calls == 3
    # an encoder that ignores music ids never splits its keys
    assert FeatureCache.key(CountingEncoder(), song, "mBR0") == FeatureCache.key(CountingEncoder(), song)


def test_killed_write_leaves_no_readable_entry(tmp_path, monkeypatch):
    song = write_audio(tmp_path / "a.wav", click_track(1.0, 120.0, 3000), 3000)
    cache, encoder = FeatureCache(tmp_path / "cache"), CountingEncoder()

    def dying_savez(file, **arrays):
        file.write(b"PK\x03\x04 half an npz")  # partial bytes, then the process "dies"
        raise KeyboardInterrupt

    monkeypatch.setattr(dio.np, "savez", dying_savez)
    with pytest.raises(KeyboardInterrupt):
        cache.features_for_file(encoder, song)
    monkeypatch.undo()
    namespace = tmp_path / "cache" / FeatureCache.namespace(encoder)
    assert list(namespace.iterdir()) == []  # neither an entry nor a temporary file
    assert not cache.contains(encoder, song)
    assert cache.features_for_file(encoder, song).shape == (30, 1)
    assert encoder.calls == 2


def test_extract_dataset_resumes(song_dir, tmp_path):
    encoder = LibrosaEncoder()
    paths = sorted(song_dir.glob("*.wav"))
    # simulate an earlier run killed after the first song
    FeatureCache(tmp_path / "cache").features_for_file(encoder, paths[0], music_id=paths[0].stem)
    summary = extract_dataset(encoder, paths, tmp_path / "cache", progress=False)
    assert (summary.n_songs, summary.n_computed, summary.n_cached) == (3, 2, 1)
    assert summary.audio_seconds == pytest.approx(3.0 + 2.0 + 2.5, abs=1e-3)
    summary = extract_dataset(encoder, paths, tmp_path / "cache", progress=False)
    assert (summary.n_computed, summary.n_cached) == (0, 3)


def test_cli_fills_the_cache(song_dir, tmp_path, capsys):
    assert extract_main(["--encoder", "librosa", "--wavs", str(song_dir), "--cache", str(tmp_path / "c")]) == 0
    assert "3 encoded" in capsys.readouterr().out
    entries = list((tmp_path / "c").rglob("*.npz"))
    assert len(entries) == 3
    with np.load(entries[0]) as z:
        assert z["features"].shape[1] == 35
    assert extract_main(["--encoder", "librosa", "--wavs", str(tmp_path / "none"), "--cache", "x"]) == 2


def test_bad_files_through_the_cache(tmp_path):
    cache, encoder = FeatureCache(tmp_path / "cache"), LibrosaEncoder()
    for name, data, rate_hz, frames in (
        ("8k.wav", click_track(2.0, 120.0, 8000), 8000, 60),
        ("96k.wav", click_track(2.0, 120.0, 96000), 96000, 60),
        ("six.wav", np.tile(click_track(1.0, 120.0, 44100), (6, 1)), 44100, 30),
        ("silent.wav", np.zeros(22050, np.float32), 22050, 30),
        ("short.wav", click_track(0.2, 120.0, 22050), 22050, 6),
    ):
        path = write_audio(tmp_path / name, data, rate_hz)
        assert cache.features_for_file(encoder, path).shape == (frames, 35), name
    corrupt = tmp_path / "corrupt.wav"
    corrupt.write_bytes(b"not audio at all" * 10)
    with pytest.raises(AudioError, match="corrupt.wav"):
        cache.features_for_file(encoder, corrupt)
    tiny = write_audio(tmp_path / "tiny.wav", np.zeros(50, np.float32), 22050)
    with pytest.raises(AudioError, match="too short"):
        cache.features_for_file(encoder, tiny)


def test_cached_features_are_memory_mapped(tmp_path):
    song = write_audio(tmp_path / "a.wav", click_track(2.0, 120.0, 3000), 3000)
    computed = FeatureCache(tmp_path / "cache").features_for_file(CountingEncoder(), song)
    encoder = CountingEncoder()
    mapped = FeatureCache(tmp_path / "cache").features_for_file(encoder, song)  # a hit, in a fresh cache object
    assert encoder.calls == 0 and isinstance(mapped, np.memmap) and not mapped.flags.writeable
    np.testing.assert_array_equal(mapped, computed)


def test_mmap_npz_reads_what_numpy_reads(tmp_path):
    rng = np.random.default_rng(0)
    arrays = {
        "features": rng.standard_normal((50, 7)).astype(np.float32),
        "fortran": np.asfortranarray(rng.standard_normal((4, 3))),
        "ints": np.arange(11, dtype=np.int64),
        "empty": np.zeros((0, 5), dtype=np.float32),
        "scalar": np.array(3.5),
    }
    dio.atomic_save_npz(tmp_path / "e.npz", arrays)
    mapped = dio.mmap_npz(tmp_path / "e.npz")
    with np.load(tmp_path / "e.npz") as z:
        assert set(mapped) == set(z.files)
        for name in z.files:
            assert mapped[name].dtype == z[name].dtype and mapped[name].shape == z[name].shape, name
            np.testing.assert_array_equal(mapped[name], z[name])
    np.savez_compressed(tmp_path / "c.npz", **arrays)
    with pytest.raises(ValueError, match="compressed"):
        dio.mmap_npz(tmp_path / "c.npz")
    cache = dio.DiskCache(tmp_path, "ns")  # a compressed entry still loads, in memory
    cache.dir.mkdir()
    np.savez_compressed(cache.path("k"), **arrays)
    np.testing.assert_array_equal(cache.load("k", mmap=True)["features"], arrays["features"])
