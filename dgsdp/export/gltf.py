"""Write a motion as a binary glTF (.glb): a skinned skeleton with a simple body, animated, on a floor.

What the file holds (glTF 2.0, y-up, metres, one scene):

- One joint node per joint of the motion's skeleton (:class:`~dgsdp.motion.Skeleton`, default SMPL-24), named as its
  joints, node ``j`` is joint ``j``, parented as the skeleton's ``parents``. Each child's translation is its rest offset
  (the model's y-up rest frame), so the nodes' own TRS is the T-pose standing with its lowest joint on the floor.
- ``body``: a low-poly mesh of capsules, one per bone (from a joint to each child; feet, hands, finger tips and head get
  a short capsule or a sphere continuing them), each skinned rigidly (weight 1) to the joint that moves it, so any
  viewer shows a body. Left side blue, right side red, centre grey, as in the stick-figure videos.
- ``floor``: an unskinned square at y = 0 under the whole dance. The floor is the run's floor (``floor_height``,
  z-up metres, the height of the training data's floor: see :mod:`dgsdp.motion.floor`), not the lowest joint of
  each frame: the motion is shifted down by ``floor_height`` (the same for every frame, so the run's floor
  becomes y = 0) and converted to y-up, so a dancer who jumps leaves the floor in the file too. BVH files follow
  the same rule.
- One animation, ``dance``: for N frames at ``fps`` the keyframe times are ``i / fps`` for i = 0 .. N - 1 (the
  animation lasts (N - 1) / fps seconds), with a rotation channel for every joint (unit quaternions, x y z w, signs
  kept continuous) and a translation channel for the root (``pelvis``), LINEAR interpolation. The animation's
  ``extras`` record ``fps`` and ``frames``.

The conversion from the project's z-up world is the one of the BVH exporter: the root orientation is pre-multiplied
by the z-up -> y-up rotation, the root position mapped (x, y, z) -> (x, z, -y), local joint rotations unchanged.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pygltflib as gl
import torch

from dgsdp.export.aistpp_pkl import skeleton_motion
from dgsdp.motion import (
    SMPL24,
    Skeleton,
    matrix_to_quaternion,
    points_z_up_to_y_up,
    root_rotation_z_up_to_y_up,
)
from dgsdp.utils.io import atomic_write_bytes

ANIMATION_NAME = "dance"
BODY_NAME = "body"
FLOOR_NAME = "floor"
FLOOR_MARGIN_M = 1.5
CAPSULE_SEGMENTS = 12  # around the bone
CAP_RINGS = 3  # per hemisphere
LEAF_FRACTION = 0.5  # feet and hands continue their own bone by this fraction
HEAD_RADIUS_M = 0.1
COLOURS = {  # base colour (linear RGBA) per side
    "left": (0.05, 0.15, 0.6, 1.0),
    "right": (0.65, 0.05, 0.05, 1.0),
    "centre": (0.35, 0.35, 0.35, 1.0),
}
FLOOR_COLOUR = (0.8, 0.8, 0.8, 1.0)
FINGERS = ("index", "middle", "pinky", "ring", "thumb")  # SMPL-X's finger joints: <side>_<finger><1..3>


def _side(name: str) -> str:
    return "left" if name.startswith("left") else "right" if name.startswith("right") else "centre"


def _bone_radius(name: str) -> float:
    """Capsule radius (metres) of the bone from the joint called ``name`` to one of its children."""
    if name.endswith(tuple(f"{finger}{k}" for finger in FINGERS for k in (1, 2, 3))):
        return 0.01
    if name in ("pelvis", "spine1", "spine2", "spine3"):
        return 0.075
    if name.endswith(("hip", "knee")):
        return 0.06 if name.endswith("hip") else 0.05
    if name.endswith(("collar", "shoulder")):
        return 0.045
    if name.endswith("elbow"):
        return 0.038
    return 0.03  # neck, ankles, wrists, hands, feet


def _capsule(start: np.ndarray, end: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A capsule around the segment start -> end: (positions (V, 3), normals (V, 3), triangles (F, 3))."""
    axis = end - start
    length = float(np.linalg.norm(axis))
    w = axis / length if length > 1e-9 else np.array([0.0, 1.0, 0.0])
    helper = np.array([1.0, 0.0, 0.0]) if abs(w[0]) < 0.9 else np.array([0.0, 0.0, 1.0])
    u = np.cross(w, helper)
    u /= np.linalg.norm(u)
    v = np.cross(w, u)
    # Rings from the start pole to the end pole: (height along the axis, ring radius, normal's axial part).
    rings = []
    for k in range(CAP_RINGS + 1):  # start hemisphere, pole excluded
        phi = np.pi / 2 * (1 - k / CAP_RINGS)  # pi/2 (pole) .. 0 (equator)
        if k > 0:
            rings.append((-radius * np.sin(phi), radius * np.cos(phi), -np.sin(phi)))
    for k in range(CAP_RINGS):  # end hemisphere, equator to just before the pole
        phi = np.pi / 2 * k / CAP_RINGS
        rings.append((length + radius * np.sin(phi), radius * np.cos(phi), np.sin(phi)))
    angles = 2 * np.pi * np.arange(CAPSULE_SEGMENTS) / CAPSULE_SEGMENTS
    around = np.cos(angles)[:, None] * u + np.sin(angles)[:, None] * v  # (S, 3)
    positions = [start - radius * w]
    normals = [-w]
    for h, r, nz in rings:
        positions.extend(start + h * w + r * around)
        normals.extend(nz * w + np.sqrt(max(0.0, 1 - nz * nz)) * around)
    positions.append(end + radius * w)
    normals.append(w)
    s = CAPSULE_SEGMENTS
    faces = [(0, 1 + (i + 1) % s, 1 + i) for i in range(s)]
    for ring in range(len(rings) - 1):
        a, b = 1 + ring * s, 1 + (ring + 1) * s
        for i in range(s):
            i2 = (i + 1) % s
            faces += [(a + i, a + i2, b + i), (a + i2, b + i2, b + i)]
    last, top = 1 + (len(rings) - 1) * s, len(positions) - 1
    faces += [(last + i, last + (i + 1) % s, top) for i in range(s)]
    return np.asarray(positions), np.asarray(normals), np.asarray(faces)


