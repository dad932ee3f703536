"""The AIST++ reader on hand-written files in the real AIST++ format."""

import pickle

import numpy as np
import pytest
import soundfile as sf
import torch

from dgsdp.data.aistpp import (
    load_motion_pkl,
    music_path,
    music_tempo_bpm,
    parse_name,
    process_motion,
    read_split,
)
from dgsdp.errors import DataError
from dgsdp.motion import unpack_pose

NAME = "gBR_sBM_cAll_d04_mBR0_ch01"


def write_real_format_pkl(path, n_frames=120, scaling=93.77):
    """A motion pickle with the keys, shapes and dtypes of the AIST++ release."""
    rng = np.random.default_rng(0)
    poses = (0.1 * rng.standard_normal((n_frames, 72))).astype(np.float64)
    trans_m = np.stack([np.linspace(0, 0.6, n_frames), np.full(n_frames, 0.9), np.zeros(n_frames)], axis=1)
    data = {
        "smpl_loss": np.float64(1.23),
        "smpl_poses": poses,
        "smpl_scaling": np.array([scaling]),
        "smpl_trans": trans_m * scaling,
    }
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as f:
        pickle.dump(data, f)
    return poses, trans_m


def test_parse_name_and_tempo():
    p = parse_name(NAME)
    assert (p.genre, p.situation, p.dancer, p.music_id, p.choreography) == ("BR", "BM", "04", "mBR0", "01")
    assert music_tempo_bpm("mBR0") == 80 and music_tempo_bpm("mKR5") == 130
    assert music_tempo_bpm("mHO0") == 110 and music_tempo_bpm("mHO3") == 125
    with pytest.raises(DataError, match="not an AIST\\+\\+ motion name"):
        parse_name("dance_01")


def test_real_format_pkl_reads_and_converts(tmp_path):
    poses, trans_m = write_real_format_pkl(tmp_path / "motions" / f"{NAME}.pkl")
    got_poses, got_trans = load_motion_pkl(tmp_path / "motions" / f"{NAME}.pkl")
    assert got_poses.shape == (120, 72) and got_poses.dtype == np.float32
    np.testing.assert_allclose(got_trans, trans_m, atol=1e-5)  # smpl_trans / smpl_scaling = metres
    x = process_motion(got_poses, got_trans)
    assert x.shape == (60, 151)  # 60 -> 30 FPS takes every second frame
    # root translation is z-up: (x, y, z) y-up -> (x, -z, y)
    np.testing.assert_allclose(x[:, 4], trans_m[::2, 0], atol=1e-5)
    np.testing.assert_allclose(x[:, 6], trans_m[::2, 1], atol=1e-5)
    # the joint rotations survive the conversion: decode joint 5's rotation and compare with the input
    from dgsdp.motion import axis_angle_to_matrix

    rot = unpack_pose(torch.from_numpy(x)).rotmats[:, 5]
    expected = axis_angle_to_matrix(torch.from_numpy(poses[::2, 15:18])).float()
    assert torch.allclose(rot, expected, atol=1e-5)


def test_missing_dataset_folder_is_clear(tmp_path):
    with pytest.raises(DataError, match="no AIST\\+\\+ dataset.*dgsdp.data.synthetic"):
        read_split(tmp_path / "nowhere", "train")


def test_pkl_without_smpl_poses(tmp_path):
    p = tmp_path / "bad.pkl"
    p.write_bytes(pickle.dumps({"smpl_trans": np.zeros((3, 3))}))
    with pytest.raises(DataError, match="bad.pkl has no smpl_poses"):
        load_motion_pkl(p)


def test_unreadable_pkl(tmp_path):
    p = tmp_path / "garbage.pkl"
    p.write_bytes(b"not a pickle")
    with pytest.raises(DataError, match="cannot read motion file .*garbage.pkl"):
        load_motion_pkl(p)


def test_unknown_split_and_split_lists(tmp_path):
    root = tmp_path / "ds"
    write_real_format_pkl(root / "motions" / f"{NAME}.pkl")
    other = "gKR_sBM_cAll_d30_mKR2_ch02"
    write_real_format_pkl(root / "motions" / f"{other}.pkl")
    (root / "splits").mkdir()
    (root / "splits" / "crossmodal_train.txt").write_text(f"{NAME}\n{other}\n")
    (root / "ignore_list.txt").write_text(f"{other}\n")
    assert read_split(root, "train") == [NAME]
    with pytest.raises(DataError, match="unknown split 'training'; known splits: train, test, val"):
        read_split(root, "training")


def test_official_lists_are_shipped_and_used(tmp_path):
    # without lists of its own, a root falls back to the official lists (980 train names minus 28 ignored)
    root = tmp_path / "ds"
    name = "gWA_sFM_cAll_d25_mWA4_ch05"  # first line of the official train list
    write_real_format_pkl(root / "motions" / f"{name}.pkl")
    assert read_split(root, "train") == [name]
    from dgsdp.data.aistpp import SHIPPED_SPLITS_DIR, read_list

    train = set(read_list(SHIPPED_SPLITS_DIR / "crossmodal_train.txt"))
    ignore = set(read_list(SHIPPED_SPLITS_DIR / "ignore_list.txt"))
    assert len(train) == 980 and len(train - ignore) == 952


def test_music_path_missing(tmp_path):
    (tmp_path / "wavs").mkdir()
    sf.write(tmp_path / "wavs" / "mBR0.wav", np.zeros(100), 8000)
    assert music_path(tmp_path, "mBR0").name == "mBR0.wav"
    with pytest.raises(DataError, match="no music file for 'mBR1'"):
        music_path(tmp_path, "mBR1")
