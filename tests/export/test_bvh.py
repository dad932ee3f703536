"""BVH export, read back with the independent PyPI ``bvh`` parser and checked by an FK written here."""

import math

import numpy as np
import pytest
import torch
from bvh import Bvh

from dgsdp.errors import DataError
from dgsdp.export import matrix_to_euler_zxy, save_bvh
from dgsdp.motion import (
    JOINT_NAMES,
    PARENTS,
    axis_angle_to_matrix,
    forward_kinematics,
    points_z_up_to_y_up,
    rest_offsets,
    root_rotation_y_up_to_z_up,
)


def elementary(axis: str, degrees: float) -> np.ndarray:
    """Rotation about a coordinate axis, acting on column vectors."""
    a = math.radians(degrees)
    c, s = math.cos(a), math.sin(a)
    return {
        "X": np.array([[1, 0, 0], [0, c, -s], [0, s, c]]),
        "Y": np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
        "Z": np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]),
    }[axis]


def gimbal_rotation(rng: np.random.Generator, sign: float, eps_deg: float) -> np.ndarray:
    """Rz(a) Rx(+-90 deg + eps) Ry(c): the singular configuration of the file's Z X Y channel order."""
    a, c = rng.uniform(-180, 180, size=2)
    return elementary("Z", a) @ elementary("X", sign * 90.0 + eps_deg) @ elementary("Y", c)


