"""Point distances to a posed spherical robot model (thesis App. B, eq. B.2-B.3), on arrays.

The embodiment owns the model (which spheres, on which links); generators receive it posed
in the world as a (m, 8) array of bi-spheres ``[c1x, c1y, c1z, r1, c2x, c2y, c2z, r2]`` (a
single sphere repeats its centre) and evaluate distances here, so they need no simulator.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from contactflow.fusion.hypotheses import voxel_centers, voxel_keys

DistanceFn = Callable[[np.ndarray], np.ndarray]
"""Signed distance (n,) of world points (n, 3) to the robot surface: < 0 inside."""


def check_capsules(caps: np.ndarray, where: str = "capsules") -> np.ndarray:
    caps = np.asarray(caps, dtype=np.float64)
    if caps.ndim != 2 or caps.shape[1] != 8:
        raise ValueError(f"{where}: shape {caps.shape}, expected (m, 8) [c1, r1, c2, r2]")
    if caps.size and (not np.isfinite(caps).all() or (caps[:, [3, 7]] < 0).any()):
        raise ValueError(f"{where}: radii must be >= 0 and every value finite")
    return caps


def capsule_distance(points: np.ndarray, caps: np.ndarray, chunk: int = 65536) -> np.ndarray:
    """Signed distance of each point to the union of bi-spheres (eq. B.3 then B.2), min over parts."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    caps = check_capsules(caps)
    if caps.shape[0] == 0:
        return np.full(pts.shape[0], np.inf)
    c1, r1, c2, r2 = caps[:, 0:3], caps[:, 3], caps[:, 4:7], caps[:, 7]
    axis = c2 - c1
    len2 = np.einsum("ij,ij->i", axis, axis)
    out = np.empty(pts.shape[0])
    for s in range(0, pts.shape[0], chunk):
        p = pts[s:s + chunk, None, :]
        lam = np.einsum("nmk,mk->nm", p - c1, axis) / np.where(len2 > 0, len2, 1.0)
        lam = np.clip(lam, 0.0, 1.0)
        cmin = c1 + lam[..., None] * axis
        rmin = r1 + lam * (r2 - r1)
        out[s:s + chunk] = (np.linalg.norm(p - cmin, axis=2) - rmin).min(axis=1)
    return out


def distance_fn(caps: np.ndarray) -> DistanceFn:
    caps = check_capsules(caps)
    return lambda points: capsule_distance(points, caps)


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
    out = []
    budget = _Budget(step)
    for cap in caps:
        r = max(cap[3], cap[7])
        if r <= depth:
            continue
        lo = np.minimum(cap[0:3], cap[4:7]) - r
        hi = np.maximum(cap[0:3], cap[4:7]) + r
        # Snap to the global grid so that cells of neighbouring parts coincide.
        lo = np.floor(lo / step) * step
        budget.spend(lo, hi)
        pts = grid_points(lo, hi, step)
        out.append(pts[capsule_distance(pts, cap[None]) < -depth])
    return _distinct_cells(out, step)


MAX_CELLS = 4_000_000  # grid cells one shape may take (a robot's two hands at 5 mm take about 0.1 M)


class _Budget:
    """Counts the grid cells a shape's parts take and refuses past ``MAX_CELLS``: bi-spheres of a
    corrupted model (metres wide) would grid for minutes."""

    def __init__(self, step: float) -> None:
        self.step, self.cells = step, 0

    def spend(self, lo: np.ndarray, hi: np.ndarray) -> None:
        self.cells += int(np.prod(np.maximum(np.ceil((hi - lo) / self.step), 0)))
        if self.cells > MAX_CELLS:
            raise ValueError(f"bi-spheres spanning {np.round(hi - lo, 2).tolist()} m take over {MAX_CELLS:,} cells "
                             f"of {self.step:g} m: not a robot's parts")


def capsule_surface(caps: np.ndarray, step: float, band: float | None = None) -> np.ndarray:
    """Grid points (cell ``step``, one global grid) within ``band`` of the surface of the union of
    bi-spheres (default half a cell diagonal), gridding each part's own bounding box."""
    caps = check_capsules(caps)
    band = step * np.sqrt(3) / 2 if band is None else band
    out = []
    budget = _Budget(step)
    for cap in caps:
        r = max(cap[3], cap[7]) + band
        lo = np.floor((np.minimum(cap[0:3], cap[4:7]) - r) / step) * step
        hi = np.maximum(cap[0:3], cap[4:7]) + r
        budget.spend(lo, hi)
        pts = grid_points(lo, hi, step)
        # near this part's own surface first (one part, cheap); of those, the ones on the union's surface (a
        # point near the union's surface but not this part's lies near another part's, whose own grid has it)
        pts = pts[np.abs(capsule_distance(pts, cap[None])) <= band]
        out.append(pts[np.abs(capsule_distance(pts, caps)) <= band])
    return _distinct_cells(out, step)


def _distinct_cells(parts: list[np.ndarray], step: float) -> np.ndarray:
    """The distinct cell centres of one global grid (cell ``step``) among ``parts``, sorted: by integer
    cell keys, as parts gridded from different corners differ in the last bits of the same centre."""
    if not parts:
        return np.zeros((0, 3))
    return voxel_centers(np.unique(voxel_keys(np.concatenate(parts), step)), step)


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
