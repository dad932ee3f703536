"""Beat alignment and PFC against hand-built motions and hand-worked numbers."""

import math

import numpy as np
import pytest

from dgsdp.metrics import (
    MetricError,
    MetricWarning,
    beat_alignment,
    beat_alignment_from_beats,
    motion_beats,
    music_beats_from_features,
    pfc,
    z_up_to_y_up,
)

PERIOD_FRAMES = 30


def periodic_dance(n_frames: int = 301) -> np.ndarray:
    """All joints translate along x with per-frame step 1.1 - cos(2 pi t / 30): speed minima at t = 30 k."""
    t = np.arange(n_frames - 1)
    steps = 1.1 - np.cos(2 * np.pi * t / PERIOD_FRAMES)
    x = np.concatenate([[0.0], np.cumsum(steps)])
    joints = np.random.default_rng(0).normal(size=(1, 24, 3)).repeat(n_frames, axis=0)
    joints[:, :, 0] += x[:, None]
    return joints


GRID = np.arange(PERIOD_FRAMES, 300 - 20, PERIOD_FRAMES)  # interior minima: 30 .. 270


@pytest.mark.parametrize("fps", [60, 30])
def test_motion_beats_on_known_grid(fps):
    np.testing.assert_array_equal(motion_beats(periodic_dance(), fps=fps), GRID)


def test_beat_alignment_exact_and_shifted():
    dance = periodic_dance()
    assert beat_alignment(dance, GRID) == pytest.approx(1.0)
    assert beat_alignment(dance, GRID, variant="fact") == pytest.approx(1.0)
    # every music beat 2 frames after a motion beat: exp(-4 / (2 * 3^2)) at 60 FPS
    assert beat_alignment(dance, GRID + 2) == pytest.approx(math.exp(-4 / 18))
    # at 30 FPS the sigma is 1.5 frames: exp(-4 / (2 * 1.5^2))
    assert beat_alignment(dance, GRID + 2, fps=30) == pytest.approx(math.exp(-4 / 4.5))


def test_music_beats_past_the_speed_curve_are_ignored():
    dance = periodic_dance()  # 301 frames: speed curve of 300 values
    assert beat_alignment(dance, np.append(GRID, [299, 300, 450])) == pytest.approx(
        (GRID.size + math.exp(-(29**2) / 18)) / (GRID.size + 1)  # 299 is kept, nearest motion beat 270
    )


def test_beat_alignment_from_beats_by_hand():
    motion, music = [10, 40], [10, 43, 70]
    assert beat_alignment_from_beats(motion, music) == pytest.approx((1 + math.exp(-9 / 18) + math.exp(-900 / 18)) / 3)
    assert beat_alignment_from_beats(motion, music, variant="fact") == pytest.approx((1 + math.exp(-9 / 18)) / 2)
    assert beat_alignment_from_beats(motion, music, fps=30) == pytest.approx(
        (1 + math.exp(-9 / 4.5) + math.exp(-900 / 4.5)) / 3
    )
    with pytest.raises(ValueError, match="variant"):
        beat_alignment_from_beats(motion, music, variant="edge")


def test_no_motion_beats_warns_and_scores_zero():
    still = np.zeros((100, 24, 3))
    assert motion_beats(still).size == 0
    with pytest.warns(MetricWarning, match="0 motion beat"):
        assert beat_alignment(still, [10, 20]) == 0.0


def test_music_beats_from_features():
    features = np.zeros((20, 35))
    features[[3, 7, 15], 34] = 1.0
    features[5, 33] = 1.0  # another column: ignored
    np.testing.assert_array_equal(music_beats_from_features(features), [3, 7, 15])
    with pytest.raises(ValueError, match=r"\(T, 35\)"):
        music_beats_from_features(np.zeros((20, 34)))


def test_beats_bad_input():
    nan_dance = periodic_dance()
    nan_dance[5, 0, 0] = np.nan
    with pytest.raises(MetricError, match="NaN"):
        motion_beats(nan_dance)
    with pytest.raises(ValueError, match=r"\(T, 24, 3\)"):
        beat_alignment(np.zeros((10, 72)), [1, 2])


# ---------------------------------------------------------------- PFC


def pfc_case() -> np.ndarray:
    """5 frames, z-up. Root rises 0.01 m between frames 1 and 2 and then stops: vertical accelerations
    (x 30^2) are +9, -9, 0 -> clamped norms 9, 0, 0 -> normalised 1, 0, 0. Per frame, the left ankle
    slides 0.02 m and the left toe 0.03 m (left = 0.02); right ankle 0.05 m, right toe 0.04 m (right = 0.04)."""
    joints = np.zeros((5, 24, 3))
    joints[:, 0, 2] = [0.0, 0.0, 0.01, 0.01, 0.01]
    frames = np.arange(5)
    joints[:, 7, 0] = 0.02 * frames
    joints[:, 10, 1] = 0.03 * frames
    joints[:, 8, 0] = 0.05 * frames
    joints[:, 11, 0] = -0.04 * frames
    joints[:, 8, 2] = 0.3 * frames  # vertical foot motion does not count
    return joints


def test_pfc_hand_worked_vertical():
    # mean(0.02 * 0.04 * [1, 0, 0]) * 10000 = 8 / 3
    assert pfc(pfc_case()) == pytest.approx(8.0 / 3.0)


def test_pfc_horizontal_acceleration_counts_in_both_directions():
    joints = pfc_case()
    joints[:, 0, 2] = 0.0
    joints[:, 0, 0] = [0.0, 0.0, 0.0, 0.01, 0.01]  # accelerations 0, +9, -9 in x -> normalised 0, 1, 1
    assert pfc(joints) == pytest.approx(16.0 / 3.0)


def test_pfc_downward_acceleration_alone_is_clamped():
    joints = pfc_case()
    joints[:, 0, 2] = [0.0, 0.0, 0.0, -0.01, -0.01]  # accelerations 0, -9, +9 in z -> clamped 0, 0, 9
    assert pfc(joints) == pytest.approx(0.0008 / 3 * 10000)


def test_pfc_y_up_input_and_fps():
    joints = pfc_case()
    assert pfc(z_up_to_y_up(joints), up_axis="y") == pytest.approx(8.0 / 3.0)
    # the acceleration is normalised by its maximum, so the frame rate cancels
    assert pfc(joints, fps=60) == pytest.approx(8.0 / 3.0)


def test_pfc_without_root_acceleration_warns_and_scores_zero():
    joints = pfc_case()
    joints[:, 0, 2] = 0.0
    with pytest.warns(MetricWarning, match="never accelerates"):
        assert pfc(joints) == 0.0
    # constant velocity with rounding noise in the positions (0.01 m steps are not exact in binary)
    joints[:, 0] = np.arange(5)[:, None] * [0.01, 0.0, 0.0] + [0.3, 0.7, 0.0]
    assert np.abs(np.diff(joints[:, 0, 0], 2)).max() > 0
    with pytest.warns(MetricWarning, match="never accelerates"):
        assert pfc(joints.astype(np.float32)) == 0.0
    with pytest.raises(MetricError, match="at least 3"):
        pfc(joints[:2])
