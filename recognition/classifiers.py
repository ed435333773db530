"""LOC object recognition classifiers (thesis §8.5.3, Tables 8.2-8.3), all incremental.

* :class:`NSigmaClassifier`: the probabilistic linear classifier of eq. 8.5; an object
  matches when every feature lies within µ ± nσ of it. One match is an answer; none, or
  several when ``ambiguous="unknown"``, is "uncertain".
* :class:`NormalDensityClassifier`: a Gaussian per object (full, shrunk covariance);
  answers only when the posterior is high and the sample is not an outlier of the class.
* :class:`NearestMeanClassifier` and :class:`LeastSquaresClassifier`: the PRTools
  baselines of Table 8.3 (nearest mean in raw feature units; linear least squares on
  one-hot targets).

Every classifier learns incrementally (``learn``), keeping sufficient statistics only
(counts, means, scatter), never the samples. ``predict`` returns ``None`` for "unknown".
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.stats import chi2

UNKNOWN = None


@dataclass
class Prediction:
    label: Any | None  # None means "unknown": the classifier will not answer
    confidence: float  # in [0, 1]
    scores: dict[Any, float]


class ClassStats:
    """Running count, mean and scatter matrix of one class (Welford's update)."""

    def __init__(self, dim: int) -> None:
        self.n = 0
        self.mean = np.zeros(dim)
        self.scatter = np.zeros((dim, dim))

    def add(self, x: np.ndarray) -> None:
        self.n += 1
        delta = x - self.mean
        self.mean = self.mean + delta / self.n
        self.scatter += np.outer(delta, x - self.mean)

    @property
    def cov(self) -> np.ndarray:
        return self.scatter / max(self.n - 1, 1)

    @property
    def std(self) -> np.ndarray:
        return np.sqrt(np.maximum(np.diag(self.cov), 0.0))


class _Incremental:
    """Shared bookkeeping: per-class statistics, input checks, batch helpers."""

    def __init__(self) -> None:
        self.stats: dict[Any, ClassStats] = {}
        self.dim: int | None = None

    @property
    def classes(self) -> list[Any]:
        return list(self.stats)

    def _check(self, x: np.ndarray, where: str) -> np.ndarray:
        x = np.asarray(x, float).reshape(-1)
        if self.dim is not None and x.shape != (self.dim,):
            raise ValueError(f"{type(self).__name__}.{where}: expected {self.dim} features, got {x.shape[0]}")
        return x

    def learn(self, x: np.ndarray, label: Any) -> None:
        """Add one labelled sample; non-finite samples are ignored."""
        x = self._check(x, "learn")
        self.dim = x.shape[0]
        if not np.isfinite(x).all():
            return
        self.stats.setdefault(label, ClassStats(self.dim)).add(x)
        self._changed()

    def _changed(self) -> None:
        """Hook: invalidate cached models after learning."""

    def fit(self, X: np.ndarray, y) -> _Incremental:
        X = np.asarray(X, float)
        if X.ndim != 2 or len(X) != len(y):
            raise ValueError(f"{type(self).__name__}.fit: X {X.shape} and {len(y)} labels do not match")
        self.stats, self.dim = {}, X.shape[1]
        for x, lab in zip(X, y, strict=True):
            self.learn(x, lab)
        return self

    def predict_one(self, x: np.ndarray) -> Prediction:
        raise TypeError(f"{type(self).__name__} does not implement predict_one")

    def classify(self, x: np.ndarray) -> Prediction:
        """Prediction for one sample; garbage (NaN) or an untrained classifier gives unknown."""
        x = self._check(x, "classify")
        if not self.stats or not np.isfinite(x).all():
            return Prediction(UNKNOWN, 0.0, {})
        return self.predict_one(x)

    def predict(self, X: np.ndarray) -> list[Any | None]:
        return [self.classify(x).label for x in np.asarray(X, float)]


class NSigmaClassifier(_Incremental):
    """Eq. 8.5: x matches class i when µi - nσi <= x <= µi + nσi for every feature."""

    def __init__(self, n: float = 2.0, ambiguous: str = "unknown", min_sigma: float = 1e-9) -> None:
        super().__init__()
        if ambiguous not in ("unknown", "nearest"):
            raise ValueError(f"NSigmaClassifier.ambiguous: {ambiguous!r} is not 'unknown' or 'nearest'")
        self.n, self.ambiguous, self.min_sigma = n, ambiguous, min_sigma

    def predict_one(self, x: np.ndarray) -> Prediction:
        labels = self.classes
        mu = np.array([self.stats[k].mean for k in labels])
        sd = np.maximum(np.array([self.stats[k].std for k in labels]), self.min_sigma)
        z = np.abs(x - mu) / sd  # (classes, features)
        worst = z.max(axis=1)
        match = np.flatnonzero(worst <= self.n)
        scores = {k: float(w) for k, w in zip(labels, worst, strict=True)}
        if len(match) == 0 or (len(match) > 1 and self.ambiguous == "unknown"):
            return Prediction(UNKNOWN, 0.0, scores)
        k = match[np.argmin(worst[match])]
        return Prediction(labels[k], float(1.0 - worst[k] / self.n) if self.n > 0 else 0.0, scores)


class NormalDensityClassifier(_Incremental):
    """Gaussian class densities with shrunk full covariances and equal priors.

    Answers "unknown" when the best posterior is below ``min_posterior`` or the sample
    lies outside the ``outlier`` quantile of the chosen class (a never-seen object).
    """

    def __init__(self, shrinkage: float = 0.0, min_posterior: float = 0.9, outlier: float = 0.9999,
                 rel_floor: float = 1e-3) -> None:
        super().__init__()
        self.shrinkage, self.min_posterior, self.outlier, self.rel_floor = shrinkage, min_posterior, outlier, rel_floor
        self._model: tuple | None = None

    def _changed(self) -> None:
        self._model = None

    def _build(self) -> tuple:
        labels = self.classes
        pooled = sum((s.scatter for s in self.stats.values()), np.zeros((self.dim, self.dim)))
        npool = max(sum(s.n for s in self.stats.values()) - len(labels), 1)
        pooled = pooled / npool
        scale = np.abs(np.array([s.mean for s in self.stats.values()])).mean(axis=0)
        floor = np.diag((self.rel_floor * np.maximum(scale, 1e-9)) ** 2)
        means, precs, logdets = [], [], []
        for k in labels:
            s = self.stats[k]
            # few samples: lean on the pooled covariance; many: trust the class's own
            w = s.n / (s.n + self.dim + 1.0)
            cov = w * s.cov + (1 - w) * pooled
            cov = (1 - self.shrinkage) * cov + self.shrinkage * np.diag(np.diag(cov)) + floor
            sign, logdet = np.linalg.slogdet(cov)
            means.append(s.mean)
            precs.append(np.linalg.inv(cov))
            logdets.append(logdet)
        self._model = (labels, np.array(means), np.array(precs), np.array(logdets),
                       chi2.ppf(self.outlier, self.dim))
        return self._model

    def predict_one(self, x: np.ndarray) -> Prediction:
        labels, means, precs, logdets, limit = self._model or self._build()
        d = x - means
        maha = np.einsum("ki,kij,kj->k", d, precs, d)
        loglik = -0.5 * (maha + logdets)
        post = np.exp(loglik - loglik.max())
        post /= post.sum()
        k = int(np.argmax(post))
        scores = {lab: float(p) for lab, p in zip(labels, post, strict=True)}
        if post[k] < self.min_posterior or maha[k] > limit:
            return Prediction(UNKNOWN, float(post[k]), scores)
        return Prediction(labels[k], float(post[k]), scores)


class NearestMeanClassifier(_Incremental):
    """Nearest class mean in raw feature units (PRTools ``nmc``); always answers."""

    def predict_one(self, x: np.ndarray) -> Prediction:
        labels = self.classes
        d = np.linalg.norm(np.array([self.stats[k].mean for k in labels]) - x, axis=1)
        w = np.exp(-(d - d.min()))
        return Prediction(labels[int(np.argmin(d))], float(w.max() / w.sum()),
                          {k: float(v) for k, v in zip(labels, d, strict=True)})


class LeastSquaresClassifier(_Incremental):
    """Linear least squares onto one-hot targets; normal equations kept incrementally."""

    def __init__(self, ridge: float = 1e-9) -> None:
        super().__init__()
        self.ridge = ridge
        self._xtx: np.ndarray | None = None
        self._xty: dict[Any, np.ndarray] = {}
        self._w: np.ndarray | None = None

    def learn(self, x: np.ndarray, label: Any) -> None:
        x = self._check(x, "learn")
        if not np.isfinite(x).all():
            return
        super().learn(x, label)
        xa = np.append(x, 1.0)
        if self._xtx is None or self._xtx.shape[0] != len(xa):
            self._xtx = np.zeros((len(xa), len(xa)))
        self._xtx += np.outer(xa, xa)
        self._xty.setdefault(label, np.zeros(len(xa)))
        self._xty[label] += xa
        self._w = None

    def fit(self, X: np.ndarray, y) -> LeastSquaresClassifier:
        self._xtx, self._xty, self._w = None, {}, None
        super().fit(X, y)
        return self

    def predict_one(self, x: np.ndarray) -> Prediction:
        labels = self.classes
        if self._w is None:
            a = self._xtx + self.ridge * np.trace(self._xtx) * np.eye(len(self._xtx))
            self._w = np.linalg.solve(a, np.column_stack([self._xty[k] for k in labels]))
        out = np.append(x, 1.0) @ self._w
        k = int(np.argmax(out))
        return Prediction(labels[k], float(np.clip(out[k], 0.0, 1.0)),
                          {lab: float(v) for lab, v in zip(labels, out, strict=True)})


def outcomes(clf: _Incremental, X: np.ndarray, y) -> dict[str, float]:
    """Percentages of correct, wrong and uncertain answers of ``clf`` on a labelled set."""
    pred = clf.predict(X)
    n = max(len(pred), 1)
    unknown = sum(p is None for p in pred)
    correct = sum(p is not None and p == t for p, t in zip(pred, y, strict=True))
    return {"correct": 100.0 * correct / n, "wrong": 100.0 * (len(pred) - correct - unknown) / n,
            "uncertain": 100.0 * unknown / n}


class IncrementalRecognizer:
    """Recognise and keep learning (thesis §8.5.3): confident answers update the class
    statistics at once; unknown samples are ignored unless a supervisor labels them."""

    def __init__(self, classifier: _Incremental, learn_above: float = 0.0) -> None:
        self.classifier = classifier
        self.learn_above = learn_above
        self.learned = 0

    def observe(self, x: np.ndarray, supervisor_label: Any | None = None) -> Prediction:
        pred = self.classifier.classify(x)
        if pred.label is not None and pred.confidence >= self.learn_above:
            self.classifier.learn(x, pred.label)
            self.learned += 1
        elif pred.label is None and supervisor_label is not None:
            self.classifier.learn(x, supervisor_label)
            self.learned += 1
        return pred


def knowledge(clf: _Incremental, features: tuple[str, ...]) -> dict:
    """The learnt statistics of a classifier as plain data (JSON-ready)."""
    return {"features": list(features),
            "classes": {str(k): {"n": s.n, "mean": s.mean.tolist(), "scatter": s.scatter.tolist()}
                        for k, s in clf.stats.items()}}


def load_knowledge(clf: _Incremental, data: dict, where: str = "knowledge") -> tuple[str, ...]:
    """Fill ``clf`` with statistics saved by :func:`knowledge`; returns the feature names."""
    try:
        features = tuple(str(f) for f in data["features"])
        classes = data["classes"]
        dim = len(features)
        clf.stats, clf.dim = {}, dim
        for label, s in classes.items():
            st = ClassStats(dim)
            st.n, st.mean, st.scatter = int(s["n"]), np.array(s["mean"], float), np.array(s["scatter"], float)
            if st.mean.shape != (dim,) or st.scatter.shape != (dim, dim):
                raise ValueError(f"class {label!r} statistics do not have {dim} features")
            clf.stats[label] = st
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"{where}: invalid knowledge base: {exc}") from None
    if isinstance(clf, LeastSquaresClassifier):
        raise ValueError(f"{where}: a least-squares classifier cannot be rebuilt from class statistics")
    clf._changed()
    return features
