"""Geometric ("manual") features (32-d per sequence): fractions of frames on which 32 boolean
relations between joints hold (Mueller et al. style), the features behind FID_g and Div_g.

Each relation is evaluated on frames 1..T-1 against the previous frame, vectorised over sequences and
frames. Degenerate geometry (a zero-length direction or plane normal) gives NaN intermediate values
and therefore "false", exactly as in the reference.
"""

from __future__ import annotations

import numpy as np

from dgsdp.metrics._common import check_feature_args, check_joints, stack_by_length, to_y_up

GEOMETRIC_DIM = 32

JOINT_INDEX = {
    name: i
    for i, name in enumerate(
        [
            "root", "lhip", "rhip", "belly", "lknee", "rknee", "spine", "lankle", "rankle", "chest",
            "ltoes", "rtoes", "neck", "linshoulder", "rinshoulder", "head", "lshoulder", "rshoulder",
            "lelbow", "relbow", "lwrist", "rwrist", "lhand", "rhand",
        ]
    )
}  # fmt: skip

# Body constants (metres): distances between SMPL rest-pose joints, full precision of the reference's
# values (0.256838, 0.390848, 0.119247 rounded).
HUMERUS_LENGTH = 0.2568381092115207  # left shoulder - left elbow
SHOULDER_WIDTH = 0.39084835854945527  # left shoulder - right shoulder
HIP_WIDTH = 0.11924706586886204  # left hip - right hip

PAPER_VELOCITY_SCALE = 120.0  # the reference divides one-frame displacements by 1/120 s at any fps

# (primitive, joint or virtual-point names, threshold in metres (or m/s), angle range in degrees)
_HL, _SW, _HW = HUMERUS_LENGTH, SHOULDER_WIDTH, HIP_WIDTH
FEATURE_SPECS: list[tuple[str, tuple[str, ...], float | tuple[float, float]]] = [
    ("nmove", ("neck", "rhip", "lhip", "rwrist"), 1.8 * _HL),  # 1
    ("nmove", ("neck", "lhip", "rhip", "lwrist"), 1.8 * _HL),  # 2
    ("nplane", ("chest", "neck", "neck", "rwrist"), 0.2 * _HL),  # 3
    ("nplane", ("chest", "neck", "neck", "lwrist"), 0.2 * _HL),  # 4
    ("move", ("belly", "chest", "chest", "rwrist"), 1.8 * _HL),  # 5
    ("move", ("belly", "chest", "chest", "lwrist"), 1.8 * _HL),  # 6
    ("angle", ("relbow", "rshoulder", "relbow", "rwrist"), (0.0, 110.0)),  # 7
    ("angle", ("lelbow", "lshoulder", "lelbow", "lwrist"), (0.0, 110.0)),  # 8
    ("nplane", ("lshoulder", "rshoulder", "lwrist", "rwrist"), 2.5 * _SW),  # 9
    ("move", ("lwrist", "rwrist", "rwrist", "lwrist"), 1.4 * _HL),  # 10
    ("move", ("rwrist", "root", "lwrist", "root"), 1.4 * _HL),  # 11
    ("move", ("lwrist", "root", "rwrist", "root"), 1.4 * _HL),  # 12
    ("fast", ("rwrist",), 2.5 * _HL),  # 13
    ("fast", ("lwrist",), 2.5 * _HL),  # 14
    ("plane", ("root", "lhip", "ltoes", "rankle"), 0.38 * _HL),  # 15
    ("plane", ("root", "rhip", "rtoes", "lankle"), 0.38 * _HL),  # 16
    ("nplane", ("zero", "y_unit", "y_min", "rankle"), 1.2 * _HL),  # 17
    ("nplane", ("zero", "y_unit", "y_min", "lankle"), 1.2 * _HL),  # 18
    ("nplane", ("lhip", "rhip", "lankle", "rankle"), 2.1 * _HW),  # 19
    ("angle", ("rknee", "rhip", "rknee", "rankle"), (0.0, 110.0)),  # 20
    ("angle", ("lknee", "lhip", "lknee", "lankle"), (0.0, 110.0)),  # 21
    ("fast", ("rankle",), 2.5 * _HL),  # 22
    ("fast", ("lankle",), 2.5 * _HL),  # 23
    ("angle", ("neck", "root", "rshoulder", "relbow"), (25.0, 180.0)),  # 24
    ("angle", ("neck", "root", "lshoulder", "lelbow"), (25.0, 180.0)),  # 25
    ("angle", ("neck", "root", "rhip", "rknee"), (50.0, 180.0)),  # 26
    ("angle", ("neck", "root", "lhip", "lknee"), (50.0, 180.0)),  # 27
    ("plane", ("rankle", "neck", "lankle", "root"), 0.5 * _HL),  # 28
    ("angle", ("neck", "root", "zero", "y_unit"), (70.0, 110.0)),  # 29
    ("nplane", ("zero", "minus_y_unit", "y_min", "rwrist"), -1.2 * _HL),  # 30
    ("nplane", ("zero", "minus_y_unit", "y_min", "lwrist"), -1.2 * _HL),  # 31
    ("fast", ("root",), 2.3 * _HL),  # 32
]


def _unit(vectors: np.ndarray) -> np.ndarray:
    """Normalise (..., 3) vectors; zero vectors become NaN so every comparison on them is false."""
    return vectors / np.linalg.norm(vectors, axis=-1, keepdims=True)


