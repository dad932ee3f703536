"""The FineDance reader on the synthetic FineDance, on broken files, and the 6D conversions."""

import json
import shutil

import numpy as np
import pytest
import torch

from dgsdp.data import finedance as fd
from dgsdp.data.aistpp import read_list
from dgsdp.data.synthetic_finedance import (
    IGNORED_ID,
    SyntheticFineDanceSettings,
    generate_synthetic_finedance,
    plan_dataset,
    read_manifest,
    synthesize_sequence,
)
from dgsdp.errors import ConfigError, DataError
from dgsdp.motion import forward_kinematics, matrix_to_6d, sixd_to_matrix
from dgsdp.resources import FINEDANCE_DIR

SMALL = {"sequences_per_genre": 2, "min_seconds": 3.0, "max_seconds": 4.0, "sample_rate_hz": 8000}


@pytest.fixture(scope="module")
def synthetic(tmp_path_factory):
    return generate_synthetic_finedance(tmp_path_factory.mktemp("finedance") / "fd", **SMALL)


@pytest.fixture
def copy(synthetic, tmp_path):
    """A copy of the synthetic set that a test may break."""
    return shutil.copytree(synthetic, tmp_path / "fd")


def smpl_fk(rotmats, trans):
    """FK on the SMPL mean body's first 22 joints (same tree as SMPL-X's body): enough to test the contacts."""
    hands = torch.eye(3, dtype=rotmats.dtype).expand(*rotmats.shape[:-3], 2, 3, 3)
    return forward_kinematics(torch.cat((rotmats, hands), dim=-3), trans)[..., :22, :]


def test_layout_and_manifest(synthetic):
    manifest = read_manifest(synthetic)
    ids = sorted(p.stem for p in (synthetic / "motion").glob("*.npy"))
    assert ids == sorted(manifest["sequences"]) and len(ids) == 16 * 2 + 1
    assert not {f"{i}" for i in range(116, 124)} & set(ids)  # like the real set, no 116-123
    for seq_id in ids:
        raw = np.load(synthetic / "motion" / f"{seq_id}.npy", allow_pickle=False)
        assert raw.dtype == np.float32 and raw.shape == (manifest["sequences"][seq_id]["num_frames"], 315)
        assert (synthetic / "music_wav" / f"{seq_id}.wav").is_file()
        label = json.loads((synthetic / "label_json" / f"{seq_id}.json").read_text())
        assert set(label) == {"name", "style1", "style2"}


def test_splits_follow_the_shipped_lists_and_the_ignore_list(synthetic):
    manifest = read_manifest(synthetic)["sequences"]
    train, test = fd.read_split(synthetic, "train"), fd.read_split(synthetic, "test")
    assert sorted(train) == sorted(i for i, s in manifest.items() if s["split"] == "train")
    official_test = read_list(FINEDANCE_DIR / "crossgenre_test.txt")
    assert test == [i for i in official_test if i in manifest and i not in ("120", "130")]  # list order kept
    assert len(train) == len(test) == 16
    assert (synthetic / "motion" / f"{IGNORED_ID}.npy").is_file()  # present, but on both ignore lists
    dancer = {s: fd.read_split(synthetic, s, "dancer") for s in ("train", "val", "test")}
    assert all(dancer.values()) and not set(dancer["train"]) & set(dancer["test"] + dancer["val"])
    assert IGNORED_ID not in train + test + sum(dancer.values(), [])


def test_sequences_carry_genres_and_music(synthetic):
    manifest = read_manifest(synthetic)["sequences"]
    test = fd.load_split(synthetic, "test")
    assert sorted(s.genre for s in test) == sorted(fd.FINEDANCE_GENRES.codes)  # one test sequence per genre
    for seq in test + fd.load_split(synthetic, "train"):
        assert seq.genre == manifest[seq.id]["genre"]
        assert fd.FINEDANCE_GENRES.codes[seq.genre_index] == seq.genre
        assert seq.motion.dtype == np.float32 and seq.motion.shape[1] == 315
        assert seq.wav == synthetic / "music_wav" / f"{seq.id}.wav"
        assert seq.label.coarse_style in ("Street", "Folk", "Classic", "Mix")  # the values real labels hold
    jazz = [s for s in fd.load_split(synthetic, "train") if s.genre == "JZ"]
    written = json.loads((synthetic / "label_json" / f"{jazz[0].id}.json").read_text())["style2"]
    assert written == "jazz"  # lower case as in some real label files, still the Jazz genre


