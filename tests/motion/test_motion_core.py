import math

import numpy as np
import pytest
import torch

from dgsdp.motion import (
    PARENTS,
    MinMaxNormalizer,
    axis_angle_to_matrix,
    axis_angle_to_quaternion,
    channels_for_joints,
    foot_contacts,
    forward_kinematics,
    matrix_to_6d,
    matrix_to_axis_angle,
    matrix_to_quaternion,
    pack_pose,
    points_y_up_to_z_up,
    points_z_up_to_y_up,
    project_rotations,
    quaternion_slerp,
    quaternion_to_matrix,
    rest_offsets,
    sixd_to_matrix,
    smpl_to_pose,
    unpack_pose,
)

torch.manual_seed(0)


def random_rotvecs(*shape: int) -> torch.Tensor:
    v = torch.randn(*shape, 3, dtype=torch.float64)
    angle = torch.rand(*shape, 1, dtype=torch.float64) * (math.pi - 1e-3)
    return torch.nn.functional.normalize(v, dim=-1) * angle


def test_fk_rest_pose_reproduces_offsets():
    identity = torch.eye(3, dtype=torch.float64).expand(24, 3, 3)
    root = torch.tensor([0.3, 1.0, -0.2], dtype=torch.float64)
    joints = forward_kinematics(identity, root)
    offsets = rest_offsets(dtype=torch.float64)
    for j in range(1, 24):
        np.testing.assert_allclose(joints[j] - joints[PARENTS[j]], offsets[j], atol=1e-12)
    np.testing.assert_allclose(joints[0], root)
    # the left toe in rest pose: sum of offsets along the chain 0 -> 1 -> 4 -> 7 -> 10 (hand-added)
    chain = offsets[1] + offsets[4] + offsets[7] + offsets[10]
    np.testing.assert_allclose(joints[10], root + chain, atol=1e-12)


def test_fk_rotated_root_rotates_whole_body():
    rot = axis_angle_to_matrix(torch.tensor([0.0, 0.0, math.pi / 2], dtype=torch.float64))
    local = torch.eye(3, dtype=torch.float64).repeat(24, 1, 1)
    local[0] = rot
    joints = forward_kinematics(local, torch.zeros(3, dtype=torch.float64))
    # rotating by 90 degrees about z maps (x, y, z) -> (-y, x, z)
    off = rest_offsets(dtype=torch.float64)
    np.testing.assert_allclose(joints[3], torch.stack([-off[3, 1], off[3, 0], off[3, 2]]), atol=1e-12)


def test_fk_elbow_bend_hand_worked():
    # bend the left elbow (18) by 90 degrees about y: the wrist offset (x, y, z) -> (z, y, -x)
    local = torch.eye(3, dtype=torch.float64).repeat(24, 1, 1)
    local[18] = axis_angle_to_matrix(torch.tensor([0.0, math.pi / 2, 0.0], dtype=torch.float64))
    joints = forward_kinematics(local, torch.zeros(3, dtype=torch.float64))
    off = rest_offsets(dtype=torch.float64)
    expected = joints[18] + torch.stack([off[20, 2], off[20, 1], -off[20, 0]])
    np.testing.assert_allclose(joints[20], expected, atol=1e-12)


def test_fk_batched_matches_single():
    rots = axis_angle_to_matrix(random_rotvecs(2, 5, 24))
    trans = torch.randn(2, 5, 3, dtype=torch.float64)
    batched = forward_kinematics(rots, trans)
    single = forward_kinematics(rots[1, 3], trans[1, 3])
    np.testing.assert_allclose(batched[1, 3], single, atol=1e-12)


def test_rotation_round_trips():
    rv = random_rotvecs(1000)
    m = axis_angle_to_matrix(rv)
    assert torch.allclose(matrix_to_axis_angle(m), rv, atol=1e-5)
    assert torch.allclose(quaternion_to_matrix(matrix_to_quaternion(m)), m, atol=1e-5)
    assert torch.allclose(sixd_to_matrix(matrix_to_6d(m)), m, atol=1e-5)
    # matrices are proper rotations
    eye = torch.eye(3, dtype=torch.float64).expand_as(m)
    assert torch.allclose(m @ m.transpose(-1, -2), eye, atol=1e-10)
    assert torch.allclose(torch.linalg.det(m), torch.ones(1000, dtype=torch.float64), atol=1e-10)


