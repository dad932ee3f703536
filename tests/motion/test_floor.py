"""Feet on the floor: the floor measure and the contact-aware cleanup, checked on the FK of the cleaned motion."""

import functools
import math

import numpy as np
import pytest
import torch

from dgsdp.data.synthetic_motion import synthesize_dance
from dgsdp.editing import build_mask
from dgsdp.motion import (
    FloorCleanup,
    clean_motion,
    foot_contacts,
    matrix_to_axis_angle,
    measure_floor_height,
    pack_pose,
    pose_to_joints,
    root_rotation_y_up_to_z_up,
    smpl_to_pose,
    unpack_pose,
)
from dgsdp.motion.floor import limit_tilt_rate, limit_turn_rate

FPS = 30
FEET = [7, 8, 10, 11]


@functools.lru_cache(maxsize=8)
def dance(genre: str = "HO", seconds: float = 6.0, seed: int = 0) -> torch.Tensor:
    """A clean synthetic dance (T, 151) at 30 FPS, z-up, its lowest foot joint on z = 0 on every frame, with the
    contacts of its own foot speeds."""
    poses, trans = synthesize_dance(
        genre, np.arange(0.25, seconds, 0.5), int(seconds * FPS), rng=np.random.default_rng(seed), fps=FPS
    )
    return smpl_to_pose(torch.from_numpy(poses), torch.from_numpy(trans)).float()


def joints(motion: torch.Tensor) -> torch.Tensor:
    return pose_to_joints(motion.double())


def lowest_foot(motion: torch.Tensor) -> torch.Tensor:
    return joints(motion)[:, FEET, 2].amin(dim=1)


def joint_speeds(motion: torch.Tensor) -> torch.Tensor:
    """(T - 1, 24) joint speeds in m/s."""
    j = joints(motion)
    return (j[1:] - j[:-1]).norm(dim=-1) * FPS


def standing(n_frames: int, heights: torch.Tensor, contact: torch.Tensor) -> torch.Tensor:
    """The SMPL rest pose standing upright (z-up), its lowest foot joint at ``heights`` (T,), contacts (T,) on all
    four foot channels."""
    rot = torch.eye(3, dtype=torch.float64).expand(n_frames, 24, 3, 3).clone()
    rot[:, 0] = root_rotation_y_up_to_z_up(rot[:, 0])
    trans = torch.zeros(n_frames, 3, dtype=torch.float64)
    rest = pose_to_joints(pack_pose(torch.zeros(1, 4), trans[:1], rot[:1]).double())
    trans[:, 2] = heights.double() - rest[0, FEET, 2].min()
    return pack_pose(contact.double()[:, None].expand(n_frames, 4), trans, rot).float()


def test_measure_floor_height_of_known_floors():
    m = dance()
    assert measure_floor_height(m) == pytest.approx(0.0, abs=1e-5)  # the synthetic floor is z = 0 by construction
    raised = m.clone()
    raised[:, 6] += 0.37
    assert measure_floor_height([raised[:90], raised[90:]]) == pytest.approx(0.37, abs=1e-5)
    # the median ignores jumps: a third of the frames 0.5 m up leaves the floor where it was
    jumpy = raised.clone()
    jumpy[::3, 6] += 0.5
    assert measure_floor_height(jumpy) == pytest.approx(0.37, abs=1e-5)
    with pytest.raises(ValueError):
        measure_floor_height(torch.zeros(0, 151))


@pytest.mark.parametrize("floor", [0.0, 0.37])
def test_sinking_dance_is_lifted_onto_the_floor(floor):
    m = dance("BR")
    sunk = m.clone()
    sunk[:, 6] += floor - 0.08  # 8 cm under the floor, contacts as predicted for the clean dance
    out = clean_motion(sunk, FPS, floor)
    j = joints(out)
    assert joints(sunk)[..., 2].min() < floor - 0.07
    assert j[..., 2].min() >= floor - 0.01  # no joint of any frame more than 1 cm below the floor
    # frames with a predicted contact have their lowest contact joint on the floor: the dance is back where it was
    assert (lowest_foot(out) - floor).abs().max() < 0.01
    assert torch.equal(out[:, :4], sunk[:, :4])  # predicted contacts are kept


