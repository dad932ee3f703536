"""Editing masks: channel layout against an independent listing, frame layouts, given motions and files."""

import pickle

import numpy as np
import pytest
import torch
from motion_helpers import random_motion

from dgsdp.editing import TASKS, build_mask, keyframe_indices, load_motion_file, place_known
from dgsdp.errors import ConfigError, DataError
from dgsdp.export import save_aistpp_pkl
from dgsdp.sampling import Guidance

# Written out by hand from the SMPL joint list (motion.md), not taken from the motion core.
LOWER_BODY_NAMES = ["pelvis", "left_hip", "right_hip", "left_knee", "right_knee", "left_ankle", "right_ankle",
                    "left_foot", "right_foot"]  # fmt: skip
LOWER_BODY_INDICES = [0, 1, 2, 4, 5, 7, 8, 10, 11]
UPPER_BODY_INDICES = [3, 6, 9, 12, 13, 14, 15, 16, 17, 18, 19, 20, 21, 22, 23]


def rotation_channels(joint: int) -> set[int]:
    """Joint j's 6D rotation sits at channels 7 + 6j .. 12 + 6j (motion.md)."""
    return set(range(7 + 6 * joint, 13 + 6 * joint))


def given_channels(mask: torch.Tensor) -> set[int]:
    cols = mask.bool().all(dim=0)
    assert torch.equal(cols, mask.bool().any(dim=0)), "a body-part mask must be the same on every frame"
    return set(cols.nonzero().flatten().tolist())


def test_upper_and_lower_body_channel_layout():
    lower = {0, 1, 2, 3, 4, 5, 6}.union(*(rotation_channels(j) for j in LOWER_BODY_INDICES))
    upper = set().union(*(rotation_channels(j) for j in UPPER_BODY_INDICES))
    assert len(lower) == 7 + 9 * 6 and len(upper) == 15 * 6 and lower | upper == set(range(151))
    # upper_body: the upper body is generated, so the lower body (with root and contacts) is given
    assert given_channels(build_mask("upper_body", 12)) == lower
    assert given_channels(build_mask("lower_body", 12)) == upper
    assert given_channels(build_mask("joints", 5, joints=LOWER_BODY_NAMES, with_root=True)) == lower
    assert given_channels(build_mask("joints", 5, joints=["left_wrist", 21])) == rotation_channels(
        20
    ) | rotation_channels(21)


def test_frame_layouts():
    m = build_mask("seed_motion", 100, seed_frames=30)
    assert m[:30].eq(1).all() and m[30:].eq(0).all()
    m = build_mask("inbetween", 100, seed_frames=10, end_frames=20)
    assert m[:10].eq(1).all() and m[10:80].eq(0).all() and m[80:].eq(1).all()
    assert build_mask("none", 7).eq(0).all()
    m = build_mask("inpaint", 200, generator=torch.Generator().manual_seed(0))
    rows = m.bool().all(dim=1)
    assert rows.sum() == 140 and torch.equal(rows, m.bool().any(dim=1))  # 70% of 200 whole frames
    m2 = build_mask("inpaint", 200, generator=torch.Generator().manual_seed(1))
    assert not torch.equal(m, m2)
    assert build_mask("inpaint", 10, inpaint_fraction=0.25).bool().all(dim=1).sum() == 2  # round(2.5) = 2


def test_keyframes_in_frames_and_seconds():
    # 2-minute song at 30 FPS; keyframes at 10 s, 60.5 s and the very end (120 s is the last frame)
    assert keyframe_indices(3600, keyframe_seconds=[10, 60.5, 120]) == [300, 1815, 3599]
    assert keyframe_indices(100, keyframes=[5, -1, 5]) == [5, 99]
    m = build_mask("keyframes", 100, keyframes=[0, 50], joints=["head"])
    assert m.sum() == 12 and m[0, 7 + 6 * 15 : 13 + 6 * 15].eq(1).all() and m[50, 7 + 6 * 15] == 1
    with pytest.raises(ConfigError, match="outside the motion"):
        keyframe_indices(300, keyframe_seconds=[11])
    with pytest.raises(ConfigError, match="needs keyframes"):
        build_mask("keyframes", 10)


