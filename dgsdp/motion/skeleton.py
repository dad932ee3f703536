"""Skeletons as data: joint names, parents, rest offsets, foot joints and the pose vector's size.

Three skeletons are known:

- ``smpl24`` (:data:`SMPL24`): SMPL's 24 joints with fixed rest offsets (mean body, zero betas), as EDGE uses them.
  The official SMPL body model (licensed weights, ``smplx``) gives slightly different joint positions.
- ``smplx22``: SMPL-X's 22 body joints (SMPL's first 22: no hand joints).
- ``smplx52``: SMPL-X's 22 body joints and 15 + 15 finger joints, jaw and eyes dropped (FineDance's order).

The SMPL-X rest offsets come from the SMPL-X model file (``SMPLX_NEUTRAL.npz``: its ``J_regressor`` applied to
``v_template``) or from a joints file with the rest joint positions, read by :func:`smplx_skeleton`; the model's
licence forbids shipping it. Offsets are in metres in the model's y-up rest frame. The root's offset is zero: the
root position is the translation itself.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from dgsdp.errors import ConfigError, DataError

SKELETON_NAMES = ("smpl24", "smplx22", "smplx52")
SMPLX_URL = "https://smpl-x.is.tue.mpg.de"


@dataclass(frozen=True)
class Skeleton:
    """A kinematic tree with fixed rest offsets (see the module docstring). Joints are in topological order
    (each parent comes before its children); the pose vector of a skeleton with J joints has 4 + 3 + 6 J channels
    (foot contacts of :attr:`foot_joints`, root translation, one 6D rotation per joint)."""

    name: str
    joint_names: tuple[str, ...]
    parents: tuple[int, ...]  # -1 for the root
    rest_offsets_m: tuple[tuple[float, float, float], ...]  # from the parent, metres, y-up
    foot_joints: tuple[int, int, int, int]  # left ankle, right ankle, left toe, right toe (contact channels' order)
    lower_body_joints: tuple[int, ...]  # editing masks: the pelvis goes with the lower body

    def __post_init__(self) -> None:
        problems = _problems(self)
        if problems:
            raise ConfigError(f"skeleton {self.name!r} is malformed: " + "; ".join(problems))

    @property
    def num_joints(self) -> int:
        return len(self.joint_names)

    @property
    def pose_dim(self) -> int:
        """Channels of the pose vector: 4 foot contacts + 3 root translation + 6 per joint."""
        return 4 + 3 + 6 * self.num_joints

    @property
    def upper_body_joints(self) -> tuple[int, ...]:
        return tuple(j for j in range(self.num_joints) if j not in self.lower_body_joints)

    def rest_offsets(
        self, dtype: torch.dtype = torch.float32, device: torch.device | str | None = None
    ) -> torch.Tensor:
        """Rest offsets from each joint's parent, (J, 3) metres, y-up."""
        return torch.tensor(self.rest_offsets_m, dtype=dtype, device=device)

    def children(self, j: int) -> list[int]:
        return [c for c, p in enumerate(self.parents) if p == j]

    def joint_index(self, name_or_index: str | int) -> int:
        """Index of a joint given by name (``"left_wrist"``) or index; raises ValueError listing the names."""
        if isinstance(name_or_index, int):
            if not 0 <= name_or_index < self.num_joints:
                raise ValueError(f"joint index {name_or_index} out of range 0..{self.num_joints - 1}")
            return name_or_index
        key = str(name_or_index).strip().lower()
        if key.isdigit():
            return self.joint_index(int(key))
        if key not in self.joint_names:
            raise ValueError(f"unknown joint {name_or_index!r}; known joints: {', '.join(self.joint_names)}")
        return self.joint_names.index(key)

    def to_dict(self) -> dict[str, Any]:
        """Plain data (lists, strings, floats) for a checkpoint or a JSON file."""
        return {
            "name": self.name,
            "joint_names": list(self.joint_names),
            "parents": list(self.parents),
            "rest_offsets_m": [list(o) for o in self.rest_offsets_m],
            "foot_joints": list(self.foot_joints),
            "lower_body_joints": list(self.lower_body_joints),
        }

    @classmethod
    def from_dict(cls, data: Any, source: str = "skeleton") -> Skeleton:
        """The skeleton stored by :meth:`to_dict`; anything malformed raises one ConfigError naming the field."""
        if not isinstance(data, Mapping):
            raise ConfigError(f"{source}: a skeleton must be a mapping, got {type(data).__name__}")
        missing = [k for k in _FIELDS if k not in data]
        if missing:
            raise ConfigError(f"{source}: the skeleton has no field {', '.join(missing)}")
        try:
            name = data["name"]
            if not isinstance(name, str):
                raise TypeError("name")
            names = _seq(data["joint_names"], "joint_names", str)
            parents = _seq(data["parents"], "parents", int)
            offsets = tuple(
                tuple(float(v) for v in _seq(o, "rest_offsets_m", (int, float)))
                for o in _seq(data["rest_offsets_m"], "rest_offsets_m", (list, tuple))
            )
            feet = _seq(data["foot_joints"], "foot_joints", int)
            lower = _seq(data["lower_body_joints"], "lower_body_joints", int)
        except TypeError as e:
            raise ConfigError(f"{source}: skeleton field {e.args[0]} has the wrong type (see Skeleton.to_dict)") from e
        try:
            return cls(name, names, parents, offsets, feet, lower)  # type: ignore[arg-type]
        except ConfigError as e:
            raise ConfigError(f"{source}: {e}") from e


