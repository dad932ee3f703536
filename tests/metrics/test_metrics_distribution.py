"""FID and diversity against closed forms and hand-worked cases."""

import numpy as np
import pytest

import dgsdp.metrics.distribution as distribution
from dgsdp.metrics import MetricError, MetricWarning, diversity, fid

# Four ground-truth points with mean 0 and population std 1 per dimension: normalisation is the identity.
# Their sample covariance (ddof 1) is 4/3 * I.
UNIT_GT = np.array([[-1.0, -1.0], [1.0, 1.0], [-1.0, 1.0], [1.0, -1.0]])


def exact_samples(mean: np.ndarray, cov: np.ndarray, n: int, seed: int) -> np.ndarray:
    """n samples whose sample mean and sample covariance (ddof 1) are exactly ``mean`` and ``cov``."""
    z = np.random.default_rng(seed).normal(size=(n, mean.size))
    z -= z.mean(axis=0)
    z = z @ np.linalg.inv(np.linalg.cholesky(np.cov(z, rowvar=False))).T  # sample cov -> identity
    return z @ np.linalg.cholesky(cov).T + mean


def test_fid_of_identical_sets_is_zero():
    feats = np.random.default_rng(0).normal(size=(50, 6)) * [1, 2, 3, 4, 5, 6]
    assert fid(feats, feats) == pytest.approx(0.0, abs=1e-6)


def test_fid_scaled_and_shifted_square_by_hand():
    # pred = 2 * gt + (3, 0): mean (3, 0), covariance 16/3 I; gt covariance 4/3 I.
    # FID = 9 + 8/3 + 32/3 - 2 * tr sqrt(64/9 I) = 9 + 40/3 - 32/3 = 35/3.
    assert fid(UNIT_GT, 2.0 * UNIT_GT + [3.0, 0.0]) == pytest.approx(35.0 / 3.0, rel=1e-9)


def test_fid_against_gaussian_closed_form():
    n_gt, dim = 200, 4
    gt_cov = np.diag([0.5, 2.0, 1.0, 3.0])
    gt = exact_samples(np.array([1.0, -2.0, 0.0, 5.0]), gt_cov, n_gt, seed=1)
    a = np.random.default_rng(2).normal(size=(dim, dim))
    pred_cov = a @ a.T + 0.5 * np.eye(dim)
    pred_mean = np.array([1.5, -1.0, 0.3, 4.0])
    pred = exact_samples(pred_mean, pred_cov, 60, seed=3)
    # Normalised: gt mean 0, covariance (n / (n - 1)) I; pred mean and covariance scaled by the gt pop std.
    std = np.sqrt(np.diag(gt_cov) * (n_gt - 1) / n_gt) + 1e-10
    mean_diff = (pred_mean - gt.mean(axis=0)) / std
    pred_cov_n = pred_cov / np.outer(std, std)
    c = n_gt / (n_gt - 1)
    # tr sqrtm(c I M) = sqrt(c) * sum of the square roots of M's eigenvalues
    expected = (
        mean_diff @ mean_diff
        + c * dim
        + np.trace(pred_cov_n)
        - 2 * np.sqrt(c) * np.sqrt(np.linalg.eigvalsh(pred_cov_n)).sum()
    )
    assert fid(gt, pred) == pytest.approx(expected, rel=1e-8)


def test_diversity_of_three_points_by_hand():
    # pairwise distances 3, 4, 5 -> mean 4
    points = np.array([[0.0, 0.0], [3.0, 0.0], [0.0, 4.0]])
    assert diversity(points, UNIT_GT) == pytest.approx(4.0, rel=1e-9)
    # a ground truth with std 2 per dimension halves every distance
    assert diversity(points, 2.0 * UNIT_GT + 7.0) == pytest.approx(2.0, rel=1e-9)


def test_zero_variance_ground_truth_dimension_warns():
    gt = np.column_stack([UNIT_GT, np.ones(4)])
    with pytest.warns(MetricWarning, match=r"dimension\(s\) \[2\]"):
        value = diversity(gt[:3], gt)
    assert value == pytest.approx(np.mean([2.0, 2.0, 2.0 * np.sqrt(2.0)]), rel=1e-9)


def test_fewer_dances_than_dimensions_warns_but_returns_a_number():
    rng = np.random.default_rng(4)
    gt = rng.normal(size=(100, 8))
    with pytest.warns(MetricWarning, match="singular"):
        value = fid(gt, rng.normal(size=(5, 8)))
    assert np.isfinite(value)


def test_sqrtm_retry_with_jitter(monkeypatch):
    real_sqrtm = distribution.linalg.sqrtm
    calls = []

    def flaky_sqrtm(a):
        calls.append(a.copy())
        return np.full_like(a, np.nan) if len(calls) == 1 else real_sqrtm(a)

    monkeypatch.setattr(distribution.linalg, "sqrtm", flaky_sqrtm)
    cov = np.diag([1.0, 4.0])
    with pytest.warns(MetricWarning, match="retrying"):
        value = distribution.frechet_distance(np.zeros(2), cov, np.zeros(2), cov)
    np.testing.assert_allclose(calls[1], (cov + 1e-5 * np.eye(2)) @ (cov + 1e-5 * np.eye(2)))
    # tr sqrtm((S + eps)^2) = tr S + 2 eps, so the value is -4 eps
    assert value == pytest.approx(-4e-5, abs=1e-9)


def test_imaginary_part_is_reported_and_dropped(monkeypatch):
    monkeypatch.setattr(distribution.linalg, "sqrtm", lambda a: np.eye(2) * (0.5 + 0.5j))
    with pytest.warns(MetricWarning, match="imaginary"):
        value = distribution.frechet_distance(np.zeros(2), np.eye(2), np.zeros(2), np.eye(2))
    assert value == pytest.approx(2.0)  # 2 + 2 - 2 * tr(0.5 I)


def test_bad_feature_input():
    with pytest.raises(MetricError, match="at least 2"):
        fid(UNIT_GT, UNIT_GT[:1])
    with pytest.raises(MetricError, match="at least 2"):
        diversity(UNIT_GT[:1], UNIT_GT)
    with pytest.raises(ValueError, match=r"\(N, 2\)"):
        fid(UNIT_GT, np.zeros((4, 3)))
    bad = UNIT_GT.copy()
    bad[0, 0] = np.nan
    with pytest.raises(MetricError, match="NaN"):
        fid(UNIT_GT, bad)