def test_split_lists_in_the_root_override_the_shipped_ones(copy):
    (copy / "splits").mkdir()
    (copy / "splits" / "crossgenre_test.txt").write_text("# two only\n063\n132\n")
    assert fd.read_split(copy, "test") == ["063", "132"]
    (copy / "splits" / "crossgenre_test.txt").write_text("063\ngBR_sBM_cAll_d04_mBR0_ch01\n")
    with pytest.raises(DataError, match="three-digit"):
        fd.read_split(copy, "test")


def test_unknown_scheme_split_or_joints(synthetic):
    with pytest.raises(ConfigError, match="scheme"):
        fd.read_split(synthetic, "train", "style")
    with pytest.raises(ConfigError, match="val"):
        fd.read_split(synthetic, "val")  # FineDance@Genre has no validation split
    with pytest.raises(ConfigError, match="body"):
        fd.motion_parts(np.zeros((2, 315)), "hands")


def test_missing_dataset_names_the_synthetic_command(tmp_path):
    with pytest.raises(DataError, match="synthetic_finedance"):
        fd.read_split(tmp_path / "nowhere", "train")


def _bad_npy(path, kind):
    good = np.load(path)
    if kind == "shape":
        np.save(path, good[:, :168])
    elif kind == "nan":
        good[3, 10] = np.nan
        np.save(path, good)
    elif kind == "pickle":
        np.save(path, np.array([{"poses": good}], dtype=object), allow_pickle=True)
    elif kind == "text":
        path.write_text("not an array")
    elif kind == "strings":
        np.save(path, np.full((4, 315), "x"))


@pytest.mark.parametrize(
    "kind, message",
    [("shape", "shape"), ("nan", "NaN"), ("pickle", "unpickling"), ("text", "cannot"), ("strings", "float")],
)
def test_bad_motion_file_is_one_clear_error(copy, kind, message):
    path = copy / "motion" / "063.npy"
    _bad_npy(path, kind)
    with pytest.raises(DataError, match=message) as info:
        fd.load_sequence(copy, "063")
    assert str(path) in str(info.value)
    with pytest.raises(DataError, match="1 of 16") as info:  # the whole split: every bad file listed, once
        fd.load_split(copy, "test")
    assert str(info.value).count("063") >= 1


@pytest.mark.parametrize(
    "text, message",
    [
        ("{not json", "not valid JSON"),
        ("[1, 2]", "list"),
        ('{"style1": "Folk", "name": "x"}', "style2"),
        ('{"style1": "Folk", "style2": "Salsa"}', "Salsa"),
        ('{"style1": "", "style2": "Dai"}', "style1"),
        ('{"style1": "Folk", "style2": "Dai", "name": 3}', "name"),
    ],
)
def test_bad_label_is_one_clear_error(copy, text, message):
    path = copy / "label_json" / "063.json"
    path.write_text(text)
    with pytest.raises(DataError, match=message) as info:
        fd.load_sequence(copy, "063")
    assert str(path) in str(info.value)


def test_label_aliases_and_case(copy):
    path = copy / "label_json" / "063.json"
    path.write_text('{"name": "song", "style1": "Folk", "style2": "Tai"}')
    assert fd.read_label(path).genre == "DA"
    path.write_text('{"style1": "Street", "style2": "hiphop"}')
    assert fd.read_label(path) == fd.Label("HH", 3, "Street", "")


@pytest.mark.parametrize("missing", ["music_wav/063.wav", "label_json/063.json"])
def test_missing_wav_or_label_is_one_clear_error(copy, missing):
    (copy / missing).unlink()
    with pytest.raises(DataError, match="063") as info:
        fd.load_sequence(copy, "063")
    assert str(copy / missing) in str(info.value)