_FIELDS = ("name", "joint_names", "parents", "rest_offsets_m", "foot_joints", "lower_body_joints")


def _seq(value: Any, field: str, kind: type | tuple[type, ...]) -> tuple:
    if not isinstance(value, (list, tuple)) or any(
        not isinstance(v, kind) or (isinstance(v, bool) and kind is not bool) for v in value
    ):
        raise TypeError(field)
    return tuple(value)


def _problems(s: Skeleton) -> list[str]:
    out = []
    n = len(s.joint_names)
    if n == 0:
        return ["it has no joints"]
    if len(set(s.joint_names)) != n:
        out.append("joint names repeat")
    if len(s.parents) != n or len(s.rest_offsets_m) != n:
        out.append(f"{n} joint names, {len(s.parents)} parents, {len(s.rest_offsets_m)} rest offsets")
    if s.parents and s.parents[0] != -1:
        out.append("joint 0 must be the root (parent -1)")
    bad = [j for j, p in enumerate(s.parents) if j > 0 and not 0 <= p < j]
    if bad:
        out.append(f"joints {bad} do not have an earlier joint as parent (joints must be in topological order)")
    if any(len(o) != 3 or not all(math.isfinite(v) for v in o) for o in s.rest_offsets_m):
        out.append("each rest offset must be 3 finite numbers")
    if len(s.foot_joints) != 4:
        out.append(f"foot_joints must name 4 joints, got {len(s.foot_joints)}")
    for field in ("foot_joints", "lower_body_joints"):
        if any(not 0 <= j < n for j in getattr(s, field)):
            out.append(f"{field} {list(getattr(s, field))} has joints outside 0..{n - 1}")
    return out


# --- SMPL, 24 joints --------------------------------------------------------------------------------------------
SMPL24 = Skeleton(
    name="smpl24",
    joint_names=(
        "pelvis",
        "left_hip",
        "right_hip",
        "spine1",
        "left_knee",
        "right_knee",
        "spine2",
        "left_ankle",
        "right_ankle",
        "spine3",
        "left_foot",
        "right_foot",
        "neck",
        "left_collar",
        "right_collar",
        "head",
        "left_shoulder",
        "right_shoulder",
        "left_elbow",
        "right_elbow",
        "left_wrist",
        "right_wrist",
        "left_hand",
        "right_hand",
    ),  # fmt: skip
    parents=(-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 20, 21),
    rest_offsets_m=(
        (0.0, 0.0, 0.0),
        (0.05858135, -0.08228004, -0.01766408),
        (-0.06030973, -0.09051332, -0.01354254),
        (0.00443945, 0.12440352, -0.03838522),
        (0.04345142, -0.38646945, 0.008037),
        (-0.04325663, -0.38368791, -0.00484304),
        (0.00448844, 0.1379564, 0.02682033),
        (-0.01479032, -0.42687458, -0.037428),
        (0.01905555, -0.4200455, -0.03456167),
        (-0.00226458, 0.05603239, 0.00285505),
        (0.04105436, -0.06028581, 0.12204243),
        (-0.03483987, -0.06210566, 0.13032329),
        (-0.0133902, 0.21163553, -0.03346758),
        (0.07170245, 0.11399969, -0.01889817),
        (-0.08295366, 0.11247234, -0.02370739),
        (0.01011321, 0.08893734, 0.05040987),
        (0.12292141, 0.04520509, -0.019046),
        (-0.11322832, 0.04685326, -0.00847207),
        (0.2553319, -0.01564902, -0.02294649),
        (-0.26012748, -0.01436928, -0.03126873),
        (0.26570925, 0.01269811, -0.00737473),
        (-0.26910836, 0.00679372, -0.00602676),
        (0.08669055, -0.01063603, -0.01559429),
        (-0.0887537, -0.00865157, -0.01010708),
    ),
    foot_joints=(7, 8, 10, 11),
    lower_body_joints=(0, 1, 2, 4, 5, 7, 8, 10, 11),
)

