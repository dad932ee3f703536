"""Distribution metrics on per-sequence features: FID and diversity (Bailando's protocol).

Both normalise features with the ground-truth set's mean and population standard deviation, so that
every feature dimension counts on the same scale.
"""

from __future__ import annotations

import warnings

import numpy as np
from scipy import linalg
from scipy.spatial.distance import pdist

from dgsdp.metrics._common import MetricError, MetricWarning

NORMALISE_EPS = 1e-10
SQRTM_JITTER = 1e-5
IMAGINARY_TOLERANCE = 1e-3


def _check_features(features: np.ndarray, name: str, min_rows: int, dim: int | None = None) -> np.ndarray:
    """Return ``features`` as float64 (N, D) after checking shape, finiteness and the number of rows."""
    arr = np.asarray(features, dtype=np.float64)
    if arr.ndim != 2 or (dim is not None and arr.shape[1] != dim):
        expected = f"(N, {dim})" if dim is not None else "(N, D)"
        raise ValueError(f"{name} must have shape {expected} (one feature row per dance); got {arr.shape}.")
    if arr.shape[0] < min_rows:
        raise MetricError(f"{name} has {arr.shape[0]} row(s); this metric needs at least {min_rows} dances.")
    if not np.isfinite(arr).all():
        raise MetricError(f"{name} contains NaN or infinite values; recompute the features of those dances.")
    return arr


def normalise_features(gt_features: np.ndarray, *others: np.ndarray) -> list[np.ndarray]:
    """Scale ``gt_features`` (N, D) and each of ``others`` (M, D) by the ground truth's statistics.

    x -> (x - mean_gt) / (std_gt + 1e-10), population std (ddof 0) as in the reference. Ground-truth
    dimensions with zero variance are kept (reference arithmetic) but trigger a MetricWarning, because
    any generated value differing there is blown up by 1e10.
    """
    mean = gt_features.mean(axis=0)
    std = gt_features.std(axis=0)
    constant = np.nonzero(std == 0)[0]
    if constant.size:
        warnings.warn(
            f"ground-truth feature dimension(s) {constant.tolist()} have zero variance; any difference in "
            "them dominates FID and diversity. Use more ground-truth dances or drop those dimensions.",
            MetricWarning,
            stacklevel=3,
        )
    return [(x - mean) / (std + NORMALISE_EPS) for x in (gt_features, *others)]


def frechet_distance(mu1: np.ndarray, cov1: np.ndarray, mu2: np.ndarray, cov2: np.ndarray) -> float:
    """Frechet distance between Gaussians: |mu1 - mu2|^2 + tr(S1) + tr(S2) - 2 tr sqrtm(S1 S2).

    mu: (D,), cov: (D, D). If sqrtm is not finite, 1e-5 * I is added to both covariances and it is
    retried. The real part is used; an imaginary part above 1e-3 is reported with a MetricWarning.
    """
    diff = mu1 - mu2
    covmean = linalg.sqrtm(cov1 @ cov2)
    if not np.isfinite(covmean).all():
        warnings.warn(
            f"sqrtm of the covariance product is not finite; retrying with {SQRTM_JITTER} added to the diagonals.",
            MetricWarning,
            stacklevel=2,
        )
        offset = np.eye(cov1.shape[0]) * SQRTM_JITTER
        covmean = linalg.sqrtm((cov1 + offset) @ (cov2 + offset))
    if np.iscomplexobj(covmean):
        imaginary = float(np.max(np.abs(covmean.imag)))
        if imaginary > IMAGINARY_TOLERANCE:
            warnings.warn(
                f"sqrtm of the covariance product has an imaginary part up to {imaginary:.3g}; "
                "using the real part (the FID value is numerically unreliable).",
                MetricWarning,
                stacklevel=2,
            )
        covmean = covmean.real
    return float(diff @ diff + np.trace(cov1) + np.trace(cov2) - 2.0 * np.trace(covmean))


def fid(gt_features: np.ndarray, pred_features: np.ndarray) -> float:
    """FID between generated and ground-truth feature sets, after ground-truth normalisation.

    gt_features: (N_gt, D), pred_features: (N_pred, D), both with at least 2 rows. Covariances use
    ddof = 1. Fewer generated dances than dimensions make the covariance singular: the value is still
    returned but with a MetricWarning, since it then depends strongly on the sample.
    """
    gt = _check_features(gt_features, "gt_features", min_rows=2)
    pred = _check_features(pred_features, "pred_features", min_rows=2, dim=gt.shape[1])
    for name, arr in (("generated", pred), ("ground-truth", gt)):
        if arr.shape[0] <= arr.shape[1]:
            warnings.warn(
                f"{arr.shape[0]} {name} dances for {arr.shape[1]} feature dimensions: the covariance is "
                "singular and FID is unreliable; use more dances.",
                MetricWarning,
                stacklevel=2,
            )
    gt_n, pred_n = normalise_features(gt, pred)
    return frechet_distance(
        pred_n.mean(axis=0), np.cov(pred_n, rowvar=False), gt_n.mean(axis=0), np.cov(gt_n, rowvar=False)
    )


def diversity(features: np.ndarray, gt_features: np.ndarray) -> float:
    """Mean Euclidean distance over all unordered pairs of ``features`` (N, D), N >= 2, after normalising
    them with the statistics of ``gt_features`` (N_gt, D)."""
    gt = _check_features(gt_features, "gt_features", min_rows=1)
    feats = _check_features(features, "features", min_rows=2, dim=gt.shape[1])
    _, feats_n = normalise_features(gt, feats)
    return float(pdist(feats_n).mean())
