"""Test helpers shared across test folders (importable because tests/conftest.py puts tests/ on sys.path)."""

import numpy as np
import torch

from dgsdp.motion import REST_OFFSETS_M, axis_angle_to_matrix, pack_pose


def random_motion(n: int, seed: int = 0, num_joints: int = 24) -> torch.Tensor:
    """A valid unnormalised motion (n, 7 + 6 J): random joint rotations, a wandering root, binary contacts."""
    g = torch.Generator().manual_seed(seed)
    rot = axis_angle_to_matrix(0.5 * torch.randn(n, num_joints, 3, generator=g, dtype=torch.float64))
    trans = torch.randn(n, 3, generator=g, dtype=torch.float64).cumsum(0) * 0.01
    contacts = (torch.rand(n, 4, generator=g) > 0.5).double()
    return pack_pose(contacts, trans, rot).float()


# SMPL-X's 55-joint kinematic tree as published with the model (body 0-21, jaw, left eye, right eye, 15 left-hand
# joints, 15 right-hand joints), written out here independently of dgsdp.motion.skeleton.
SMPLX55_PARENTS = [
    -1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 15, 15, 15,
    20, 25, 26, 20, 28, 29, 20, 31, 32, 20, 34, 35, 20, 37, 38,
    21, 40, 41, 21, 43, 44, 21, 46, 47, 21, 49, 50, 21, 52, 53,
]  # fmt: skip


def made_up_smplx_joints(seed: int = 0) -> np.ndarray:
    """Invented SMPL-X rest joint positions (55, 3), y-up metres: a body in SMPL's shape plus random small finger,
    jaw and eye offsets (the real ones come from the licensed model file, which tests never have)."""
    rng = np.random.default_rng(seed)
    offsets = np.zeros((55, 3))
    offsets[:22] = np.asarray(REST_OFFSETS_M[:22]) * 1.05
    offsets[22:] = rng.normal(0.0, 0.03, size=(33, 3))
    joints = np.zeros((55, 3))
    joints[0] = (0.001, -0.3, 0.02)
    for j in range(1, 55):
        joints[j] = joints[SMPLX55_PARENTS[j]] + offsets[j]
    return joints


def write_made_up_smplx_model(path, seed: int = 0, n_verts: int = 200) -> np.ndarray:
    """Write a made-up SMPL-X model .npz (v_template, J_regressor, kintree_table) whose regressed joints are
    :func:`made_up_smplx_joints`; returns those joints (55, 3)."""
    rng = np.random.default_rng(seed + 1)
    joints = made_up_smplx_joints(seed)
    free = n_verts - 55  # the last 55 vertices: one per joint, placed so that its regressed joint lands right
    verts = rng.normal(0.0, 0.5, size=(n_verts, 3))
    reg = np.zeros((55, n_verts))
    for j in range(55):
        reg[j, rng.choice(free, size=4, replace=False)] = 0.125
        reg[j, free + j] = 0.5
        verts[free + j] = (joints[j] - reg[j, :free] @ verts[:free]) / 0.5
    kintree = np.array([[2**32 - 1] + SMPLX55_PARENTS[1:], list(range(55))], dtype=np.int64)
    np.savez(path, v_template=verts, J_regressor=reg, kintree_table=kintree, f=np.zeros((1, 3), np.int64))
    return joints
