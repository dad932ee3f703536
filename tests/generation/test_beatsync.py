"""Beat sync: a dance whose pauses lie off the beats comes out with its pauses on them, within the limits."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from dgsdp.generation.beatsync import BeatSync, beat_anchors, resample, sync_to_beats, warp_times
from dgsdp.metrics.beats import beat_alignment, kinematic_speed, motion_beats
from dgsdp.motion import pack_pose, pose_to_joints

FPS = 30.0
PERIOD = 15  # frames per beat (120 BPM)


def walking_with_pauses(pauses: np.ndarray, n_frames: int) -> torch.Tensor:
    """A standing body gliding along x, 0.5 m per stroke, that stops dead at each time in ``pauses`` (frames):
    within a stroke the speed follows 1 - cos, so the joint speed's only minima are the pauses."""
    t = np.arange(n_frames, dtype=np.float64)
    k = np.clip(np.searchsorted(pauses, t, side="right") - 1, 0, len(pauses) - 2)
    u = np.clip((t - pauses[k]) / (pauses[k + 1] - pauses[k]), 0.0, 1.0)
    x = 0.5 * (k + u - np.sin(2 * np.pi * u) / (2 * np.pi))
    trans = torch.zeros(n_frames, 3, dtype=torch.float64)
    trans[:, 0] = torch.from_numpy(x)
    trans[:, 2] = 0.9
    rotmats = torch.eye(3, dtype=torch.float64).expand(n_frames, 24, 3, 3)
    return pack_pose(torch.ones(n_frames, 4, dtype=torch.float64), trans, rotmats)


def test_pauses_a_few_frames_off_the_beat_are_moved_onto_it():
    n = 300
    beats = np.arange(20, 280, PERIOD)
    pauses = np.concatenate([[5.5 - PERIOD], beats + 3.5, [n + 3.5]]).astype(np.float64)  # 3.5 frames late
    motion = walking_with_pauses(pauses, n)
    joints = pose_to_joints(motion).numpy()
    before = motion_beats(joints, fps=FPS)
    assert len(before) == len(beats)  # one kinematic beat per pause, off the music beat
    assert np.all(before[1:-1] == beats[1:-1] + 3)  # speed entry t lies between frames t and t + 1

    synced = sync_to_beats(motion, beats, FPS)
    assert synced.shape == motion.shape
    after = motion_beats(pose_to_joints(synced).numpy(), fps=FPS)
    for b in beats:
        assert np.abs(after - b).min() <= 1, f"no kinematic beat within a frame of the music beat {b}"
    score_before = beat_alignment(joints, beats, fps=FPS)
    score_after = beat_alignment(pose_to_joints(synced).numpy(), beats, fps=FPS)
    assert score_after > score_before + 0.3


def test_anchors_pick_the_deepest_dip_within_reach_and_keep_the_rate_limits():
    beats = np.array([30, 45, 60, 75, 90])
    speed = np.ones(120)
    for b in beats:  # a shallow dip 1 frame after each beat and a deep one 3 frames before
        speed[b + 1] = 0.8
        speed[b - 3] = 0.1
    got_beats, sources = beat_anchors(speed, beats)
    np.testing.assert_array_equal(got_beats, beats)
    np.testing.assert_array_equal(sources, beats - 3)
    # a dip beyond a quarter beat (3.75 frames) is out of reach: only the shallow ones remain
    speed = np.ones(120)
    for b in beats:
        speed[b + 1] = 0.8
        speed[b - 5] = 0.1
    _, sources = beat_anchors(speed, beats)
    np.testing.assert_array_equal(sources, beats + 1)


def test_the_warp_never_runs_faster_or_slower_than_the_limit():
    rng = np.random.default_rng(0)
    beats = np.cumsum(rng.integers(12, 18, size=40)) + 10
    speed = rng.uniform(0.2, 1.0, size=int(beats[-1]) + 20)  # many random dips: anchors fight over them
    settings = BeatSync(max_rate=1.25)
    got_beats, sources = beat_anchors(speed, beats, settings)
    assert len(got_beats) > len(beats) // 2
    assert np.all(np.abs(sources - got_beats) <= settings.max_shift_beats * 18)
    times = warp_times(len(speed), got_beats, sources)
    assert times[0] >= 0 and times[-1] <= len(speed) - 1
    slopes = np.diff(times)
    inside = (np.arange(len(slopes)) >= got_beats[0]) & (np.arange(len(slopes)) < got_beats[-1])
    assert np.all(slopes[inside] >= 1 / 1.25 - 1e-9) and np.all(slopes[inside] <= 1.25 + 1e-9)