def test_sixd_round_trip_on_the_synthetic_motion(synthetic):
    raw = fd.load_sequence(synthetic, "063").motion
    sixd = torch.from_numpy(raw[:, 3:]).double().reshape(-1, 52, 6)
    rotmats = sixd_to_matrix(sixd)
    # stored rotations are valid: 6D -> matrix -> 6D gives them back, and the matrices are rotations
    assert torch.allclose(matrix_to_6d(rotmats), sixd, atol=1e-6)
    assert torch.allclose(rotmats @ rotmats.transpose(-1, -2), torch.eye(3, dtype=torch.float64), atol=1e-6)
    assert torch.allclose(torch.linalg.det(rotmats), torch.ones(1, dtype=torch.float64), atol=1e-6)
    # raw -> (translation, rotations) z-up -> raw
    trans, full = fd.motion_parts(raw, "full")
    assert np.allclose(fd.raw_motion(trans, full), raw, atol=1e-6)
    assert torch.allclose(trans, torch.from_numpy(raw[:, [0, 2, 1]]).double() * torch.tensor([1.0, -1.0, 1.0]))


def test_pose_vectors_body_and_full(synthetic):
    raw = fd.load_sequence(synthetic, "063").motion
    body = fd.pose_vector(raw, "body", smpl_fk)
    assert body.shape == (len(raw), 139) and body.dtype == np.float32
    assert set(np.unique(body[:, :4])) <= {0.0, 1.0} and body[:, :4].mean() > 0.1  # the feet stand still at times
    # joints other than the root keep the stored 6D; the hands are dropped
    assert np.allclose(body[:, 13:], raw[:, 9 : 9 + 21 * 6], atol=1e-6)
    # the synthetic dancer stands on the floor: lowest foot joint at height 0 (z-up)
    trans, rotmats = fd.motion_parts(raw, "body")
    assert smpl_fk(rotmats, trans)[..., [7, 8, 10, 11], 2].min(-1).values.abs().max() < 1e-4
    full = fd.pose_vector(raw, "full", lambda r, t: torch.zeros(*r.shape[:-2], 3, dtype=r.dtype))
    assert full.shape == (len(raw), 319) and np.allclose(full[:, 4:7], body[:, 4:7])
    assert np.allclose(full[:, 7 + 22 * 6 :], raw[:, 3 + 22 * 6 :], atol=1e-6)  # fingers kept
    with pytest.raises(ValueError, match="fk returned"):
        fd.pose_vector(raw, "body", lambda r, t: torch.zeros(len(r), 24, 3))
    # a body-only motion written back as raw gets flat hands
    hands = fd.raw_motion(trans, rotmats)[:, 3 + 22 * 6 :].reshape(-1, 30, 6)
    assert np.allclose(hands, [1, 0, 0, 0, 1, 0])


def test_skeleton_adapter_asks_for_the_matching_skeleton(monkeypatch):
    import dgsdp.motion.skeleton as skeleton

    calls = []
    monkeypatch.setattr(skeleton, "skeleton_from_config", lambda name, path, option: calls.append((name, path, option)))
    fd.finedance_skeleton("body", "j.npy")
    fd.finedance_skeleton("full", "j.npy", option="x.y")
    assert calls == [("smplx22", "j.npy", "data.smplx_file"), ("smplx52", "j.npy", "x.y")]


def test_generation_is_deterministic_and_reused(synthetic, tmp_path):
    again = generate_synthetic_finedance(tmp_path / "again", **SMALL)
    for sub in ("motion", "music_wav", "label_json"):
        for path in (synthetic / sub).iterdir():
            assert path.read_bytes() == (again / sub / path.name).read_bytes(), path.name
    stamp = (again / "motion" / "063.npy").stat().st_mtime_ns
    generate_synthetic_finedance(again, **SMALL)  # complete with the same settings: nothing is written
    assert (again / "motion" / "063.npy").stat().st_mtime_ns == stamp
    plan = next(p for p in plan_dataset(SyntheticFineDanceSettings(**SMALL)) if p.seq_id == "063")
    beats = np.arange(0.2, 3.0, 0.5)
    seed0, seed1 = (synthesize_sequence(plan, 3.0, beats, seed) for seed in (0, 1))
    assert seed0.shape == seed1.shape and not np.allclose(seed0, seed1)


def test_generator_refuses_a_foreign_folder_and_bad_settings(tmp_path):
    (tmp_path / "motion").mkdir()
    (tmp_path / "motion" / "001.npy").write_bytes(b"real data")
    with pytest.raises(DataError, match="refusing"):
        generate_synthetic_finedance(tmp_path, **SMALL)
    with pytest.raises(ConfigError, match="sequences_per_genre"):
        generate_synthetic_finedance(tmp_path / "new", sequences_per_genre=1)
