"""Exports on an SMPL-X skeleton (a made-up one: the model file is licensed): BVH, GLB, the AIST++ pickle, the
video frame and the studio viewer's JSON all carry the run's skeleton, checked against forward kinematics."""

import json
import sys
from pathlib import Path

import numpy as np
import pygltflib
import pytest
import torch
from motion_helpers import made_up_smplx_joints, random_motion

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bvh import Bvh  # noqa: E402
from test_bvh import bvh_fk  # noqa: E402
from test_gltf import read_accessor, trs  # noqa: E402

from dgsdp.errors import DataError  # noqa: E402
from dgsdp.export import render_frame  # noqa: E402
from dgsdp.generation import write_motion  # noqa: E402
from dgsdp.motion import forward_kinematics, points_z_up_to_y_up, smplx_skeleton, unpack_pose  # noqa: E402
from dgsdp.safety.safe_pickle import load_pickle  # noqa: E402
from dgsdp.studio.viewer import write_joints_json  # noqa: E402

FLOOR = 0.05


@pytest.fixture(scope="module", params=["body22", "full52"])
def written(request, tmp_path_factory):
    folder = tmp_path_factory.mktemp(request.param)
    np.save(folder / "joints.npy", made_up_smplx_joints(seed=4))
    skel = smplx_skeleton(request.param, folder / "joints.npy")
    motion = random_motion(12, seed=5, num_joints=skel.num_joints)
    files = write_motion(
        motion, folder / "dance", fps=30, formats=["pkl", "bvh", "glb", "npy"], floor_height=FLOOR, skeleton=skel
    )
    parts = unpack_pose(motion.double(), skel)
    fk = forward_kinematics(parts.rotmats, parts.root_trans, skeleton=skel)  # (T, J, 3) z-up
    return skel, motion, {f.suffix: f for f in files}, fk


def test_bvh_hierarchy_and_positions(written):
    skel, _, files, fk = written
    mocap = Bvh(files[".bvh"].read_text())
    names, positions = bvh_fk(mocap)
    assert sorted(names) == sorted(skel.joint_names)
    for name in names:
        parent = mocap.joint_parent(name)
        j = skel.joint_names.index(name)
        assert (parent.name if parent else None) == (skel.joint_names[skel.parents[j]] if j else None)
    shifted = fk.clone()
    shifted[..., 2] -= FLOOR  # the run's floor at height 0
    ours = points_z_up_to_y_up(shifted).numpy()[:, [skel.joint_names.index(n) for n in names]]
    assert np.abs(positions - ours).max() < 1e-5


def test_glb_nodes_and_world_positions(written):
    skel, _, files, fk = written
    gltf = pygltflib.GLTF2().load(str(files[".glb"]))
    blob = gltf.binary_blob()
    joints = gltf.skins[0].joints
    assert [gltf.nodes[i].name for i in joints] == list(skel.joint_names)
    for j, i in enumerate(joints):
        assert sorted(gltf.nodes[i].children) == [joints[c] for c in skel.children(j)]
    (anim,) = gltf.animations
    tracks = {
        (ch.target.node, ch.target.path): read_accessor(gltf, blob, anim.samplers[ch.sampler].output)
        for ch in anim.channels
    }
    frame = 7
    world = [None] * skel.num_joints
    for j, i in enumerate(joints):
        translation = tracks[(i, "translation")][frame] if j == 0 else gltf.nodes[i].translation
        local = trs(translation, tracks[(i, "rotation")][frame])
        world[j] = local if j == 0 else world[skel.parents[j]] @ local
    y_up = np.array([w[:3, 3] for w in world])
    z_up = np.stack((y_up[:, 0], -y_up[:, 2], y_up[:, 1] + FLOOR), axis=-1)
    np.testing.assert_allclose(z_up, fk[frame].numpy(), atol=1e-4)


def test_pkl_records_the_skeleton(written):
    skel, _, files, fk = written
    data = load_pickle(files[".pkl"], "the exported motion")
    assert data["smpl_poses"].shape == (12, 3 * skel.num_joints)
    assert data["skeleton"] == skel.name and data["joint_names"] == list(skel.joint_names)
    np.testing.assert_allclose(data["joints3d"], points_z_up_to_y_up(fk).numpy(), atol=1e-5)
    assert np.load(files[".npy"]).shape == (12, skel.pose_dim)


def test_video_frame_and_viewer_json(written, tmp_path):
    skel, _, _, fk = written
    image = render_frame(fk[0].numpy(), size=(64, 64), skeleton=skel)
    assert image.shape == (64, 64, 3) and (image != 255).any()
    with pytest.raises(DataError, match=f"\\({skel.num_joints}, 3\\)"):
        render_frame(np.zeros((24, 3)), skeleton=skel)
    data = json.loads(write_joints_json(tmp_path / "v.json", fk.numpy(), 30, skeleton=skel).read_text())
    assert data["parents"] == list(skel.parents) and data["n_joints"] == skel.num_joints
    assert data["head"] == 15 and data["side"][skel.joint_names.index("left_wrist")] == "l"
    if skel.num_joints == 52:
        assert data["side"][skel.joint_names.index("right_thumb3")] == "r"


def test_a_motion_of_another_skeleton_is_refused(written, tmp_path):
    skel, motion, _, _ = written
    with pytest.raises(ValueError, match=f"{skel.pose_dim} channels"):
        write_motion(torch.zeros(5, 151), tmp_path / "x", fps=30, formats=["npy"], skeleton=skel)