def test_floating_dance_with_predicted_contacts_is_put_down():
    m = dance("PO")
    up = m.clone()
    up[:, 6] += 0.3
    out = clean_motion(up, FPS, 0.0)
    low = lowest_foot(out)
    assert (lowest_foot(up) > 0.1).all()
    assert (low > 0.1).float().mean() == 0.0  # no frame floats (lowest foot more than 10 cm up)
    assert low.abs().max() < 0.01
    # putting it down adds no fast motion
    assert joint_speeds(out).max() < joint_speeds(m).max() + 0.5


def test_short_jump_without_contacts_is_kept():
    n, start, flight = 75, 30, 9  # a 0.3 s flight
    t = torch.arange(flight + 2, dtype=torch.float64) / (flight + 1)
    heights = torch.zeros(n, dtype=torch.float64)
    heights[start - 1 : start + flight + 1] = 4 * 0.2 * t * (1 - t)  # a parabola 20 cm high
    contact = (heights == 0).double()
    m = standing(n, heights, contact)
    out = clean_motion(m, FPS, 0.0)
    low = lowest_foot(out)
    assert low[start : start + flight].max() == pytest.approx(0.2, abs=0.01)
    assert (low - lowest_foot(m)).abs().max() < 0.005
    assert low.min() > -0.005


def test_long_float_without_contacts_is_brought_down():
    n, start, length = 120, 30, 60  # 2 s in the air: no jump lasts that long
    heights = torch.zeros(n, dtype=torch.float64)
    ramp = torch.linspace(0, 1, 10, dtype=torch.float64)
    heights[start : start + length] = 0.4
    heights[start : start + 10] = 0.4 * ramp
    heights[start + length - 10 : start + length] = 0.4 * ramp.flip(0)
    contact = (heights == 0).double()
    m = standing(n, heights, contact)
    out = clean_motion(m, FPS, 0.0)
    low = lowest_foot(out)
    assert lowest_foot(m)[start + 10 : start + length - 10].min() > 0.39
    assert low[start + 13 : start + length - 13].abs().max() < 0.01  # down on the floor
    assert low.min() > -0.005 and low.max() < 0.05  # where it rose fast, the smooth correction rounds it off
    assert joint_speeds(out).max() < joint_speeds(m).max()  # smoothly: no faster than the input moved
    # the same float shorter than the bound stays up
    settings = FloorCleanup(max_air_seconds=3.0)
    kept = lowest_foot(clean_motion(m, FPS, 0.0, settings=settings))
    assert kept[start + 10 : start + length - 10].min() > 0.39


def sliding_m_per_s(motion: torch.Tensor, contacts: torch.Tensor) -> float:
    """Mean horizontal speed of foot joints over consecutive frames where they are in contact."""
    feet = joints(motion)[:, FEET, :2]
    speed = (feet[1:] - feet[:-1]).norm(dim=-1) * FPS
    on = (contacts[1:] > 0.5) & (contacts[:-1] > 0.5)
    return float(speed[on].mean())


def test_foot_locking_stops_planted_feet_sliding():
    m = dance("LH")
    drift = m.clone()
    t = torch.arange(len(m)) / FPS
    drift[:, 4] += 0.05 * torch.sin(2 * math.pi * 0.7 * t)  # the root wanders as a model's does
    drift[:, 5] += 0.04 * torch.cos(2 * math.pi * 0.5 * t)
    drift[:, 7:] += 0.005 * torch.randn(len(m), 144, generator=torch.Generator().manual_seed(0))
    contacts = m[:, :4]
    before = sliding_m_per_s(drift, contacts)
    out = clean_motion(drift, FPS, 0.0)
    after = sliding_m_per_s(out, contacts)
    assert sliding_m_per_s(m, contacts) < 0.02 and before > 0.1
    assert after < before / 5
    # holding feet adds no fast motion: the 99.9th percentile of joint speed does not rise
    assert (
        torch.quantile(joint_speeds(out).flatten(), 0.999) < torch.quantile(joint_speeds(drift).flatten(), 0.999) + 0.1
    )
    # the legs were moved by IK, nothing else: the upper body is where it was
    upper = [3, 6, 9, 12, 13, 14, 15, 16, 17, 18, 19, 20, 21, 22, 23]
    assert torch.allclose(joints(out)[:, upper, :2], joints(drift)[:, upper, :2], atol=1e-6)
    # and switching it off leaves the sliding
    assert (
        sliding_m_per_s(clean_motion(drift, FPS, 0.0, settings=FloorCleanup(lock_feet=False)), contacts) > 0.8 * before
    )


