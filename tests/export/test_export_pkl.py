"""AIST++ pickle export: y-up conventions by hand, and a round trip through the project's AIST++ reader."""

import math
import pickle

import numpy as np
import pytest
import torch

from dgsdp.data.aistpp import load_motion_pkl, process_motion
from dgsdp.errors import DataError
from dgsdp.export import save_aistpp_pkl
from dgsdp.motion import (
    axis_angle_to_matrix,
    foot_contacts,
    forward_kinematics,
    pack_pose,
    points_z_up_to_y_up,
    unpack_pose,
)


def random_motion(frames: int, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Local rotations (T, 24, 3, 3) with angles up to 3 rad, and a wandering root (T, 3), z-up metres."""
    g = torch.Generator().manual_seed(seed)
    axes = torch.nn.functional.normalize(torch.randn(frames, 24, 3, generator=g, dtype=torch.float64), dim=-1)
    angles = torch.rand(frames, 24, 1, generator=g, dtype=torch.float64) * 3.0
    trans = torch.randn(frames, 3, generator=g, dtype=torch.float64) * 0.5 + torch.tensor([0.0, 0.0, 0.9])
    return axis_angle_to_matrix(axes * angles), trans


def test_hand_worked_axes(tmp_path):
    # A body standing upright in the z-up world: root = +90 deg about x (y-up -> z-up), other joints identity.
    upright = torch.tensor([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]], dtype=torch.float64)
    rot = torch.eye(3, dtype=torch.float64).repeat(2, 24, 1, 1)
    rot[:, 0] = upright
    rot[1, 0] = upright @ axis_angle_to_matrix(torch.tensor([0.0, math.pi / 2, 0.0]).double())
    trans = torch.tensor([[1.0, 2.0, 3.0], [0.5, -0.25, 0.9]], dtype=torch.float64)
    path = save_aistpp_pkl(tmp_path / "m.pkl", rot, trans)
    with open(path, "rb") as f:
        data = pickle.load(f)
    assert set(data) == {"smpl_poses", "smpl_trans", "smpl_scaling", "smpl_loss", "joints3d", "fps", "floor_height"}
    assert data["smpl_poses"].shape == (2, 72) and data["joints3d"].shape == (2, 24, 3)
    np.testing.assert_allclose(data["smpl_scaling"], [1.0])
    assert data["smpl_loss"] == 0.0 and data["fps"] == 30.0
    # Upright in y-up means no root rotation; the second frame turns pi/2 about the vertical (y) axis.
    np.testing.assert_allclose(data["smpl_poses"][0], 0.0, atol=1e-7)
    np.testing.assert_allclose(data["smpl_poses"][1, :3], [0.0, math.pi / 2, 0.0], atol=1e-6)
    np.testing.assert_allclose(data["smpl_poses"][:, 3:], 0.0, atol=1e-7)
    # (x, y, z) z-up -> (x, z, -y) y-up
    np.testing.assert_allclose(data["smpl_trans"], [[1.0, 3.0, -2.0], [0.5, 0.9, 0.25]], atol=1e-7)
    # Upright rest pose: y-up joints are the root plus the accumulated rest offsets, head above the pelvis.
    head_minus_pelvis = data["joints3d"][0, 15] - data["joints3d"][0, 0]
    assert head_minus_pelvis[1] > 0.5 and abs(head_minus_pelvis[0]) < 0.05


def test_round_trip_through_reader(tmp_path):
    rot, trans = random_motion(45, seed=3)
    path = save_aistpp_pkl(tmp_path / "gen.pkl", rot.float(), trans.float(), fps=30)
    assert [p.name for p in tmp_path.iterdir()] == ["gen.pkl"]  # no temporary file left behind

    poses, trans_m = load_motion_pkl(path)
    x = process_motion(poses, trans_m, source_fps=30, fps=30)
    expected = pack_pose(foot_contacts(forward_kinematics(rot, trans)), trans, rot).numpy()
    assert x.shape == expected.shape == (45, 151)
    back = unpack_pose(torch.from_numpy(x).double())
    assert (back.rotmats - rot).abs().max() < 1e-5
    np.testing.assert_allclose(x[:, 4:7], expected[:, 4:7], atol=1e-5)
    np.testing.assert_array_equal(x[:, :4], expected[:, :4])

    with open(path, "rb") as f:
        data = pickle.load(f)
    joints_y_up = points_z_up_to_y_up(forward_kinematics(rot, trans)).numpy()
    np.testing.assert_allclose(data["joints3d"], joints_y_up, atol=1e-5)


def test_bad_input_raises(tmp_path):
    rot, trans = random_motion(4, seed=0)
    with pytest.raises(DataError, match=r"\(T, 24, 3, 3\)"):
        save_aistpp_pkl(tmp_path / "a.pkl", rot[:, :22], trans)
    rot[1, 3, 0, 0] = float("nan")
    with pytest.raises(DataError, match="NaN"):
        save_aistpp_pkl(tmp_path / "a.pkl", rot, trans)
    assert not any(tmp_path.iterdir())


def test_write_motion_keeps_model_coordinates_in_data_files_and_the_floor_at_zero_in_views(tmp_path):
    """The rule of write_motion: npy and pkl hold the model's coordinates (the pkl records the floor height), BVH
    and GLB put the run's floor at y = 0."""
    from bvh import Bvh
    from motion_helpers import random_motion
    from test_bvh import bvh_fk

    from dgsdp.generation import write_motion
    from dgsdp.motion import JOINT_NAMES, pose_to_joints

    motion = random_motion(10)
    motion[:, 6] += 1.0
    files = write_motion(motion, tmp_path / "d", fps=30, formats=["npy", "pkl", "bvh"], floor_height=0.25)
    by_suffix = {f.suffix: f for f in files}
    np.testing.assert_array_equal(np.load(by_suffix[".npy"]), motion.numpy())
    joints_y_up = points_z_up_to_y_up(pose_to_joints(motion.double())).numpy()
    with open(by_suffix[".pkl"], "rb") as f:
        data = pickle.load(f)
    assert data["floor_height"] == 0.25
    np.testing.assert_allclose(data["joints3d"], joints_y_up, atol=1e-5)
    names, positions = bvh_fk(Bvh(by_suffix[".bvh"].read_text()))
    expected = joints_y_up[:, [JOINT_NAMES.index(n) for n in names]] - np.array([0.0, 0.25, 0.0])
    np.testing.assert_allclose(positions, expected, atol=1e-4)