def rest_joint_positions(offsets: np.ndarray, skeleton: Skeleton = SMPL24) -> np.ndarray:
    """(J, 3) y-up positions of the T-pose (all rotations identity) with the lowest joint at y = 0."""
    pos = np.zeros((skeleton.num_joints, 3))
    for j in range(1, skeleton.num_joints):
        pos[j] = pos[skeleton.parents[j]] + offsets[j]
    pos[:, 1] -= pos[:, 1].min()
    return pos


def body_parts(
    offsets: np.ndarray, skeleton: Skeleton = SMPL24
) -> list[tuple[int, str, np.ndarray, np.ndarray, np.ndarray]]:
    """Capsules of the body in the bind pose (``rest_joint_positions``): (joint that moves it, side, positions,
    normals, triangles) for each bone."""
    pos = rest_joint_positions(offsets, skeleton)
    names = skeleton.joint_names
    parts = []
    for j in range(skeleton.num_joints):
        children = skeleton.children(j)
        for c in children:
            side = _side(names[c]) if _side(names[j]) == "centre" else _side(names[j])
            parts.append((j, side, *_capsule(pos[j], pos[c], _bone_radius(names[j]))))
        if not children and names[j] == "head":
            parts.append((j, "centre", *_capsule(pos[j] + [0, 0.07, 0], pos[j] + [0, 0.07, 0], HEAD_RADIUS_M)))
        elif not children:  # feet, hands and finger tips continue their bone
            end = pos[j] + LEAF_FRACTION * offsets[j]
            parts.append((j, _side(names[j]), *_capsule(pos[j], end, _bone_radius(names[j]))))
    return parts


def _continuous(quats: np.ndarray) -> np.ndarray:
    """Flip quaternion signs (T, J, 4) so that consecutive frames have a non-negative dot product."""
    q = quats.copy()
    for t in range(1, len(q)):
        flip = np.sum(q[t] * q[t - 1], axis=-1) < 0
        q[t, flip] *= -1
    return q


class _Buffer:
    """Packs arrays into one binary buffer (4-byte aligned views) and records their accessors."""

    def __init__(self, gltf: gl.GLTF2) -> None:
        self.gltf = gltf
        self.chunks: list[bytes] = []
        self.length = 0

    def add(self, data: np.ndarray, type_: str, component: int, target: int | None = None, minmax: bool = False) -> int:
        raw = np.ascontiguousarray(data).tobytes()
        view = gl.BufferView(buffer=0, byteOffset=self.length, byteLength=len(raw), target=target)
        self.gltf.bufferViews.append(view)
        pad = (-len(raw)) % 4
        self.chunks.append(raw + b"\x00" * pad)
        self.length += len(raw) + pad
        flat = data.reshape(len(data), -1)
        accessor = gl.Accessor(
            bufferView=len(self.gltf.bufferViews) - 1,
            componentType=component,
            count=len(data),
            type=type_,
            min=flat.min(axis=0).tolist() if minmax else None,
            max=flat.max(axis=0).tolist() if minmax else None,
        )
        self.gltf.accessors.append(accessor)
        return len(self.gltf.accessors) - 1

    def finish(self) -> bytes:
        blob = b"".join(self.chunks)
        self.gltf.buffers.append(gl.Buffer(byteLength=len(blob)))
        return blob


