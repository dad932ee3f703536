"""Synthetic dance motion for the synthetic AIST++ dataset: SMPL poses that hit the beats in a genre's style.

A dance is choreographed as keyframes on the music's beats (an "eight count" of moves at a time): arm poses from
the genre's vocabulary, torso and head accents, pelvis level, and footwork (steps, kicks, stomps, turns). Between
beats every channel follows an ease profile that starts and stops at zero speed, so joint speed falls to a local
minimum on each beat; the profile's shape (smooth or a sharp hit) is part of the genre. Legs are placed by
two-bone inverse kinematics on foot targets, so a planted foot stays exactly where it landed and the lowest foot
joint touches the floor (y = 0) on every frame. On request (``variation_rng``) each eight-count block also
travels, turns and sinks by its own amount around the genre's usual, so that these vary within a genre.

Conventions: SMPL joint order, y-up, metres, the body faces +z at zero yaw and +x is the body's left.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch
from scipy.special import betainc

from dgsdp.motion import FOOT_JOINTS, NUM_JOINTS, forward_kinematics, matrix_to_axis_angle, rest_offsets

FPS = 60
# Joint indices (SMPL order).
PELVIS, L_HIP, R_HIP, SPINE1, L_KNEE, R_KNEE, SPINE2, L_ANKLE, R_ANKLE, SPINE3, L_TOE, R_TOE = range(12)
NECK, L_COLLAR, R_COLLAR, HEAD, L_SHOULDER, R_SHOULDER, L_ELBOW, R_ELBOW, L_WRIST, R_WRIST = range(12, 22)


@dataclass(frozen=True)
class ArmPose:
    """One arm's key pose, written for the left arm (the right arm mirrors it).

    elevation: 0 hanging down, 90 horizontal, 180 straight up; azimuth: 0 out to the side, 90 forward, >90 across
    the body; twist: roll of the upper arm (which way the elbow bends); elbow: flexion. All degrees.
    """

    elevation: float
    azimuth: float
    twist: float
    elbow: float


@dataclass(frozen=True)
class DanceStyle:
    """A genre's movement vocabulary: posture, footwork, arm poses, accents and sharpness."""

    pelvis_height_m: float  # standing pelvis height before level changes
    lean_deg: float  # forward lean of the torso
    stance_width_m: float
    turnout_deg: float  # feet (and knees) turned outwards
    arm_poses: tuple[ArmPose, ...]
    arm_ease: tuple[float, float]  # speed profile exponents (a, b) within a beat: (1, 1) smooth, (4, 4) a hit
    body_ease: tuple[float, float]
    step_prob: float  # chance that a beat moves a foot
    step_m: float  # how far a stepping foot leaves its home position
    step_directions: tuple[tuple[float, float], ...]  # body-frame (x left, z forward) unit-ish step directions
    lift_m: float  # swing foot lift
    kick_prob: float = 0.0  # of the foot moves, the fraction that are kicks (out and back, high)
    kick_m: float = 0.0
    stomp_prob: float = 0.0  # of the foot moves, the fraction that lift and stamp in place
    travel_m: float = 0.0  # body travel per step
    turn_prob: float = 0.0  # chance that a beat turns the body
    turn_deg: float = 0.0
    heel_lift_deg: float = 0.0  # on-beat heel raises (releve, heel-toe footwork)
    bounce_m: float = 0.0  # pelvis dip between beats (the groove)
    level_m: float = 0.0  # on-beat random pelvis drops (level work)
    torso_pitch_deg: float = 0.0  # per-beat chest accents
    torso_yaw_deg: float = 0.0
    torso_roll_deg: float = 0.0
    hip_roll_deg: float = 0.0  # pelvis isolations
    head_deg: float = 0.0
    wrist_deg: float = 0.0  # wrist rolls and flicks
    shrug_deg: float = 0.0
    arm_jitter_deg: float = 10.0  # per-beat random variation of the arm pose
    symmetric_arms: float = 0.5  # chance that a block mirrors one arm onto the other
    arm_amplitude: float = 1.0  # scales all arm angles away from a relaxed pose
    extra: dict[str, float] = field(default_factory=dict)


# Step directions: x is outwards for the stepping foot (negative: crossing in front of or behind the other foot).
_SIDE = ((1.0, 0.0),)
_FWD_BACK = ((0.0, 1.0), (0.0, -1.0))
_DIAG = ((0.7, 0.7), (-0.7, 0.7), (0.7, -0.7), (-0.7, -0.7))

