"""Movement attributes (level, arms, travel, turning) on hand-made motions, against values worked out by hand."""

import math

import numpy as np
import pytest
import torch
from motion_helpers import made_up_smplx_joints

from dgsdp.metrics import MetricError
from dgsdp.metrics import attributes as at
from dgsdp.motion import SMPL24, pack_pose, pose_to_joints, root_rotation_y_up_to_z_up, smplx_skeleton


def still(n: int = 10, skeleton=SMPL24) -> np.ndarray:
    """(n, J, 3) joints, all at the origin: each test places the joints its measure reads."""
    return np.zeros((n, skeleton.num_joints, 3))


def test_standing_height_is_the_rest_pose_pelvis_above_its_lowest_foot_joint():
    # SMPL's rest offsets (y): hip, knee, ankle, foot of each leg; the right toe is the lowest foot joint
    left = -0.08228004 - 0.38646945 - 0.42687458 - 0.06028581
    right = -0.09051332 - 0.38368791 - 0.4200455 - 0.06210566
    assert at.standing_height(SMPL24) == pytest.approx(-min(left, right))
    # a body standing in the rest pose on a floor at its lowest foot joint is at level 1; 0.3 m lower, less
    trans = torch.tensor([[0.0, 0.0, 0.9], [0.0, 0.0, 0.6]], dtype=torch.float64)
    rotations = torch.eye(3, dtype=torch.float64).repeat(2, 24, 1, 1)
    rotations[:, 0] = root_rotation_y_up_to_z_up(rotations[:, 0])  # the rest pose stood up in the z-up world
    pose = pack_pose(torch.ones(2, 4, dtype=torch.float64), trans, rotations)
    joints = pose_to_joints(pose).numpy()
    floor = joints[0, list(SMPL24.foot_joints), 2].min()
    levels = at.pelvis_levels(joints, SMPL24, floor_m=floor)
    assert levels[0] == pytest.approx(1.0, abs=1e-6)
    assert levels[1] == pytest.approx((0.6 - (0.9 + min(left, right))) / -min(left, right), abs=1e-6)


def test_level_of_a_pelvis_at_known_heights():
    joints = still(3)
    joints[:, 0, 2] = [0.5, 0.8, 1.1]
    h = at.standing_height(SMPL24)
    np.testing.assert_allclose(at.pelvis_levels(joints, SMPL24, floor_m=0.1), [0.4 / h, 0.7 / h, 1.0 / h])


def test_arm_height_in_arm_lengths():
    # SMPL's rest offsets: shoulder -> elbow -> wrist, per side
    left = math.hypot(0.2553319, -0.01564902, -0.02294649) + math.hypot(0.26570925, 0.01269811, -0.00737473)
    right = math.hypot(-0.26012748, -0.01436928, -0.03126873) + math.hypot(-0.26910836, 0.00679372, -0.00602676)
    joints = still(3)
    joints[:, 16, 2] = joints[:, 17, 2] = 1.4  # shoulders
    joints[:, 20, 2] = [1.4 + left, 1.4, 1.4 - left]  # left wrist: overhead, level, hanging
    joints[:, 21, 2] = [1.4 + right, 1.4 + right / 2, 1.4 - right]
    np.testing.assert_allclose(at.arm_heights(joints, SMPL24), [1.0, 0.25, -1.0], atol=1e-12)


def test_travel_is_the_pelvis_speed_over_the_floor():
    joints = still(31)
    joints[:, 0, 0] = np.arange(31) * 0.02  # 2 cm a frame along x: 0.6 m/s at 30 FPS
    joints[:, 0, 2] = 0.9 + 0.05 * np.sin(np.arange(31))  # bobbing up and down does not travel
    np.testing.assert_allclose(at.travel_speeds(joints, SMPL24, fps=30), 0.6, atol=1e-12)
    joints[:, 0, 1] = np.arange(31) * 0.02  # and 2 cm along y: sqrt(2) times as fast
    np.testing.assert_allclose(at.travel_speeds(joints, SMPL24, fps=30), 0.6 * math.sqrt(2), atol=1e-12)


