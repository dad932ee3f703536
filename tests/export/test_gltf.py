"""GLB export: read back by independent readers (pygltflib's parser with our own accessor decoding and FK,
trimesh, and the Khronos glTF validator when node has it), compared with the project's FK."""

import json
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pygltflib
import pytest
import torch

from dgsdp.errors import DataError
from dgsdp.export import save_glb
from dgsdp.motion import JOINT_NAMES, PARENTS, axis_angle_to_matrix, forward_kinematics, root_rotation_y_up_to_z_up

COMPONENTS = {5121: np.uint8, 5123: np.uint16, 5125: np.uint32, 5126: np.float32}
WIDTH = {"SCALAR": 1, "VEC3": 3, "VEC4": 4, "MAT4": 16}


def dance(frames: int, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    """A random motion: rotations up to about 1 rad per joint, travelling root 0.9 m above the floor, one jump."""
    g = torch.Generator().manual_seed(seed)
    rot = axis_angle_to_matrix(0.5 * torch.randn(frames, 24, 3, generator=g, dtype=torch.float64))
    rot[:, 0] = root_rotation_y_up_to_z_up(rot[:, 0])
    t = torch.arange(frames, dtype=torch.float64)
    trans = torch.stack((0.03 * t, -0.02 * t, 0.9 + 0.3 * (t == frames // 2)), dim=-1)
    return rot, trans


def read_accessor(gltf: pygltflib.GLTF2, blob: bytes, index: int) -> np.ndarray:
    acc = gltf.accessors[index]
    view = gltf.bufferViews[acc.bufferView]
    dtype = np.dtype(COMPONENTS[acc.componentType])
    width = WIDTH[acc.type]
    start = (view.byteOffset or 0) + (acc.byteOffset or 0)
    stride = view.byteStride or dtype.itemsize * width
    assert stride == dtype.itemsize * width  # tightly packed
    data = np.frombuffer(blob, dtype=dtype, count=acc.count * width, offset=start)
    return data.reshape(acc.count, width)


def quat_xyzw_to_matrix(q: np.ndarray) -> np.ndarray:
    x, y, z, w = q / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])  # fmt: skip


def trs(translation, rotation) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3] = quat_xyzw_to_matrix(np.asarray(rotation, dtype=np.float64))
    m[:3, 3] = translation
    return m


@pytest.fixture(scope="module")
def written(tmp_path_factory) -> tuple[Path, torch.Tensor, torch.Tensor]:
    rot, trans = dance(37)
    path = save_glb(tmp_path_factory.mktemp("glb") / "dance.glb", rot, trans, fps=30)
    return path, rot, trans


def test_skeleton_names_and_skin(written):
    path, _, _ = written
    gltf = pygltflib.GLTF2().load(str(path))
    blob = gltf.binary_blob()
    (skin,) = gltf.skins
    names = [gltf.nodes[j].name for j in skin.joints]
    assert names == list(JOINT_NAMES)
    for j, node_index in enumerate(skin.joints):  # hierarchy follows SMPL's parents
        children = [skin.joints.index(c) for c in gltf.nodes[node_index].children]
        assert sorted(children) == [c for c in range(24) if PARENTS[c] == j]
    # Inverse bind matrices undo the joints' rest (node TRS) world transforms.
    ibm = read_accessor(gltf, blob, skin.inverseBindMatrices).reshape(24, 4, 4).transpose(0, 2, 1)
    world = [None] * 24
    for j, node_index in enumerate(skin.joints):
        node = gltf.nodes[node_index]
        local = trs(node.translation or [0, 0, 0], node.rotation or [0, 0, 0, 1])
        world[j] = local if PARENTS[j] < 0 else world[PARENTS[j]] @ local
    for j in range(24):
        np.testing.assert_allclose(ibm[j] @ world[j], np.eye(4), atol=1e-6)
    # Every body vertex follows exactly one joint.
    body = next(m for m in gltf.meshes if m.name == "body")
    for prim in body.primitives:
        weights = read_accessor(gltf, blob, prim.attributes.WEIGHTS_0)
        joints = read_accessor(gltf, blob, prim.attributes.JOINTS_0)
        np.testing.assert_array_equal(weights[:, 0], 1.0)
        assert (joints[:, 0] < 24).all() and (weights[:, 1:] == 0).all()


def test_animation_length_and_world_positions_match_fk(written):
    path, rot, trans = written
    n = rot.shape[0]
    gltf = pygltflib.GLTF2().load(str(path))
    blob = gltf.binary_blob()
    (anim,) = gltf.animations
    tracks: dict[tuple[int, str], np.ndarray] = {}
    for ch in anim.channels:
        sampler = anim.samplers[ch.sampler]
        times = read_accessor(gltf, blob, sampler.input)[:, 0]
        assert len(times) == n
        np.testing.assert_allclose(times, np.arange(n) / 30, atol=1e-6)
        assert times[-1] == pytest.approx((n - 1) / 30)
        tracks[(ch.target.node, ch.target.path)] = read_accessor(gltf, blob, sampler.output)
    joint_nodes = gltf.skins[0].joints
    assert {key for key in tracks if key[1] == "rotation"} == {(j, "rotation") for j in joint_nodes}
    assert {key for key in tracks if key[1] == "translation"} == {(joint_nodes[0], "translation")}

    fk_z_up = forward_kinematics(rot, trans).numpy()
    for frame in (0, 1, n // 2, n - 1):
        world = [None] * 24
        for j, node_index in enumerate(joint_nodes):
            node = gltf.nodes[node_index]
            translation = tracks.get((node_index, "translation"), [node.translation])[frame if j == 0 else 0]
            local = trs(translation, tracks[(node_index, "rotation")][frame])
            world[j] = local if PARENTS[j] < 0 else world[PARENTS[j]] @ local
        y_up = np.array([w[:3, 3] for w in world])
        z_up = np.stack((y_up[:, 0], -y_up[:, 2], y_up[:, 1]), axis=-1)  # (x, y, z) y-up -> (x, -z, y) z-up
        np.testing.assert_allclose(z_up, fk_z_up[frame], atol=1e-4)


def test_floor_at_true_height(written):
    path, _, trans = written
    gltf = pygltflib.GLTF2().load(str(path))
    blob = gltf.binary_blob()
    floor_node = next(n for n in gltf.nodes if n.name == "floor")
    assert floor_node.translation in (None, [0, 0, 0]) and floor_node.rotation is None
    floor = gltf.meshes[floor_node.mesh].primitives[0]
    corners = read_accessor(gltf, blob, floor.attributes.POSITION)
    np.testing.assert_array_equal(corners[:, 1], 0.0)
    # The root's path (x, -y in y-up) lies over the floor; the root height is kept, jump included.
    assert corners[:, 0].min() < trans[:, 0].min() and corners[:, 0].max() > trans[:, 0].max()
    assert corners[:, 2].min() < -trans[:, 1].max() and corners[:, 2].max() > -trans[:, 1].min()


def test_trimesh_loads_a_body_standing_on_the_floor(written):
    trimesh = pytest.importorskip("trimesh")
    path, _, _ = written
    scene = trimesh.load(str(path), force="scene")
    assert len(scene.geometry) == 4  # body: left, right, centre; floor
    body = [g for name, g in scene.geometry.items() if "floor" not in name]
    bounds = np.array([g.bounds for g in body])
    lo, hi = bounds[:, 0].min(axis=0), bounds[:, 1].max(axis=0)
    # Bind pose (T-pose) read without the animation: lowest joint on the floor (capsules reach a few cm below),
    # about 1.7 m tall, arms spread about 1.6 m.
    assert -0.08 < lo[1] < 0.0 and 1.6 < hi[1] < 1.85
    assert 1.4 < hi[0] - lo[0] < 1.9
    assert all(g.is_watertight for g in body)


def test_one_frame_and_bad_input(tmp_path):
    rot, trans = dance(1)
    path = save_glb(tmp_path / "still.glb", rot, trans)
    gltf = pygltflib.GLTF2().load(str(path))
    assert gltf.accessors[gltf.animations[0].samplers[0].input].count == 1
    with pytest.raises(DataError, match="24, 3, 3"):
        save_glb(tmp_path / "bad.glb", rot[:, :23], trans)
    with pytest.raises(DataError, match="fps"):
        save_glb(tmp_path / "bad.glb", rot, trans, fps=0)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["still.glb"]


VALIDATOR_SCRIPT = """
const fs = require('fs');
const validator = require('gltf-validator');
validator.validateBytes(new Uint8Array(fs.readFileSync(process.argv[1])))
  .then((r) => console.log(JSON.stringify(r.issues)))
  .catch((e) => { console.error(String(e)); process.exit(2); });
"""


def _validator_available() -> bool:
    if shutil.which("node") is None:
        return False
    probe = subprocess.run(["node", "-e", "require.resolve('gltf-validator')"], capture_output=True, env=os.environ)
    return probe.returncode == 0


@pytest.mark.skipif(
    not _validator_available(),
    reason="the Khronos glTF validator is not installed (npm install gltf-validator; set NODE_PATH to its node_modules)",
)
def test_khronos_validator_reports_no_issue(written):
    path, _, _ = written
    out = subprocess.run(["node", "-e", VALIDATOR_SCRIPT, str(path)], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    issues = json.loads(out.stdout)
    assert issues["numErrors"] == 0 and issues["numWarnings"] == 0, issues["messages"]


def test_write_motion_writes_glb(tmp_path):
    from motion_helpers import random_motion

    from dgsdp.errors import ConfigError
    from dgsdp.generation import write_motion
    from dgsdp.motion import unpack_pose

    motion = random_motion(12)
    (path,) = write_motion(motion, tmp_path / "song", fps=30, formats=["glb"])
    assert path == tmp_path / "song.glb"
    gltf = pygltflib.GLTF2().load(str(path))
    blob = gltf.binary_blob()
    root_track = next(ch for ch in gltf.animations[0].channels if ch.target.path == "translation")
    root = read_accessor(gltf, blob, gltf.animations[0].samplers[root_track.sampler].output)
    trans = unpack_pose(motion.double()).root_trans.numpy()
    np.testing.assert_allclose(root, np.stack((trans[:, 0], trans[:, 2], -trans[:, 1]), axis=-1), atol=1e-6)
    with pytest.raises(ConfigError, match="unknown output format.*gltf"):
        write_motion(motion, tmp_path / "other", fps=30, formats=["gltf"])


def test_skinned_body_follows_the_animated_bones(written):
    """Skinning by hand (joint world matrix @ inverse bind matrix @ vertex) at one frame: every body vertex lies
    within a capsule radius (plus the head's sphere) of the bones between the animated joints."""
    path, rot, trans = written
    gltf = pygltflib.GLTF2().load(str(path))
    blob = gltf.binary_blob()
    anim = gltf.animations[0]
    tracks = {
        (ch.target.node, ch.target.path): read_accessor(gltf, blob, anim.samplers[ch.sampler].output)
        for ch in anim.channels
    }
    frame = 20
    joint_nodes = gltf.skins[0].joints
    world = [None] * 24
    for j, node_index in enumerate(joint_nodes):
        node = gltf.nodes[node_index]
        translation = tracks[(node_index, "translation")][frame] if j == 0 else node.translation
        local = trs(translation, tracks[(node_index, "rotation")][frame])
        world[j] = local if PARENTS[j] < 0 else world[PARENTS[j]] @ local
    ibm = read_accessor(gltf, blob, gltf.skins[0].inverseBindMatrices).reshape(24, 4, 4).transpose(0, 2, 1)
    joints = np.array([w[:3, 3] for w in world])
    segments = [(joints[PARENTS[j]], joints[j]) for j in range(1, 24)]

    def distance_to_bones(p: np.ndarray) -> float:
        best = np.inf
        for a, b in segments:
            t = np.clip(np.dot(p - a, b - a) / max(np.dot(b - a, b - a), 1e-12), 0.0, 1.0)
            best = min(best, np.linalg.norm(p - (a + t * (b - a))))
        return best

    body = next(m for m in gltf.meshes if m.name == "body")
    far = 0.0
    for prim in body.primitives:
        verts = read_accessor(gltf, blob, prim.attributes.POSITION).astype(np.float64)
        owners = read_accessor(gltf, blob, prim.attributes.JOINTS_0)[:, 0]
        for v, j in zip(verts[::7], owners[::7]):
            skinned = (world[j] @ ibm[j] @ np.append(v, 1.0))[:3]
            far = max(far, distance_to_bones(skinned))
    assert far < 0.2  # capsules are at most 7.5 cm thick; the head sphere (10 cm) sits 7 cm above the head joint


def test_the_runs_floor_is_the_floor_square(tmp_path):
    """A run whose floor is 0.4 m up (z-up): the body is lowered by 0.4 m, so that floor is the square at y = 0."""
    rot, trans = dance(6)
    path = save_glb(tmp_path / "floor.glb", rot, trans, fps=30, floor_height=0.4)
    gltf = pygltflib.GLTF2().load(str(path))
    blob = gltf.binary_blob()
    root_track = next(ch for ch in gltf.animations[0].channels if ch.target.path == "translation")
    root = read_accessor(gltf, blob, gltf.animations[0].samplers[root_track.sampler].output)
    t = trans.numpy()
    np.testing.assert_allclose(root, np.stack((t[:, 0], t[:, 2] - 0.4, -t[:, 1]), axis=-1), atol=1e-6)
    floor_node = next(n for n in gltf.nodes if n.name == "floor")
    corners = read_accessor(gltf, blob, gltf.meshes[floor_node.mesh].primitives[0].attributes.POSITION)
    np.testing.assert_array_equal(corners[:, 1], 0.0)
