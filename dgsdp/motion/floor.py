"""Feet on the floor: the floor height of a dataset, and a contact-aware cleanup of generated motion.

Floor height. Motion is z-up metres; the floor is the height of the lowest foot joint (the skeleton's foot joints,
SMPL's 7, 8, 10, 11: ankles and toes) when a foot stands on the ground. :func:`measure_floor_height` takes the median
over all frames of the lowest foot joint's height: dancers have a foot on the floor in most frames, so jumps and lifts
do not move it. The synthetic dataset gives 0.0 (its lowest foot joint touches z = 0 on every frame); real AIST++ has
its floor elsewhere. Joints lie inside the body, so the floor by this measure is a few centimetres above the sole.

Cleanup (:func:`clean_motion`), from the model's own predicted foot contacts (channels 0-3, > 0.5 = contact):

0. Turn-rate limit: the body's facing (the root joint's rotation) turns at most ``max_turn_rate`` radians per
   second (15, about 2.4 full turns a second; the synthetic training dances' fastest turn is 13.1, their 99.9th
   percentile 10.3). A weak model that cannot decide which way the dancer faces flips the whole body in one
   frame (40-90 rad/s), which throws the hands at 10-20 m/s; limited, the flip becomes a quick turn. Each
   frame's root rotation moves towards the model's by at most the limit (the rest is made up on the next
   frames). Frames whose root rotation is given keep it.
   Before it, the body's up axis (the root's local y) tilts at most ``max_tilt_rate`` radians per second (6; the
   synthetic dances' fastest tilt is 2.7): a model that loses the body's orientation tumbles it over instead. While
   the tilt is limited the facing is carried over from the previous frame.
1. Foot locking: a foot (its ankle or toe predicted in contact, and down: within ``plant_height_m`` of its
   standing height once the body is on the floor) stays where it was planted. Over each run of such frames the
   joint is held at its mean horizontal position (over ``lock_window_seconds`` around each frame, so a short plant
   is held still and a model that predicts contacts all the time keeps its slow footwork); the ankle is moved
   horizontally by the difference with a two-bone IK of hip and knee (the knee bends about its own hinge axis,
   the ankle keeps its orientation so the toe moves with it), blended in and out over ``lock_blend_seconds``.
   The toe is held wherever it touches, the ankle where only it does.
2. Vertical root correction: where a contact is predicted, the lowest contact foot joint is put on the floor;
   a run of frames without any contact no longer than ``max_air_seconds`` is a jump and keeps its own height (the
   offset is interpolated between the frames around it); a longer run cannot be a jump and is brought down (its
   lowest foot joint on the floor). The offset curve is smoothed over time (a Gaussian of ``smooth_seconds``), then
   raised smoothly wherever a joint would still be below the floor, and finally clamped so that no joint of any
   frame is below the floor.

The bound of 0.5 s: a jump's flight time t and the rise h of the body's centre satisfy h = g t^2 / 8, so 0.5 s of
flight means rising 0.31 m, already a high dance jump; a body that stays up longer without any foot contact is
floating, not jumping.

Given channels (editing masks) are never changed: frames whose root height is given get no vertical correction
(blended in over ``given_blend_seconds`` away from them), frames where a leg's channels are given get no IK on that
leg, and every given channel of the result is copied from the input exactly. The contact channels are kept as
predicted.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch
from scipy.ndimage import distance_transform_edt, gaussian_filter1d, maximum_filter1d

from dgsdp.motion.fk import forward_kinematics
from dgsdp.motion.representation import ROTATION_CHANNELS, check_pose_dim, unpack_pose
from dgsdp.motion.rotation import axis_angle_to_matrix, matrix_to_6d, matrix_to_axis_angle
from dgsdp.motion.skeleton import SMPL24, Skeleton

Leg = tuple[tuple[int, int, int, int], tuple[int, int]]


def legs(skeleton: Skeleton = SMPL24) -> tuple[Leg, Leg]:
    """Each side's (hip, knee, ankle, toe) joints and its contact channels (ankle, toe): the ankle and toe are the
    skeleton's foot joints, the knee the ankle's parent, the hip the knee's (SMPL: (1, 4, 7, 10), (2, 5, 8, 11))."""
    out = []
    for side in (0, 1):
        ankle, toe = skeleton.foot_joints[side], skeleton.foot_joints[2 + side]
        knee = skeleton.parents[ankle]
        hip = skeleton.parents[knee] if knee >= 0 else -1
        if skeleton.parents[toe] != ankle or hip <= 0:
            raise ValueError(
                f"skeleton {skeleton.name}: foot joints {skeleton.foot_joints} are not ankle-toe pairs of legs"
            )
        out.append(((hip, knee, ankle, toe), (side, 2 + side)))
    return out[0], out[1]