DANCE_STYLES: dict[str, DanceStyle] = {
    # Break (toprock and drops): low, leaning in, wide crossing steps and kicks, guard arms, reaches to the floor.
    "BR": DanceStyle(
        pelvis_height_m=0.72, lean_deg=22, stance_width_m=0.38, turnout_deg=20,
        arm_poses=(ArmPose(45, 60, 0, 90), ArmPose(60, 100, 0, 70), ArmPose(20, 70, 0, 20), ArmPose(70, 20, 0, 100),
                   ArmPose(10, 80, 0, 10)),
        arm_ease=(2, 2), body_ease=(2, 2), step_prob=0.85, step_m=0.3,
        step_directions=((0.0, 1.0), (-0.8, 0.6), (0.0, -1.0), (1.0, 0.0)), lift_m=0.12, kick_prob=0.3, kick_m=0.45,
        travel_m=0.05, turn_prob=0.08, turn_deg=90, bounce_m=0.03, level_m=0.16, torso_pitch_deg=12,
        torso_yaw_deg=15, head_deg=10, arm_jitter_deg=12,
    ),
    # Pop: upright, few steps, sharp angular arm hits with chest and head pops.
    "PO": DanceStyle(
        pelvis_height_m=0.90, lean_deg=0, stance_width_m=0.3, turnout_deg=10,
        arm_poses=(ArmPose(90, 0, 0, 90), ArmPose(90, 90, 0, 0), ArmPose(45, 0, 90, 90), ArmPose(90, 30, -90, 90),
                   ArmPose(10, 20, 0, 0), ArmPose(90, 60, 0, 120)),
        arm_ease=(5, 5), body_ease=(4, 4), step_prob=0.25, step_m=0.15, step_directions=_SIDE, lift_m=0.05,
        bounce_m=0.0, torso_pitch_deg=10, head_deg=30, wrist_deg=20, shrug_deg=12, arm_jitter_deg=4,
        symmetric_arms=0.3,
    ),
    # Lock: points, wrist rolls and locks (forearm folded by the shoulder), side kicks, knee drops.
    "LO": DanceStyle(
        pelvis_height_m=0.86, lean_deg=8, stance_width_m=0.32, turnout_deg=15,
        arm_poses=(ArmPose(130, 45, 0, 0), ArmPose(80, 30, -90, 140), ArmPose(60, 80, 0, 90),
                   ArmPose(100, 70, 90, 60), ArmPose(20, 30, 0, 120)),
        arm_ease=(3, 3), body_ease=(2.5, 2.5), step_prob=0.4, step_m=0.2, step_directions=_SIDE + _FWD_BACK,
        lift_m=0.1, kick_prob=0.35, kick_m=0.35, level_m=0.12, torso_pitch_deg=12, head_deg=15, wrist_deg=80,
        shrug_deg=10, arm_jitter_deg=6,
    ),
    # Middle hip-hop: bent knees, rocking torso, step-touch groove, loose mid-height arms.
    "MH": DanceStyle(
        pelvis_height_m=0.83, lean_deg=10, stance_width_m=0.36, turnout_deg=15,
        arm_poses=(ArmPose(40, 40, 0, 80), ArmPose(60, 60, 0, 100), ArmPose(30, 20, 0, 60), ArmPose(50, 90, 0, 90)),
        arm_ease=(1.5, 1.5), body_ease=(1.5, 1.5), step_prob=0.6, step_m=0.22, step_directions=_SIDE + _DIAG,
        lift_m=0.06, bounce_m=0.05, torso_pitch_deg=14, torso_roll_deg=6, head_deg=15, shrug_deg=8,
        arm_jitter_deg=10, symmetric_arms=0.6,
    ),
    # LA-style hip-hop: choreographic, big arm sweeps across the body, torso twists, diagonal steps that travel.
    "LH": DanceStyle(
        pelvis_height_m=0.85, lean_deg=6, stance_width_m=0.34, turnout_deg=10,
        arm_poses=(ArmPose(140, 30, 0, 20), ArmPose(60, 120, 0, 40), ArmPose(100, 0, 0, 10), ArmPose(30, 90, 0, 90),
                   ArmPose(120, 80, -60, 60)),
        arm_ease=(2.5, 2.5), body_ease=(2, 2), step_prob=0.55, step_m=0.28, step_directions=_DIAG + _FWD_BACK,
        lift_m=0.08, travel_m=0.08, turn_prob=0.06, turn_deg=90, bounce_m=0.02, torso_pitch_deg=8,
        torso_yaw_deg=25, head_deg=20, arm_jitter_deg=10, symmetric_arms=0.3,
    ),
    # House: fast footwork on every beat with heel-toe lifts, bouncing, travelling sideways, low loose arms.
    "HO": DanceStyle(
        pelvis_height_m=0.86, lean_deg=12, stance_width_m=0.3, turnout_deg=15,
        arm_poses=(ArmPose(25, 30, 0, 50), ArmPose(35, 50, 0, 70), ArmPose(15, 20, 0, 30)),
        arm_ease=(1.2, 1.2), body_ease=(1.2, 1.2), step_prob=0.95, step_m=0.25, step_directions=_SIDE + _DIAG,
        lift_m=0.08, travel_m=0.15, heel_lift_deg=25, bounce_m=0.06, torso_pitch_deg=10, head_deg=10,
        arm_jitter_deg=6, symmetric_arms=0.7, arm_amplitude=0.8,
    ),
    # Waack: upright, arms whipping fast over the head, few steps, poses.
    "WA": DanceStyle(
        pelvis_height_m=0.90, lean_deg=0, stance_width_m=0.28, turnout_deg=10,
        arm_poses=(ArmPose(160, 30, 0, 100), ArmPose(170, 80, 90, 120), ArmPose(120, -20, 0, 10),
                   ArmPose(140, 90, -90, 130), ArmPose(90, 10, 0, 0)),
        arm_ease=(6, 6), body_ease=(2, 2), step_prob=0.2, step_m=0.15, step_directions=_SIDE, lift_m=0.05,
        hip_roll_deg=8, torso_pitch_deg=6, head_deg=20, wrist_deg=40, shrug_deg=10, arm_jitter_deg=8,
        symmetric_arms=0.2,
    ),
    # Krump: wide low stance, big chest pops, arm strikes, heavy stomps.
    "KR": DanceStyle(
        pelvis_height_m=0.78, lean_deg=15, stance_width_m=0.46, turnout_deg=25,
        arm_poses=(ArmPose(100, 40, 0, 110), ArmPose(70, 100, 0, 30), ArmPose(110, 20, -60, 90), ArmPose(40, 60, 0, 120)),
        arm_ease=(3, 1.5), body_ease=(3, 1.5), step_prob=0.55, step_m=0.15, step_directions=_SIDE + _FWD_BACK,
        lift_m=0.18, stomp_prob=0.7, bounce_m=0.04, level_m=0.06, torso_pitch_deg=28, torso_yaw_deg=12,
        head_deg=20, shrug_deg=15, arm_jitter_deg=10,
    ),
    # Street jazz: long straight-arm lines, hip isolations, kicks and turns.
    "JS": DanceStyle(
        pelvis_height_m=0.88, lean_deg=4, stance_width_m=0.3, turnout_deg=25,
        arm_poses=(ArmPose(135, 20, 0, 5), ArmPose(90, 0, 0, 0), ArmPose(45, 60, 0, 10), ArmPose(160, 60, 0, 10)),
        arm_ease=(2, 2), body_ease=(2, 2), step_prob=0.55, step_m=0.3, step_directions=_DIAG + _FWD_BACK,
        lift_m=0.08, kick_prob=0.3, kick_m=0.55, travel_m=0.06, turn_prob=0.12, turn_deg=180, hip_roll_deg=12,
        torso_pitch_deg=6, torso_roll_deg=8, head_deg=15, wrist_deg=25, arm_jitter_deg=8, symmetric_arms=0.5,
    ),
    # Ballet jazz: tall, releve, large smooth rounded arm arcs, turns, extensions.
    "JB": DanceStyle(
        pelvis_height_m=0.91, lean_deg=0, stance_width_m=0.22, turnout_deg=35,
        arm_poses=(ArmPose(20, 60, -30, 35), ArmPose(80, 60, -40, 30), ArmPose(170, 50, -40, 35),
                   ArmPose(90, 10, -30, 15), ArmPose(140, 40, -40, 25)),
        arm_ease=(1, 1), body_ease=(1, 1), step_prob=0.5, step_m=0.3, step_directions=_FWD_BACK + _SIDE,
        lift_m=0.06, kick_prob=0.35, kick_m=0.6, travel_m=0.08, turn_prob=0.2, turn_deg=180, heel_lift_deg=35,
        torso_pitch_deg=5, torso_roll_deg=8, head_deg=15, arm_jitter_deg=6, symmetric_arms=0.7,
    ),
}  # fmt: skip


