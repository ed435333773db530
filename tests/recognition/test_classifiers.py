"""LOC classifiers on synthetic feature sets with known separability."""

from __future__ import annotations

import numpy as np
import pytest

from contactflow.recognition.classifiers import (
    ClassStats,
    IncrementalRecognizer,
    LeastSquaresClassifier,
    NearestMeanClassifier,
    NormalDensityClassifier,
    NSigmaClassifier,
    outcomes,
)


def blobs(means, sd, n, seed):
    rng = np.random.default_rng(seed)
    X = np.vstack([rng.normal(m, sd, size=(n, len(m))) for m in means])
    y = np.repeat(np.arange(len(means)), n)
    return X, y


SEPARATED = [(0.0, 0.0), (10.0, 0.0), (0.0, 10.0), (10.0, 10.0)]


@pytest.mark.parametrize("clf", [NSigmaClassifier(3), NSigmaClassifier(2), NormalDensityClassifier(),
                                 NearestMeanClassifier(), LeastSquaresClassifier()])
def test_separable_classes_are_recognised(clf):
    X, y = blobs(SEPARATED, 1.0, 80, 0)
    Xt, yt = blobs(SEPARATED, 1.0, 80, 1)
    res = outcomes(clf.fit(X, y), Xt, yt)
    assert res["wrong"] < 1.0
    floor = 85.0 if isinstance(clf, NSigmaClassifier) and clf.n == 2 else 97.0
    if isinstance(clf, LeastSquaresClassifier):
        floor = 70.0  # four classes in a square: the middle two are masked by a linear fit
    assert res["correct"] >= floor, res


def test_n_sigma_tolerance_trades_uncertain_for_wrong():
    X, y = blobs([(0.0, 0.0), (2.5, 0.0), (0.0, 2.5)], 1.0, 300, 2)
    Xt, yt = blobs([(0.0, 0.0), (2.5, 0.0), (0.0, 2.5)], 1.0, 300, 3)
    r2 = outcomes(NSigmaClassifier(2, "nearest").fit(X, y), Xt, yt)
    r3 = outcomes(NSigmaClassifier(3, "nearest").fit(X, y), Xt, yt)
    assert r3["uncertain"] < r2["uncertain"]
    assert r3["wrong"] >= r2["wrong"]
    strict = outcomes(NSigmaClassifier(3, "unknown").fit(X, y), Xt, yt)
    assert strict["wrong"] < r3["wrong"] and strict["uncertain"] > r3["uncertain"]


def test_overlapping_classes_give_unknown_not_a_forced_answer():
    X, y = blobs([(0.0, 0.0), (0.5, 0.0)], 1.0, 300, 4)
    Xt, yt = blobs([(0.0, 0.0), (0.5, 0.0)], 1.0, 200, 5)
    nd = outcomes(NormalDensityClassifier(min_posterior=0.9).fit(X, y), Xt, yt)
    assert nd["uncertain"] > 80.0 and nd["wrong"] < 10.0
    assert outcomes(NearestMeanClassifier().fit(X, y), Xt, yt)["uncertain"] == 0.0


def test_never_seen_object_and_garbage_are_unknown():
    X, y = blobs(SEPARATED, 1.0, 50, 6)
    for clf in (NormalDensityClassifier(), NSigmaClassifier(3)):
        clf.fit(X, y)
        assert clf.classify(np.array([60.0, -40.0])).label is None
        assert clf.classify(np.array([np.nan, 1.0])).label is None
    assert NormalDensityClassifier().classify(np.zeros(2)).label is None  # untrained
    with pytest.raises(ValueError, match="expected 2 features"):
        NormalDensityClassifier().fit(X, y).classify(np.zeros(3))


def test_normal_density_uses_correlation_that_axis_boxes_miss():
    rng = np.random.default_rng(7)
    t = rng.normal(0, 3, size=(400, 1))
    a = np.hstack((t, t + rng.normal(0, 0.2, (400, 1))))
    b = np.hstack((t, t + 1.5 + rng.normal(0, 0.2, (400, 1))))
    X, y = np.vstack((a, b)), np.repeat([0, 1], 400)
    t2 = rng.normal(0, 3, size=(400, 1))
    Xt = np.vstack((np.hstack((t2, t2 + rng.normal(0, 0.2, (400, 1)))),
                    np.hstack((t2, t2 + 1.5 + rng.normal(0, 0.2, (400, 1))))))
    nd = outcomes(NormalDensityClassifier().fit(X, y), Xt, y)
    ns = outcomes(NSigmaClassifier(2).fit(X, y), Xt, y)
    assert nd["correct"] > 97.0
    assert ns["correct"] < 60.0


def test_welford_statistics_match_numpy():
    X = np.random.default_rng(8).normal(size=(100, 3)) * [1, 5, 0.1]
    s = ClassStats(3)
    for x in X:
        s.add(x)
    assert np.allclose(s.mean, X.mean(axis=0))
    assert np.allclose(s.cov, np.cov(X.T))


def test_incremental_learning_updates_statistics_from_confident_answers():
    X, y = blobs(SEPARATED, 1.0, 4, 9)
    rec = IncrementalRecognizer(NormalDensityClassifier())
    rec.classifier.fit(X, y)
    n0 = sum(s.n for s in rec.classifier.stats.values())
    Xs, ys = blobs(SEPARATED, 1.0, 50, 10)
    preds = [rec.observe(x) for x in Xs]
    assert rec.learned == sum(p.label is not None for p in preds) > 150
    assert sum(s.n for s in rec.classifier.stats.values()) == n0 + rec.learned
    assert np.allclose(rec.classifier.stats[3].mean, (10, 10), atol=0.5)
    rec.observe(np.array([60.0, 60.0]))
    assert 4 not in rec.classifier.stats
    rec.observe(np.array([60.0, 60.0]), supervisor_label=4)
    assert rec.classifier.stats[4].n == 1


def test_least_squares_learns_incrementally_like_batch():
    X, y = blobs(SEPARATED[:2], 1.0, 60, 11)
    batch = LeastSquaresClassifier().fit(X, y)
    inc = LeastSquaresClassifier()
    for x, lab in zip(X, y, strict=True):
        inc.learn(x, lab)
    Xt, _ = blobs(SEPARATED[:2], 1.0, 30, 12)
    assert batch.predict(Xt) == inc.predict(Xt)