def test_sixd_convention_is_first_two_rows():
    m = axis_angle_to_matrix(random_rotvecs(4))
    sixd = matrix_to_6d(m)
    assert torch.equal(sixd[:, :3], m[:, 0, :]) and torch.equal(sixd[:, 3:], m[:, 1, :])
    # decoding a perturbed 6D still gives a rotation
    r = sixd_to_matrix(sixd + 0.05 * torch.randn_like(sixd))
    assert torch.allclose(r @ r.transpose(-1, -2), torch.eye(3, dtype=torch.float64).expand_as(r), atol=1e-10)


def test_quaternion_convention_is_xyzw():
    q = axis_angle_to_quaternion(torch.tensor([math.pi / 2, 0.0, 0.0], dtype=torch.float64))
    s = math.sqrt(0.5)
    assert torch.allclose(q, torch.tensor([s, 0.0, 0.0, s], dtype=torch.float64))


def test_slerp_hand_worked():
    # halfway between identity and 90 degrees about z is 45 degrees about z
    q0 = axis_angle_to_quaternion(torch.zeros(3, dtype=torch.float64))
    q1 = axis_angle_to_quaternion(torch.tensor([0.0, 0.0, math.pi / 2], dtype=torch.float64))
    mid = quaternion_slerp(q0, q1, 0.5)
    expected = axis_angle_to_quaternion(torch.tensor([0.0, 0.0, math.pi / 4], dtype=torch.float64))
    assert torch.allclose(mid, expected, atol=1e-12)
    # per-element weights: 0 gives q0, 1 gives q1
    qa = axis_angle_to_quaternion(random_rotvecs(3))
    qb = axis_angle_to_quaternion(random_rotvecs(3))
    w = torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64)
    out = quaternion_slerp(qa, qb, w)
    same = lambda a, b: torch.allclose(a, b, atol=1e-9) or torch.allclose(a, -b, atol=1e-9)  # noqa: E731
    assert same(out[0], qa[0]) and same(out[1], qb[1]) and same(out[2], qa[2])


def test_axes_conversion_hand_worked():
    p = torch.tensor([1.0, 2.0, 3.0])
    assert torch.equal(points_y_up_to_z_up(p), torch.tensor([1.0, -3.0, 2.0]))
    assert torch.allclose(points_z_up_to_y_up(points_y_up_to_z_up(p)), p)


def test_pose_vector_pack_unpack_round_trip():
    rots = axis_angle_to_matrix(random_rotvecs(3, 24)).float()
    contacts = torch.tensor([[1, 0, 1, 0], [0, 0, 0, 0], [1, 1, 1, 1]], dtype=torch.float32)
    trans = torch.randn(3, 3)
    x = pack_pose(contacts, trans, rots)
    assert x.shape == (3, 151)
    parts = unpack_pose(x)
    assert torch.equal(parts.contacts, contacts) and torch.equal(parts.root_trans, trans)
    assert torch.allclose(parts.rotmats, rots, atol=1e-5)
    # joint j's 6D lives at channels 7+6j .. 12+6j
    assert torch.equal(x[:, 7 + 6 * 5 : 13 + 6 * 5], matrix_to_6d(rots[:, 5]))


def test_project_rotations_keeps_valid_rotations_and_repairs_shrunken_ones():
    rots = axis_angle_to_matrix(random_rotvecs(5, 24))
    x = pack_pose(torch.rand(5, 4, dtype=torch.float64), torch.randn(5, 3, dtype=torch.float64), rots)
    torch.testing.assert_close(project_rotations(x), x, atol=1e-12, rtol=0)
    # the mean of a 60-degree turn left and one right about z (a model unsure which way the body turns): the 6D
    # columns shrink to (cos 60deg, 0, 0) and (0, cos 60deg, 0), which decode to no turn
    left, right = (
        axis_angle_to_matrix(torch.tensor([0.0, 0.0, s * math.pi / 3], dtype=torch.float64)) for s in (1, -1)
    )
    y = x.clone()
    y[0, 7:13] = (matrix_to_6d(left) + matrix_to_6d(right)) / 2
    torch.testing.assert_close(y[0, 7:13], torch.tensor([0.5, 0, 0, 0, 0.5, 0], dtype=torch.float64))
    out = project_rotations(y)
    torch.testing.assert_close(out[0, 7:13], torch.tensor([1.0, 0, 0, 0, 1, 0], dtype=torch.float64))  # no turn
    torch.testing.assert_close(out[1:], x[1:], atol=1e-12, rtol=0)
    torch.testing.assert_close(out[:, :7], y[:, :7])  # contacts and root translation untouched
    # any 6D vector: the output decodes to the same rotation, and its two columns are orthonormal
    z = x.clone()
    z[..., 7:] += 0.3 * torch.randn_like(z[..., 7:])
    p = project_rotations(z)
    torch.testing.assert_close(unpack_pose(p).rotmats, unpack_pose(z).rotmats, atol=1e-12, rtol=0)
    six = p[..., 7:].reshape(5, 24, 6)
    torch.testing.assert_close(six[..., :3].norm(dim=-1), torch.ones(5, 24, dtype=torch.float64))
    torch.testing.assert_close(six[..., 3:].norm(dim=-1), torch.ones(5, 24, dtype=torch.float64))
    torch.testing.assert_close((six[..., :3] * six[..., 3:]).sum(-1), torch.zeros(5, 24, dtype=torch.float64))
    root = project_rotations(z, "root")  # the root's rotation only
    torch.testing.assert_close(root[..., :13], p[..., :13])
    torch.testing.assert_close(root[..., 13:], z[..., 13:])
    with pytest.raises(ValueError, match="151 channels"):
        project_rotations(torch.zeros(3, 150))
    with pytest.raises(ValueError, match="'all' joints or of the 'root'"):
        project_rotations(x, "hips")