# ---------------------------------------------------------------------------------------------------------------
# Small rotation helpers on numpy arrays (angles in radians, any leading shape).


def _rx(a: np.ndarray) -> np.ndarray:
    a = np.asarray(a, dtype=np.float64)
    c, s, o, i = np.cos(a), np.sin(a), np.zeros_like(a), np.ones_like(a)
    return np.stack([np.stack([i, o, o], -1), np.stack([o, c, -s], -1), np.stack([o, s, c], -1)], -2)


def _ry(a: np.ndarray) -> np.ndarray:
    a = np.asarray(a, dtype=np.float64)
    c, s, o, i = np.cos(a), np.sin(a), np.zeros_like(a), np.ones_like(a)
    return np.stack([np.stack([c, o, s], -1), np.stack([o, i, o], -1), np.stack([-s, o, c], -1)], -2)


def _rz(a: np.ndarray) -> np.ndarray:
    a = np.asarray(a, dtype=np.float64)
    c, s, o, i = np.cos(a), np.sin(a), np.zeros_like(a), np.ones_like(a)
    return np.stack([np.stack([c, -s, o], -1), np.stack([s, c, o], -1), np.stack([o, o, i], -1)], -2)


def _apply(m: np.ndarray, v: np.ndarray) -> np.ndarray:
    return np.einsum("...ij,...j->...i", m, v)


def _normalize(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-9)


# ---------------------------------------------------------------------------------------------------------------
# Keyframes on beats and their interpolation.