LEGS = legs(SMPL24)
ROOT_Z_CHANNEL = 6
_ROOT_ROTATION = slice(ROTATION_CHANNELS.start, ROTATION_CHANNELS.start + 6)
BODY_UP_AXIS = 1  # the root's local y (SMPL's up) is the body's up axis: its world direction is z when standing
# Passes of the vertical offset's smoother: each adds back the smoothed residual (1 - (1 - G)^(n + 1) overall).
REFINE_STEPS = 2


@dataclass(frozen=True)
class FloorCleanup:
    """Settings of :func:`clean_motion` (see the module docstring)."""

    contact_threshold: float = 0.5  # a contact channel above this is a predicted contact
    max_air_seconds: float | None = 0.5  # longest run without contacts kept as a jump; None: any (no limit)
    smooth_seconds: float = 0.1  # Gaussian sigma of the vertical offset curve
    lock_feet: bool = True  # foot locking (two-bone leg IK); False: vertical correction only
    lock_blend_seconds: float = 0.1  # a lock fades in before and out after its contact run over this time
    lock_window_seconds: float = 2.0  # a foot is held at its mean position over this window of its contact run
    plant_height_m: float = 0.05  # a contact joint higher than this above its standing height is not planted
    max_lock_m: float = 0.3  # a lock moves a foot at most this far (a longer slide is not a planted foot)
    given_blend_seconds: float = 0.2  # corrections fade out towards given (masked) frames over this time
    floor_tolerance_m: float = 0.0  # joints may end at most this far below the floor
    max_turn_rate: float | None = 15.0  # radians per second of the root rotation (2.4 turns); None: off
    max_tilt_rate: float | None = 6.0  # radians per second the body's up axis tilts (a tumble); None: off

    def __post_init__(self) -> None:
        if not 0.0 <= self.contact_threshold <= 1.0:
            raise ValueError(f"contact_threshold must lie in [0, 1], got {self.contact_threshold}")
        names = ("max_air_seconds", "smooth_seconds", "lock_blend_seconds", "lock_window_seconds", "plant_height_m")
        for name in (*names, "max_lock_m", "given_blend_seconds"):
            value = getattr(self, name)
            if name == "max_air_seconds" and value is None:
                continue
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be a finite number >= 0, got {value}")
        if not (math.isfinite(self.floor_tolerance_m) and self.floor_tolerance_m >= 0):
            raise ValueError(f"floor_tolerance_m must be a finite number >= 0, got {self.floor_tolerance_m}")
        for name in ("max_turn_rate", "max_tilt_rate"):
            value = getattr(self, name)
            if value is not None and not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive number of radians per second or None, got {value}")


def lowest_foot_height(joints: torch.Tensor, skeleton: Skeleton = SMPL24) -> torch.Tensor:
    """Height (z) of the lowest foot joint (SMPL: 7, 8, 10, 11) per frame: joints (..., J, 3) -> (...)."""
    return joints[..., list(skeleton.foot_joints), 2].amin(dim=-1)