def test_mask_errors():
    with pytest.raises(ConfigError, match="seed_motion"):
        build_mask("moonwalk", 10)
    with pytest.raises(ConfigError, match="unknown joint"):
        build_mask("joints", 10, joints=["tail"])
    with pytest.raises(ConfigError, match="inpaint_fraction"):
        build_mask("inpaint", 10, inpaint_fraction=1.5)
    assert set(TASKS) >= {
        "seed_motion",
        "inbetween",
        "inpaint",
        "upper_body",
        "lower_body",
        "joints",
        "keyframes",
    }


def test_place_known_layouts():
    motion = torch.arange(20 * 151, dtype=torch.float32).reshape(20, 151)
    m = build_mask("inbetween", 50, seed_frames=8, end_frames=12)
    known = place_known("inbetween", motion, m, seed_frames=8, end_frames=12)
    assert torch.equal(known[:8], motion[:8]) and torch.equal(known[38:], motion[8:])
    m = build_mask("keyframes", 50, keyframes=[3, 40])
    known = place_known("keyframes", motion[:2], m)
    assert torch.equal(known[3], motion[0]) and torch.equal(known[40], motion[1])
    m = build_mask("seed_motion", 50, seed_frames=10)
    assert torch.equal(place_known("seed_motion", motion, m, seed_frames=10)[:10], motion[:10])
    with pytest.raises(ConfigError, match="at least 50 frames"):
        place_known("upper_body", motion, build_mask("upper_body", 50))
    with pytest.raises(ConfigError, match="one frame per keyframe"):
        place_known("keyframes", motion[:3], build_mask("keyframes", 50, keyframes=[1, 2]))


def test_motion_files(tmp_path):
    x = random_motion(40)
    np.save(tmp_path / "ok.npy", x.numpy())
    assert torch.equal(load_motion_file(tmp_path / "ok.npy"), x)
    with open(tmp_path / "array.pkl", "wb") as f:
        pickle.dump(x.numpy(), f)
    assert torch.equal(load_motion_file(tmp_path / "array.pkl"), x)
    # an AIST++ pickle written by the exporter (30 FPS, y-up) reads back as the same z-up motion
    from dgsdp.motion import unpack_pose

    parts = unpack_pose(x.double())
    save_aistpp_pkl(tmp_path / "aist.pkl", parts.rotmats, parts.root_trans, fps=30)
    back = load_motion_file(tmp_path / "aist.pkl")
    assert back.shape == (40, 151)
    torch.testing.assert_close(back[:, 4:], x[:, 4:], atol=1e-4, rtol=0)
    np.save(tmp_path / "wrong.npy", np.zeros((10, 150), dtype=np.float32))
    with pytest.raises(DataError, match=r"shape \(10, 150\).*\(N, 151\)"):
        load_motion_file(tmp_path / "wrong.npy")
    with pytest.raises(DataError, match="does not exist"):
        load_motion_file(tmp_path / "missing.npy")
    (tmp_path / "k.txt").write_text("1 2 3")
    with pytest.raises(DataError, match="unsupported"):
        load_motion_file(tmp_path / "k.txt")


def test_guidance_ramp_and_edit_cap():
    g = Guidance(2.0, 3.0, ramp_fraction=0.5, edit_cap_below_t=100)
    # 50 steps, EDGE's ramp clip(linspace(0, 2w, 50), max=w): step 0 -> 0, step 10 -> 20/49 of the weights
    assert (g.at(0, 50, 999, False).music_weight, g.at(0, 50, 999, False).style_weight) == (0.0, 0.0)
    assert g.at(10, 50, 799, False).music_weight == pytest.approx(2.0 * 20 / 49)
    assert g.at(10, 50, 799, False).style_weight == pytest.approx(3.0 * 20 / 49)
    assert g.at(30, 50, 399, True).music_weight == 2.0
    capped = g.at(49, 50, 19, True)
    assert (capped.music_weight, capped.style_weight) == (1.0, 1.0)
    assert g.at(49, 50, 19, False).music_weight == 2.0