@pytest.mark.parametrize("omega", [3.0, -3.0, 12.0])
def test_turning_is_the_absolute_yaw_rate_of_the_hips(omega):
    # the hips on a circle of 10 cm turning at omega rad/s (through +-pi several times at 12 rad/s)
    t = np.arange(60) / 30
    joints = still(60)
    theta = 0.4 + omega * t
    joints[:, 1, :2] = np.stack([np.cos(theta), np.sin(theta)], -1) * 0.1  # left hip
    joints[:, 2, :2] = -joints[:, 1, :2]  # right hip
    joints[:, :, 2] += 0.9
    np.testing.assert_allclose(at.turning_rates(joints, SMPL24, fps=30), abs(omega), atol=1e-9)


def test_travel_and_turning_are_read_over_half_a_second_so_jitter_cancels():
    # a standing body whose pelvis and facing jitter every frame (1 cm, 0.01 rad back and forth): frame to frame that
    # reads 0.3 m/s and 0.3 rad/s; over the half second (15 steps, an odd number of flips) it reads a thirtieth
    n = 61
    flip = np.where(np.arange(n) % 2 == 0, 0.5, -0.5)
    joints = still(n)
    joints[:, 0, 0] = 0.01 * flip
    yaw = 0.4 + 0.01 * flip
    joints[:, 1, :2] = np.stack([np.cos(yaw), np.sin(yaw)], -1) * 0.1
    joints[:, 2, :2] = -joints[:, 1, :2]
    assert at.SPAN_SECONDS == 0.5
    inner = slice(8, -8)  # steps whose half second lies within the dance
    np.testing.assert_allclose(at.travel_speeds(joints, SMPL24, fps=30)[inner], 0.01 * 30 / 15, atol=1e-12)
    np.testing.assert_allclose(at.turning_rates(joints, SMPL24, fps=30)[inner], 0.01 * 30 / 15, atol=1e-6)
    # near the ends the span is cut short: two frames are read over their one step
    assert at.travel_speeds(joints[:2], SMPL24, fps=30)[0] == pytest.approx(0.3)
    # a walk at 0.6 m/s with the same jitter reads 0.6 (within the jitter's thirtieth)
    joints[:, 0, 0] += np.arange(n) * 0.02
    np.testing.assert_allclose(at.travel_speeds(joints, SMPL24, fps=30)[inner], 0.6, atol=0.021)
    assert len(at.turning_rates(joints, SMPL24)) == n - 1


def test_facing_still_does_not_turn_and_a_dance_averages_its_series():
    joints = still(31)
    joints[:, 1, 0], joints[:, 2, 0] = 0.1, -0.1
    joints[:, 0, 0] = np.arange(31) * 0.01
    figures = at.movement_attributes(joints, SMPL24, fps=30)
    assert set(figures) == set(at.MEASURES)
    assert figures["turning"] == 0.0 and figures["travel"] == pytest.approx(0.3)


def test_the_measures_read_smplx_skeletons_by_joint_name(tmp_path):
    np.save(tmp_path / "j.npy", made_up_smplx_joints())
    for kind in ("body22", "full52"):
        skel = smplx_skeleton(kind, tmp_path / "j.npy")
        joints = still(4, skel)
        joints[:, 0, 0] = np.arange(4) * 0.01
        joints[:, 16, 2] = joints[:, 17, 2] = 1.0
        series = at.movement_series(joints, skel, fps=30)
        np.testing.assert_allclose(series["travel"], 0.3)
        assert len(series["speed"]) == 3 and len(series["level"]) == 4
        offsets = np.asarray(skel.rest_offsets_m)
        arm = [np.linalg.norm(offsets[[18, 20]], axis=-1).sum(), np.linalg.norm(offsets[[19, 21]], axis=-1).sum()]
        np.testing.assert_allclose(series["arms"], (-1.0 / arm[0] - 1.0 / arm[1]) / 2)  # wrists 1 m below


def test_bad_joints_are_refused():
    with pytest.raises(ValueError, match=r"\(T, 24, 3\)"):
        at.travel_speeds(np.zeros((5, 22, 3)), SMPL24)
    with pytest.raises(MetricError, match="at least 2"):
        at.turning_rates(still(1), SMPL24)
    bad = still(3)
    bad[1, 3, 0] = np.nan
    with pytest.raises(MetricError, match="NaN"):
        at.arm_heights(bad, SMPL24)