def test_resample_interpolates_between_neighbouring_frames():
    x = torch.arange(10, dtype=torch.float64)[:, None].expand(10, 3)
    out = resample(x, np.array([0.0, 0.25, 4.5, 9.0]))
    np.testing.assert_allclose(out[:, 0].numpy(), [0.0, 0.25, 4.5, 9.0])


def test_edits_short_dances_and_songs_without_beats_are_left_alone():
    motion = walking_with_pauses(np.array([-10.0, 22, 37, 52, 67, 90]), 80)
    beats = np.array([20, 35, 50, 65])
    assert torch.equal(sync_to_beats(motion, beats, FPS, mask=torch.zeros_like(motion)), motion)
    assert torch.equal(sync_to_beats(motion, np.array([40]), FPS), motion)
    assert torch.equal(sync_to_beats(motion[:2], beats, FPS), motion[:2])
    batch = torch.stack([motion, motion])
    assert torch.equal(sync_to_beats(batch, beats, FPS)[1], sync_to_beats(motion, beats, FPS))
    with pytest.raises(ValueError, match="151"):
        sync_to_beats(motion[:, :10], beats, FPS)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"max_shift_beats": 0.0},
        {"max_shift_beats": 0.6},
        {"max_rate": 1.0},
        {"rate_penalty": -1.0},
        {"max_shift_beats": 0.5, "max_skip": 1},
    ],
)
def test_bad_settings_are_refused(kwargs):
    with pytest.raises(ValueError):
        BeatSync(**kwargs)


def test_kinematic_speed_is_the_curve_of_the_beats():
    joints = pose_to_joints(walking_with_pauses(np.array([-5.0, 20, 40, 60, 90]), 80)).numpy()
    v = kinematic_speed(joints, fps=FPS)
    minima = np.nonzero((v[1:-1] < v[:-2]) & (v[1:-1] < v[2:]))[0] + 1
    np.testing.assert_array_equal(minima, motion_beats(joints, fps=FPS))


def test_a_retime_that_loses_the_other_trackers_beat_is_not_kept():
    """The dance pauses on beat set B (what a second tracker hears); the beats it is aligned to, A, lie 3 frames
    later (a tracker off by a fifth of a beat). The retime moves the pauses onto A: better on A, worse on B. Judged
    by A alone it is kept; judged by A and B (``check_beats``) the model's own timing is kept, and the stats say
    so. A retime that helps on both sets is kept."""
    from dgsdp.generation.beatsync import retime_helps, timing_margins

    n = 300
    b = np.arange(20, 280, PERIOD)
    a = b + 3
    motion = walking_with_pauses(np.concatenate([[5.0 - PERIOD], b, [n + 5.0]]).astype(np.float64), n)
    stats: list[dict] = []
    alone = sync_to_beats(motion, a, FPS, stats=stats)
    assert stats[-1]["retimed"] == 1.0 and stats[-1]["judged_beat_sets"] == 1.0
    assert not torch.equal(alone, motion)
    joints, moved = (pose_to_joints(m).numpy() for m in (motion, alone))
    before, after = timing_margins(joints, [a, b], FPS), timing_margins(moved, [a, b], FPS)
    assert (after[:2] > before[:2]).all() and (after[2:] < before[2:]).all()  # better on A, worse on B
    kept = sync_to_beats(motion, a, FPS, stats=stats, check_beats=[b])
    assert torch.equal(kept, motion)
    assert stats[-1] == {**stats[-1], "retimed": 0.0, "judged_beat_sets": 2.0, "mean_shift_ms": 0.0}
    assert torch.equal(sync_to_beats(motion, a, FPS, settings=BeatSync(judge=False), check_beats=[b]), alone)
    # pauses half-way between: a retime onto A that B agrees with is kept
    late = walking_with_pauses(np.concatenate([[5.0 - PERIOD], a + 2.5, [n + 5.0]]).astype(np.float64), n)
    helped = sync_to_beats(late, a, FPS, stats=stats, check_beats=[a + 1])
    assert stats[-1]["retimed"] == 1.0 and not torch.equal(helped, late)
    assert retime_helps(np.array([0.1, 0.2]), np.array([0.1, 0.3])) and not retime_helps(
        np.array([0.1]), np.array([0.1])
    )
    assert not retime_helps(np.array([0.1, np.nan]), np.array([0.09, 0.5]))


def test_a_dance_says_which_timing_beat_sync_kept():
    from dgsdp.generation import Dance

    motion = torch.zeros(2, 10, 151)
    judged = {"beats": 4.0, "anchored_beats": 3.0, "judged_beat_sets": 2.0}
    assert Dance(motion, 30, finishing=[{**judged, "retimed": 1.0}] * 2).notes() == [
        "beat sync: retimed onto the song's beats"
    ]
    [note] = Dance(motion, 30, finishing=[{**judged, "retimed": 1.0}, {**judged, "retimed": 0.0}]).notes()
    assert note.startswith("beat sync: the model's own timing kept in 1 of 2 dances")
    assert Dance(motion, 30, finishing=[{"beats": 4.0, "judged_beat_sets": 0.0}]).notes() == []  # beat sync off