def hard_motion(frames: int, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Random local rotations with angles up to pi, several joints (root included, as exported) at or near
    gimbal lock; a root wandering around; z-up metres."""
    rng = np.random.default_rng(seed)
    axes = rng.normal(size=(frames, 24, 3))
    axes /= np.linalg.norm(axes, axis=-1, keepdims=True)
    rot = axis_angle_to_matrix(torch.from_numpy(axes * rng.uniform(0, math.pi, size=(frames, 24, 1)))).numpy()
    for t in range(0, frames, 2):
        for j in rng.choice(24, size=6, replace=False):
            rot[t, j] = gimbal_rotation(rng, rng.choice([-1.0, 1.0]), rng.choice([0.0, 1e-7, -1e-4, 0.3]))
    rot = torch.from_numpy(rot)
    # Root: gimbal lock in the exported (y-up) orientation on some frames.
    for t in range(1, frames, 3):
        rot[t, 0] = root_rotation_y_up_to_z_up(torch.from_numpy(gimbal_rotation(rng, 1.0, 0.0)))
    trans = torch.from_numpy(rng.normal(size=(frames, 3)) * 0.8 + np.array([0.0, 0.0, 0.9]))
    return rot, trans


def bvh_fk(mocap: Bvh) -> tuple[list[str], np.ndarray]:
    """Joint names (file order) and world positions (T, J, 3) from parsed offsets and channels."""
    names = mocap.get_joints_names()
    frames = mocap.nframes
    positions: dict[str, np.ndarray] = {}
    rotations: dict[str, np.ndarray] = {}
    for name in names:
        channels = mocap.joint_channels(name)
        values = np.array(mocap.frames_joint_channels(name, channels))  # (T, n)
        local = np.tile(np.eye(3), (frames, 1, 1))
        translation = np.zeros((frames, 3))
        for k, ch in enumerate(channels):
            if ch.endswith("rotation"):
                local = local @ np.stack([elementary(ch[0], v) for v in values[:, k]])
            else:
                translation[:, "XYZ".index(ch[0])] = values[:, k]
        offset = np.array(mocap.joint_offset(name))
        parent = mocap.joint_parent(name)
        if parent is None:
            positions[name] = offset + translation
            rotations[name] = local
        else:
            pr = rotations[parent.name]
            positions[name] = positions[parent.name] + pr @ offset
            rotations[name] = pr @ local
    return names, np.stack([positions[n] for n in names], axis=1)


@pytest.fixture(scope="module")
def motion():
    return hard_motion(24, seed=7)


def test_hierarchy_and_header(tmp_path, motion):
    rot, trans = motion
    path = save_bvh(tmp_path / "dance.bvh", rot, trans, fps=30)
    mocap = Bvh(path.read_text())
    names = mocap.get_joints_names()
    assert sorted(names) == sorted(JOINT_NAMES) and names[0] == "pelvis"
    for name in names:
        j = JOINT_NAMES.index(name)
        parent = mocap.joint_parent(name)
        assert (parent.name if parent is not None else None) == (JOINT_NAMES[PARENTS[j]] if j else None)
        expected_offset = rest_offsets(dtype=torch.float64)[j].numpy() if j else np.zeros(3)
        np.testing.assert_allclose(mocap.joint_offset(name), expected_offset, atol=1e-6)
        expected_channels = ["Zrotation", "Xrotation", "Yrotation"]
        if j == 0:
            expected_channels = ["Xposition", "Yposition", "Zposition"] + expected_channels
        assert mocap.joint_channels(name) == expected_channels
    assert mocap.nframes == len(mocap.frames) == 24
    assert mocap.frame_time == pytest.approx(1 / 30, abs=1e-7)
    # Leaf joints (feet, head, hands) end in an End Site.
    assert path.read_text().count("End Site") == 5


def test_fk_of_parsed_file_matches_ours(tmp_path, motion):
    rot, trans = motion
    path = save_bvh(tmp_path / "dance.bvh", rot, trans, fps=30)
    names, positions = bvh_fk(Bvh(path.read_text()))
    ours = points_z_up_to_y_up(forward_kinematics(rot, trans)).numpy()
    ours = ours[:, [JOINT_NAMES.index(n) for n in names]]
    assert np.abs(positions - ours).max() < 1e-3  # 1 mm
    assert np.abs(positions - ours).max() < 1e-5  # in fact limited by the 6 printed decimals


def test_centimetres(tmp_path, motion):
    rot, trans = motion
    metres = Bvh(save_bvh(tmp_path / "m.bvh", rot[:3], trans[:3]).read_text())
    centi = Bvh(save_bvh(tmp_path / "cm.bvh", rot[:3], trans[:3], units="cm").read_text())
    names, pos_m = bvh_fk(metres)
    _, pos_cm = bvh_fk(centi)
    np.testing.assert_allclose(pos_cm, 100 * pos_m, atol=1e-3)


def test_euler_hand_worked_and_gimbal():
    # Channel order Z X Y: R = Rz(30) Rx(20) Ry(-50) must come back as (30, 20, -50) degrees.
    r = elementary("Z", 30) @ elementary("X", 20) @ elementary("Y", -50)
    np.testing.assert_allclose(np.degrees(matrix_to_euler_zxy(r)), [30, 20, -50], atol=1e-9)
    rng = np.random.default_rng(0)
    mats = np.stack([gimbal_rotation(rng, s, e) for s in (-1, 1) for e in (0.0, 1e-9, 1e-6, -1e-3)] * 5)
    z, x, y = np.degrees(matrix_to_euler_zxy(mats)).T
    rebuilt = np.stack([elementary("Z", a) @ elementary("X", b) @ elementary("Y", c) for a, b, c in zip(z, x, y)])
    assert np.abs(rebuilt - mats).max() < 1e-9


def test_bad_input_raises(tmp_path, motion):
    rot, trans = motion
    with pytest.raises(DataError, match="units"):
        save_bvh(tmp_path / "a.bvh", rot, trans, units="inch")
    with pytest.raises(DataError, match="offsets"):
        save_bvh(tmp_path / "a.bvh", rot, trans, offsets=torch.zeros(23, 3))
    assert not any(tmp_path.iterdir())


def test_the_runs_floor_is_at_height_zero(tmp_path, motion):
    """A run whose floor is 0.3 m up: the file is the same dance, lowered by 0.3 m (its floor at y = 0)."""
    rot, trans = motion
    path = save_bvh(tmp_path / "floor.bvh", rot, trans, fps=30, floor_height=0.3)
    names, positions = bvh_fk(Bvh(path.read_text()))
    ours = points_z_up_to_y_up(forward_kinematics(rot, trans)).numpy()[:, [JOINT_NAMES.index(n) for n in names]]
    np.testing.assert_allclose(positions, ours - np.array([0.0, 0.3, 0.0]), atol=1e-5)
    with pytest.raises(DataError, match="floor"):
        save_bvh(tmp_path / "nan.bvh", rot, trans, floor_height=float("nan"))
