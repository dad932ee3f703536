"""Style accuracy: a genre classifier fitted on ground-truth dance features, applied to generated dances.

None of the papers measures whether a dance shows the requested style; this gives a number to report
next to the others. The classifier is linear on standardised features (kinetic + geometric, or any
per-dance features) and its whole state is a handful of numpy arrays, so it can be saved with
``np.savez(path, **clf.state())`` and restored with ``GenreClassifier.from_state(np.load(path))``.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping

import numpy as np
from scipy.optimize import minimize
from scipy.special import logsumexp

from dgsdp.metrics._common import MetricError, MetricWarning, check_choice

CLASSIFIER_METHODS = ("logistic", "centroid")
_STATE_KEYS = ("method", "classes", "mean", "scale", "weights", "bias")


class GenreClassifier:
    """Linear genre classifier on standardised features.

    ``method="logistic"`` (default): multinomial logistic regression with an L2 penalty ``l2`` on the
    weights, fitted by L-BFGS. ``method="centroid"``: nearest class mean (Euclidean, standardised space),
    written as the equivalent linear rule score_k = x . c_k - |c_k|^2 / 2.
    """

    def __init__(self, method: str = "logistic", l2: float = 1e-2, max_iter: int = 500) -> None:
        self.method = check_choice(method, CLASSIFIER_METHODS, "method")
        self.l2 = float(l2)
        self.max_iter = int(max_iter)
        self.classes: np.ndarray | None = None  # (K,)
        self.mean: np.ndarray | None = None  # (D,)
        self.scale: np.ndarray | None = None  # (D,)
        self.weights: np.ndarray | None = None  # (D, K)
        self.bias: np.ndarray | None = None  # (K,)

    def _standardise(self, features: np.ndarray) -> np.ndarray:
        arr = np.asarray(features, dtype=np.float64)
        if arr.ndim != 2 or arr.shape[1] != self.mean.shape[0]:
            raise ValueError(f"features must have shape (N, {self.mean.shape[0]}); got {arr.shape}.")
        if not np.isfinite(arr).all():
            raise MetricError("features contain NaN or infinite values; recompute the features of those dances.")
        return (arr - self.mean) / self.scale

    def fit(self, features: np.ndarray, labels: np.ndarray) -> GenreClassifier:
        """Fit on ground-truth features (N, D) and genre labels (N,) with at least two distinct genres."""
        x = np.asarray(features, dtype=np.float64)
        y = np.asarray(labels).reshape(-1)
        if x.ndim != 2 or x.shape[0] != y.shape[0]:
            raise ValueError(f"features must have shape (N, D) with N = len(labels) = {y.shape[0]}; got {x.shape}.")
        if not np.isfinite(x).all():
            raise MetricError("features contain NaN or infinite values; recompute the features of those dances.")
        self.classes, y_index = np.unique(y, return_inverse=True)
        if self.classes.size < 2:
            raise MetricError(f"the classifier needs at least 2 genres in the labels; got {self.classes.tolist()}.")
        self.mean = x.mean(axis=0)
        std = x.std(axis=0)
        self.scale = np.where(std > 0, std, 1.0)  # constant features stay at 0 after centring
        z = (x - self.mean) / self.scale
        one_hot = np.eye(self.classes.size)[y_index]  # (N, K)
        centroids = (one_hot.T @ z) / one_hot.sum(axis=0)[:, None]  # (K, D)
        self.weights = centroids.T.copy()
        self.bias = -0.5 * np.sum(centroids**2, axis=1)
        if self.method == "logistic":
            self._fit_logistic(z, one_hot)
        return self

    def _fit_logistic(self, z: np.ndarray, one_hot: np.ndarray) -> None:
        """Minimise mean cross-entropy + l2 / 2 * |W|^2, starting from the nearest-centroid rule."""
        n, d = z.shape
        k = one_hot.shape[1]

        def loss_and_grad(params: np.ndarray) -> tuple[float, np.ndarray]:
            w, b = params[: d * k].reshape(d, k), params[d * k :]
            logits = z @ w + b
            log_prob = logits - logsumexp(logits, axis=1, keepdims=True)
            loss = -np.sum(one_hot * log_prob) / n + 0.5 * self.l2 * np.sum(w**2)
            residual = (np.exp(log_prob) - one_hot) / n  # (N, K)
            grad_w = z.T @ residual + self.l2 * w
            return loss, np.concatenate([grad_w.ravel(), residual.sum(axis=0)])

        start = np.concatenate([self.weights.ravel(), self.bias])
        result = minimize(loss_and_grad, start, jac=True, method="L-BFGS-B", options={"maxiter": self.max_iter})
        self.weights = result.x[: d * k].reshape(d, k)
        self.bias = result.x[d * k :]

    def _require_fitted(self) -> None:
        if self.weights is None:
            raise MetricError("the genre classifier is not fitted; call fit() or load a saved state first.")

    def predict(self, features: np.ndarray) -> np.ndarray:
        """Genre labels (M,) for features (M, D)."""
        self._require_fitted()
        scores = self._standardise(features) @ self.weights + self.bias
        return self.classes[np.argmax(scores, axis=1)]

    def accuracy(self, features: np.ndarray, labels: np.ndarray) -> float:
        """Fraction of dances (M, D) whose predicted genre equals ``labels`` (M,)."""
        y = np.asarray(labels).reshape(-1)
        predicted = self.predict(features)
        if predicted.shape[0] != y.shape[0]:
            raise ValueError(f"got {predicted.shape[0]} feature rows but {y.shape[0]} labels.")
        if y.size == 0:
            raise MetricError("style accuracy needs at least one dance; got none.")
        unknown = np.setdiff1d(y, self.classes)
        if unknown.size:
            warnings.warn(
                f"labels {unknown.tolist()} were not seen in training and always count as wrong.",
                MetricWarning,
                stacklevel=2,
            )
        return float(np.mean(predicted == y))

    def state(self) -> dict[str, np.ndarray]:
        """Plain numpy arrays describing the fitted classifier (for ``np.savez``)."""
        self._require_fitted()
        return {
            "method": np.array(self.method),
            "classes": self.classes,
            "mean": self.mean,
            "scale": self.scale,
            "weights": self.weights,
            "bias": self.bias,
        }

    @classmethod
    def from_state(cls, state: Mapping[str, np.ndarray]) -> GenreClassifier:
        """Rebuild a fitted classifier from :meth:`state` (or the ``np.load`` of its ``.npz``)."""
        missing = [key for key in _STATE_KEYS if key not in state]
        if missing:
            raise MetricError(f"genre classifier state lacks {missing}; save it with np.savez(path, **clf.state()).")
        clf = cls(method=str(state["method"]))
        for key in _STATE_KEYS[1:]:
            setattr(clf, key, np.asarray(state[key]))
        return clf


def style_accuracy(
    gt_features: np.ndarray,
    gt_labels: np.ndarray,
    pred_features: np.ndarray,
    pred_labels: np.ndarray,
    method: str = "logistic",
) -> float:
    """Fit a :class:`GenreClassifier` on ground truth (N, D) + (N,), return its accuracy on generated
    dances (M, D) against the genres they were asked to show (M,)."""
    return GenreClassifier(method=method).fit(gt_features, gt_labels).accuracy(pred_features, pred_labels)