def measure_floor_height(
    motions: torch.Tensor | np.ndarray | list, chunk_frames: int = 65536, skeleton: Skeleton = SMPL24
) -> float:
    """The floor height (z-up metres) of unnormalised motions (..., D) or a list of (T, D), D the skeleton's pose
    size: the median over all frames of the lowest foot joint's height (FK in chunks, so a whole dataset fits in
    memory)."""
    dim = skeleton.pose_dim
    if isinstance(motions, list | tuple):
        parts = [torch.as_tensor(np.asarray(m)).reshape(-1, dim) for m in motions]
        flat = torch.cat(parts) if parts else torch.zeros(0, dim)
    else:
        flat = torch.as_tensor(motions).reshape(-1, dim)
    if len(flat) == 0:
        raise ValueError("cannot measure the floor height of an empty set of motions")
    heights = [
        lowest_foot_height(unpack_pose(flat[i : i + chunk_frames].double(), skeleton).joints(), skeleton)
        for i in range(0, len(flat), chunk_frames)
    ]
    value = float(torch.cat(heights).median())
    if not math.isfinite(value):
        raise ValueError("the motions hold non-finite values: cannot measure their floor height")
    return value


# --- small 1-D helpers ----------------------------------------------------------------------------------------
def _runs(flags: np.ndarray) -> list[tuple[int, int]]:
    """[start, end) of every run of True in a 1-D boolean array."""
    padded = np.concatenate(([False], flags.astype(bool), [False]))
    edges = np.flatnonzero(padded[1:] != padded[:-1])
    return list(zip(edges[0::2].tolist(), edges[1::2].tolist()))


def _clean_contacts(contacts: np.ndarray) -> np.ndarray:
    """(T, C) booleans without one-frame gaps and one-frame runs (flicker of a model's predictions)."""
    out = contacts.copy()
    if len(out) >= 3:
        gap = ~out[1:-1] & out[:-2] & out[2:]
        out[1:-1] |= gap
    for c in range(out.shape[1]):
        for a, b in _runs(out[:, c]):
            if b - a < 2:
                out[a:b, c] = False
    return out


def _smoothstep(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3 - 2 * x)


def _free_weight(blocked: np.ndarray, ramp_frames: int) -> np.ndarray:
    """(T,) weight: 0 on blocked frames, rising smoothly to 1 at ``ramp_frames`` + 1 frames away from them."""
    if not blocked.any():
        return np.ones(len(blocked))
    if blocked.all():
        return np.zeros(len(blocked))
    dist = distance_transform_edt(~blocked)
    return _smoothstep(dist / (ramp_frames + 1)) if ramp_frames > 0 else (dist > 0).astype(float)


def _smooth(x: np.ndarray, sigma_frames: float) -> np.ndarray:
    return gaussian_filter1d(x, sigma_frames, mode="nearest") if sigma_frames > 0 else x.copy()


def _max_air_frames(s: FloorCleanup, fps: float, n_frames: int) -> int:
    """The longest run of frames without contact kept as a jump (all of them without the limit)."""
    return n_frames if s.max_air_seconds is None else int(math.floor(s.max_air_seconds * fps))


# --- vertical root correction ---------------------------------------------------------------------------------
def _vertical_offset(
    joints_z: np.ndarray, contacts: np.ndarray, floor: float, fps: float, s: FloorCleanup, skeleton: Skeleton
) -> np.ndarray:
    """The root height offset (T,) for joints' heights (T, J) and cleaned contacts (T, 4)."""
    n = len(joints_z)
    z = joints_z - floor
    need = -z.min(axis=1)  # the least offset that keeps every joint on or above the floor
    feet = z[:, list(skeleton.foot_joints)]
    grounded = np.maximum(-feet.min(axis=1), need)  # lowest foot joint on the floor
    any_contact = contacts.any(axis=1)
    lowest_contact = np.where(contacts, feet, np.inf).min(axis=1)
    target = np.where(any_contact, np.maximum(-lowest_contact, need), np.nan)
    max_air = _max_air_frames(s, fps, n)
    for a, b in _runs(~any_contact):
        before = target[a - 1] if a > 0 else None
        after = target[b] if b < n else None
        if b - a > max_air or (before is None and after is None):
            target[a:b] = grounded[a:b]  # floating, not jumping: down to the floor
        elif before is None or after is None:
            target[a:b] = before if after is None else after
        else:  # a jump keeps its own trajectory above the shift of the frames around it
            w = (np.arange(a, b) - (a - 1)) / (b - a + 1)
            target[a:b] = (1 - w) * before + w * after
    sigma = s.smooth_seconds * fps
    offset = _smooth(target, sigma)
    for _ in range(REFINE_STEPS):  # follow the target's slow changes closely while still rounding off its steps
        offset = offset + _smooth(target - offset, sigma)
    # Raise the curve smoothly where a joint is still below the floor, then clamp what little is left.
    width = 2 * int(math.ceil(2 * sigma)) + 1
    for _ in range(6):
        deficit = np.maximum(need - s.floor_tolerance_m - offset, 0.0)
        if deficit.max(initial=0.0) < 1e-4:
            break
        offset = offset + _smooth(maximum_filter1d(deficit, width, mode="nearest"), sigma)
    return np.maximum(offset, need - s.floor_tolerance_m)


