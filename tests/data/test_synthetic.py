"""The synthetic AIST++ generator: layout, determinism, beats in the music and the motion, genre styles, feet."""

from __future__ import annotations

import json
import pickle
from pathlib import Path

import numpy as np
import pytest
import torch

from dgsdp.audio.numba_cache import librosa
from dgsdp.data import synthetic
from dgsdp.data.aistpp import load_motion_pkl, music_tempo_bpm, parse_name, read_split
from dgsdp.data.synthetic import (
    GENRE_CODES,
    MANIFEST,
    PARTIAL_MARKER,
    generate_synthetic_aistpp,
    main,
    music_beat_times_s,
    read_manifest,
)
from dgsdp.errors import ConfigError, DataError
from dgsdp.metrics import GenreClassifier, beat_alignment, geometric_features, kinetic_features
from dgsdp.motion import FOOT_JOINTS, axis_angle_to_matrix, forward_kinematics

FPS = 60
SECONDS = 10.0
PER_GENRE = 5


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """All ten genres, five dances each (four train, one test per genre), 10 s."""
    return generate_synthetic_aistpp(
        tmp_path_factory.mktemp("synthetic") / "aistpp",
        seed=0,
        sequences_per_genre=PER_GENRE,
        seconds=SECONDS,
    )


@pytest.fixture(scope="module")
def manifest(dataset: Path) -> dict:
    return read_manifest(dataset)


@pytest.fixture(scope="module")
def joints(dataset: Path, manifest: dict) -> dict[str, np.ndarray]:
    """FK joint positions (T, 24, 3), metres, y-up, of every dance not on the ignore list."""
    ignored = set((dataset / "ignore_list.txt").read_text().split())
    out = {}
    for name in manifest["sequences"]:
        if name in ignored:
            continue
        with open(dataset / "motions" / f"{name}.pkl", "rb") as f:
            data = pickle.load(f)
        rotmats = axis_angle_to_matrix(torch.from_numpy(data["smpl_poses"]).double().reshape(-1, 24, 3))
        trans_m = torch.from_numpy(data["smpl_trans"]).double() / float(data["smpl_scaling"][0])
        out[name] = forward_kinematics(rotmats, trans_m).numpy()
    return out


