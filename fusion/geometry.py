"""Point distances to a posed spherical robot model (thesis App. B, eq. B.2-B.3), on arrays.

The embodiment owns the model (which spheres, on which links); generators receive it posed
in the world as a (m, 8) array of bi-spheres ``[c1x, c1y, c1z, r1, c2x, c2y, c2z, r2]`` (a
single sphere repeats its centre) and evaluate distances here, so they need no simulator.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from contactflow.fusion import kernels
from contactflow.fusion.hypotheses import unique_keys, voxel_centers

DistanceFn = Callable[[np.ndarray], np.ndarray]
"""Signed distance (n,) of world points (n, 3) to the robot surface: < 0 inside."""


def check_capsules(caps: np.ndarray, where: str = "capsules") -> np.ndarray:
    caps = np.asarray(caps, dtype=np.float64)
    if caps.ndim != 2 or caps.shape[1] != 8:
        raise ValueError(f"{where}: shape {caps.shape}, expected (m, 8) [c1, r1, c2, r2]")
    if caps.size and (not np.isfinite(caps).all() or (caps[:, [3, 7]] < 0).any()):
        raise ValueError(f"{where}: radii must be >= 0 and every value finite")
    return caps


def part_distances(points: np.ndarray, caps: np.ndarray) -> np.ndarray:
    """(n, m) signed distance of each of ``points`` (n, 3) to each bi-sphere of ``caps`` (m, 8; eq. B.3 then B.2)."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 1, 3)
    c1, r1, c2, r2 = caps[:, 0:3], caps[:, 3], caps[:, 4:7], caps[:, 7]
    axis = c2 - c1
    len2 = np.einsum("ij,ij->i", axis, axis)
    lam = np.clip(np.einsum("nmk,mk->nm", p - c1, axis) / np.where(len2 > 0, len2, 1.0), 0.0, 1.0)
    return np.linalg.norm(p - (c1 + lam[..., None] * axis), axis=2) - (r1 + lam * (r2 - r1))


def capsule_distance(points: np.ndarray, caps: np.ndarray, chunk: int = 65536) -> np.ndarray:
    """Signed distance of each point to the union of bi-spheres (eq. B.3 then B.2), min over parts."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    caps = check_capsules(caps)
    if caps.shape[0] == 0:
        return np.full(pts.shape[0], np.inf)
    out = np.empty(pts.shape[0])
    for s in range(0, pts.shape[0], chunk):
        out[s:s + chunk] = part_distances(pts[s:s + chunk], caps).min(axis=1)
    return out


def distance_fn(caps: np.ndarray, cutoff: float = np.inf) -> DistanceFn:
    """The signed distance to the union of ``caps``; with a finite ``cutoff``, ``+inf`` for the points outside every
    part's bounding box grown by ``cutoff`` (farther than that from the union): what a caller that only tells
    near from far needs, without a distance to each part for every point of a large grid."""
    caps = check_capsules(caps)
    if not np.isfinite(cutoff) or caps.shape[0] == 0:
        return lambda points: capsule_distance(points, caps)
    r1, r2 = caps[:, 3:4], caps[:, 7:8]
    lo = np.minimum(caps[:, 0:3] - r1, caps[:, 4:7] - r2) - cutoff
    hi = np.maximum(caps[:, 0:3] + r1, caps[:, 4:7] + r2) + cutoff
    g_lo, g_hi = lo.min(axis=0), hi.max(axis=0)

    def near(points: np.ndarray, chunk: int = 16384) -> np.ndarray:
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        out = np.full(pts.shape[0], np.inf)
        cand = np.flatnonzero(np.all((pts >= g_lo) & (pts <= g_hi), axis=1))  # in the union's box first: one test
        for s in range(0, cand.size, chunk):
            idx = cand[s:s + chunk]
            p = pts[idx, None, :]
            boxed = idx[((p >= lo) & (p <= hi)).all(axis=2).any(axis=1)]
            out[boxed] = capsule_distance(pts[boxed], caps)
        return out

    return near


def gradient(distance: DistanceFn, points: np.ndarray, h: float = 1e-3) -> np.ndarray:
    """Outward unit normals of the distance field by central differences (zero where flat)."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    n = pts.shape[0]
    offsets = np.concatenate([np.eye(3) * h, -np.eye(3) * h])
    d = distance((pts[None, :, :] + offsets[:, None, :]).reshape(-1, 3)).reshape(6, n)
    g = (d[:3] - d[3:]).T / (2 * h)
    norm = np.linalg.norm(g, axis=1, keepdims=True)
    return np.divide(g, norm, out=np.zeros_like(g), where=norm > 1e-9)


