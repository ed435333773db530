"""Compiled (numba) kernel of the self filter: distances of cloud points to a robot's s-topes, culled by their boxes.

Why compiled: the numpy version tests every point against every s-tope's box and then
evaluates every s-tope for the points near any of them, each step an (N, M) temporary; the
self filter was the slowest hop of the deployed vision chain (bench vision: ~28 ms a frame
for tombatossals' 60 s-topes). This loop visits each point once and evaluates only the
s-topes whose box holds it.
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