@pytest.mark.parametrize("genre", ["BR", "JB", "KR"])
def test_clean_ground_truth_passes_nearly_unchanged(genre):
    m = dance(genre)
    out = clean_motion(m, FPS, 0.0)
    moved = (joints(out) - joints(m)).norm(dim=-1)
    assert moved.max() < 0.02  # cm-level at worst, where a foot is planted while it still creeps
    assert moved.mean() < 0.001


@pytest.mark.parametrize("task", ["seed_motion", "lower_body", "inpaint"])
def test_given_channels_are_never_changed(task):
    m = dance("WA")
    sunk = m.clone()
    sunk[:, 6] -= 0.1
    sunk[:, 4] += 0.03 * torch.sin(torch.arange(len(m)) / 5.0)  # sliding too, for the IK to act on
    mask = build_mask(task, len(m), seed_frames=30, generator=torch.Generator().manual_seed(0))
    out = clean_motion(sunk, FPS, 0.0, mask=mask)
    given = mask.bool()
    assert torch.equal(out[given], sunk[given])
    free_root = ~given[:, 6]
    # where the root height is the model's (away from given frames), the dance comes up out of the floor
    far = free_root & torch.from_numpy(np.convolve(free_root.numpy(), np.ones(15), "same") == 15)
    if task != "inpaint":  # inpainting gives most frames at random: no free stretch is that long
        assert far.sum() > 30 and joints(out)[far][..., 2].min() > -0.01
    # a batch of samples with one mask: each sample cleaned, given channels kept
    batch = torch.stack([sunk, sunk + 0.0])
    assert torch.equal(clean_motion(batch, FPS, 0.0, mask=mask)[:, given], batch[:, given])


def test_contacts_from_a_model_and_bad_inputs():
    m = dance("LO")
    # contacts recomputed from the cleaned motion agree with the predicted ones on most frames
    out = clean_motion(m, FPS, 0.0)
    agree = (foot_contacts(joints(out)) == (m[:, :4] > 0.5).double()).double().mean()
    assert agree > 0.95
    with pytest.raises(ValueError):
        clean_motion(m[:, :150], FPS, 0.0)
    with pytest.raises(ValueError):
        clean_motion(m, FPS, float("nan"))
    with pytest.raises(ValueError):
        clean_motion(m, FPS, 0.0, mask=torch.ones(5, 151))
    with pytest.raises(ValueError):
        FloorCleanup(max_air_seconds=-1.0)


