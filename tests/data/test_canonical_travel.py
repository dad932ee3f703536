"""Mirrored dances and windows that travel one way (``data.canonical_travel``)."""

import dataclasses
import math

import numpy as np
import pytest
import torch

from dgsdp.data.datamodule import DanceDataModule, Sequence, WindowDataset
from dgsdp.data.device import host_only_reason
from dgsdp.data.synthetic import generate_synthetic_aistpp
from dgsdp.motion.axes import root_rotation_y_up_to_z_up
from dgsdp.motion.representation import lateral_travel, mirror_partners, mirror_pose, pack_pose, pose_to_joints
from dgsdp.motion.rotation import axis_angle_to_matrix
from dgsdp.motion.skeleton import SMPL24

REFLECT = torch.tensor([-1.0, 1.0, 1.0])


def symmetric_smpl():
    """SMPL-24 with each right joint's rest offset the mirror image of its left partner's and the spine on x = 0:
    a skeleton whose mirrored dances are exact mirror images."""
    partners = mirror_partners(SMPL24)
    offsets = []
    for j, name in enumerate(SMPL24.joint_names):
        x, y, z = SMPL24.rest_offsets_m[j if not name.startswith("right_") else partners[j]]
        offsets.append((-x, y, z) if name.startswith("right_") else (0.0 if partners[j] == j else x, y, z))
    return dataclasses.replace(SMPL24, name="smpl24-symmetric", rest_offsets_m=tuple(offsets))


def random_dance(frames=40, seed=0, skeleton=SMPL24):
    g = torch.Generator().manual_seed(seed)
    rotmats = axis_angle_to_matrix(0.6 * torch.randn(frames, skeleton.num_joints, 3, generator=g))
    trans = torch.randn(frames, 3, generator=g).cumsum(0) * 0.05
    contacts = (torch.rand(frames, 4, generator=g) > 0.5).float()
    return pack_pose(contacts, trans, rotmats)


def test_partners_exchange_sides_and_keep_the_spine():
    partners = mirror_partners(SMPL24)
    names = SMPL24.joint_names
    assert [names[p] for p in partners][:3] == ["pelvis", "right_hip", "left_hip"]
    assert names[partners[names.index("left_wrist")]] == "right_wrist"
    assert all(partners[p] == j for j, p in enumerate(partners))
    lopsided = dataclasses.replace(
        SMPL24, name="lopsided", joint_names=SMPL24.joint_names[:-1] + ("right_paw",)
    )  # left_hand without a right_hand
    with pytest.raises(ValueError, match="left_hand"):
        mirror_partners(lopsided)


def test_mirrored_joints_are_the_mirror_image_on_a_symmetric_skeleton():
    skeleton = symmetric_smpl()
    pose = random_dance(skeleton=skeleton)
    joints, mirrored = pose_to_joints(pose, skeleton), pose_to_joints(mirror_pose(pose, skeleton), skeleton)
    expected = joints[:, mirror_partners(skeleton)] * REFLECT
    assert torch.allclose(mirrored, expected, atol=1e-5)
    assert torch.equal(mirror_pose(pose, skeleton)[:, [0, 1, 2, 3]], pose[:, [1, 0, 3, 2]])  # contacts swap sides


def test_on_smpl_the_error_is_the_rest_offsets_asymmetry_and_twice_is_the_same_dance():
    pose = random_dance(seed=1)
    mirrored = mirror_pose(pose)
    assert torch.equal(mirror_pose(mirrored), pose)
    err = (pose_to_joints(mirrored) - pose_to_joints(pose)[:, mirror_partners()] * REFLECT).norm(dim=-1)
    assert 0.001 < float(err.max()) < 0.05  # SMPL's left and right offsets differ by up to about a centimetre
    batch = torch.stack([pose, mirrored])  # any leading shape
    assert torch.equal(mirror_pose(batch)[1], pose)


