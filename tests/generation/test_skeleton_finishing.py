"""The jobs after sampling on an SMPL-X skeleton (made-up rest joints): floor cleanup, beat sync, editing masks,
window stitching and the metrics' joints read the skeleton they are given."""

import dataclasses

import numpy as np
import pytest
import torch
from gen_helpers import STYLE_DIM, tiny_spec, write_click_song
from motion_helpers import made_up_smplx_joints, random_motion

from dgsdp.editing import build_mask
from dgsdp.evaluation.features import motion_to_joints
from dgsdp.generation import DanceGenerator, EditSettings, stitch_windows
from dgsdp.generation.beatsync import sync_to_beats
from dgsdp.motion import clean_motion, pose_to_joints, smplx_skeleton
from dgsdp.motion.floor import legs
from dgsdp.sampling import SamplingSettings
from dgsdp.style import StyleBank
from dgsdp.training import DanceDiffusion


@pytest.fixture(scope="module", params=["body22", "full52"])
def skel(request, tmp_path_factory):
    path = tmp_path_factory.mktemp("smplx") / "joints.npy"
    np.save(path, made_up_smplx_joints(seed=2))
    return smplx_skeleton(request.param, path)


def test_floor_cleanup(skel):
    assert legs(skel) == (((1, 4, 7, 10), (0, 2)), ((2, 5, 8, 11), (1, 3)))
    x = random_motion(60, seed=1, num_joints=skel.num_joints).double()
    x[:, 6] += 0.3  # floating above the floor
    stats = []
    out = clean_motion(x, 30, 0.0, stats=stats, skeleton=skel)
    assert out.shape == x.shape and len(stats) == 1
    assert pose_to_joints(out, skel)[..., 2].min() >= -1e-6  # no joint below the floor
    arms_and_hands = [7 + 6 * j + k for j in range(12, skel.num_joints) for k in range(6)]
    assert torch.equal(out[:, arms_and_hands], x[:, arms_and_hands])  # only the root and legs are touched
    mask = torch.zeros_like(x)
    mask[:10] = 1
    kept = clean_motion(x, 30, 0.0, mask=mask, skeleton=skel)
    assert torch.equal(kept[:10], x[:10])
    with pytest.raises(ValueError, match=f"{skel.pose_dim} channels"):
        clean_motion(x[:, :-6], 30, 0.0, skeleton=skel)  # one joint short


def test_beat_sync_and_stitching(skel):
    x = random_motion(60, seed=2, num_joints=skel.num_joints)
    stats = []
    out = sync_to_beats(x, np.array([10, 25, 40]), 30, stats=stats, skeleton=skel)
    assert out.shape == x.shape and stats[0]["beats"] == 3
    assert torch.equal(sync_to_beats(x, np.array([10]), 30, mask=torch.ones_like(x), skeleton=skel), x)
    windows = torch.stack([x[:40], x[20:60]])
    torch.testing.assert_close(stitch_windows(windows, 20), x, atol=2e-6, rtol=0)


def test_editing_masks_cover_the_hands(skel):
    first_hand_channel = 7 + 6 * 22
    upper = build_mask("upper_body", 8, skeleton=skel)
    lower = build_mask("lower_body", 8, skeleton=skel)
    assert upper.shape == lower.shape == (8, skel.pose_dim)
    assert torch.equal(upper + lower, torch.ones_like(upper))  # the two tasks split the channels
    assert upper[:, :7].eq(1).all() and lower[:, 7 + 6 * 20].eq(1).all()  # root given / left wrist given
    assert lower[:, first_hand_channel:].eq(1).all()  # fingers go with the upper body
    if skel.num_joints == 52:
        thumb = build_mask("joints", 4, joints=["left_thumb3"], skeleton=skel)
        assert thumb.sum() == 4 * 6 and thumb[0, 7 + 6 * 36 : 13 + 6 * 36].eq(1).all()


def test_metrics_read_smpl_layout(skel):
    x = random_motion(10, seed=3, num_joints=skel.num_joints)
    fk = pose_to_joints(x.double(), skel).numpy()
    joints = motion_to_joints(x.numpy(), skel)
    assert joints.shape == (10, 24, 3)
    np.testing.assert_array_equal(joints[:, :22], fk[:, :22])
    names = skel.joint_names
    left, right = ("left_middle1", "right_middle1") if skel.num_joints == 52 else ("left_wrist", "right_wrist")
    np.testing.assert_array_equal(joints[:, 22], fk[:, names.index(left)])
    np.testing.assert_array_equal(joints[:, 23], fk[:, names.index(right)])


def test_an_smplx_model_dances_edits_and_writes_its_files(skel, tmp_path):
    spec = dataclasses.replace(tiny_spec(), skeleton=skel)
    torch.manual_seed(0)
    model = DanceDiffusion(spec).eval()
    model.set_style_bank(StyleBank(torch.eye(STYLE_DIM), torch.arange(STYLE_DIM), STYLE_DIM))
    model.normalizer.fit(random_motion(200, seed=4, num_joints=skel.num_joints))
    gen = DanceGenerator(model, cache_dir=tmp_path / "cache")
    write_click_song(tmp_path / "song.wav", 4.0)
    dance = gen.dance_to_song(tmp_path / "song.wav", "krump", sampling=SamplingSettings(steps=1), seconds=3.0)
    assert dance.skeleton == skel and dance.motion.shape == (1, 90, skel.pose_dim)
    assert dance.joints.shape == (1, 90, skel.num_joints, 3) and dance.smpl()["poses"].shape == (
        90,
        3 * skel.num_joints,
    )
    assert dance.finishing[0]["beats"] > 0  # beat sync and the floor cleanup ran on this skeleton
    assert dance.finishing[0]["judged_beat_sets"] == 2  # the retime was judged by both trackers' beats
    files = dance.save(tmp_path / "out" / "dance", formats=("npy", "pkl", "bvh", "glb"))
    assert sorted(f.suffix for f in files) == [".bvh", ".glb", ".npy", ".pkl"]
    edit = EditSettings(task="seed_motion", motion_file=str(tmp_path / "out" / "dance.npy"), seed_frames=20)
    edited = gen.dance_to_song(
        tmp_path / "song.wav", "krump", edit=edit, sampling=SamplingSettings(steps=1), seconds=3.0
    )
    torch.testing.assert_close(edited.motion[0, :20], dance.motion[0, :20], atol=1e-5, rtol=0)