def bouncing_walk(seed: int, n: int = 300) -> tuple[torch.Tensor, np.ndarray, np.ndarray]:
    """The walking body with its pauses up to 2 frames off the beats (120 BPM) and its root bouncing 10 cm at a
    random rate, with another tracker's beats off by up to 2 frames: (motion, beats, the other tracker's beats).
    The floor cleanup puts the bouncing root back on the floor, which moves the speed dips."""
    rng = np.random.default_rng(seed)
    beats = np.arange(20, 280, PERIOD)
    pauses = beats + rng.uniform(-2, 2, len(beats))
    motion = walking_with_pauses(np.concatenate([[pauses[0] - PERIOD], pauses, [n + 5.0]]), n)
    t = np.arange(n)
    motion[:, 6] += torch.from_numpy(0.1 * np.sin(2 * np.pi * t / rng.uniform(8, 20) + rng.uniform(0, 2 * np.pi)))
    return motion.float(), beats, beats + rng.integers(-2, 3)


def test_the_judge_decides_on_the_finished_dance():
    """The floor cleanup runs after the retime and moves the pauses too, so the judge decides on the finished dances:
    over 12 bouncing walks, the finished dance (DanceGenerator.finish, the floor cleanup on the floor at 0) is the
    cleaned retime where the stats say it was kept, else the cleaned raw dance; on every judged margin (BAS minus
    the half-beat-shifted copy's, both variants, both beat sets) it is no lower than the cleaned raw dance's or no
    lower than the raw dance's; it lies below the raw dance only where both cleaned timings do, and the stats and
    the notes say on how many margins and by how much. (Judged before the cleanup, seeds 0 and 7 fell below both.)"""
    from types import SimpleNamespace

    from dgsdp.generation import Dance, DanceGenerator
    from dgsdp.metrics.beats import beat_scores
    from dgsdp.motion import SMPL24, clean_motion

    def margins(motion: torch.Tensor, beat_sets: list[np.ndarray]) -> np.ndarray:
        joints = pose_to_joints(motion.double()).numpy()
        scores = [beat_scores(joints, b, fps=FPS, variant=v) for b in beat_sets for v in ("bas", "bas_edge")]
        return np.array([s.bas - s.shifted for s in scores])

    generator = SimpleNamespace(fps=30, floor_height=0.0, skeleton=SMPL24)  # what finish reads of a generator
    seen = set()
    for seed in range(12):
        motion, beats, other = bouncing_walk(seed)
        stats: list[dict] = []
        finished = DanceGenerator.finish(generator, motion[None], beats, stats=stats, check_beats=[other])[0]
        own = clean_motion(motion, FPS, 0.0)
        retimed = clean_motion(sync_to_beats(motion, beats, FPS, settings=BeatSync(judge=False)), FPS, 0.0)
        raw_m, own_m, new_m, got = (margins(m, [beats, other]) for m in (motion, own, retimed, finished))
        assert (got >= own_m - 1e-9).all() or (got >= raw_m - 1e-9).all(), f"seed {seed}: {got} {own_m} {raw_m}"
        below = int((got < raw_m - 1e-9).sum())
        if below:  # the cleanup's own doing: no timing avoided it
            assert (own_m < raw_m - 1e-9).any() and (new_m < raw_m - 1e-9).any()
        kept = stats[0]["retimed"] == 1.0
        torch.testing.assert_close(finished, retimed if kept else own, atol=1e-6, rtol=0)
        assert stats[0]["below_raw_margins"] == below and stats[0]["judged_beat_sets"] == 2
        assert stats[0]["below_raw_by"] == pytest.approx(max(0.0, (raw_m - got).max()), abs=1e-12)
        assert "foot_locked_frames" in stats[0]  # the cleanup's stats of the dance returned
        notes = Dance(finished[None], 30, raw=motion[None], finishing=stats).notes()
        assert notes[0].startswith("beat sync: retimed" if kept else "beat sync: the model's own timing kept")
        said = f"on {below} of 4 judged beat scores, by up to {max(0.0, (raw_m - got).max()):.3f}"
        assert any("the floor cleanup moved the pauses" in n and said in n for n in notes) == (below > 0)
        seen.add((kept, below > 0))
    assert {(True, False), (False, False), (False, True)} <= seen  # each outcome was tested
