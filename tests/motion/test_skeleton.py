"""Skeletons as data: SMPL-24's constants, SMPL-X loaders from a made-up model or joints file, plain-data round
trip and clear errors for bad files."""

import json

import numpy as np
import pytest
import torch
from motion_helpers import SMPLX55_PARENTS, made_up_smplx_joints, write_made_up_smplx_model

from dgsdp.errors import ConfigError, DataError
from dgsdp.motion import (
    FOOT_JOINTS,
    JOINT_NAMES,
    PARENTS,
    SMPL24,
    SMPLX52_JOINT_NAMES,
    SMPLX52_PARENTS,
    Skeleton,
    rest_offsets,
    skeleton_from_config,
    smplx_skeleton,
)

# SMPL-X's joint order after jaw (22) and eyes (23, 24), as published with the model: fingers index, middle,
# pinky, ring, thumb, three joints each, left hand then right hand
KEPT = [j for j in range(55) if j not in (22, 23, 24)]


def test_smpl24_is_the_old_constants():
    assert SMPL24.name == "smpl24" and SMPL24.num_joints == 24 and SMPL24.pose_dim == 151
    assert SMPL24.joint_names == JOINT_NAMES and SMPL24.parents == PARENTS and SMPL24.foot_joints == FOOT_JOINTS
    assert PARENTS == (-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 20, 21)
    assert torch.equal(SMPL24.rest_offsets(torch.float64), rest_offsets(torch.float64))
    assert rest_offsets().shape == (24, 3) and rest_offsets().dtype == torch.float32
    assert SMPL24.joint_index("left_wrist") == 20 and SMPL24.upper_body_joints[0] == 3


def test_smplx52_order_and_parents():
    assert len(SMPLX52_JOINT_NAMES) == 52 and len(set(SMPLX52_JOINT_NAMES)) == 52
    assert SMPLX52_JOINT_NAMES[:22] == JOINT_NAMES[:22]
    assert SMPLX52_JOINT_NAMES[22:25] == ("left_index1", "left_index2", "left_index3")
    assert SMPLX52_JOINT_NAMES[34:37] == ("left_thumb1", "left_thumb2", "left_thumb3")
    assert SMPLX52_JOINT_NAMES[37] == "right_index1" and SMPLX52_JOINT_NAMES[-1] == "right_thumb3"
    # the published 55-joint tree with jaw and eyes removed and the indices renumbered
    renumber = {old: new for new, old in enumerate(KEPT)} | {-1: -1}
    assert SMPLX52_PARENTS == tuple(renumber[SMPLX55_PARENTS[j]] for j in KEPT)
    for j in range(22, 52):  # every finger hangs off its own wrist
        root = j
        while root >= 22:
            root = SMPLX52_PARENTS[root]
        assert root == (20 if SMPLX52_JOINT_NAMES[j].startswith("left") else 21)


@pytest.mark.parametrize("kind,n", [("body22", 22), ("full52", 52)])
def test_smplx_from_model_file(tmp_path, kind, n):
    path = tmp_path / "SMPLX_NEUTRAL.npz"
    write_made_up_smplx_model(path)
    with np.load(path) as f:  # independent: regress the joints from the file
        joints = (f["J_regressor"] @ f["v_template"])[KEPT]
    skel = smplx_skeleton(kind, path)
    assert skel.name == f"smplx{n}" and skel.num_joints == n and skel.pose_dim == 7 + 6 * n
    assert skel.foot_joints == (7, 8, 10, 11)
    offsets = skel.rest_offsets(torch.float64).numpy()
    assert offsets.shape == (n, 3)
    np.testing.assert_allclose(offsets[0], 0.0)
    for j in range(1, n):
        np.testing.assert_allclose(offsets[j], joints[j] - joints[SMPLX52_PARENTS[j]], atol=1e-12)