# The SMPL skeleton's fields under the names the project used before skeletons were data.
JOINT_NAMES = SMPL24.joint_names
NUM_JOINTS = SMPL24.num_joints
PARENTS = SMPL24.parents
REST_OFFSETS_M = SMPL24.rest_offsets_m
FOOT_JOINTS = SMPL24.foot_joints
LOWER_BODY_JOINTS = SMPL24.lower_body_joints
UPPER_BODY_JOINTS = SMPL24.upper_body_joints
rest_offsets = SMPL24.rest_offsets
joint_index = SMPL24.joint_index

# --- SMPL-X -------------------------------------------------------------------------------------------------------
_FINGERS = ("index", "middle", "pinky", "ring", "thumb")
_HAND = tuple(f"{finger}{k}" for finger in _FINGERS for k in (1, 2, 3))
SMPLX52_JOINT_NAMES: tuple[str, ...] = (
    SMPL24.joint_names[:22] + tuple(f"left_{h}" for h in _HAND) + tuple(f"right_{h}" for h in _HAND)
)
# each finger is a chain of three from its wrist (20 left, 21 right)
SMPLX52_PARENTS: tuple[int, ...] = SMPL24.parents[:22] + tuple(
    wrist if k == 0 else 22 + 15 * side + 3 * f + k - 1
    for side, wrist in ((0, 20), (1, 21))
    for f in range(5)
    for k in range(3)
)
# SMPL-X's 55 joints: the 52 above with jaw (parent head) and the two eyes (parent head) after the body.
_SMPLX55_PARENTS: tuple[int, ...] = (
    SMPL24.parents[:22] + (15, 15, 15) + tuple(p if p < 22 else p + 3 for p in SMPLX52_PARENTS[22:])
)
_SMPLX55_DROPPED = (22, 23, 24)  # jaw, left eye, right eye
SMPLX_KINDS = {"body22": 22, "full52": 52}


def smplx_skeleton(kind: str, joints_file: str | Path | None, *, option: str = "skeleton.smplx_file") -> Skeleton:
    """SMPL-X's body (``kind="body22"``) or body-and-hands (``"full52"``) skeleton with the rest offsets of
    ``joints_file``: the SMPL-X model file (``SMPLX_NEUTRAL.npz``, joints = ``J_regressor @ v_template``, parents
    from ``kintree_table``) or an .npy/.npz holding rest joint positions (55, 3) in SMPL-X's order or (52, 3) in
    the order of :data:`SMPLX52_JOINT_NAMES`. ``option`` names the setting that gives the path, for messages."""
    if kind not in SMPLX_KINDS:
        raise ConfigError(f"unknown SMPL-X skeleton {kind!r}; choose one of {', '.join(SMPLX_KINDS)}")
    joints = _smplx_rest_joints(joints_file, option)  # (52, 3), y-up metres
    n = SMPLX_KINDS[kind]
    parents = SMPLX52_PARENTS[:n]
    offsets = [(0.0, 0.0, 0.0)] + [tuple(float(v) for v in joints[j] - joints[parents[j]]) for j in range(1, n)]
    return Skeleton(
        name="smplx22" if n == 22 else "smplx52",
        joint_names=SMPLX52_JOINT_NAMES[:n],
        parents=parents,
        rest_offsets_m=tuple(offsets),  # type: ignore[arg-type]
        foot_joints=SMPL24.foot_joints,
        lower_body_joints=SMPL24.lower_body_joints,
    )