def test_two_bone_leg_ik_reaches_its_target():
    """FK of the IK's rotations puts the ankle on the target and keeps the foot's orientation."""
    from dgsdp.motion import axis_angle_to_matrix, forward_kinematics
    from dgsdp.motion.floor import leg_ik

    g = torch.Generator().manual_seed(3)
    n = 64
    rot = axis_angle_to_matrix(0.3 * torch.randn(n, 24, 3, generator=g, dtype=torch.float64))
    rot[:, 4, :, :] = axis_angle_to_matrix(torch.tensor([0.8, 0.0, 0.0], dtype=torch.float64))  # a bent knee
    root = torch.zeros(n, 3, dtype=torch.float64)
    j, glob = forward_kinematics(rot, root, return_global_rotmats=True)
    move = 0.06 * torch.randn(n, 3, generator=g, dtype=torch.float64)
    target = j[:, 7] + move
    hip, knee, ankle = leg_ik(glob[:, 0], glob[:, 1], glob[:, 4], glob[:, 7], j[:, 1], j[:, 4], j[:, 7], target)
    new = rot.clone()
    new[:, 1], new[:, 4], new[:, 7] = hip, knee, ankle
    j2, glob2 = forward_kinematics(new, root, return_global_rotmats=True)
    reach = (j[:, 4] - j[:, 1]).norm(dim=-1) + (j[:, 7] - j[:, 4]).norm(dim=-1)
    within = (target - j[:, 1]).norm(dim=-1) < 0.95 * reach
    assert within.sum() > n // 2
    assert (j2[within, 7] - target[within]).norm(dim=-1).max() < 1e-3
    assert torch.allclose(glob2[:, 7], glob[:, 7], atol=1e-9)  # the foot turns with nothing
    assert torch.allclose(j2[:, 10] - j2[:, 7], j[:, 10] - j[:, 7], atol=1e-9)  # so the toe moves with the ankle
    # the knee only bends about its hinge (x): no twist or sideways bend of the knee appears
    rel = knee @ rot[:, 4].transpose(-1, -2)
    assert torch.allclose(rel[:, 0, 0], torch.ones(n, dtype=torch.float64), atol=1e-9)
    # an unreachable target straightens the leg towards it
    far = j[:, 1] + 2.0 * (j[:, 7] - j[:, 1])
    hip, knee, ankle = leg_ik(glob[:, 0], glob[:, 1], glob[:, 4], glob[:, 7], j[:, 1], j[:, 4], j[:, 7], far)
    new[:, 1], new[:, 4], new[:, 7] = hip, knee, ankle
    j3 = forward_kinematics(new, root)
    assert ((j3[:, 7] - j3[:, 1]).norm(dim=-1) > 0.97 * reach).all()
    cos = torch.nn.functional.cosine_similarity(j3[:, 7] - j3[:, 1], far - j[:, 1], dim=-1)
    assert (cos > 0.999).all()


def _yaw(angles: torch.Tensor) -> torch.Tensor:
    """Rotations (T, 3, 3) about z by ``angles`` (T,) radians."""
    c, s = angles.cos(), angles.sin()
    rot = torch.zeros(len(angles), 3, 3, dtype=torch.float64)
    rot[:, 0, 0], rot[:, 0, 1], rot[:, 1, 0], rot[:, 1, 1], rot[:, 2, 2] = c, -s, s, c, 1.0
    return rot


def _angle_between(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    cos = ((a.transpose(-1, -2) @ b).diagonal(dim1=-2, dim2=-1).sum(-1) - 1) / 2
    return cos.clamp(-1, 1).arccos()


def test_turn_rate_limit_makes_a_one_frame_flip_a_quick_turn():
    # facing 0 for 10 frames, then pi - 0.1 (a one-frame flip), then a slow turn within the limit
    angles = torch.cat((torch.zeros(10), torch.full((20,), math.pi - 0.1), math.pi - 0.1 + 0.2 * torch.arange(1, 11)))
    rot = _yaw(angles.double())
    limit = 0.5  # per frame
    out = limit_turn_rate(rot, limit)
    steps = _angle_between(out[:-1], out[1:])
    assert steps.max() <= limit + 1e-9
    assert torch.equal(out[:10], rot[:10])
    # it turns at the limit until it has caught up: six steps of 0.5 on frames 10-15, the last 0.04 on frame 16
    torch.testing.assert_close(steps[9:15], torch.full((6,), limit, dtype=torch.float64))
    torch.testing.assert_close(_angle_between(out[15], rot[15]), torch.tensor(math.pi - 0.1 - 3.0, dtype=torch.float64))
    torch.testing.assert_close(out[16:], rot[16:])
    # a sequence within the limit comes back exactly; given frames keep their rotation
    assert torch.equal(limit_turn_rate(rot[20:], limit), rot[20:])
    given = np.zeros(len(rot), dtype=bool)
    given[12] = True
    held = limit_turn_rate(rot, limit, given)
    assert torch.equal(held[12], rot[12]) and _angle_between(held[10], rot[9]) <= limit + 1e-9


def _pitch(angles: torch.Tensor) -> torch.Tensor:
    """Rotations (T, 3, 3) about x by ``angles`` (T,) radians, after facing 0.3 rad about z: the body's up axis
    (the root's local y) tips over."""
    c, s = angles.cos(), angles.sin()
    rot = torch.zeros(len(angles), 3, 3, dtype=torch.float64)
    rot[:, 0, 0], rot[:, 1, 1], rot[:, 1, 2], rot[:, 2, 1], rot[:, 2, 2] = 1.0, c, -s, s, c
    up = torch.tensor([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]], dtype=torch.float64)  # local y -> world z
    return rot @ _yaw(torch.full((len(angles),), 0.3, dtype=torch.float64)) @ up