def test_smplx_from_joints_files(tmp_path):
    joints55 = made_up_smplx_joints(seed=3)
    np.save(tmp_path / "j55.npy", joints55)
    np.savez(tmp_path / "j52.npz", joints=joints55[KEPT])
    a = smplx_skeleton("full52", tmp_path / "j55.npy")
    b = smplx_skeleton("full52", str(tmp_path / "j52.npz"))
    assert a == b
    # left index1 hangs off the left wrist: its offset is the difference of the made-up positions 25 and 20
    np.testing.assert_allclose(a.rest_offsets_m[22], joints55[25] - joints55[20], atol=1e-12)
    body = smplx_skeleton("body22", tmp_path / "j55.npy")
    assert body.rest_offsets_m == a.rest_offsets_m[:22] and body.parents == PARENTS[:22]
    assert skeleton_from_config("smplx22", tmp_path / "j55.npy") == body
    assert skeleton_from_config("smpl24") is SMPL24


@pytest.mark.parametrize("skel_name", ["smpl24", "smplx52"])
def test_to_dict_round_trip_is_plain_data(tmp_path, skel_name):
    np.save(tmp_path / "j.npy", made_up_smplx_joints())
    skel = SMPL24 if skel_name == "smpl24" else smplx_skeleton("full52", tmp_path / "j.npy")
    data = skel.to_dict()
    assert Skeleton.from_dict(json.loads(json.dumps(data))) == skel  # JSON-able: no objects inside
    assert Skeleton.from_dict(data) == skel


def test_missing_smplx_file_says_where_to_get_it(tmp_path):
    for missing in (None, tmp_path / "nowhere.npz"):
        with pytest.raises((ConfigError, DataError)) as err:
            smplx_skeleton("full52", missing, option="data.finedance.smplx_file")
        assert "https://smpl-x.is.tue.mpg.de" in str(err.value) and "data.finedance.smplx_file" in str(err.value)


def test_bad_smplx_files_rejected(tmp_path):
    np.save(tmp_path / "wrong_shape.npy", np.zeros((24, 3)))
    np.save(tmp_path / "nan.npy", np.full((52, 3), np.nan))
    np.savez(tmp_path / "two.npz", a=np.zeros((52, 3)), b=np.zeros((52, 3)))
    (tmp_path / "model.pkl").write_bytes(b"not read")
    (tmp_path / "garbage.npz").write_bytes(b"garbage")
    np.save(tmp_path / "objects.npy", np.array([{"a": 1}], dtype=object))
    path = tmp_path / "badtree.npz"
    write_made_up_smplx_model(path)
    with np.load(path) as f:
        arrays = dict(f)
    arrays["kintree_table"] = arrays["kintree_table"].copy()
    arrays["kintree_table"][0, 30] = 0
    np.savez(path, **arrays)
    for name in ("wrong_shape.npy", "nan.npy", "two.npz", "model.pkl", "garbage.npz", "objects.npy", "badtree.npz"):
        with pytest.raises(DataError, match="smpl-x.is.tue.mpg.de"):
            smplx_skeleton("full52", tmp_path / name)
    with pytest.raises(ConfigError, match="body22"):
        smplx_skeleton("hands", tmp_path / "nan.npy")
    with pytest.raises(ConfigError, match="smplx52"):
        skeleton_from_config("smplx", None)


def test_from_dict_rejects_bad_data():
    good = SMPL24.to_dict()
    cases = {
        "root": {**good, "parents": [0] + good["parents"][1:]},  # the root must be -1
        "topological": {**good, "parents": good["parents"][:5] + [9] + good["parents"][6:]},
        "outside": {**good, "foot_joints": [7, 8, 10, 99]},
        "rest_offsets_m": {**good, "rest_offsets_m": "abc"},
        "no field parents": {k: v for k, v in good.items() if k != "parents"},
        "finite": {**good, "rest_offsets_m": [[float("nan"), 0, 0]] + good["rest_offsets_m"][1:]},
        "23 joint names": {**good, "joint_names": good["joint_names"][:-1]},
    }
    for what, data in cases.items():
        with pytest.raises(ConfigError, match="ckpt.pt") as err:
            Skeleton.from_dict(data, source="ckpt.pt")
        assert what in str(err.value)
    with pytest.raises(ConfigError):
        Skeleton.from_dict(["not", "a", "mapping"])