def _smplx_rest_joints(path: str | Path | None, option: str) -> np.ndarray:
    """Rest joint positions (52, 3) float64 from an SMPL-X model file or joints file (see smplx_skeleton)."""
    where = (
        f"Download the SMPL-X model (SMPLX_NEUTRAL.npz, free registration, its licence forbids redistribution) from "
        f"{SMPLX_URL} and give its path with {option}=/path/to/SMPLX_NEUTRAL.npz (or a .npy/.npz of its rest joint "
        "positions, (55, 3) or (52, 3))"
    )
    if path is None or str(path).strip() in ("", "None", "null"):
        raise ConfigError(f"the SMPL-X skeleton needs the SMPL-X model file, and {option} is not set. {where}")
    p = Path(path).expanduser()
    if not p.is_file():
        raise DataError(f"SMPL-X model file {p} ({option}) does not exist. {where}")
    if p.suffix.lower() not in (".npz", ".npy"):
        raise DataError(
            f"SMPL-X model file {p} ({option}) is not an .npz or .npy (pickled model files are not read). {where}"
        )
    try:
        if p.suffix.lower() == ".npy":
            arrays = {"arr_0": np.load(p, allow_pickle=False)}
        else:
            with np.load(p, allow_pickle=False) as loaded:
                arrays = {k: np.asarray(loaded[k]) for k in loaded.files}
    except Exception as e:  # noqa: BLE001 - any unreadable file is one user error
        raise DataError(f"cannot read SMPL-X file {p} ({option}): {e}. {where}") from e
    if "v_template" in arrays and "J_regressor" in arrays:
        verts, reg = arrays["v_template"].astype(np.float64), arrays["J_regressor"].astype(np.float64)
        if verts.ndim != 2 or verts.shape[1] != 3 or reg.ndim != 2 or reg.shape != (55, verts.shape[0]):
            raise DataError(
                f"SMPL-X model file {p}: J_regressor {reg.shape} and v_template {verts.shape} are not SMPL-X's "
                f"(55, V) and (V, 3). {where}"
            )
        if "kintree_table" in arrays:
            kintree = arrays["kintree_table"]
            parents = tuple(-1 if j == 0 else int(kintree[0, j]) for j in range(kintree.shape[1]))
            if kintree.shape != (2, 55) or parents != _SMPLX55_PARENTS:
                raise DataError(f"SMPL-X model file {p}: its kintree_table is not SMPL-X's 55-joint tree. {where}")
        joints = reg @ verts
    else:
        candidates = [a for k, a in arrays.items() if k in ("joints", "arr_0")] or list(arrays.values())
        if len(candidates) != 1:
            raise DataError(
                f"SMPL-X file {p} holds {sorted(arrays)}; expected the SMPL-X model (v_template, J_regressor, "
                f"kintree_table) or one array of rest joint positions (key 'joints'). {where}"
            )
        joints = candidates[0]
    if joints.ndim != 2 or joints.shape not in ((55, 3), (52, 3)) or not np.issubdtype(joints.dtype, np.number):
        raise DataError(f"SMPL-X joints in {p} have shape {joints.shape}; expected (55, 3) or (52, 3). {where}")
    joints = joints.astype(np.float64)
    if not np.isfinite(joints).all():
        raise DataError(f"SMPL-X joints in {p} are not all finite. {where}")
    if joints.shape[0] == 55:
        joints = np.delete(joints, _SMPLX55_DROPPED, axis=0)
    return joints


# SMPL-24 joints a skeleton without them stands in for, in order of preference
SMPL_STAND_INS = {"left_hand": ("left_middle1", "left_wrist"), "right_hand": ("right_middle1", "right_wrist")}


def smpl24_layout(skeleton: Skeleton) -> list[int]:
    """For each of SMPL's 24 joints, the index of the same joint in ``skeleton``: joints (..., J, 3) indexed with it
    are in SMPL's layout (..., 24, 3), for measures defined on SMPL's joints (the metrics, beat sync's speed).
    SMPL-X's 22 body joints are SMPL's first 22; SMPL's hand joints (22, 23) are the middle fingers' first joints
    where the skeleton has fingers, else the wrists."""
    names = skeleton.joint_names
    out = []
    for name in SMPL24.joint_names:
        found = [c for c in (name, *SMPL_STAND_INS.get(name, ())) if c in names]
        if not found:
            raise ValueError(f"skeleton {skeleton.name} has no joint {name!r} (nor a stand-in for it)")
        out.append(names.index(found[0]))
    return out


def skeleton_from_config(
    name: str, smplx_file: str | Path | None = None, *, option: str = "skeleton.smplx_file"
) -> Skeleton:
    """The skeleton a config names (one of :data:`SKELETON_NAMES`); SMPL-X ones read ``smplx_file``."""
    if name == "smpl24":
        return SMPL24
    if name == "smplx22":
        return smplx_skeleton("body22", smplx_file, option=option)
    if name == "smplx52":
        return smplx_skeleton("full52", smplx_file, option=option)
    raise ConfigError(f"unknown skeleton {name!r}; choose one of {', '.join(SKELETON_NAMES)}")
