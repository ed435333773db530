"""Compiled (numba) kernels of the vision chain: the self filter's distances of cloud points to a robot's s-topes,
culled by their boxes, and the voxel grid of a cloud's downsampling.

Why compiled: the numpy self filter tests every point against every s-tope's box and then
evaluates every s-tope for the points near any of them, each step an (N, M) temporary; the
self filter was the slowest hop of the deployed vision chain (bench vision: ~28 ms a frame
for tombatossals' 60 s-topes). This loop visits each point once and evaluates only the
s-topes whose box holds it. The downsampling's voxel numbers took a minimum and a maximum over
the points' axis of an (N, 3) array, and its centroids a unique and four bincounts, 5.2 ms
for a 71k-point frame of the simulator's camera.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def culled_stope_distance(points: np.ndarray, c1: np.ndarray, c2: np.ndarray, r1: np.ndarray, r2: np.ndarray,
                          lo: np.ndarray, hi: np.ndarray, out: np.ndarray) -> None:
    """Eq. B.2-B.3 into ``out``: each point's smallest signed distance to the s-topes whose box
    (``lo``/``hi``, (M, 3)) holds it, ``inf`` when none does."""
    m = c1.shape[0]
    for i in range(points.shape[0]):
        px, py, pz = points[i, 0], points[i, 1], points[i, 2]
        best = np.inf
        for k in range(m):
            if (px < lo[k, 0] or px > hi[k, 0] or py < lo[k, 1] or py > hi[k, 1]
                    or pz < lo[k, 2] or pz > hi[k, 2]):
                continue
            dx, dy, dz = c2[k, 0] - c1[k, 0], c2[k, 1] - c1[k, 1], c2[k, 2] - c1[k, 2]
            l2 = max(dx * dx + dy * dy + dz * dz, 1e-12)
            lam = ((px - c1[k, 0]) * dx + (py - c1[k, 1]) * dy + (pz - c1[k, 2]) * dz) / l2
            lam = min(max(lam, 0.0), 1.0)
            ex = px - (c1[k, 0] + lam * dx)
            ey = py - (c1[k, 1] + lam * dy)
            ez = pz - (c1[k, 2] + lam * dz)
            d = np.sqrt(ex * ex + ey * ey + ez * ez) - (r1[k] + lam * (r2[k] - r1[k]))
            if d < best:
                best = d
        out[i] = best


@njit(cache=True, nogil=True)
def voxel_numbers(points: np.ndarray, voxel: float, out: np.ndarray) -> None:
    """The voxel of each point (edge ``voxel``), numbered x-major from the cloud's lowest voxel corner, into ``out``."""
    n = points.shape[0]
    idx = np.empty((n, 3), dtype=np.int64)
    lo = np.full(3, np.iinfo(np.int64).max)
    hi = np.full(3, np.iinfo(np.int64).min)
    for i in range(n):
        for a in range(3):
            v = np.int64(np.floor(points[i, a] / voxel))
            idx[i, a] = v
            lo[a] = min(lo[a], v)
            hi[a] = max(hi[a], v)
    d1, d2 = hi[1] - lo[1] + 1, hi[2] - lo[2] + 1
    for i in range(n):
        out[i] = ((idx[i, 0] - lo[0]) * d1 + idx[i, 1] - lo[1]) * d2 + idx[i, 2] - lo[2]


@njit(cache=True, nogil=True)
def run_means(points: np.ndarray, key: np.ndarray, order: np.ndarray) -> np.ndarray:
    """The centroid of each run of equal ``key`` along ``order`` (points sorted by key), one row per run; each
    run's points are summed in ``order``."""
    n = order.shape[0]
    runs = 0
    for j in range(n):
        runs += j == 0 or key[order[j]] != key[order[j - 1]]
    out = np.empty((runs, 3))
    g = -1
    count = 0
    sx = sy = sz = 0.0
    for j in range(n):
        i = order[j]
        if j == 0 or key[i] != key[order[j - 1]]:
            if g >= 0:
                out[g, 0], out[g, 1], out[g, 2] = sx / count, sy / count, sz / count
            g += 1
            count = 0
            sx = sy = sz = 0.0
        sx += points[i, 0]
        sy += points[i, 1]
        sz += points[i, 2]
        count += 1
    if g >= 0:
        out[g, 0], out[g, 1], out[g, 2] = sx / count, sy / count, sz / count
    return out
