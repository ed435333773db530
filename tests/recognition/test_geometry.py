"""Point-cloud geometry: the voxel grid's downsampling against its numpy definition."""

from __future__ import annotations

import numpy as np
import pytest

from contactflow.recognition.geometry import voxel_downsample


def numpy_downsample(points: np.ndarray, voxel: float) -> np.ndarray:
    """The definition: voxel numbers from the cloud's lowest corner, unique, bincount centroids."""
    idx = np.floor(points / voxel).astype(np.int64)
    idx -= idx.min(axis=0)
    dims = idx.max(axis=0) + 1
    key = (idx[:, 0] * dims[1] + idx[:, 1]) * dims[2] + idx[:, 2]
    uniq, inv = np.unique(key, return_inverse=True)
    counts = np.bincount(inv, minlength=len(uniq)).astype(float)
    return np.stack([np.bincount(inv, weights=points[:, k], minlength=len(uniq)) / counts for k in range(3)], axis=1)


# 1e-6: micrometre voxels over 2 m, whose numbers times the point count overflow int64, so the points are ordered by a
# stable argsort instead of the one sort of (voxel, point) numbers
@pytest.mark.parametrize("voxel", [0.006, 0.05, 1e-6])
def test_voxel_downsample_gives_the_numpy_centroids_bit_for_bit_in_voxel_order(voxel):
    rng = np.random.default_rng(7)
    pts = rng.uniform(-0.5, 1.5, (20_000, 3))
    pts[::4] = np.round(pts[::4] / voxel) * voxel  # on voxel boundaries
    pts[1::9] = pts[:20_000 // 9 + 1][: len(pts[1::9])]  # repeated points: several in one voxel, summed in cloud order
    got, want = voxel_downsample(pts, voxel), numpy_downsample(pts, voxel)
    assert got.shape == want.shape and np.array_equal(got, want)


def test_voxel_downsample_keeps_an_empty_cloud_and_a_voxel_of_zero():
    empty = np.zeros((0, 3))
    assert voxel_downsample(empty, 0.01) is empty
    pts = np.array([[0.0, 0.0, 0.0], [0.001, 0.0, 0.0]])
    assert voxel_downsample(pts, 0.0) is pts
    assert np.array_equal(voxel_downsample(pts, 0.01), [[0.0005, 0.0, 0.0]])