class BeatTimeline:
    """Frame times against keyframe times: which beat segment each frame is in and how far through it.

    key_times_s: (K,) increasing keyframe times covering all frames (one before the first frame, one after).
    """

    def __init__(self, key_times_s: np.ndarray, num_frames: int, fps: int) -> None:
        self.t = np.arange(num_frames) / fps
        self.seg = np.clip(np.searchsorted(key_times_s, self.t, side="right") - 1, 0, len(key_times_s) - 2)
        start, end = key_times_s[self.seg], key_times_s[self.seg + 1]
        self.phase = np.clip((self.t - start) / (end - start), 0.0, 1.0)

    def ease(self, values: np.ndarray, ease: tuple[float, float]) -> np.ndarray:
        """Per-frame values from keyframes (K, ...): eased so that speed is zero on every keyframe.

        The speed profile within a segment is proportional to phase^a (1 - phase)^b: a = b gives a symmetric
        move peaking mid-beat; a > b a hit that accelerates and stops dead on the beat.
        """
        a, b = ease
        w = betainc(a + 1.0, b + 1.0, self.phase)
        v0, v1 = values[self.seg], values[self.seg + 1]
        w = w.reshape(w.shape + (1,) * (values.ndim - 1))
        return v0 + (v1 - v0) * w

    def bump(self, heights: np.ndarray, power: float = 2.0) -> np.ndarray:
        """Per-frame mid-segment bumps: heights (K-1, ...) per segment, sin^power profile (zero at both ends)."""
        w = np.sin(np.pi * self.phase) ** power
        return heights[self.seg] * w.reshape(w.shape + (1,) * (heights.ndim - 1))


@dataclass
class Keyframes:
    """Per-beat choreography (K keyframes). Angles in radians, positions in metres, body frame x left z fwd."""

    toe_xz: np.ndarray  # (K, 2, 2) left/right toe position on the floor
    foot_yaw: np.ndarray  # (K, 2)
    heel: np.ndarray  # (K, 2) heel raise angle
    swing: np.ndarray  # (K-1, 2, 3) mid-segment foot displacement (world): lift and kicks
    weight: np.ndarray  # (K,) 0 = pelvis over the right foot, 1 = over the left
    yaw: np.ndarray  # (K,) body facing
    level: np.ndarray  # (K,) pelvis height offset
    bounce: np.ndarray  # (K-1,) pelvis dip between beats
    pelvis_pitch: np.ndarray  # (K,)
    pelvis_roll: np.ndarray  # (K,)
    torso: np.ndarray  # (K, 3) pitch, yaw, roll shared by the three spine joints
    head: np.ndarray  # (K, 2) pitch, yaw
    arms: np.ndarray  # (K, 2, 4) elevation, azimuth, twist, elbow per arm (left-arm convention)
    wrists: np.ndarray  # (K, 2, 2) roll, bend
    shrug: np.ndarray  # (K, 2)