class _Frames:
    """Joint and virtual-point positions of the current frames (1..T-1) and their previous frames.

    positions: (B, T, 24, 3) y-up metres.
    """

    def __init__(self, positions: np.ndarray) -> None:
        self.current = positions[:, 1:]  # (B, T-1, 24, 3)
        self.previous = positions[:, :-1]
        shape = self.current.shape[:2] + (3,)
        y_min = np.zeros(shape)
        y_min[..., 1] = self.current[..., 1].min(axis=-1)
        self.virtual = {
            "zero": np.zeros(shape),
            "y_unit": np.broadcast_to(np.array([0.0, 1.0, 0.0]), shape),
            "minus_y_unit": np.broadcast_to(np.array([0.0, -1.0, 0.0]), shape),
            "y_min": y_min,
        }

    def now(self, name: str) -> np.ndarray:
        """(B, T-1, 3) position of a joint or virtual point on the current frames."""
        if name in self.virtual:
            return self.virtual[name]
        return self.current[:, :, JOINT_INDEX[name]]

    def before(self, name: str) -> np.ndarray:
        """(B, T-1, 3) position of a joint on the previous frames."""
        return self.previous[:, :, JOINT_INDEX[name]]

    def relative_velocity(self, moving: str, origin: str, velocity_scale: float) -> np.ndarray:
        """(B, T-1, 3) one-frame velocity of ``moving`` relative to ``origin``, times ``velocity_scale``."""
        now = self.now(moving) - self.now(origin)
        before = self.before(moving) - self.before(origin)
        return (now - before) * velocity_scale


def _evaluate(
    frames: _Frames,
    kind: str,
    names: tuple[str, ...],
    param: float | tuple[float, float],
    mode: str,
    velocity_scale: float,
) -> np.ndarray:
    """One boolean relation on every current frame: (B, T-1) bool."""
    p = [frames.now(n) for n in names]
    if kind == "plane":
        a, b, c, point = p
        normal = _unit(np.cross(c - a, b - a))
        return np.einsum("...i,...i->...", point - a, normal) > param
    if kind == "nplane":
        n1, n2, a, point = p
        return np.einsum("...i,...i->...", point - a, _unit(n2 - n1)) > param
    if kind == "angle":
        j1, j2, k1, k2 = p
        cosine = np.einsum("...i,...i->...", _unit(j2 - j1), _unit(k2 - k1))
        angle_deg = np.degrees(np.arccos(cosine))
        low, high = param
        return (angle_deg > low) & (angle_deg < high)
    if kind == "move":
        j1, j2, _, _ = p
        # paper: the reference measures j3 relative to j1 and never reads j4;
        # corrected: j4 relative to j3 along j1 -> j2, so every named joint counts (our reading of
        # Mueller et al.'s relation; it makes features 5 and 6 follow the right and left wrist).
        moving, origin = (names[2], names[0]) if mode == "paper" else (names[3], names[2])
        velocity = frames.relative_velocity(moving, origin, velocity_scale)
        return np.einsum("...i,...i->...", velocity, _unit(j2 - j1)) > param
    if kind == "nmove":
        j1, j2, j3, _ = p
        direction = _unit(np.cross(j3 - j1, j2 - j1))
        velocity = frames.relative_velocity(names[3], names[0], velocity_scale)
        return np.einsum("...i,...i->...", velocity, direction) > param
    if kind == "fast":
        (name,) = names
        speed = np.linalg.norm(frames.now(name) - frames.before(name), axis=-1) * velocity_scale
        return speed > param
    raise AssertionError(f"unknown primitive {kind}")


def _geometric_core(positions: np.ndarray, fps: float, mode: str) -> np.ndarray:
    """Geometric features of equal-length y-up motions: (B, T, 24, 3) metres -> (B, 32)."""
    frames = _Frames(positions)
    velocity_scale = PAPER_VELOCITY_SCALE if mode == "paper" else float(fps)
    with np.errstate(invalid="ignore", divide="ignore"):
        flags = [_evaluate(frames, kind, names, param, mode, velocity_scale) for kind, names, param in FEATURE_SPECS]
    return np.stack(flags, axis=-1).mean(axis=1)  # (B, 32): fraction of frames 1..T-1


def geometric_features(joints: np.ndarray, fps: float = 60, up_axis: str = "y", mode: str = "paper") -> np.ndarray:
    """32 geometric features of one motion: the fraction of frames 1..T-1 on which each relation holds.

    joints: (T, 24, 3) positions in metres (SMPL joint order), T >= 2; ``up_axis="z"`` input is rotated
    to y-up first. The relations and thresholds are those of the reference (see FEATURE_SPECS).

    Modes:
      - ``"paper"`` (default) reproduces the reference: velocities are one-frame displacements times 120
        whatever ``fps`` is, and ``move(j1, j2, j3, j4)`` measures j3 relative to j1 and ignores j4,
        which makes feature 6 identical to feature 5 and changes features 10-12.
      - ``"corrected"``: velocities are displacements times ``fps`` (true m/s), and ``move`` measures
        j4 relative to j3 along the direction j1 -> j2.

    Returns (32,) float64 in [0, 1].
    """
    check_feature_args(fps, up_axis, mode)
    positions = to_y_up(check_joints(joints, min_frames=2), up_axis)
    return _geometric_core(positions[None], fps, mode)[0]


def geometric_features_batch(
    joints_list: list[np.ndarray] | np.ndarray, fps: float = 60, up_axis: str = "y", mode: str = "paper"
) -> np.ndarray:
    """:func:`geometric_features` of N motions (lengths may differ): list of (T_n, 24, 3) -> (N, 32)."""
    check_feature_args(fps, up_axis, mode)
    groups = stack_by_length(joints_list, min_frames=2)
    out = np.empty((sum(len(idx) for idx, _ in groups), GEOMETRIC_DIM))
    for idx, stacked in groups:
        out[idx] = _geometric_core(to_y_up(stacked, up_axis), fps, mode)
    return out
