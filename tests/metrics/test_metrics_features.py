"""Kinetic and geometric features: hand-worked cases, paper vs corrected, and agreement with the
frame-by-frame loop implementation written from the definitions."""

import numpy as np
import pytest

from dgsdp.benchmarks.metrics import geometric_features_loop, kinetic_features_loop
from dgsdp.metrics import (
    MetricError,
    MetricWarning,
    anchor_root,
    geometric_features,
    geometric_features_batch,
    kinetic_features,
    kinetic_features_batch,
    y_up_to_z_up,
)

PARENTS = [-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 20, 21]
REST_OFFSETS = np.array(
    [
        [0, 0, 0], [.05858135, -.08228004, -.01766408], [-.06030973, -.09051332, -.01354254],
        [.00443945, .12440352, -.03838522], [.04345142, -.38646945, .008037],
        [-.04325663, -.38368791, -.00484304], [.00448844, .1379564, .02682033],
        [-.01479032, -.42687458, -.037428], [.01905555, -.4200455, -.03456167],
        [-.00226458, .05603239, .00285505], [.04105436, -.06028581, .12204243],
        [-.03483987, -.06210566, .13032329], [-.0133902, .21163553, -.03346758],
        [.07170245, .11399969, -.01889817], [-.08295366, .11247234, -.02370739],
        [.01011321, .08893734, .05040987], [.12292141, .04520509, -.019046],
        [-.11322832, .04685326, -.00847207], [.2553319, -.01564902, -.02294649],
        [-.26012748, -.01436928, -.03126873], [.26570925, .01269811, -.00737473],
        [-.26910836, .00679372, -.00602676], [.08669055, -.01063603, -.01559429],
        [-.0887537, -.00865157, -.01010708],
    ]
)  # fmt: skip
RWRIST = 21


def rest_pose() -> np.ndarray:
    """SMPL rest pose (T-pose), y-up, root at the origin: (24, 3)."""
    pose = np.zeros((24, 3))
    for j in range(1, 24):
        pose[j] = pose[PARENTS[j]] + REST_OFFSETS[j]
    return pose


def static(pose: np.ndarray, n_frames: int) -> np.ndarray:
    return np.repeat(pose[None], n_frames, axis=0)


