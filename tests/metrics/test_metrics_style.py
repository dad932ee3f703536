"""Genre classifier and style accuracy."""

import numpy as np
import pytest

from dgsdp.metrics import GenreClassifier, MetricError, MetricWarning, style_accuracy

GENRES = np.array(["gBR", "gHO", "gJB"])


def clusters(n_per_genre: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Three well separated genres in 6-d (centres 10 apart, unit noise) with very different feature scales."""
    rng = np.random.default_rng(seed)
    centres = np.array([[0.0] * 6, [10.0] * 6, [0.0, 10.0, 0.0, 10.0, 0.0, 10.0]])
    feats = np.concatenate([c + rng.normal(size=(n_per_genre, 6)) for c in centres])
    feats *= [1.0, 100.0, 0.01, 1.0, 1000.0, 1.0]
    return feats, np.repeat(GENRES, n_per_genre)


@pytest.mark.parametrize("method", ["logistic", "centroid"])
def test_separable_genres_are_recognised(method):
    gt, gt_labels = clusters(30, seed=0)
    pred, pred_labels = clusters(10, seed=1)
    assert style_accuracy(gt, gt_labels, pred, pred_labels, method=method) == 1.0
    # asking for the wrong genre (shift labels by one) is always wrong
    assert style_accuracy(gt, gt_labels, pred, np.roll(pred_labels, 10), method=method) == 0.0


def test_nearest_centroid_by_hand():
    # 1-d: mean 5, std 5 -> standardised centroids -1 (a) and +1 (b); 4 -> -0.2 (a), 6 -> +0.2 (b)
    clf = GenreClassifier(method="centroid").fit(np.array([[0.0], [0.0], [10.0], [10.0]]), ["a", "a", "b", "b"])
    np.testing.assert_array_equal(clf.predict(np.array([[4.0], [6.0], [-50.0]])), ["a", "b", "a"])
    assert clf.accuracy(np.array([[4.0], [6.0]]), ["a", "a"]) == 0.5


def test_state_round_trip_through_npz(tmp_path):
    gt, gt_labels = clusters(20, seed=2)
    clf = GenreClassifier().fit(gt, gt_labels)
    path = tmp_path / "genre_classifier.npz"
    np.savez(path, **clf.state())
    with np.load(path) as data:  # allow_pickle is False by default: the state is plain arrays
        restored = GenreClassifier.from_state(data)
    probe = np.random.default_rng(3).normal(size=(50, 6)) * gt.std(axis=0) + gt.mean(axis=0)
    np.testing.assert_array_equal(restored.predict(probe), clf.predict(probe))
    assert restored.method == "logistic"


def test_classifier_errors():
    with pytest.raises(MetricError, match="not fitted"):
        GenreClassifier().predict(np.zeros((2, 3)))
    with pytest.raises(MetricError, match="at least 2 genres"):
        GenreClassifier().fit(np.zeros((4, 3)), ["a"] * 4)
    with pytest.raises(ValueError, match="method"):
        GenreClassifier(method="svm")
    clf = GenreClassifier().fit(*clusters(5, seed=4))
    with pytest.raises(ValueError, match=r"\(N, 6\)"):
        clf.predict(np.zeros((2, 5)))
    with pytest.raises(MetricError, match="NaN"):
        clf.predict(np.full((1, 6), np.nan))
    with pytest.warns(MetricWarning, match="not seen"):
        assert clf.accuracy(np.zeros((1, 6)), ["gKR"]) == 0.0


def test_logistic_regression_beats_centroid_on_a_thin_margin():
    # Two parallel strips y = 0.1 x and y = 0.1 x + 0.5: linearly separable, but a's far end lies
    # nearer b's mean, so the nearest-centroid rule misclassifies points that the fitted boundary gets.
    rng = np.random.default_rng(0)
    xa, xb = rng.uniform(-10, 10, 100), rng.uniform(0, 30, 100)
    feats = np.concatenate([np.column_stack([xa, 0.1 * xa]), np.column_stack([xb, 0.1 * xb + 0.5])])
    labels = np.repeat(["a", "b"], 100)
    centroid = GenreClassifier(method="centroid").fit(feats, labels).accuracy(feats, labels)
    logistic = GenreClassifier(method="logistic", l2=1e-4).fit(feats, labels).accuracy(feats, labels)
    assert centroid < 0.95 and logistic > centroid + 0.04