def grid_points(lo: np.ndarray, hi: np.ndarray, step: float) -> np.ndarray:
    """Centres of a regular grid of cells of size ``step`` covering the box [lo, hi]."""
    lo, hi = np.asarray(lo, dtype=float), np.asarray(hi, dtype=float)
    axes = [np.arange(lo[a] + step / 2, hi[a], step) for a in range(3)]
    mesh = np.meshgrid(*axes, indexing="ij")
    return np.stack([m.ravel() for m in mesh], axis=1)


def surface_points(distance: DistanceFn, lo: np.ndarray, hi: np.ndarray, step: float, band: float | None = None) -> np.ndarray:
    """Grid points within ``band`` (default half a cell diagonal) of the surface, inside [lo, hi]."""
    pts = grid_points(lo, hi, step)
    band = step * np.sqrt(3) / 2 if band is None else band
    return pts[np.abs(distance(pts)) <= band]


def capsules_bounds(caps: np.ndarray, margin: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    caps = check_capsules(caps)
    r = np.concatenate([caps[:, 3], caps[:, 7]])[:, None]
    c = np.concatenate([caps[:, 0:3], caps[:, 4:7]])
    return (c - r).min(axis=0) - margin, (c + r).max(axis=0) + margin


def interior_points(caps: np.ndarray, step: float, depth: float) -> np.ndarray:
    """Grid points (cell ``step``) deeper than ``depth`` inside the bi-spheres, gridding each
    part's own bounding box so a long arm costs no more than its volume."""
    caps = check_capsules(caps)
    return _shape(caps, step, 0.0, depth, surface=False)


MAX_CELLS = 4_000_000  # grid cells one shape may take (a robot's two hands at 5 mm take about 0.1 M)


def capsule_surface(caps: np.ndarray, step: float, band: float | None = None) -> np.ndarray:
    """Grid points (cell ``step``, one global grid) within ``band`` of the surface of the union of
    bi-spheres (default half a cell diagonal), gridding each part's own bounding box."""
    caps = check_capsules(caps)
    band = step * np.sqrt(3) / 2 if band is None else band
    return _shape(caps, step, band, 0.0, surface=True)


def _shape(caps: np.ndarray, step: float, band: float, depth: float, surface: bool) -> np.ndarray:
    """The distinct cell centres of a surface or an interior (:func:`kernels.shape_cells`), each part's box
    snapped to the global grid so that cells of neighbouring parts coincide; over ``MAX_CELLS`` cells in
    all is refused (bi-spheres of a corrupted model, metres wide, would grid for minutes)."""
    if caps.shape[0] == 0:
        return np.zeros((0, 3))
    r = caps[:, [3, 7]].max(axis=1)[:, None] + band
    lo = np.minimum(caps[:, 0:3], caps[:, 4:7]) - r
    hi = np.maximum(caps[:, 0:3], caps[:, 4:7]) + r
    first = np.floor(lo / step)
    parts = caps[:, [3, 7]].max(axis=1) > depth if not surface else np.ones(len(caps), dtype=bool)
    cells = np.maximum(np.ceil(hi / step - 0.5) - first, 0).prod(axis=1)[parts].sum()
    if cells > MAX_CELLS:
        raise ValueError(f"bi-spheres spanning {np.round(hi.max(axis=0) - lo.min(axis=0), 2).tolist()} m take over "
                         f"{MAX_CELLS:,} cells of {step:g} m: not a robot's parts")
    if np.abs(first).max() >= kernels.KEY_OFFSET - 1 or np.abs(hi / step).max() >= kernels.KEY_OFFSET - 1:
        raise ValueError(f"bi-spheres out of the voxel grid's range (±{kernels.KEY_OFFSET * step:g} m)")
    keys = kernels.shape_cells(caps, first.astype(np.int64), hi, float(step), float(band), float(depth), surface)
    return voxel_centers(unique_keys(keys), step)


class PoseMemo:
    """Points computed from bi-spheres (``fn(caps)``), kept while the bi-spheres stay within ``tol`` of
    the ones they were computed for: a robot at rest, whose joint readings jitter by micrometres, costs
    one computation, not one per cycle."""

    def __init__(self, fn: Callable[[np.ndarray], np.ndarray], tol: float = 1e-3) -> None:
        self.fn, self.tol = fn, tol
        self._caps: np.ndarray | None = None
        self._points = np.zeros((0, 3))

    def __call__(self, caps: np.ndarray) -> np.ndarray:
        if self._caps is None or self._caps.shape != caps.shape or np.abs(self._caps - caps).max() > self.tol:
            self._caps, self._points = caps.copy(), self.fn(caps)
        return self._points