def random_motion(n_frames: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    steps = rng.normal(scale=0.015, size=(n_frames, 24, 3))
    return rest_pose()[None] + np.array([0.3, 0.9, -0.2]) + np.cumsum(steps, axis=0)


# ---------------------------------------------------------------- kinetic


def test_static_skeleton_kinetic_paper_energy_is_3540_times_position():
    pose = np.random.default_rng(0).normal(size=(24, 3))
    feats = kinetic_features(static(pose, 20), mode="paper").reshape(24, 3)
    np.testing.assert_allclose(feats[:, :2], 0.0, atol=1e-12)
    # v2 = 0, v1 = p - 60 p = -59 p, term = 59 p * 60 = 3540 p
    np.testing.assert_allclose(feats[:, 2], 3540.0 * np.linalg.norm(pose, axis=1), rtol=1e-12)
    at_30fps = kinetic_features(static(pose, 20), fps=30, mode="paper").reshape(24, 3)
    np.testing.assert_allclose(at_30fps[:, 2], 30.0 * 29.0 * np.linalg.norm(pose, axis=1), rtol=1e-12)


def test_static_skeleton_kinetic_corrected_is_zero():
    pose = np.random.default_rng(1).normal(size=(24, 3))
    np.testing.assert_allclose(kinetic_features(static(pose, 20), mode="corrected"), 0.0, atol=1e-9)


@pytest.mark.parametrize("fps", [60, 30])
def test_constant_velocity_kinetic_energy(fps):
    rng = np.random.default_rng(2)
    velocity_mps = rng.normal(size=(24, 3))
    t_s = np.arange(40)[:, None, None] / fps
    joints = rng.normal(size=(1, 24, 3)) + velocity_mps[None] * t_s
    feats = kinetic_features(joints, fps=fps, mode="corrected").reshape(24, 3)
    np.testing.assert_allclose(feats[:, 0], velocity_mps[:, 0] ** 2 + velocity_mps[:, 2] ** 2, rtol=1e-9)
    np.testing.assert_allclose(feats[:, 1], velocity_mps[:, 1] ** 2, rtol=1e-9)
    np.testing.assert_allclose(feats[:, 2], 0.0, atol=1e-6)


def test_three_frame_case_worked_by_hand():
    # One joint moving along x through 0, 1, 3 at 2 FPS (ft = 0.5 s); all other joints at the origin.
    joints = np.zeros((3, 24, 3))
    joints[:, 5, 0] = [0.0, 1.0, 3.0]
    # both frames' windows cover both displacements: (1 + 2) / (2 * 0.5) = 3 m/s, so KE_h = 9.
    # The only acceleration is at k = 1: v2 = 2 / 0.5 = 4; corrected v1 = 1 / 0.5 = 2 -> (4 - 2) / 0.5 = 4;
    # paper v1 = 1 - 0 / 0.5 = 1 -> (4 - 1) / 0.5 = 6.
    corrected = kinetic_features(joints, fps=2, mode="corrected").reshape(24, 3)
    paper = kinetic_features(joints, fps=2, mode="paper").reshape(24, 3)
    np.testing.assert_allclose(corrected[5], [9.0, 0.0, 4.0])
    np.testing.assert_allclose(paper[5], [9.0, 0.0, 6.0])
    np.testing.assert_allclose(np.delete(paper, 5, axis=0), 0.0)


def test_z_up_input_is_converted_before_features():
    rng = np.random.default_rng(3)
    joints_z = np.zeros((30, 24, 3)) + rng.normal(size=(24, 3))
    joints_z[:, :, 2] += 0.5 * np.arange(30)[:, None] / 60  # 0.5 m/s upwards in z-up coordinates
    feats = kinetic_features(joints_z, up_axis="z", mode="corrected").reshape(24, 3)
    np.testing.assert_allclose(feats[:, 1], 0.25, rtol=1e-9)  # vertical KE in y-up
    np.testing.assert_allclose(feats[:, 0], 0.0, atol=1e-12)
    y_up = random_motion(25, seed=4)
    for fn in (kinetic_features, geometric_features):
        np.testing.assert_allclose(fn(y_up_to_z_up(y_up), up_axis="z"), fn(y_up), rtol=1e-12, atol=1e-9)


@pytest.mark.parametrize("mode", ["paper", "corrected"])
@pytest.mark.parametrize("n_frames", [3, 4, 5, 7, 40])
def test_kinetic_matches_loop_implementation(mode, n_frames):
    joints = random_motion(n_frames, seed=n_frames)
    expected = kinetic_features_loop(joints, mode=mode)
    got = kinetic_features(joints, mode=mode)
    np.testing.assert_allclose(got, expected, rtol=1e-6, atol=1e-9)


def test_paper_and_corrected_kinetic_differ_only_in_energy():
    joints = random_motion(30, seed=5)
    paper = kinetic_features(joints, mode="paper").reshape(24, 3)
    corrected = kinetic_features(joints, mode="corrected").reshape(24, 3)
    np.testing.assert_array_equal(paper[:, :2], corrected[:, :2])
    assert np.all(np.abs(paper[:, 2] - corrected[:, 2]) > 1.0)


def test_two_frames_warn_and_zero_energy():
    joints = random_motion(2, seed=6)
    with pytest.warns(MetricWarning, match="at least 3 frames"):
        feats = kinetic_features(joints).reshape(24, 3)
    assert np.all(feats[:, 2] == 0) and np.all(np.isfinite(feats))
    np.testing.assert_allclose(feats[:, :2], kinetic_features_loop(joints).reshape(24, 3)[:, :2])


# ---------------------------------------------------------------- geometric


def test_fast_rwrist_paper_uses_120_per_second_at_60fps():
    # threshold 2.5 * 0.256838 = 0.642 m/s; 0.4 m/s at 60 FPS reads as 0.8 in paper mode.
    for speed_mps, paper_true, corrected_true in [(0.4, True, False), (0.3, False, False), (0.7, True, True)]:
        joints = static(rest_pose(), 11)
        joints[:, RWRIST, 0] += speed_mps * np.arange(11) / 60
        paper = geometric_features(joints, fps=60, mode="paper")
        corrected = geometric_features(joints, fps=60, mode="corrected")
        assert paper[12] == float(paper_true) and corrected[12] == float(corrected_true)
        assert paper[13] == 0.0 and corrected[13] == 0.0  # the left wrist stays still


def test_upright_trunk_is_not_horizontal_but_lying_is():
    upright = geometric_features(static(rest_pose(), 5))
    lying = geometric_features(static(y_up_to_z_up(rest_pose()), 5))  # rotated 90 degrees about x
    assert upright[28] == 0.0 and lying[28] == 1.0


def test_rest_pose_angles():
    feats = geometric_features(static(rest_pose(), 5))
    assert feats[6] == 0.0 and feats[7] == 0.0  # straight elbows: ~180 degrees, outside 0-110
    assert feats[19] == 0.0 and feats[20] == 0.0  # straight knees
    assert feats[23] == 1.0 and feats[24] == 1.0  # arms ~90 degrees from the trunk, inside 25-180
    assert feats[25] == 0.0 and feats[26] == 0.0  # thighs along the trunk, outside 50-180
    assert feats[31] == 0.0  # the root does not move


def test_move_feature_5_vs_6_paper_identical_corrected_by_hand():
    joints = static(rest_pose(), 9)
    joints[:, RWRIST, 1] += 1.0 * np.arange(9) / 60  # right wrist rises at 1 m/s, relative to a still chest
    paper = geometric_features(joints, mode="paper")
    corrected = geometric_features(joints, mode="corrected")
    # paper: chest relative to belly (both still) -> false for both; corrected: wrist along belly->chest
    # (about 0.99 m/s) > 1.8 * 0.256838 = 0.462 for the right wrist only.
    assert paper[4] == paper[5] == 0.0
    assert corrected[4] == 1.0 and corrected[5] == 0.0


@pytest.mark.parametrize("mode", ["paper", "corrected"])
@pytest.mark.parametrize("n_frames", [2, 3, 50])
def test_geometric_matches_loop_implementation(mode, n_frames):
    joints = random_motion(n_frames, seed=10 + n_frames)
    np.testing.assert_allclose(
        geometric_features(joints, mode=mode), geometric_features_loop(joints, mode=mode), atol=1e-12
    )


def test_geometric_paper_vs_corrected_differ_where_documented():
    joints = random_motion(300, seed=7)
    paper = geometric_features(joints, fps=30, mode="paper")
    corrected = geometric_features(joints, fps=30, mode="corrected")
    assert paper[4] == paper[5]
    assert corrected[4] != corrected[5]
    velocity_free = [2, 3, 6, 7, 8, 14, 15, 16, 17, 18, 19, 20, 23, 24, 25, 26, 27, 28, 29, 30]
    np.testing.assert_array_equal(paper[velocity_free], corrected[velocity_free])
    velocity_based = [0, 1, 4, 9, 10, 11, 12, 13, 21, 22, 31]
    assert np.any(paper[velocity_based] != corrected[velocity_based])


def test_geometric_features_are_fractions_of_frames():
    joints = static(rest_pose(), 5)
    joints[3:, RWRIST, 0] += np.array([0.0, 0.1])  # one jump of 0.1 m in frames 1..4 -> 1 of 4 frames fast
    assert geometric_features(joints)[12] == 0.25


# ---------------------------------------------------------------- batch, anchoring, bad input


def test_batches_match_single_calls_with_mixed_lengths():
    motions = [random_motion(n, seed=n) for n in (12, 20, 12, 3)]
    kin = kinetic_features_batch(motions, mode="corrected")
    geo = geometric_features_batch(motions, fps=30)
    assert kin.shape == (4, 72) and geo.shape == (4, 32)
    for n, m in enumerate(motions):
        np.testing.assert_array_equal(kin[n], kinetic_features(m, mode="corrected"))
        np.testing.assert_array_equal(geo[n], geometric_features(m, fps=30))


def test_anchor_root_moves_first_root_to_origin():
    joints = random_motion(10, seed=8)
    anchored = anchor_root(joints)
    np.testing.assert_allclose(anchored[0, 0], 0.0, atol=1e-15)
    np.testing.assert_allclose(anchored - anchored[:, :1], joints - joints[:, :1], atol=1e-12)
    np.testing.assert_allclose(anchored[5, 3], joints[5, 3] - joints[0, 0])


@pytest.mark.parametrize("fn", [kinetic_features, geometric_features])
def test_bad_input(fn):
    with pytest.raises(ValueError, match=r"\(T, 24, 3\)"):
        fn(np.zeros((10, 22, 3)))
    with pytest.raises(ValueError, match=r"\(T, 24, 3\)"):
        fn(np.zeros((24, 3)))
    with pytest.raises(MetricError, match="at least 2"):
        fn(np.zeros((1, 24, 3)))
    nan_motion = random_motion(10, seed=9)
    nan_motion[4, 7, 1] = np.nan
    with pytest.raises(MetricError, match="NaN"):
        fn(nan_motion)
    with pytest.raises(ValueError, match="mode"):
        fn(random_motion(5, seed=1), mode="fixed")
    with pytest.raises(ValueError, match="up_axis"):
        fn(random_motion(5, seed=1), up_axis="x")


@pytest.mark.slow
def test_vectorised_features_are_50x_faster_than_the_loop_with_identical_values():
    from dgsdp.benchmarks.metrics import run

    result = run(n_sequences=40, n_frames=300, n_loop=2, mode="paper")
    assert result["max_rel_diff_kinetic"] < 1e-9 and result["max_abs_diff_geometric"] == 0.0
    assert result["speedup"] >= 50