def _tree_bytes(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


# ---------------------------------------------------------------------------------------------------------------
# Layout


def test_layout_names_and_pickles(dataset: Path, manifest: dict) -> None:
    sequences = manifest["sequences"]
    assert len(sequences) == len(GENRE_CODES) * PER_GENRE + 1  # plus one ignored take
    assert {p.stem for p in (dataset / "motions").glob("*.pkl")} == set(sequences)
    for name, info in sequences.items():
        parsed = parse_name(name)
        assert parsed.genre == info["genre"] and parsed.music_id == info["music_id"]
        assert parsed.music_id[1:3] == parsed.genre
        assert info["bpm"] == music_tempo_bpm(parsed.music_id)
        assert (dataset / "wavs" / f"{parsed.music_id}.wav").is_file()
        with open(dataset / "motions" / f"{name}.pkl", "rb") as f:
            data = pickle.load(f)
        assert set(data) == {"smpl_poses", "smpl_trans", "smpl_scaling", "smpl_loss"}
        n = int(SECONDS * FPS)
        assert data["smpl_poses"].shape == (n, 72) and data["smpl_poses"].dtype == np.float32
        assert data["smpl_trans"].shape == (n, 3) and data["smpl_trans"].dtype == np.float32
        assert data["smpl_scaling"].shape == (1,) and data["smpl_scaling"].dtype == np.float32
        assert isinstance(data["smpl_loss"], float)
        assert 80 < data["smpl_scaling"][0] < 110  # AIST++-like: trans / scaling is metres
        pelvis_height_m = data["smpl_trans"][:, 1] / data["smpl_scaling"][0]
        assert 0.4 < pelvis_height_m.mean() < 1.0
    assert {info["genre"] for info in sequences.values()} == set(GENRE_CODES)


def test_splits_are_crossmodal_and_cover_all_genres(dataset: Path, manifest: dict) -> None:
    train = (dataset / "splits" / "crossmodal_train.txt").read_text().split()
    test = (dataset / "splits" / "crossmodal_test.txt").read_text().split()
    ignored = (dataset / "ignore_list.txt").read_text().split()
    assert set(train) | set(test) == set(manifest["sequences"]) and not set(train) & set(test)
    assert len(ignored) == 1 and set(ignored) <= set(train)
    assert {parse_name(n).genre for n in test} == set(GENRE_CODES)
    assert {parse_name(n).genre for n in train} == set(GENRE_CODES)
    # Test music is never heard in training (the AIST++ cross-modal split).
    assert not {parse_name(n).music_id for n in test} & {parse_name(n).music_id for n in train}
    for name in test:
        assert manifest["sequences"][name]["split"] == "test"


def test_the_aistpp_reader_reads_it(dataset: Path) -> None:
    train = read_split(dataset, "train")
    ignored = (dataset / "ignore_list.txt").read_text().split()
    assert ignored[0] not in train and len(train) == len(GENRE_CODES) * (PER_GENRE - 1)
    poses, trans_m = load_motion_pkl(dataset / "motions" / f"{train[0]}.pkl")
    assert poses.shape == (int(SECONDS * FPS), 72) and trans_m.shape == (int(SECONDS * FPS), 3)


# ---------------------------------------------------------------------------------------------------------------
# Determinism, reuse, unfinished runs


def test_same_seed_same_bytes_other_seed_differs(tmp_path: Path) -> None:
    kwargs = dict(sequences_per_genre=2, seconds=3.0, genres=("BR", "HO"), sample_rate_hz=16000)
    a = _tree_bytes(generate_synthetic_aistpp(tmp_path / "a", seed=3, **kwargs))
    b = _tree_bytes(generate_synthetic_aistpp(tmp_path / "b", seed=3, **kwargs))
    c = _tree_bytes(generate_synthetic_aistpp(tmp_path / "c", seed=4, **kwargs))
    assert a == b
    assert a.keys() == c.keys()
    for key in a:
        if key.startswith(("motions/", "wavs/")):
            assert a[key] != c[key], key


def test_complete_dataset_is_reused_and_unfinished_one_redone(tmp_path: Path, monkeypatch) -> None:
    kwargs = dict(sequences_per_genre=2, seconds=2.5, genres=("KR",), sample_rate_hz=16000, num_ignored=0)
    root = generate_synthetic_aistpp(tmp_path / "d", **kwargs)
    motion = next((root / "motions").glob("*.pkl"))
    stamps = {p: p.stat().st_mtime_ns for p in root.rglob("*") if p.is_file()}
    with monkeypatch.context() as m:  # reusing synthesizes nothing and rewrites no file
        for name in ("synthesize_music", "synthesize_dance", "atomic_write_bytes", "atomic_write_text"):
            m.setattr(synthetic, name, lambda *a, _name=name, **k: pytest.fail(f"{_name} called on a complete dataset"))
        assert generate_synthetic_aistpp(root, **kwargs) == root
    assert {p: p.stat().st_mtime_ns for p in root.rglob("*") if p.is_file()} == stamps

    # A killed run leaves its in-progress marker and no manifest: the next call generates again.
    (root / PARTIAL_MARKER).write_text("{}")
    (root / MANIFEST).unlink()
    motion.unlink()
    generate_synthetic_aistpp(root, **kwargs)
    assert motion.is_file() and (root / MANIFEST).is_file() and not (root / PARTIAL_MARKER).exists()

    # Other settings: regenerated, files of the old settings removed.
    generate_synthetic_aistpp(root, **{**kwargs, "genres": ("PO",)})
    assert all(p.name.startswith("gPO") for p in (root / "motions").glob("*.pkl"))
    assert all(p.name.startswith("mPO") for p in (root / "wavs").glob("*.wav"))


def test_refuses_foreign_folder_and_bad_settings(tmp_path: Path) -> None:
    foreign = tmp_path / "real_aistpp"
    (foreign / "motions").mkdir(parents=True)
    with pytest.raises(DataError, match="not empty"):
        generate_synthetic_aistpp(foreign, sequences_per_genre=2, seconds=2.5, genres=("BR",))
    with pytest.raises(ConfigError, match="sequences_per_genre"):
        generate_synthetic_aistpp(tmp_path / "x", sequences_per_genre=1)
    with pytest.raises(ConfigError, match="unknown genres"):
        generate_synthetic_aistpp(tmp_path / "x", genres=("XX",))


def test_command_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    main(["--out", str(tmp_path / "cli"), "--sequences-per-genre", "2", "--seconds", "2.5", "--genres", "LO"])
    assert "3 motions" in capsys.readouterr().out
    assert json.loads((tmp_path / "cli" / MANIFEST).read_text())["settings"]["genres"] == ["LO"]


# ---------------------------------------------------------------------------------------------------------------
# Music: a beat tracker finds the tempo of the music id, and the beats where the manifest says


def test_beat_tracker_finds_the_music_tempo(dataset: Path, manifest: dict) -> None:
    ids = []
    for genre in ("BR", "HO", "JS", "KR", "JB"):  # breakbeat, four on the floor, swing, slow heavy, tonal
        present = sorted((m for m in manifest["music"] if m[1:3] == genre), key=music_tempo_bpm)
        ids += [present[0], present[-1]]
    bpms = [music_tempo_bpm(m) for m in ids]
    assert min(bpms) <= 90 and max(bpms) >= 130 and any(m.startswith("mHO") for m in ids)
    for music_id in ids:
        y, sr = librosa.load(dataset / "wavs" / f"{music_id}.wav", sr=None)
        tempo, beat_frames = librosa.beat.beat_track(y=y, sr=sr)
        tempo = float(np.atleast_1d(tempo)[0])
        bpm = music_tempo_bpm(music_id)
        # librosa's tempo grid has one lag per 512-sample hop: at 135 BPM and 44.1 kHz the neighbouring tempi
        # are 132.5 and 136.0 BPM, so the tracker may land one lag away.
        grid_step = bpm**2 * 512 / (60.0 * sr)
        assert abs(tempo - bpm) <= max(2.0, 1.05 * grid_step), (music_id, tempo)
        # The tracked beats are the synthesised ones (not off-beats): most within 50 ms of a true beat.
        tracked_s = librosa.frames_to_time(beat_frames, sr=sr)
        true_s = music_beat_times_s(manifest, music_id)
        error_s = np.abs(tracked_s[:, None] - true_s[None, :]).min(axis=1)
        assert np.mean(error_s < 0.05) > 0.8, (music_id, error_s)


# ---------------------------------------------------------------------------------------------------------------
# Motion: beats, genres, floor and feet


def test_motion_beats_fall_on_music_beats(manifest: dict, joints: dict[str, np.ndarray]) -> None:
    aligned, shifted = [], []
    for name, positions in joints.items():
        info = manifest["sequences"][name]
        beats_s = music_beat_times_s(manifest, info["music_id"])
        half_beat_s = 30.0 / info["bpm"]
        aligned.append(beat_alignment(positions, np.round(beats_s * FPS).astype(int)))
        shifted.append(beat_alignment(positions, np.round((beats_s + half_beat_s) * FPS).astype(int)))
    aligned, shifted = np.array(aligned), np.array(shifted)
    # AIST++ ground truth scores about 0.24; the shifted control should be far lower than the real one.
    assert aligned.mean() > 0.4, aligned.mean()
    assert aligned.mean() > 4 * shifted.mean(), (aligned.mean(), shifted.mean())
    assert np.mean(aligned > shifted) > 0.9


def test_genres_are_separable(manifest: dict, joints: dict[str, np.ndarray]) -> None:
    names = sorted(joints)
    features = np.stack([np.concatenate([kinetic_features(joints[n]), geometric_features(joints[n])]) for n in names])
    genres = np.array([manifest["sequences"][n]["genre"] for n in names])
    is_test = np.array([manifest["sequences"][n]["split"] == "test" for n in names])
    classifier = GenreClassifier(method="centroid").fit(features[~is_test], genres[~is_test])
    accuracy = float(np.mean(classifier.predict(features[is_test]) == genres[is_test]))
    assert is_test.sum() == len(GENRE_CODES)
    assert accuracy >= 0.7, accuracy  # chance: 0.1

    # Independently of the metrics code: each genre keeps its posture, e.g. Break lowest, Waack's hands highest.
    def mean_of(genre: str, fn) -> float:
        return float(np.mean([fn(joints[n]) for n in names if manifest["sequences"][n]["genre"] == genre]))

    pelvis = {g: mean_of(g, lambda j: j[:, 0, 1].mean()) for g in GENRE_CODES}
    wrists_above_pelvis = {g: mean_of(g, lambda j: (j[:, 20:22, 1] - j[:, :1, 1]).mean()) for g in GENRE_CODES}
    assert min(pelvis, key=pelvis.get) == "BR"
    assert max(wrists_above_pelvis, key=wrists_above_pelvis.get) in ("WA", "JS")


def test_feet_on_the_floor_and_planted_feet_do_not_slide(joints: dict[str, np.ndarray]) -> None:
    for name, positions in joints.items():
        feet_y = positions[:, list(FOOT_JOINTS), 1]
        assert feet_y.min() >= -0.01, name  # nothing below the floor
        assert np.all(feet_y.min(axis=1) < 0.005), name  # and always a foot on it (no long jumps)
        toes = positions[:, [10, 11]]
        planted = (toes[1:, :, 1] < 0.002) & (toes[:-1, :, 1] < 0.002)  # (T-1, 2)
        step_m = np.linalg.norm(toes[1:, :, [0, 2]] - toes[:-1, :, [0, 2]], axis=-1)
        assert planted.mean() > 0.4, name
        assert step_m[planted].max() < 0.001, (name, step_m[planted].max())
        # The dances do move: the feet travel when they are not planted.
        assert step_m[~planted].max() > 0.005, name


@pytest.mark.slow
def test_default_dataset_has_every_genre(tmp_path: Path) -> None:
    """The default settings: 10 genres x 8 dances and one ignored take (its speed: python -m
    dgsdp.benchmarks.synthetic)."""
    manifest = read_manifest(generate_synthetic_aistpp(tmp_path / "default"))
    assert len(manifest["sequences"]) == 81
    assert {s["genre"] for s in manifest["sequences"].values()} == set(GENRE_CODES)