def test_smpl_to_pose_from_y_up_standing_body_is_upright_z_up():
    poses = torch.zeros(4, 72)
    trans_y_up = torch.tensor([[0.0, 0.9, 0.0]]).repeat(4, 1)
    x = smpl_to_pose(poses, trans_y_up)
    joints = unpack_pose(x).joints()
    # head above pelvis along +z after the conversion, and root translation converted (x, y, z) -> (x, -z, y)
    assert (joints[:, 15, 2] > joints[:, 0, 2] + 0.4).all()
    assert torch.allclose(x[:, 4:7], torch.tensor([0.0, 0.0, 0.9]).expand(4, 3))
    assert (x[:, :4] == 1).all()  # a static body has every foot in contact


def test_contacts_planted_vs_moving_foot():
    t = 10
    joints = torch.zeros(t, 24, 3)
    # left ankle (7) planted; right ankle (8) moves 5 cm per frame; left toe (10) creeps 5 mm per frame;
    # right toe (11) stops after frame 4
    joints[:, 8, 0] = torch.arange(t) * 0.05
    joints[:, 10, 1] = torch.arange(t) * 0.005
    joints[:, 11, 0] = torch.clamp(torch.arange(t), max=4) * 0.05
    c = foot_contacts(joints)
    assert c.shape == (t, 4)
    assert (c[:, 0] == 1).all()  # planted
    assert (c[:-1, 1] == 0).all() and c[-1, 1] == 1  # moving; the last frame has speed 0 by definition
    assert (c[:, 2] == 1).all()  # below 1 cm per frame
    assert (c[:4, 3] == 0).all() and (c[4:, 3] == 1).all()


def test_channels_for_joints_layout():
    ch = channels_for_joints(["left_wrist"], with_root_and_contacts=False)
    assert ch == list(range(7 + 6 * 20, 13 + 6 * 20))
    ch = channels_for_joints([0], with_root_and_contacts=True)
    assert ch == list(range(0, 13))
    with pytest.raises(ValueError, match="known joints"):
        channels_for_joints(["tail"], with_root_and_contacts=False)


def test_normalizer_min_max_and_state_is_plain_tensors():
    data = torch.tensor([[0.0, 5.0, 1.0], [1.0, 5.0, 3.0], [0.0, 5.0, 2.0]])
    norm = MinMaxNormalizer(3).fit(data)
    y = norm.normalize(data)
    assert torch.equal(y[:, 0], torch.tensor([-1.0, 1.0, -1.0]))  # binary -> -1/+1
    assert torch.equal(y[:, 1], torch.tensor([-1.0, -1.0, -1.0]))  # zero range -> range 1
    assert torch.allclose(y[:, 2], torch.tensor([-1.0, 1.0, 0.0]))
    assert torch.allclose(norm.unnormalize(y), data)
    # Outside the training range nothing is clipped: channel 0 spans [0, 1] -> 2.0 is 3.0, channel 2 spans [1, 3]
    # -> 10.0 is (10 - 1) / 2 * 2 - 1 = 8.0; and back again exactly.
    outside = torch.tensor([[2.0, 5.0, 10.0]])
    torch.testing.assert_close(norm.normalize(outside), torch.tensor([[3.0, -1.0, 8.0]]))
    torch.testing.assert_close(norm.unnormalize(norm.normalize(outside)), outside)
    state = norm.state_dict()
    assert all(type(v) is torch.Tensor for v in state.values())
    other = MinMaxNormalizer(3)
    other.load_state_dict(state)
    assert torch.equal(other.normalize(data), y)
