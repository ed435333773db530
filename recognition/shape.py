"""V4 shape classification by the curvedness index of the silhouette contour (thesis §8.4.2, §8.5.2).

The curvedness of a contour is the length of its curved features over its total length.
The contour is simplified by Douglas-Peucker with a tolerance relative to the object's
size; long pieces are straight features, and runs of short pieces joined by gentle turns
are curved features (an isolated short piece between two corners is a short edge, not a
curve). Class membership is the reciprocal of the relative distance to each class centre
(eq. 8.3), normalised to percentages (eq. 8.4); an answer needs 70 % confidence, except
that box/cylinder uncertainty is resolved as the less restrictive cylinder.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import contourpy
import numpy as np

from contactflow.recognition.geometry import Box, check_intrinsics, check_pose, depth_to_points

BOX, CYLINDER, SPHERE = "box", "cylinder", "sphere"
UNKNOWN = "unknown"
SHAPES = (BOX, CYLINDER, SPHERE)


def silhouette_contour(mask: np.ndarray) -> np.ndarray:
    """Outer contour of the largest blob of a boolean mask, as an (N, 2) closed polyline (px)."""
    m = np.asarray(mask, bool)
    if m.ndim != 2 or m.sum() < 9:
        return np.zeros((0, 2))
    z = np.pad(m.astype(float), 1)
    lines = contourpy.contour_generator(z=z, line_type=contourpy.LineType.Separate).lines(0.5)
    if not lines:
        return np.zeros((0, 2))
    best = max(lines, key=lambda ln: abs(_area(ln)))
    return best[:, ::-1] - 1.0 if len(best) >= 4 else np.zeros((0, 2))


def _area(poly: np.ndarray) -> float:
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


def _douglas_peucker(pts: np.ndarray, eps: float) -> np.ndarray:
    """Indices of the kept vertices of an open polyline."""
    keep = np.zeros(len(pts), bool)
    keep[0] = keep[-1] = True
    stack = [(0, len(pts) - 1)]
    while stack:
        i, j = stack.pop()
        if j <= i + 1:
            continue
        a, b = pts[i], pts[j]
        ab = b - a
        n = np.hypot(*ab)
        seg = pts[i + 1:j] - a
        d = np.abs(ab[0] * seg[:, 1] - ab[1] * seg[:, 0]) / n if n > 1e-12 else np.hypot(seg[:, 0], seg[:, 1])
        k = int(np.argmax(d))
        if d[k] > eps:
            m = i + 1 + k
            keep[m] = True
            stack += [(i, m), (m, j)]
    return np.flatnonzero(keep)


@dataclass(frozen=True)
class CurvednessParams:
    tolerance: float = 0.025  # DP tolerance as a fraction of the equivalent radius
    straight_fraction: float = 0.12  # pieces longer than this fraction of the perimeter are straight
    corner_deg: float = 40.0  # a turn sharper than this between pieces is a corner
    min_run: int = 3  # short pieces needed in a row to make a curved feature
    min_tolerance: float = 1.2  # px, pixel staircases are not features
    smooth: float = 1.5  # px, Gaussian smoothing of the contour against segmentation noise


def curvedness(contour: np.ndarray, params: CurvednessParams = CurvednessParams()) -> float:
    """Curved fraction of a closed contour's length, in [0, 1]; NaN for a degenerate contour."""
    c = np.asarray(contour, float)
    if c.ndim != 2 or len(c) < 8 or not np.isfinite(c).all():
        return float("nan")
    if np.allclose(c[0], c[-1]):
        c = c[:-1]
    area = abs(_area(c))
    if area < 4.0:
        return float("nan")
    r_eq = np.sqrt(area / np.pi)
    if params.smooth > 0:
        c = _smooth_closed(_resample_closed(c, 1.0), params.smooth)
    # start at the point farthest from the centroid: a corner, if there is one
    start = int(np.argmax(np.linalg.norm(c - c.mean(axis=0), axis=1)))
    c = np.roll(c, -start, axis=0)
    closed = np.vstack((c, c[:1]))
    idx = _douglas_peucker(closed, max(params.tolerance * r_eq, params.min_tolerance))
    verts = closed[idx]
    seg = np.diff(verts, axis=0)
    lengths = np.hypot(seg[:, 0], seg[:, 1])
    ok = lengths > 1e-9
    seg, lengths = seg[ok], lengths[ok]
    if len(lengths) < 3:
        return 0.0
    perimeter = lengths.sum()
    heading = np.arctan2(seg[:, 1], seg[:, 0])
    turn = np.abs(np.angle(np.exp(1j * (np.roll(heading, -1) - heading))))  # turn after piece i
    short = lengths < params.straight_fraction * perimeter
    gentle_before = np.degrees(np.roll(turn, 1)) < params.corner_deg
    gentle_after = np.degrees(turn) < params.corner_deg
    # a short piece is curved when it is joined gently to a neighbouring short piece
    curved = short & ((gentle_before & np.roll(short, 1)) | (gentle_after & np.roll(short, -1)))
    if params.min_run > 2:
        curved = _runs_at_least(curved, params.min_run)
    return float(lengths[curved].sum() / perimeter)


def _resample_closed(c: np.ndarray, step: float) -> np.ndarray:
    """Points every ``step`` of arc length along a closed polyline."""
    closed = np.vstack((c, c[:1]))
    s = np.concatenate(([0.0], np.cumsum(np.hypot(*np.diff(closed, axis=0).T))))
    n = max(int(s[-1] / step), 8)
    t = np.linspace(0.0, s[-1], n, endpoint=False)
    return np.column_stack((np.interp(t, s, closed[:, 0]), np.interp(t, s, closed[:, 1])))


