"""Surface points of a hand's collision shapes: vertices, and points along the edges for slicing."""

from __future__ import annotations

import numpy as np

from contactflow.embodiments.hand_geometry import _along_edges


def test_points_along_edges_fill_the_sloped_faces_a_band_of_vertices_misses() -> None:
    # a wedge: one sloped edge from the bottom (z 0) at x 0 to the top (z 0.04) at x 0.05
    v = np.array([[0.0, 0.0, 0.0], [0.05, 0.0, 0.04], [0.0, 0.01, 0.0]])
    tri = np.array([[0, 1, 2]])
    pts = _along_edges(v, tri, 0.002)
    assert np.array_equal(pts[:3], v)  # the vertices come first
    lo = pts[pts[:, 2] <= 0.03]  # a band of the wedge's lowest 3 cm
    assert v[v[:, 2] <= 0.03][:, 0].max() == 0.0  # its vertices alone say the band does not reach along x
    assert lo[:, 0].max() > 0.0375 - 0.003  # the sloped edge does: 3/4 of the way, within a step
    on_edge = [min(np.linalg.norm(np.cross(p - a, b - a)) / np.linalg.norm(b - a) for a, b in ((v[0], v[1]), (v[1], v[2]), (v[0], v[2])))
               for p in pts]
    assert max(on_edge) < 1e-12  # every point lies on an edge
    d = np.sort(np.linalg.norm(pts[pts[:, 1] == 0.0] - v[0], axis=1))
    assert np.diff(d).max() <= 0.002 + 1e-12  # no gap longer than the step