@dataclass(frozen=True)
class BlockVariation:
    """How each eight-count block of one dance departs from its genre's usual movement (:func:`draw_variation`).

    travel_m: (N,) body travel per step; step_prob: (N,) chance that a beat moves a foot (a travelling block steps
    more, as walking does); turn_prob: (N,) chance that a beat turns the body; turn_deg: the turn's size; level_m:
    (N,) pelvis height offset through the block (negative: lower).
    """

    travel_m: np.ndarray
    step_prob: np.ndarray
    turn_prob: np.ndarray
    turn_deg: float
    level_m: np.ndarray

    @classmethod
    def usual(cls, style: DanceStyle, num_keys: int) -> BlockVariation:
        """Every block at the genre's own amounts: the dance without variation."""
        blocks = -(-num_keys // 8)
        return cls(
            travel_m=np.full(blocks, style.travel_m), step_prob=np.full(blocks, style.step_prob),
            turn_prob=np.full(blocks, style.turn_prob), turn_deg=style.turn_deg, level_m=np.zeros(blocks),
        )  # fmt: skip


VARIATION_SCALES = (0.0, 0.5, 1.0, 2.0, 4.0)
"""A block's travel and turning are the genre's usual amounts times one of these (drawn alike)."""
VARIATION_STEP_PROBS = (0.0, 0.6, 0.7, 0.85, 1.0)
"""A block that travels by the scale of the same place steps on at least this share of its beats: travel comes
with steps, so a genre that seldom steps would hardly travel at any scale."""
VARIATION_FLOOR_TRAVEL_M = 0.08
"""The usual travel per step that the scales multiply in a genre that does not travel (travel_m = 0)."""
VARIATION_FLOOR_TURN_PROB = 0.06
"""The usual chance of a turn per beat that the scales multiply in a genre that rarely or never turns."""
VARIATION_LEVEL_M = (-0.15, 0.03)
"""A block's pelvis offset is drawn uniformly in this range (m); the legs' reach caps the rise."""


def draw_variation(style: DanceStyle, num_keys: int, rng: np.random.Generator) -> BlockVariation:
    """Per eight-count block, how much the dance travels, turns and how low it is: the genre's usual amounts
    (at least :data:`VARIATION_FLOOR_TRAVEL_M` and :data:`VARIATION_FLOOR_TURN_PROB`) times a scale drawn from
    :data:`VARIATION_SCALES` (a travelling block steps more: :data:`VARIATION_STEP_PROBS`), and a level offset
    drawn in :data:`VARIATION_LEVEL_M`, so that a genre's windows
    range from on the spot to travelling and from facing ahead to spinning, at several heights."""
    blocks = -(-num_keys // 8)
    scales = np.asarray(VARIATION_SCALES)
    travel_scale = rng.integers(len(scales), size=blocks)
    travel = max(style.travel_m, VARIATION_FLOOR_TRAVEL_M) * scales[travel_scale]
    turn = max(style.turn_prob, VARIATION_FLOOR_TURN_PROB) * scales[rng.integers(len(scales), size=blocks)]
    return BlockVariation(
        travel_m=travel,
        step_prob=np.maximum(style.step_prob, np.asarray(VARIATION_STEP_PROBS)[travel_scale]),
        turn_prob=np.minimum(turn, 0.6),
        turn_deg=style.turn_deg or 90.0,
        level_m=rng.uniform(*VARIATION_LEVEL_M, size=blocks),
    )


def _choreograph(
    style: DanceStyle, num_keys: int, basic: bool, rng: np.random.Generator, variation: BlockVariation | None = None
) -> Keyframes:
    """Per-beat keyframes for a whole dance: eight-count blocks of arm, torso and foot moves.

    ``basic`` (AIST++'s sBM) repeats one block's move throughout; otherwise (sFM) every block draws new moves.
    Per-dance variation: amplitude, which poses, their order, mirroring, step choices. ``variation`` (optional)
    sets each block's travel, turning and level (:func:`draw_variation`); without it every block has the genre's
    own (:meth:`BlockVariation.usual`), and ``rng`` draws exactly what it drew before the option existed.
    """
    deg = np.pi / 180.0
    k = num_keys
    variation = variation or BlockVariation.usual(style, k)
    amp = rng.uniform(0.75, 1.25)  # the dancer's energy on this take
    height = style.pelvis_height_m + rng.uniform(-0.02, 0.02)
    width = style.stance_width_m * rng.uniform(0.9, 1.1)
    turnout = style.turnout_deg * deg
    home = np.array([[width / 2, 0.0], [-width / 2, 0.0]])  # body-frame toe homes (left, right)

    # ---- upper body, built per eight-count block
    relaxed = np.array([15.0, 40.0, 0.0, 30.0])
    arms = np.zeros((k, 2, 4))
    wrists = np.zeros((k, 2, 2))
    torso = np.zeros((k, 3))
    head = np.zeros((k, 2))
    shrug = np.zeros((k, 2))
    pelvis_roll = np.zeros(k)
    level = np.zeros(k)
    block_rng_state = rng.bit_generator.state if basic else None
    for start in range(0, k, 8):
        if basic:
            rng.bit_generator.state = block_rng_state  # the same block every time
        n = min(8, k - start)
        period = int(rng.choice([2, 4]))
        poses = np.array([[(p.elevation, p.azimuth, p.twist, p.elbow)] for p in style.arm_poses])[:, 0]
        seq_left = poses[rng.integers(len(poses), size=period)]
        if rng.random() < style.symmetric_arms:
            seq_right = seq_left
        else:
            seq_right = poses[rng.integers(len(poses), size=period)]
        if rng.random() < 0.5:
            seq_left, seq_right = seq_right, seq_left
        signs = rng.choice([-1.0, 1.0], size=(5, period))
        for i in range(n):
            j = i % period
            for side, seq in enumerate((seq_left, seq_right)):
                pose = relaxed + (seq[j] - relaxed) * style.arm_amplitude * amp
                arms[start + i, side] = pose + rng.normal(0, style.arm_jitter_deg, 4)
                wrists[start + i, side] = (signs[0, j] * style.wrist_deg, signs[1, j] * style.wrist_deg * 0.3)
            torso[start + i] = (
                style.lean_deg * 0.5 + signs[2, j] * style.torso_pitch_deg * amp,
                signs[3, j] * style.torso_yaw_deg * amp,
                signs[4, j] * style.torso_roll_deg * amp,
            )
            head[start + i] = (-signs[2, j] * style.head_deg * 0.5, signs[3, j] * style.head_deg) * np.array(amp)
            shrug[start + i] = signs[0, j] * style.shrug_deg, -signs[0, j] * style.shrug_deg
            pelvis_roll[start + i] = signs[4, j] * style.hip_roll_deg
            if style.level_m > 0 and rng.random() < 0.3:
                level[start + i] = -style.level_m * rng.uniform(0.6, 1.2)
                if style.lean_deg > 15:  # Break drops: reach for the floor
                    arms[start + i, :] = (10.0, 80.0, 0.0, 10.0) + rng.normal(0, 5, (2, 4))
    if basic:
        rng.bit_generator.state = block_rng_state
        rng.random(1000)  # move on past the block's draws so that footwork is not tied to them

    # ---- footwork: one foot moves at most per beat, so one foot always stays planted
    toe_xz = np.zeros((k, 2, 2))
    foot_yaw = np.zeros((k, 2))
    heel = np.zeros((k, 2))
    swing = np.zeros((k - 1, 2, 3))
    weight = np.full(k, 0.5)
    yaw = np.zeros(k)
    anchor = rng.normal(0, 0.3, 2)
    facing = rng.uniform(-0.5, 0.5)
    travel_dir = rng.choice([-1.0, 1.0])
    offsets = np.zeros((2, 2))  # current body-frame offset of each foot from its home
    for side in range(2):
        toe_xz[0, side] = anchor + _apply(_ry(facing)[[0, 2]][:, [0, 2]], home[side])
        foot_yaw[0, side] = facing + (turnout if side == 0 else -turnout)
    yaw[0] = facing
    next_foot = int(rng.integers(2))
    for b in range(1, k):
        toe_xz[b], foot_yaw[b], yaw[b] = toe_xz[b - 1], foot_yaw[b - 1], yaw[b - 1]
        heel[b] = 0.0
        if style.heel_lift_deg > 0 and rng.random() < 0.5:
            heel[b, int(rng.integers(2))] = style.heel_lift_deg * deg
        block = b // 8
        travel_m = variation.travel_m[block]
        turning = rng.random() < variation.turn_prob[block]
        if turning:
            yaw[b] = yaw[b - 1] + rng.choice([-1.0, 1.0]) * variation.turn_deg * deg
        if rng.random() >= variation.step_prob[block] and not turning:
            weight[b] = 0.5 + rng.uniform(-0.2, 0.2)
            continue
        side = next_foot
        next_foot = 1 - side
        lift = style.lift_m * rng.uniform(0.8, 1.2)
        rot = _ry(yaw[b])[[0, 2]][:, [0, 2]]  # 2D rotation of body-frame (x, z)
        kind = rng.random()
        if kind < style.kick_prob:
            offsets[side] = 0.0
            forward = _apply(_ry(yaw[b]), np.array([0.3 if side == 0 else -0.3, 0.0, 1.0]))
            swing[b - 1, side] = _normalize(forward) * style.kick_m * amp + [0.0, style.kick_m * 0.6, 0.0]
        elif kind < style.kick_prob + style.stomp_prob:
            swing[b - 1, side, 1] = lift * 1.2
            weight[b] = 0.5
        else:
            if np.any(offsets[side] != 0.0):
                offsets[side] = 0.0  # step back home
            else:
                direction = np.array(style.step_directions[int(rng.integers(len(style.step_directions)))])
                outward = np.array([1.0 if side == 0 else -1.0, 1.0])
                offsets[side] = direction * outward * style.step_m * rng.uniform(0.7, 1.2)
            if travel_m > 0:
                anchor = anchor + _apply(rot, np.array([travel_dir * travel_m, 0.0]))
                if rng.random() < 0.15:
                    travel_dir = -travel_dir
        swing[b - 1, side, 1] = max(swing[b - 1, side, 1], lift)
        # The pelvis stands over the body anchor, so a foot far from it gets pulled back in.
        toe_xz[b, side] = anchor + _apply(rot, home[side] + offsets[side])
        foot_yaw[b, side] = yaw[b] + (turnout if side == 0 else -turnout)
        heel[b, side] = 0.0
        weight[b] = 0.5 + (0.25 if side == 1 else -0.25)  # weight towards the foot that stays
        # The planted foot pivots on its toe to follow a turn (heel raised while it does).
        other = 1 - side
        if turning:
            foot_yaw[b, other] = yaw[b] + (turnout if other == 0 else -turnout)
            heel[b, other] = max(heel[b, other], 15 * deg)
        # Keep the planted foot within reach of the new anchor.
        if np.linalg.norm(toe_xz[b, other] - anchor) > 0.45:
            anchor = 0.5 * (anchor + toe_xz[b, other])

    level = level + np.repeat(variation.level_m, 8)[:k]
    bounce = np.full(k - 1, -style.bounce_m * amp)
    pelvis_pitch = np.full(k, style.lean_deg * 0.5 * deg) + rng.normal(0, 2 * deg, k)
    return Keyframes(
        toe_xz=toe_xz, foot_yaw=foot_yaw, heel=heel, swing=swing, weight=weight, yaw=yaw,
        level=level + height, bounce=bounce, pelvis_pitch=pelvis_pitch, pelvis_roll=pelvis_roll * deg,
        torso=torso * deg, head=head * deg, arms=arms * deg, wrists=wrists * deg, shrug=shrug * deg,
    )  # fmt: skip


# ---------------------------------------------------------------------------------------------------------------
# From keyframes to SMPL parameters.


def _arm_rotations(arm: np.ndarray, side: int) -> tuple[np.ndarray, np.ndarray]:
    """Local shoulder and elbow rotations (T, 3, 3) from (T, 4) elevation, azimuth, twist, elbow (radians).

    Written for the left arm (rest direction +x); the right arm is its mirror image through the x = 0 plane.
    """
    elev, azim, twist, elbow = arm[:, 0], arm[:, 1], arm[:, 2], arm[:, 3]
    sign = 1.0 if side == 0 else -1.0
    shoulder = _ry(-sign * azim) @ _rz(sign * (elev - np.pi / 2)) @ _rx(twist)
    return shoulder, _ry(-sign * np.clip(elbow, 0.0, 2.6))


def _leg_ik(
    hip: np.ndarray,
    root_rot: np.ndarray,
    ankle: np.ndarray,
    foot_rot: np.ndarray,
    side: int,
    offsets: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Two-bone IK: local hip, knee and ankle rotations (T, 3, 3) that put the ankle at ``ankle`` (T, 3).

    The knee bends about its x axis and points along the foot's forward direction; the ankle then takes the
    foot's global rotation ``foot_rot`` (T, 3, 3). Unreachable targets straighten the leg towards them.
    """
    a = offsets[L_KNEE if side == 0 else R_KNEE]
    b = offsets[L_ANKLE if side == 0 else R_ANKLE]
    # |a + Rx(beta) b|^2 = K + 2 r cos(beta - phi0)
    p = a[1] * b[1] + a[2] * b[2]
    q = a[2] * b[1] - a[1] * b[2]
    big_k = a @ a + b @ b + 2 * a[0] * b[0]
    r, phi0 = np.hypot(p, q), np.arctan2(q, p)
    target = ankle - hip
    d = np.linalg.norm(target, axis=-1)
    beta = phi0 + np.arccos(np.clip((d**2 - big_k) / (2 * r), -1.0, 1.0))
    knee = _rx(beta)
    v_rest = a + _apply(knee, b)
    pole_rest = np.broadcast_to(np.array([0.0, 0.0, 1.0]), v_rest.shape)
    root_t = np.swapaxes(root_rot, -1, -2)
    v_loc = _apply(root_t, target)
    pole_loc = _apply(root_t, foot_rot[..., :, 2] * np.array([1.0, 0.0, 1.0]))

    def basis(v: np.ndarray, pole: np.ndarray) -> np.ndarray:
        e1 = _normalize(v)
        e2 = _normalize(pole - (pole * e1).sum(-1, keepdims=True) * e1)
        return np.stack([e1, e2, np.cross(e1, e2)], -1)

    hip_local = basis(v_loc, pole_loc) @ np.swapaxes(basis(v_rest, pole_rest), -1, -2)
    knee_global = root_rot @ hip_local @ knee
    ankle_local = np.swapaxes(knee_global, -1, -2) @ foot_rot
    return hip_local, knee, ankle_local


def _max_leg_reach_m(offsets: np.ndarray, side: int) -> float:
    a = offsets[L_KNEE if side == 0 else R_KNEE]
    b = offsets[L_ANKLE if side == 0 else R_ANKLE]
    return float(np.linalg.norm(a) + np.linalg.norm(b))


def synthesize_dance(
    genre: str | DanceStyle,
    beat_times_s: np.ndarray,
    num_frames: int,
    *,
    rng: np.random.Generator,
    basic: bool = False,
    fps: int = FPS,
    timing_jitter_s: float = 0.01,
    variation_rng: np.random.Generator | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """A dance in ``genre``'s style on the given music beats.

    genre: an AIST++ genre code of :data:`DANCE_STYLES`, or a style of one's own. beat_times_s: (B,) beat times
    of the music. Returns SMPL ``poses`` (T, 72) axis-angle (SMPL joint order) and root translation ``trans_m``
    (T, 3) in metres, y-up, with the lowest foot joint on the floor (y = 0). ``variation_rng`` (optional) draws
    each eight-count block's travel, turning and level (:func:`draw_variation`) apart from ``rng``, so a dance made
    without it is the same as before the option existed.
    """
    style = genre if isinstance(genre, DanceStyle) else DANCE_STYLES[genre]
    period_s = float(np.median(np.diff(beat_times_s))) if len(beat_times_s) > 1 else 0.5
    duration_s = num_frames / fps
    # Keyframes on every beat, extended by whole beats to cover the whole clip; a little human timing jitter.
    first = beat_times_s[0] - period_s * np.ceil((beat_times_s[0] + 1e-9) / period_s)
    key_times = np.arange(first, duration_s + 2 * period_s, period_s)
    key_times[1:-1] += rng.normal(0.0, timing_jitter_s, len(key_times) - 2)
    variation = None if variation_rng is None else draw_variation(style, len(key_times), variation_rng)
    keys = _choreograph(style, len(key_times), basic, rng, variation)
    line = BeatTimeline(key_times, num_frames, fps)
    body, arms_ease = style.body_ease, style.arm_ease
    offsets = rest_offsets(torch.float64).numpy()

    # Feet: toes eased between placements with a lift (and kick) on the way; the swing profile rises faster than
    # the foot travels, so a foot leaves and lands vertically.
    toe_xz = line.ease(keys.toe_xz, (max(body[0], 2.0), max(body[1], 2.0)))  # (T, 2, 2)
    swing = line.bump(keys.swing * [0.0, 1.0, 0.0]) + line.bump(keys.swing * [1.0, 0.0, 1.0], power=4.0)  # (T, 2, 3)
    toe = np.stack([toe_xz[..., 0], np.zeros(toe_xz.shape[:2]), toe_xz[..., 1]], -1) + swing
    foot_yaw = line.ease(keys.foot_yaw, body)
    heel = line.ease(keys.heel, body) + line.bump(np.abs(keys.swing[..., 1]) * 2.0)  # point the swinging foot
    foot_rot = _ry(foot_yaw) @ _rx(heel)  # (T, 2, 3, 3)
    toe_offsets = np.stack([offsets[L_TOE], offsets[R_TOE]])
    ankle = toe - _apply(foot_rot, toe_offsets)

    # Pelvis: over the weighted feet, at the style's height with level changes and the between-beat bounce.
    yaw = line.ease(keys.yaw, body)
    pitch = line.ease(keys.pelvis_pitch, body)
    roll = line.ease(keys.pelvis_roll, body)
    root_rot = _ry(yaw) @ _rx(pitch) @ _rz(roll)
    weight = line.ease(keys.weight, body)
    feet_xz = ankle[..., [0, 2]]
    pelvis_xz = weight[:, None] * feet_xz[:, 0] + (1 - weight[:, None]) * feet_xz[:, 1]
    pelvis_xz = pelvis_xz - 0.03 * np.stack([np.sin(yaw), np.cos(yaw)], -1)  # hips sit slightly behind the feet
    pelvis_y = line.ease(keys.level, body) + line.bump(keys.bounce)
    # Lower the pelvis where a planted foot could not otherwise be reached.
    for side, hip_joint in ((0, L_HIP), (1, R_HIP)):
        planted = toe[:, side, 1] < 0.02
        hip_rel = _apply(root_rot, offsets[hip_joint])
        dxz = np.linalg.norm(pelvis_xz + hip_rel[:, [0, 2]] - ankle[:, side, [0, 2]], axis=-1)
        reach = 0.97 * _max_leg_reach_m(offsets, side)
        max_y = ankle[:, side, 1] + np.sqrt(np.maximum(reach**2 - dxz**2, 0.05)) - hip_rel[:, 1]
        pelvis_y = np.where(planted, np.minimum(pelvis_y, max_y), pelvis_y)
    root = np.stack([pelvis_xz[:, 0], pelvis_y, pelvis_xz[:, 1]], -1)

    local = np.broadcast_to(np.eye(3), (num_frames, NUM_JOINTS, 3, 3)).copy()
    local[:, PELVIS] = root_rot
    for side, (hip_joint, knee_joint, ankle_joint) in enumerate(((L_HIP, L_KNEE, L_ANKLE), (R_HIP, R_KNEE, R_ANKLE))):
        hip_pos = root + _apply(root_rot, offsets[hip_joint])
        local[:, hip_joint], local[:, knee_joint], local[:, ankle_joint] = _leg_ik(
            hip_pos, root_rot, ankle[:, side], foot_rot[:, side], side, offsets
        )
    # The torso counters most of the pelvis lean and adds the style's own accents.
    torso = line.ease(keys.torso, body)
    spine = _ry(torso[:, 1] / 3) @ _rx((torso[:, 0] - pitch) / 3) @ _rz(torso[:, 2] / 3)
    for joint in (SPINE1, SPINE2, SPINE3):
        local[:, joint] = spine
    head = line.ease(keys.head, body)
    local[:, NECK] = _rx(head[:, 0] / 2) @ _ry(head[:, 1] / 2)
    local[:, HEAD] = local[:, NECK]
    arms = line.ease(keys.arms, arms_ease)
    wrists = line.ease(keys.wrists, arms_ease)
    shrug = line.ease(keys.shrug, arms_ease)
    for side, (collar, shoulder, elbow, wrist) in enumerate(
        ((L_COLLAR, L_SHOULDER, L_ELBOW, L_WRIST), (R_COLLAR, R_SHOULDER, R_ELBOW, R_WRIST))
    ):
        sign = 1.0 if side == 0 else -1.0
        local[:, collar] = _rz(sign * shrug[:, side])
        local[:, shoulder], local[:, elbow] = _arm_rotations(arms[:, side], side)
        local[:, wrist] = _rx(wrists[:, side, 0]) @ _rz(sign * wrists[:, side, 1])

    # Put the lowest foot joint on the floor (IK already does for planted feet; this guards its rounding).
    rotmats = torch.from_numpy(local)
    joints = forward_kinematics(rotmats, torch.from_numpy(root)).numpy()
    root[:, 1] -= joints[:, list(FOOT_JOINTS), 1].min(axis=1)
    poses = matrix_to_axis_angle(rotmats).reshape(num_frames, NUM_JOINTS * 3).numpy()
    return poses, root
