"""FK and the pose vector on any skeleton: SMPL-24 gives the same tensors bit for bit as the code before skeletons
were data; SMPL-X body-22 and 52 match an independent numpy FK."""

import numpy as np
import pytest
import torch
from motion_helpers import SMPLX55_PARENTS, made_up_smplx_joints

from dgsdp.motion import (
    REST_OFFSETS_M,
    SMPL24,
    axis_angle_to_matrix,
    channels_for_joints,
    foot_contacts,
    forward_kinematics,
    matrix_to_6d,
    pack_pose,
    pose_to_joints,
    project_rotations,
    sixd_to_matrix,
    smpl_to_pose,
    smplx_skeleton,
    unpack_pose,
)
from dgsdp.motion.axes import points_y_up_to_z_up, root_rotation_y_up_to_z_up

# --- the SMPL-only code path as it was before skeletons were data (fk.py and representation.py, trimmed) -------
OLD_PARENTS = (-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 20, 21)


def old_fk(local_rotmats, root_trans):
    offsets = torch.tensor(REST_OFFSETS_M, dtype=local_rotmats.dtype)
    positions, rotations = [root_trans], [local_rotmats[..., 0, :, :]]
    for j in range(1, 24):
        p = OLD_PARENTS[j]
        positions.append(positions[p] + (rotations[p] @ offsets[j].unsqueeze(-1)).squeeze(-1))
        rotations.append(rotations[p] @ local_rotmats[..., j, :, :])
    return torch.stack(positions, dim=-2), torch.stack(rotations, dim=-3)


def old_pose_to_joints(x):
    rot = sixd_to_matrix(x[..., 7:151].reshape(*x.shape[:-1], 24, 6))
    return old_fk(rot, x[..., 4:7])[0]


def old_smpl_to_pose(poses, trans):
    rot = axis_angle_to_matrix(poses.reshape(*poses.shape[:-1], 24, 3)).clone()
    rot[..., 0, :, :] = root_rotation_y_up_to_z_up(rot[..., 0, :, :])
    trans = points_y_up_to_z_up(trans)
    joints = old_fk(rot, trans)[0]
    feet = joints[..., [7, 8, 10, 11], :]
    speed = torch.zeros(feet.shape[:-1], dtype=joints.dtype)
    speed[..., :-1, :] = (feet[..., 1:, :, :] - feet[..., :-1, :, :]).norm(dim=-1)
    contacts = (speed < 0.01).to(joints.dtype)
    return torch.cat((contacts, trans, matrix_to_6d(rot).flatten(-2)), dim=-1)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_smpl24_bit_identical_to_the_old_code(dtype):
    g = torch.Generator().manual_seed(7)
    poses = (0.6 * torch.randn(3, 40, 72, generator=g)).to(dtype)
    trans = torch.randn(3, 40, 3, generator=g).cumsum(1).to(dtype) * 0.02
    rot = axis_angle_to_matrix(poses.reshape(3, 40, 24, 3))
    new_joints, new_glob = forward_kinematics(rot, trans, return_global_rotmats=True)
    old_joints, old_glob = old_fk(rot, trans)
    assert torch.equal(new_joints, old_joints) and torch.equal(new_glob, old_glob)
    x = smpl_to_pose(poses, trans)
    assert x.shape == (3, 40, 151) and torch.equal(x, old_smpl_to_pose(poses, trans))
    assert torch.equal(pose_to_joints(x), old_pose_to_joints(x))
    assert torch.equal(forward_kinematics(rot, trans, skeleton=SMPL24), old_joints)


def numpy_fk(rotmats, root, parents, offsets):
    """Independent FK: world transform of each joint as a 4x4 matrix, composed parent to child."""
    n = len(parents)
    out = np.zeros(rotmats.shape[:-3] + (n, 3))
    for idx in np.ndindex(rotmats.shape[:-3]):
        world = [None] * n
        for j in range(n):
            local = np.eye(4)
            local[:3, :3] = rotmats[idx + (j,)]
            local[:3, 3] = root[idx] if parents[j] < 0 else offsets[j]
            world[j] = local if parents[j] < 0 else world[parents[j]] @ local
            out[idx + (j,)] = world[j][:3, 3]
    return out


@pytest.mark.parametrize("kind,n", [("body22", 22), ("full52", 52)])
def test_smplx_fk_and_pose_vector(tmp_path, kind, n):
    joints55 = made_up_smplx_joints(seed=1)
    np.save(tmp_path / "joints.npy", joints55)
    skel = smplx_skeleton(kind, tmp_path / "joints.npy")
    kept = [j for j in range(55) if j not in (22, 23, 24)][:n]
    renumber = {old: new for new, old in enumerate(kept)}
    parents = [-1] + [renumber[SMPLX55_PARENTS[j]] for j in kept[1:]]
    offsets = np.stack([np.zeros(3)] + [joints55[j] - joints55[SMPLX55_PARENTS[j]] for j in kept[1:]])
    # in the rest pose the joints are the model's, moved so the root sits at the translation
    rest = forward_kinematics(
        torch.eye(3, dtype=torch.float64).expand(n, 3, 3), torch.zeros(3, dtype=torch.float64), skeleton=skel
    )
    np.testing.assert_allclose(rest.numpy(), joints55[kept] - joints55[0], atol=1e-12)

    g = torch.Generator().manual_seed(2)
    rot = axis_angle_to_matrix(0.7 * torch.randn(2, 5, n, 3, generator=g, dtype=torch.float64))
    trans = torch.randn(2, 5, 3, generator=g, dtype=torch.float64)
    joints = forward_kinematics(rot, trans, skeleton=skel)
    np.testing.assert_allclose(joints.numpy(), numpy_fk(rot.numpy(), trans.numpy(), parents, offsets), atol=1e-12)

    contacts = foot_contacts(joints, skeleton=skel)
    x = pack_pose(contacts, trans, rot)
    assert x.shape == (2, 5, skel.pose_dim) == (2, 5, 7 + 6 * n)
    parts = unpack_pose(x, skel)
    np.testing.assert_allclose(parts.rotmats.numpy(), rot.numpy(), atol=1e-12)
    np.testing.assert_allclose(pose_to_joints(x, skel).numpy(), joints.numpy(), atol=1e-12)
    assert torch.equal(project_rotations(x, "all", skel)[..., :7], x[..., :7])
    name, index = ("left_thumb3", 36) if n == 52 else ("right_wrist", 21)
    assert channels_for_joints([name], False, skel) == list(range(7 + 6 * index, 13 + 6 * index))
    aa = 0.3 * torch.randn(4, 3 * n, generator=g, dtype=torch.float64)
    assert smpl_to_pose(aa, torch.zeros(4, 3, dtype=torch.float64), skeleton=skel).shape == (4, skel.pose_dim)
    with pytest.raises(ValueError, match=f"{skel.pose_dim} channels"):
        unpack_pose(torch.zeros(5, 151), skel)
    with pytest.raises(ValueError, match=f"\\(..., {n}, 3, 3\\)"):
        forward_kinematics(torch.eye(3).expand(24, 3, 3), torch.zeros(3), skeleton=skel)