def facing_dance(yaw, shift, frames=30):
    """A dancer standing at yaw ``yaw`` (about z) whose root moves by ``shift`` (x, y) over the frames."""
    root = root_rotation_y_up_to_z_up(torch.eye(3))
    c, s = math.cos(yaw), math.sin(yaw)
    turn = torch.tensor([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    rotmats = torch.eye(3).repeat(frames, 24, 1, 1)
    rotmats[:, 0] = turn @ root
    trans = torch.zeros(frames, 3)
    trans[:, :2] = torch.linspace(0, 1, frames)[:, None] * torch.tensor(shift)
    return pack_pose(torch.zeros(frames, 4), trans, rotmats)


def test_lateral_travel_is_along_the_dancers_left():
    # at zero yaw the body's left is +x (z-up, facing -y)
    assert float(lateral_travel(facing_dance(0.0, (0.6, 0.0)))) == pytest.approx(0.6, abs=1e-6)
    assert float(lateral_travel(facing_dance(0.0, (0.0, 0.6)))) == pytest.approx(0.0, abs=1e-6)
    # turned a quarter to its left, its left is +y
    assert float(lateral_travel(facing_dance(math.pi / 2, (0.0, 0.6)))) == pytest.approx(0.6, abs=1e-6)
    assert float(lateral_travel(facing_dance(math.pi / 2, (0.6, 0.0)))) == pytest.approx(0.0, abs=1e-6)
    # the left hip is on the left: FK agrees with the rotation's first column
    joints = pose_to_joints(facing_dance(0.7, (0.0, 0.0)))[0]
    across = joints[SMPL24.joint_index("left_hip"), :2] - joints[SMPL24.joint_index("right_hip"), :2]
    assert float(across @ torch.tensor([math.cos(0.7), math.sin(0.7)])) > 0.1
    right = facing_dance(0.3, (0.5 * math.cos(0.3), 0.5 * math.sin(0.3)))
    assert float(lateral_travel(mirror_pose(right))) == pytest.approx(-float(lateral_travel(right)), abs=1e-6)


class Identity:
    def normalize(self, x):
        return x


def zigzag_sequence(frames=300):
    """A dance that travels to its left for 2.5 s, then to its right, with random joint rotations."""
    pose = random_dance(frames, seed=3)
    pose[:, 7:13] = facing_dance(0.0, (0.0, 0.0), frames)[:, 7:13]  # facing ahead
    x = np.concatenate([np.linspace(0, 1.5, frames // 2), np.linspace(1.5, 0, frames - frames // 2)])
    pose[:, 4] = torch.from_numpy(x).float()
    return Sequence("gBR_sBM_cAll_d04_mBR0_ch01", "BR", 0, "mBR0", pose.numpy(), None)


def test_every_canonical_window_travels_left_and_the_others_are_untouched():
    seq = zigzag_sequence()
    plain = WindowDataset([seq], Identity(), length=60, stride=15)
    canonical = WindowDataset([seq], Identity(), length=60, stride=15, canonical_travel=True)
    mirrored = 0
    for i in range(len(plain)):
        a, b = plain[i]["motion"], canonical[i]["motion"]
        if float(lateral_travel(a)) >= 0:
            assert torch.equal(a, b)
        else:
            mirrored += 1
            assert torch.equal(b, mirror_pose(a))
        assert float(lateral_travel(b)) >= 0
    assert 0 < mirrored < len(plain)
    assert host_only_reason(canonical) is not None and host_only_reason(plain) is None


def test_datamodule_normalises_mirrored_windows_within_range_and_keeps_their_movement(tmp_path):
    movement = ["travel", "turning", "level"]
    root = generate_synthetic_aistpp(
        tmp_path / "synthetic", sequences_per_genre=2, seconds=6.0, genres=["HO", "LH"], num_ignored=0,
        sample_rate_hz=16000, movement_variation=True,
    )  # fmt: skip
    plain = DanceDataModule(
        str(root), str(tmp_path / "cache"), batch_size=4, progress=False, movement_channels=movement
    )
    canonical = DanceDataModule(
        str(root), str(tmp_path / "cache"), batch_size=4, progress=False, movement_channels=movement,
        canonical_travel=True,
    )  # fmt: skip
    plain.setup("fit")
    canonical.setup("fit")
    a, b = plain.datasets["train"], canonical.datasets["train"]
    assert len(a) == len(b)
    flipped = 0
    for i in range(len(b)):
        item, same = b[i], a[i]
        assert float(item["motion"].abs().max()) <= 1.0 + 1e-6  # the normaliser saw the mirror images too
        raw = canonical.normalizer.unnormalize(item["motion"])
        assert float(lateral_travel(raw)) >= -1e-4
        assert torch.equal(item["movement"], same["movement"])  # travel, turning and level do not change sides
        flipped += not torch.allclose(raw, plain.normalizer.unnormalize(same["motion"]), atol=1e-4)
    assert 0 < flipped < len(b)