def _smooth_closed(c: np.ndarray, sigma: float) -> np.ndarray:
    """Circular Gaussian smoothing of an evenly sampled closed contour (sigma in samples)."""
    r = int(np.ceil(3 * sigma))
    k = np.exp(-0.5 * (np.arange(-r, r + 1) / sigma) ** 2)
    k /= k.sum()
    padded = np.vstack((c[-r:], c, c[:r])) if r < len(c) else np.tile(c, (3, 1))[len(c) - r:2 * len(c) + r]
    return np.column_stack([np.convolve(padded[:, i], k, mode="valid") for i in range(2)])


def _runs_at_least(flags: np.ndarray, n: int) -> np.ndarray:
    """Keep only circular runs of True of length >= n."""
    if flags.all() or not flags.any():
        return flags
    k = int(np.argmin(flags))
    f = np.roll(flags, -k)
    out = np.zeros_like(f)
    i = 0
    while i < len(f):
        if f[i]:
            j = i
            while j < len(f) and f[j]:
                j += 1
            if j - i >= n:
                out[i:j] = True
            i = j
        else:
            i += 1
    return np.roll(out, k)


def object_mask(depth: np.ndarray, K: np.ndarray, world_T_cam: np.ndarray, box: Box, margin: float = 0.01,
                floor: float = 0.012) -> np.ndarray:
    """Silhouette of a segmented object: pixels whose 3-D point lies in its (grown) box.

    Points in the bottom ``floor`` metres of the box are left out: they are the plane the
    object stands on.
    """
    d = np.asarray(depth, np.float32)
    if d.ndim != 2 or d.size == 0:
        return np.zeros(d.shape if d.ndim == 2 else (0, 0), bool)
    K, T = check_intrinsics(K), check_pose(world_T_cam)
    v, u = np.mgrid[0:d.shape[0], 0:d.shape[1]]
    with np.errstate(invalid="ignore"):
        ok = np.isfinite(d) & (d > 0)
    mask = np.zeros(d.shape, bool)
    if not ok.any():
        return mask
    pts = depth_to_points(np.where(ok, d, np.nan), K, T, 1, 0.0, np.inf)
    loc = box.local(pts)
    half = box.extent / 2
    inside = np.all(np.abs(loc[:, :2]) <= half[:2] + margin, axis=1)
    inside &= (loc[:, 2] <= half[2] + margin) & (loc[:, 2] >= -half[2] + floor)
    mask[v[ok][inside], u[ok][inside]] = True
    return mask


@dataclass
class ShapeClassifier:
    """Curvedness statistics per class (µK, σK), membership eq. 8.3-8.4 and the 70 % rule."""

    confidence: float = 0.70
    min_sigma: float = 0.01  # floor of σK, so one clean training view does not make σ = 0
    classes: tuple[str, ...] = SHAPES
    samples: dict[str, list[float]] = field(default_factory=dict)
    prior_mu: tuple[float, ...] = ()  # class centres used until a class has 2 samples of its own
    prior_sigma: tuple[float, ...] = ()

    @classmethod
    def from_stats(cls, mu, sigma, confidence: float = 0.70, classes: tuple[str, ...] = SHAPES) -> ShapeClassifier:
        """A classifier from stored µK, σK (e.g. a primitive's parameters)."""
        if len(mu) != len(classes) or len(sigma) != len(classes):
            raise ValueError(f"ShapeClassifier.from_stats: need {len(classes)} means and sigmas, "
                             f"got {len(mu)} and {len(sigma)}")
        return cls(confidence=confidence, classes=classes, prior_mu=tuple(float(v) for v in mu),
                   prior_sigma=tuple(float(v) for v in sigma))

    def fit(self, values: np.ndarray, labels: list[str]) -> ShapeClassifier:
        self.samples = {k: [] for k in self.classes}
        for v, lab in zip(values, labels, strict=True):
            self.learn(float(v), lab)
        return self

    def learn(self, value: float, label: str) -> None:
        """Incremental learning: add one labelled curvedness value."""
        if label not in self.classes:
            raise ValueError(f"ShapeClassifier.learn: label {label!r} not in {self.classes}")
        if np.isfinite(value):
            self.samples.setdefault(label, []).append(float(value))

    def stats(self) -> tuple[np.ndarray, np.ndarray]:
        mu, sd = [], []
        for i, k in enumerate(self.classes):
            v = self.samples.get(k, [])
            if len(v) >= 2 or (len(v) == 1 and not self.prior_mu):
                mu.append(np.mean(v))
                sd.append(max(float(np.std(v)), self.min_sigma))
            elif self.prior_mu:
                mu.append(self.prior_mu[i])
                sd.append(max(self.prior_sigma[i], self.min_sigma))
            else:
                raise ValueError(f"ShapeClassifier: no training samples for {k!r}")
        return np.array(mu), np.array(sd)

    def probabilities(self, value: float) -> np.ndarray:
        """Class percentages p_iK (eq. 8.4) as fractions; NaN input gives all NaN."""
        if not np.isfinite(value):
            return np.full(len(self.classes), np.nan)
        mu, sd = self.stats()
        m = sd / np.maximum(np.abs(value - mu), 1e-9)
        return m / m.sum()

    def classify(self, value: float) -> tuple[str, np.ndarray]:
        """(label or "unknown", probabilities)."""
        p = self.probabilities(value)
        if not np.isfinite(p).all():
            return UNKNOWN, p
        k = int(np.argmax(p))
        if p[k] >= self.confidence:
            return self.classes[k], p
        if BOX in self.classes and CYLINDER in self.classes:
            ib, ic = self.classes.index(BOX), self.classes.index(CYLINDER)
            if p[ib] + p[ic] >= self.confidence:
                return CYLINDER, p
        return UNKNOWN, p