# --- foot locking ---------------------------------------------------------------------------------------------
def _rotation(axis: torch.Tensor, angle: torch.Tensor) -> torch.Tensor:
    """(N, 3, 3) rotations by ``angle`` (N,) about unit ``axis`` (N, 3)."""
    return axis_angle_to_matrix(axis * angle[:, None])


def _swing(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """(N, 3, 3) the smallest rotations taking directions a (N, 3) to b (N, 3)."""
    a = a / a.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    b = b / b.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    cross = torch.linalg.cross(a, b, dim=-1)
    sin = cross.norm(dim=-1)
    angle = torch.atan2(sin, (a * b).sum(-1))
    axis = torch.where(sin[:, None] > 1e-12, cross / sin.clamp_min(1e-12)[:, None], torch.zeros_like(cross))
    return _rotation(axis, angle)


def leg_ik(
    g_pelvis: torch.Tensor,
    g_hip: torch.Tensor,
    g_knee: torch.Tensor,
    g_ankle: torch.Tensor,
    hip: torch.Tensor,
    knee: torch.Tensor,
    ankle: torch.Tensor,
    target: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Two-bone IK: new local hip, knee and ankle rotations (N, 3, 3) that move the ankle to ``target`` (N, 3).

    Inputs are global rotations (N, 3, 3) of the pelvis, hip, knee and ankle and positions (N, 3) of hip, knee and
    ankle. The knee turns about its own hinge (x) axis by the smallest angle that gives the hip-ankle distance of
    the target (the leg straightens towards an unreachable target), the hip then swings the leg onto the target,
    and the ankle keeps its global orientation."""
    thigh, shin = knee - hip, ankle - knee
    axis = g_knee[..., :, 0]  # the knee's hinge: its x axis in the world
    shin_par = (shin * axis).sum(-1, keepdim=True) * axis
    shin_perp = shin - shin_par
    # |thigh + shin(phi)|^2 = l1^2 + l2^2 + 2 (p + q cos phi + r sin phi) for the shin turned by phi about the axis
    p = (thigh * shin_par).sum(-1)
    q = (thigh * shin_perp).sum(-1)
    r = (thigh * torch.linalg.cross(axis, shin_perp, dim=-1)).sum(-1)
    m = torch.hypot(q, r).clamp_min(1e-9)
    phi0 = torch.atan2(r, q)
    base = thigh.pow(2).sum(-1) + shin.pow(2).sum(-1)
    dist2 = (target - hip).pow(2).sum(-1)
    cos = ((dist2 - base) / 2 - p) / m
    delta = torch.acos(cos.clamp(-0.9999, 0.9999))
    options = torch.stack((phi0 + delta, phi0 - delta))
    wrapped = torch.remainder(options + math.pi, 2 * math.pi) - math.pi
    phi = torch.where(wrapped[0].abs() <= wrapped[1].abs(), wrapped[0], wrapped[1])  # the smallest change
    bend = _rotation(axis, phi)
    new_ankle = knee + (bend @ shin.unsqueeze(-1)).squeeze(-1)
    swing = _swing(new_ankle - hip, target - hip)
    g_hip_new = swing @ g_hip
    g_knee_new = swing @ bend @ g_knee
    return (
        g_pelvis.transpose(-1, -2) @ g_hip_new,
        g_hip_new.transpose(-1, -2) @ g_knee_new,
        g_knee_new.transpose(-1, -2) @ g_ankle,
    )


def _joint_lock(
    xy: np.ndarray, contact: np.ndarray, blend: int, half_window: int, max_lock_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """Horizontal shift (T, 2) that holds one joint (positions ``xy`` (T, 2)) where it is planted over each of its
    contact runs (``contact`` (T,)), and the weight (T,) of that shift: 1 in a run, fading out over ``blend`` frames
    before and after it. The hold is the joint's mean position over the run's frames within ``half_window`` frames:
    a run up to ``half_window`` + 1 frames long is held still at its mean; a longer one creeps with its own slow
    travel (a model that predicts contacts all the time keeps its footwork)."""
    n = len(xy)
    shift = np.zeros((n, 2))
    weight = np.zeros(n)
    for a, b in _runs(contact):
        cum = np.concatenate((np.zeros((1, 2)), np.cumsum(xy[a:b], axis=0)))
        t = np.arange(b - a)
        lo, hi = np.maximum(t - half_window, 0), np.minimum(t + half_window + 1, b - a)
        seg = (cum[hi] - cum[lo]) / (hi - lo)[:, None] - xy[a:b]
        norm = np.linalg.norm(seg, axis=-1, keepdims=True)
        seg *= np.minimum(1.0, max_lock_m / np.maximum(norm, 1e-12))
        lo, hi = max(0, a - blend), min(n, b + blend)
        idx = np.arange(lo, hi)
        w = np.ones(len(idx))
        w[idx < a] = _smoothstep((idx[idx < a] - (a - blend - 1)) / (blend + 1))
        w[idx >= b] = _smoothstep(((b + blend) - idx[idx >= b]) / (blend + 1))
        values = seg[np.clip(idx - a, 0, b - a - 1)]
        better = w > weight[lo:hi]
        shift[lo:hi][better] = values[better]
        weight[lo:hi] = np.maximum(weight[lo:hi], w)
    return shift, weight


def _foot_shift(feet_xy: np.ndarray, contacts: np.ndarray, fps: float, s: FloorCleanup) -> np.ndarray:
    """The horizontal move (T, 2) of one foot's ankle that holds the foot where it is planted.

    feet_xy: (T, 2, 2) horizontal positions of the ankle and the toe; contacts: (T, 2) of ankle and toe. The toe
    is held wherever it touches (a foot turning or lifting its heel pivots about it); the ankle where only it
    touches. The foot moves rigidly, so holding either joint is a move of the ankle."""
    blend = max(1, int(round(s.lock_blend_seconds * fps)))
    half = int(round(s.lock_window_seconds * fps / 2))
    toe_shift, toe_w = _joint_lock(feet_xy[:, 1], contacts[:, 1], blend, half, s.max_lock_m)
    ankle_shift, ankle_w = _joint_lock(feet_xy[:, 0], contacts[:, 0], blend, half, s.max_lock_m)
    return toe_w[:, None] * toe_shift + ((1 - toe_w) * ankle_w)[:, None] * ankle_shift


def _lock_feet(
    rotmats: torch.Tensor,
    root: torch.Tensor,
    contacts: np.ndarray,
    fps: float,
    s: FloorCleanup,
    free: np.ndarray,
    skeleton: Skeleton,
) -> torch.Tensor:
    """Local rotations (T, J, 3, 3) with planted feet held in place (``free``: (T, 2) IK weight per leg)."""
    joints, globals_ = forward_kinematics(rotmats, root, return_global_rotmats=True, skeleton=skeleton)
    out = rotmats.clone()
    for side, ((hip, knee, ankle, toe), channels) in enumerate(legs(skeleton)):
        feet_xy = joints[:, [ankle, toe], :2].numpy()
        shift = _foot_shift(feet_xy, contacts[:, list(channels)], fps, s) * free[:, side, None]
        frames = np.flatnonzero(np.abs(shift).max(axis=1) > 1e-7)
        if len(frames) == 0:
            continue
        f = torch.from_numpy(frames)
        move = torch.zeros(len(frames), 3, dtype=joints.dtype)
        move[:, :2] = torch.from_numpy(shift[frames]).to(joints.dtype)
        g = globals_[f]
        j = joints[f]
        local = leg_ik(
            g[:, 0], g[:, hip], g[:, knee], g[:, ankle], j[:, hip], j[:, knee], j[:, ankle], j[:, ankle] + move
        )
        out[f, hip], out[f, knee], out[f, ankle] = local
    return out


# --- the cleanup ----------------------------------------------------------------------------------------------
def limit_turn_rate(rotations: torch.Tensor, max_step_rad: float, given: np.ndarray | None = None) -> torch.Tensor:
    """Rotations (T, 3, 3) -> the same sequence turning at most ``max_step_rad`` per frame: each frame turns from
    the previous result towards its own rotation, about the axis between them, by at most the limit. Frames
    ``given`` (T,) bool keep their rotation."""
    # the model's own turn between consecutive frames: while the result is not behind, a frame within the limit
    # is kept as it is without further work
    steps = matrix_to_axis_angle(rotations[:-1].transpose(-1, -2) @ rotations[1:])
    fast = (torch.linalg.vector_norm(steps, dim=-1) > max_step_rad).tolist()

    def catch_up(previous: torch.Tensor, target: torch.Tensor) -> torch.Tensor | None:
        rotvec = matrix_to_axis_angle(previous.transpose(0, 1) @ target)  # the turn still to make
        angle = float(torch.linalg.vector_norm(rotvec))
        return previous @ axis_angle_to_matrix(rotvec * (max_step_rad / angle)) if angle > max_step_rad else None

    return _rate_limited(rotations, fast, given, catch_up)


def _rate_limited(
    rotations: torch.Tensor,
    fast: list[bool],
    given: np.ndarray | None,
    catch_up: Callable[[torch.Tensor, torch.Tensor], torch.Tensor | None],
) -> torch.Tensor:
    """The pass shared by the turn and tilt limits over rotations (T, 3, 3): a frame the model moves within the limit
    (``fast[t - 1]`` False) is kept while the result is not behind; otherwise ``catch_up(previous result, model's
    rotation)`` gives the frame's limited rotation, or None when the model's is within reach. Frames ``given`` keep
    their rotation."""
    out = rotations.clone()
    behind = False
    for t in range(1, len(rotations)):
        if given is not None and given[t]:
            behind = False
            continue
        if not behind and not fast[t - 1]:
            continue
        limited = catch_up(out[t - 1], rotations[t])
        behind = limited is not None
        if behind:
            out[t] = limited
    return out


def _axis_rotation(a: torch.Tensor, b: torch.Tensor, angle: float) -> torch.Tensor:
    """The rotation (3, 3) by ``angle`` about the axis that turns unit vector ``a`` towards unit vector ``b`` along
    the shortest way. Opposite vectors turn about an axis perpendicular to ``a``."""
    axis = torch.linalg.cross(a, b)
    n = float(torch.linalg.vector_norm(axis))
    if n < 1e-12:
        if float(a @ b) > 0:
            return torch.eye(3, dtype=a.dtype)
        helper = torch.zeros_like(a)
        helper[int(torch.argmin(a.abs()))] = 1.0
        axis = torch.linalg.cross(a, helper)
        n = float(torch.linalg.vector_norm(axis))
    return axis_angle_to_matrix(axis * (angle / n))


def limit_tilt_rate(rotations: torch.Tensor, max_step_rad: float, given: np.ndarray | None = None) -> torch.Tensor:
    """Root rotations (T, 3, 3) -> the same sequence whose body up axis (the root's local y: world up when the body
    stands) tilts at most ``max_step_rad`` per frame: where the model's up axis runs ahead, the frame is the previous
    result tilted by the smallest rotation that moves its up axis towards the model's by the limit. A body tipping
    over faster than that is not a pose the model knows: its facing is not trusted either and is carried over from
    the previous frame (the turn-rate limit then catches up with the model's facing). Frames ``given`` (T,) bool
    keep their rotation."""
    up = rotations[:, :, BODY_UP_AXIS]
    fast = (torch.sum(up[:-1] * up[1:], dim=-1).clamp(-1.0, 1.0).arccos() > max_step_rad).tolist()

    def catch_up(previous: torch.Tensor, target: torch.Tensor) -> torch.Tensor | None:
        previous_up, target_up = previous[:, BODY_UP_AXIS], target[:, BODY_UP_AXIS]
        if float(torch.dot(previous_up, target_up).clamp(-1.0, 1.0).arccos()) <= max_step_rad:
            return None
        return _axis_rotation(previous_up, target_up, max_step_rad) @ previous

    return _rate_limited(rotations, fast, given, catch_up)


def _standing_heights(skeleton: Skeleton) -> np.ndarray:
    """Heights (4,) of the foot joints (SMPL: 7, 8, 10, 11) above the toes of a flat foot: the ankle sits above its
    toe by the toe's rest offset, the toes are the floor's reference."""
    offsets = skeleton.rest_offsets(torch.float64).numpy()
    left_toe, right_toe = skeleton.foot_joints[2], skeleton.foot_joints[3]
    return np.array([-offsets[left_toe, 1], -offsets[right_toe, 1], 0.0, 0.0])


def _leg_channels(side: int, skeleton: Skeleton) -> list[int]:
    hip, knee, ankle, _ = legs(skeleton)[side][0]
    return [ROTATION_CHANNELS.start + 6 * j + k for j in (hip, knee, ankle) for k in range(6)]


def _clean_one(
    x: torch.Tensor,
    fps: float,
    floor: float,
    mask: torch.Tensor | None,
    s: FloorCleanup,
    stats: dict[str, int],
    skeleton: Skeleton,
) -> torch.Tensor:
    """One motion (T, D) cleaned; ``stats`` gets how many frames each step touched."""
    x = x.double()
    parts = unpack_pose(x, skeleton)
    contacts = _clean_contacts(parts.contacts.numpy() > s.contact_threshold)
    n = len(x)
    ramp = int(round(s.given_blend_seconds * fps))
    given = None if mask is None else mask.numpy() > 0
    root_free = np.ones(n) if given is None else _free_weight(given[:, ROOT_Z_CHANNEL], ramp)
    rotmats = parts.rotmats
    out = x.clone()
    if s.max_turn_rate is not None or s.max_tilt_rate is not None:
        root_given = None if given is None else given[:, _ROOT_ROTATION].any(axis=1)
        root = rotmats[:, 0]
        if s.max_tilt_rate is not None:
            tilted = limit_tilt_rate(root, s.max_tilt_rate / fps, root_given)
            stats["tilt_limited_frames"] = int((tilted != root).flatten(-2).any(-1).sum())
            root = tilted
        if s.max_turn_rate is not None:
            turned = limit_turn_rate(root, s.max_turn_rate / fps, root_given)
            stats["turn_limited_frames"] = int((turned != root).flatten(-2).any(-1).sum())
            root = turned
        turned = (root != rotmats[:, 0]).flatten(-2).any(-1)  # frames the limit changed
        if turned.any():
            out[:, _ROOT_ROTATION] = torch.where(turned[:, None], matrix_to_6d(root), x[:, _ROOT_ROTATION])
            parts = unpack_pose(out, skeleton)
            rotmats = parts.rotmats
    if s.lock_feet:
        free = np.ones((n, 2))
        if given is not None:
            for side in (0, 1):
                free[:, side] = _free_weight(given[:, _leg_channels(side, skeleton)].any(axis=1), ramp)
        # Only a contact joint that is down (once the body is on the floor) is planted: the model's contacts
        # alone would also hold a raised foot.
        z = forward_kinematics(rotmats, parts.root_trans, skeleton=skeleton)[..., 2].numpy()
        z_on_floor = z + (_vertical_offset(z, contacts, floor, fps, s, skeleton) * root_free)[:, None]
        feet_z = z_on_floor[:, list(skeleton.foot_joints)]
        planted = contacts & (feet_z - floor < _standing_heights(skeleton) + s.plant_height_m)
        rotmats = _lock_feet(rotmats, parts.root_trans, planted, fps, s, free, skeleton)
        changed = sorted({c for side in (0, 1) for c in _leg_channels(side, skeleton)})
        moved = (rotmats != parts.rotmats).flatten(-2).any(-1).any(-1)  # frames the IK touched
        stats["foot_locked_frames"] = int(moved.sum())
        sixd = matrix_to_6d(rotmats).flatten(-2)
        out[:, changed] = torch.where(
            moved[:, None], sixd[:, [c - ROTATION_CHANNELS.start for c in changed]], x[:, changed]
        )
    max_air = _max_air_frames(s, fps, n)
    stats["grounded_air_frames"] = sum(b - a for a, b in _runs(~contacts.any(axis=1)) if b - a > max_air)
    joints = forward_kinematics(rotmats, parts.root_trans, skeleton=skeleton)
    offset = _vertical_offset(joints[..., 2].numpy(), contacts, floor, fps, s, skeleton) * root_free
    out[:, ROOT_Z_CHANNEL] = x[:, ROOT_Z_CHANNEL] + torch.from_numpy(offset)
    if given is not None:
        out = torch.where(mask.bool(), x, out)
    return out


def clean_motion(
    motion: torch.Tensor,
    fps: float,
    floor_height: float = 0.0,
    *,
    mask: torch.Tensor | None = None,
    settings: FloorCleanup | None = None,
    stats: list[dict[str, int]] | None = None,
    skeleton: Skeleton = SMPL24,
) -> torch.Tensor:
    """Feet on the floor (see the module docstring): unnormalised motion (T, D) or (S, T, D) on ``skeleton`` (D its pose
    size), z-up, at ``fps``, with its floor at ``floor_height`` metres -> the cleaned motion, same shape and dtype.
    ``mask`` (T, D) or (S, T, D), 1 = given: those channels come back exactly as they went in. ``stats``: a list that
    gets one dict per motion, the frames each step touched (``tilt_limited_frames``, ``turn_limited_frames`` (with the
    limits on), ``foot_locked_frames`` (with foot locking) and ``grounded_air_frames``: frames of runs without contact
    longer than ``max_air_seconds``, brought down)."""
    check_pose_dim(motion, skeleton, "clean_motion's motion")
    if motion.ndim not in (2, 3):
        raise ValueError(f"clean_motion needs motion (T, D) or (S, T, D), got {tuple(motion.shape)}")
    if not (fps > 0 and math.isfinite(float(floor_height))):
        raise ValueError(f"fps must be positive and the floor height finite, got {fps} and {floor_height}")
    s = settings or FloorCleanup()
    batch = motion if motion.ndim == 3 else motion[None]
    masks = None
    if mask is not None:
        if mask.shape not in (batch.shape, batch.shape[1:]):
            raise ValueError(f"mask {tuple(mask.shape)} does not match motion {tuple(motion.shape)}")
        masks = mask.detach().cpu().expand_as(batch)
    src = batch.detach().cpu()
    notes: list[dict[str, int]] = [{} for _ in range(len(src))]
    cleaned = [
        _clean_one(src[i], float(fps), float(floor_height), None if masks is None else masks[i], s, notes[i], skeleton)
        for i in range(len(src))
    ]
    if stats is not None:
        stats.extend(notes)
    out = torch.stack(cleaned).to(device=motion.device, dtype=motion.dtype)
    if mask is not None:  # exactly the given values, whatever the dtype round trip did
        out = torch.where(masks.to(motion.device).bool(), batch, out)
    return out if motion.ndim == 3 else out[0]