def _material(gltf: gl.GLTF2, name: str, colour: Sequence[float], double_sided: bool = False) -> int:
    pbr = gl.PbrMetallicRoughness(baseColorFactor=list(colour), metallicFactor=0.0, roughnessFactor=0.8)
    gltf.materials.append(gl.Material(name=name, pbrMetallicRoughness=pbr, doubleSided=double_sided))
    return len(gltf.materials) - 1


def gltf_document(
    rotmats: torch.Tensor | np.ndarray,
    root_trans: torch.Tensor | np.ndarray,
    fps: float = 30,
    offsets: torch.Tensor | np.ndarray | None = None,
    floor_height: float = 0.0,
    skeleton: Skeleton = SMPL24,
) -> gl.GLTF2:
    """The glTF document (binary blob attached) of a z-up motion on ``skeleton``: rotmats (T, J, 3, 3) local
    rotations, root_trans (T, 3) metres, at ``fps``, its floor at ``floor_height``; see the module docstring."""
    rot, trans, offs = skeleton_motion(rotmats, root_trans, fps, offsets, floor_height, skeleton)
    n_frames = rot.shape[0]
    n_joints = skeleton.num_joints

    rot = rot.clone()
    rot[:, 0] = root_rotation_z_up_to_y_up(rot[:, 0])
    quats = _continuous(matrix_to_quaternion(rot).numpy())  # (T, J, 4) x y z w
    position = points_z_up_to_y_up(trans).numpy()  # (T, 3), the run's floor at y = 0
    bind = rest_joint_positions(offs, skeleton)

    gltf = gl.GLTF2(asset=gl.Asset(version="2.0", generator="dgsdp"))
    buf = _Buffer(gltf)

    # Joint nodes 0..J-1 in the skeleton's order, T-pose standing on the floor.
    for j in range(n_joints):
        translation = bind[0] if j == 0 else offs[j]
        gltf.nodes.append(
            gl.Node(name=skeleton.joint_names[j], translation=translation.tolist(), children=skeleton.children(j))
        )

    # Body: one primitive per side; every vertex follows exactly one joint.
    materials = {side: _material(gltf, f"body_{side}", colour) for side, colour in COLOURS.items()}
    primitives = []
    parts = body_parts(offs, skeleton)
    for side, material in materials.items():
        pos, nrm, tri, joint_ids = [], [], [], []
        start = 0
        for joint, part_side, p, n, f in parts:
            if part_side != side:
                continue
            pos.append(p)
            nrm.append(n)
            tri.append(f + start)
            joint_ids.append(np.full(len(p), joint))
            start += len(p)
        positions = np.concatenate(pos).astype(np.float32)
        normals = np.concatenate(nrm).astype(np.float32)
        triangles = np.concatenate(tri).astype(np.uint16).reshape(-1)
        joints4 = np.zeros((len(positions), 4), dtype=np.uint8)
        joints4[:, 0] = np.concatenate(joint_ids)
        weights4 = np.zeros((len(positions), 4), dtype=np.float32)
        weights4[:, 0] = 1.0
        attributes = gl.Attributes(
            POSITION=buf.add(positions, gl.VEC3, gl.FLOAT, gl.ARRAY_BUFFER, minmax=True),
            NORMAL=buf.add(normals, gl.VEC3, gl.FLOAT, gl.ARRAY_BUFFER),
            JOINTS_0=buf.add(joints4, gl.VEC4, gl.UNSIGNED_BYTE, gl.ARRAY_BUFFER),
            WEIGHTS_0=buf.add(weights4, gl.VEC4, gl.FLOAT, gl.ARRAY_BUFFER),
        )
        indices = buf.add(triangles, gl.SCALAR, gl.UNSIGNED_SHORT, gl.ELEMENT_ARRAY_BUFFER, minmax=True)
        primitives.append(gl.Primitive(attributes=attributes, indices=indices, material=material))
    gltf.meshes.append(gl.Mesh(name=BODY_NAME, primitives=primitives))

    # Inverse bind matrices: the bind pose has identity rotations, so each is a translation by -position.
    inverse_bind = np.tile(np.eye(4, dtype=np.float32), (n_joints, 1, 1))
    inverse_bind[:, :3, 3] = -bind
    column_major = np.ascontiguousarray(inverse_bind.transpose(0, 2, 1))
    gltf.skins.append(
        gl.Skin(
            name="smpl" if skeleton == SMPL24 else skeleton.name,
            joints=list(range(n_joints)),
            skeleton=0,
            inverseBindMatrices=buf.add(column_major.reshape(n_joints, 16), gl.MAT4, gl.FLOAT),
        )
    )
    gltf.nodes.append(gl.Node(name=BODY_NAME, mesh=0, skin=0))
    body_node = len(gltf.nodes) - 1

    # Floor: a square at y = 0 covering the root's path with a margin.
    lo = position[:, [0, 2]].min(axis=0) - FLOOR_MARGIN_M
    hi = position[:, [0, 2]].max(axis=0) + FLOOR_MARGIN_M
    corners = np.array([[lo[0], 0, lo[1]], [lo[0], 0, hi[1]], [hi[0], 0, hi[1]], [hi[0], 0, lo[1]]], np.float32)
    floor_attributes = gl.Attributes(
        POSITION=buf.add(corners, gl.VEC3, gl.FLOAT, gl.ARRAY_BUFFER, minmax=True),
        NORMAL=buf.add(np.tile(np.float32([0, 1, 0]), (4, 1)), gl.VEC3, gl.FLOAT, gl.ARRAY_BUFFER),
    )
    floor_indices = buf.add(np.uint16([0, 1, 2, 0, 2, 3]), gl.SCALAR, gl.UNSIGNED_SHORT, gl.ELEMENT_ARRAY_BUFFER)
    floor_material = _material(gltf, FLOOR_NAME, FLOOR_COLOUR, double_sided=True)
    gltf.meshes.append(
        gl.Mesh(
            name=FLOOR_NAME,
            primitives=[gl.Primitive(attributes=floor_attributes, indices=floor_indices, material=floor_material)],
        )
    )
    gltf.nodes.append(gl.Node(name=FLOOR_NAME, mesh=1))
    floor_node = len(gltf.nodes) - 1

    # Animation: keyframe i at i / fps seconds.
    times = (np.arange(n_frames, dtype=np.float64) / fps).astype(np.float32)
    time_accessor = buf.add(times, gl.SCALAR, gl.FLOAT, minmax=True)
    samplers = [
        gl.AnimationSampler(input=time_accessor, output=buf.add(position.astype(np.float32), gl.VEC3, gl.FLOAT))
    ]
    channels = [gl.AnimationChannel(sampler=0, target=gl.AnimationChannelTarget(node=0, path="translation"))]
    for j in range(n_joints):
        output = buf.add(quats[:, j].astype(np.float32), gl.VEC4, gl.FLOAT)
        samplers.append(gl.AnimationSampler(input=time_accessor, output=output))
        channels.append(
            gl.AnimationChannel(sampler=len(samplers) - 1, target=gl.AnimationChannelTarget(node=j, path="rotation"))
        )
    gltf.animations.append(
        gl.Animation(
            name=ANIMATION_NAME,
            samplers=samplers,
            channels=channels,
            extras={"fps": float(fps), "frames": int(n_frames)},
        )
    )

    gltf.scenes.append(gl.Scene(name="dance", nodes=[0, body_node, floor_node]))
    gltf.scene = 0
    gltf.set_binary_blob(buf.finish())
    return gltf


def save_glb(
    path: str | os.PathLike,
    rotmats: torch.Tensor | np.ndarray,
    root_trans: torch.Tensor | np.ndarray,
    fps: float = 30,
    offsets: torch.Tensor | np.ndarray | None = None,
    floor_height: float = 0.0,
    skeleton: Skeleton = SMPL24,
) -> Path:
    """Write a z-up motion (rotmats (T, J, 3, 3) local rotations on ``skeleton``, root_trans (T, 3) metres, at
    ``fps``) as a y-up binary glTF (.glb) with a skinned body, the run's floor (``floor_height``, z-up metres) as a
    square at y = 0 and one animation (atomic). Returns the path."""
    path = Path(path)
    gltf = gltf_document(rotmats, root_trans, fps=fps, offsets=offsets, floor_height=floor_height, skeleton=skeleton)
    atomic_write_bytes(path, b"".join(gltf.save_to_bytes()))
    return path