def test_tilt_rate_limit_makes_a_one_frame_tumble_a_quick_lean_and_keeps_the_facing():
    # upright for 10 frames, then lying on its back (the up axis turned by pi/2 in one frame) for 20 frames
    angles = torch.cat((torch.zeros(10), torch.full((20,), math.pi / 2))).double()
    rot = _pitch(angles)
    limit = 0.5
    out = limit_tilt_rate(rot, limit)
    up_out = out[:, :, 1]
    tilt = torch.sum(up_out[:-1] * up_out[1:], dim=-1).clamp(-1, 1).arccos()
    assert tilt.max() <= limit + 1e-9
    # three steps of 0.5 on frames 10-12, then the last 0.071 on frame 13, and the model's own rotation after that
    torch.testing.assert_close(tilt[9:12], torch.full((3,), limit, dtype=torch.float64))
    torch.testing.assert_close(tilt[12], torch.tensor(math.pi / 2 - 1.5, dtype=torch.float64))
    assert torch.equal(out[:10], rot[:10]) and torch.equal(out[13:], rot[13:])
    # each limited frame is the previous one tipped over (a swing: about an axis perpendicular to its up axis),
    # so the facing is carried over; here it is the model's own (0.3 rad about z before tipping)
    for t in range(10, 13):
        swing = matrix_to_axis_angle(out[t] @ out[t - 1].transpose(0, 1))
        assert abs(float(swing @ up_out[t - 1])) < 1e-9
        torch.testing.assert_close(float(swing.norm()), limit)
    torch.testing.assert_close(out[12], _pitch(torch.tensor([1.5], dtype=torch.float64))[0])
    given = np.zeros(len(rot), dtype=bool)
    given[11] = True
    assert torch.equal(limit_tilt_rate(rot, limit, given)[11], rot[11])
    assert torch.equal(limit_tilt_rate(rot[10:], limit), rot[10:])  # no tilt at all: unchanged


def test_cleanup_limits_a_flipped_root_and_keeps_turns_of_real_dances():
    m = dance("BR")
    flipped = m.clone()
    # the whole body faces backwards on frames 60-61 (a weak model's flip): its hands jump metres in a frame
    parts_rot = flipped[60:62, 7:13].reshape(2, 3, 2)
    flipped[60:62, 7:13] = (torch.tensor([[-1.0, 0, 0], [0, -1.0, 0], [0, 0, 1.0]]) @ parts_rot).reshape(2, 6)
    assert joint_speeds(flipped).max() > 20
    out = clean_motion(flipped, FPS, 0.0)
    # the dance itself peaks at 3.8 m/s, flipped at 21.7; limited, the flip is a turn there and back: 6.9 m/s
    assert joint_speeds(m).max() < 4 and joint_speeds(out).max() < 7.5
    rot_out = joints(out)  # the root's facing turns at most 15 rad/s
    root = unpack_pose(out.double()).rotmats[:, 0]
    assert _angle_between(root[:-1], root[1:]).max() * FPS <= 15.0 + 1e-6
    assert torch.isfinite(rot_out).all()
    # the training dances' own turns are within the limit: the root rotation of a clean dance is untouched
    for genre in ("BR", "JB", "KR", "HO"):
        clean = dance(genre)
        assert torch.equal(clean_motion(clean, FPS, 0.0)[:, 7:13], clean[:, 7:13].to(torch.float32))
    with pytest.raises(ValueError, match="max_turn_rate"):
        FloorCleanup(max_turn_rate=0.0)
    with pytest.raises(ValueError, match="max_tilt_rate"):
        FloorCleanup(max_tilt_rate=float("nan"))
    assert torch.equal(clean_motion(flipped, FPS, 0.0, settings=FloorCleanup(max_turn_rate=None, max_tilt_rate=None))[:, 7:13],
                       flipped[:, 7:13])  # fmt: skip
