"""Hypothesis clouds, voxel keys, the voxel hash index and the hypothesis space."""

import numpy as np
import pytest

from contactflow.fusion import kernels
from contactflow.fusion.hypotheses import (
    Hypotheses,
    HypothesisSpace,
    HypothesisType,
    VoxelIndex,
    pack_keys,
    unique_keys,
    unpack_keys,
    voxel_centers,
    voxel_keys,
    voxelize,
)


@pytest.mark.parametrize("n", [0, 1, 7, 5000])
def test_unique_keys_is_numpys_unique_with_its_inverse(n):
    rng = np.random.default_rng(n)
    keys = voxel_keys(rng.uniform(-0.2, 0.2, (n, 3)), 0.02)  # a coarse grid: many repeated keys
    want, want_inv = np.unique(keys, return_inverse=True)
    got, inv = unique_keys(keys, return_inverse=True)
    assert np.array_equal(got, want) and np.array_equal(unique_keys(keys), want)
    assert np.array_equal(inv, want_inv) and np.array_equal(got[inv], keys)


def test_keys_roundtrip_negative_and_positive():
    ijk = np.array([[0, 0, 0], [-5, 7, -1_000_000], [1_000_000, -3, 2]])
    assert np.array_equal(unpack_keys(pack_keys(ijk)), ijk)
    with pytest.raises(ValueError, match="out of range"):
        pack_keys(np.array([[1 << 21, 0, 0]]))


def test_voxel_centers_are_inside_their_voxel():
    pts = np.random.default_rng(1).uniform(-1, 1, (500, 3))
    c = voxel_centers(voxel_keys(pts, 0.005), 0.005)
    assert np.abs(c - pts).max() <= 0.0025 + 1e-12


def test_index_insert_lookup_duplicates_and_growth():
    rng = np.random.default_rng(0)
    idx = VoxelIndex(16)
    keys = rng.integers(0, 1 << 50, 5000)
    rows = idx.insert(np.concatenate([keys, keys[:100]]))
    assert idx.count == np.unique(keys).size
    assert np.array_equal(rows[:100], rows[5000:])
    assert np.array_equal(idx.lookup(keys), rows[:5000])
    assert np.array_equal(idx.row_keys[rows[:5000]], keys)
    assert (idx.lookup(rng.integers(1 << 51, 1 << 52, 50)) == -1).all()
    # new rows are numbered in order of first appearance
    more = rng.integers(1 << 52, 1 << 53, 10)
    assert np.array_equal(idx.insert(more), np.arange(5000, 5010))


def test_released_rows_leave_every_probe_chain_whole_and_are_taken_first():
    rng = np.random.default_rng(3)
    for trial in range(300):
        idx = VoxelIndex(8)  # 16 slots, up to 8 keys: long probe chains that wrap around the table's end
        keys = rng.choice(1 << 40, 8, replace=False)
        rows = idx.insert(keys)
        gone = rng.choice(8, rng.integers(1, 8), replace=False)
        idx.release(rows[gone])
        kept = np.setdiff1d(np.arange(8), gone)
        assert np.array_equal(idx.lookup(keys[kept]), rows[kept]), trial
        assert (idx.lookup(keys[gone]) == -1).all(), trial
        # new keys take the rows released, the last one first, before any new row; growth keeps every row
        new = rng.choice(1 << 40, gone.size + 20, replace=False) + (1 << 41)
        got = idx.insert(new)
        assert np.array_equal(got[: gone.size], rows[gone][::-1]) and np.array_equal(got[gone.size:], np.arange(8, 28))
        assert idx.count == 28 and idx.nfree == 0 and idx.size > 16
        assert np.array_equal(idx.lookup(np.concatenate([keys[kept], new])), np.concatenate([rows[kept], got]))


def test_voxelize_sum_keeps_single_contact_mass_and_max_for_multi():
    pts = np.array([[0.001, 0.001, 0.001], [0.002, 0.002, 0.002], [0.1, 0.1, 0.1]])
    h = Hypotheses.make(pts, [0.25, 0.25, 0.5], force=[2.0, 4.0, 1.0], direction=[[1, 0, 0]] * 3)
    s = voxelize(h, 0.005, "sum")
    assert len(s) == 2 and s.likelihood.sum() == pytest.approx(1.0)
    m = voxelize(h, 0.005, "max")
    assert sorted(m.likelihood) == [0.25, 0.5]
    first = np.argmin(m.location[:, 0])
    assert m.force[first] == pytest.approx(3.0)  # likelihood-weighted mean
    assert np.allclose(m.direction[first], [1, 0, 0])


def test_voxelize_type_null_wins():
    h = Hypotheses.make(np.zeros((2, 3)), 1.0, np.array([HypothesisType.REGULAR, HypothesisType.NULL]))
    assert voxelize(h).kind.tolist() == [HypothesisType.NULL]


def test_bad_hypotheses_name_the_field():
    with pytest.raises(ValueError, match="'likelihood'"):
        Hypotheses.make(np.zeros((2, 3)), [0.5, 1.5])
    with pytest.raises(ValueError, match="NaN"):
        Hypotheses.make(np.array([[np.nan, 0, 0]]), 0.5)
    with pytest.raises(ValueError, match="'kind'"):
        Hypotheses.make(np.zeros((1, 3)), 0.5, np.array([7]))


def test_space_expiry_in_the_fused_pass_and_compact_keep_rows_consistent():
    sp = HypothesisSpace(0.005, capacity=16)
    pts = np.random.default_rng(2).uniform(0, 0.3, (300, 3))
    h_old = Hypotheses.make(pts[:200], 0.5, stamp=0.0)
    h_new = Hypotheses.make(pts[200:], 0.7, stamp=1.0)
    sp.put(0, h_old)
    sp.put(1, h_new)
    fused = sp.fuse(2, older_than=0.5)
    live = fused[-1]
    keys_new = np.unique(voxel_keys(pts[200:], 0.005))
    assert live == keys_new.size and fused[0].shape == (keys_new.size, kernels.OUT_SOURCES + 2)  # the old cloud expired
    assert np.array_equal(np.sort(voxel_keys(fused[0][:, :3], 0.005)), keys_new)
    assert np.allclose(fused[0][:, kernels.OUT_SOURCES:], [0.0, 0.7])
    assert sp.compact(live_rows=live)
    assert sp.n == keys_new.size
    rows = sp.index.lookup(keys_new)
    assert (rows >= 0).all() and np.allclose(sp.lik[1, rows], 0.7)
    assert np.allclose(sp.centers(rows), voxel_centers(keys_new, 0.005))
    # compacted in place, in order: the rows left behind are empty records, the index knows only the live keys
    assert np.array_equal(np.sort(rows), np.arange(keys_new.size))
    assert np.isinf(sp.rec[sp.n:300, :, kernels.STAMP]).all() and not sp.rec[sp.n:300, :, kernels.LIK].any()
    assert (sp.index.lookup(np.setdiff1d(voxel_keys(pts[:200], 0.005), keys_new)) == -1).all()
    assert sp.index.count == sp.n and not sp.compact(live_rows=sp.n)  # nothing left to drop


def test_kernel_type_codes_and_point_keys_match_the_numpy_definitions():
    assert (kernels.REGULAR, kernels.NULL) == (HypothesisType.REGULAR, HypothesisType.NULL)
    rng = np.random.default_rng(3)
    pts = rng.uniform(-2, 2, (1000, 3))
    pts[::5] = np.round(pts[::5] / 0.005) * 0.005  # on voxel boundaries, as numpy's floor puts them
    sp = HypothesisSpace(0.005, capacity=16)
    sp.put(0, Hypotheses.make(pts, 0.5))
    keys = np.unique(voxel_keys(pts, 0.005))
    assert np.array_equal(np.sort(sp.keys[: sp.n]), keys)
    assert np.allclose(sp.centers(sp.index.lookup(keys)), voxel_centers(keys, 0.005))
    for far in ([1e5, 0.0, 0.0], [0.0, 0.0, -1e5], [0.0, 6e3, 0.0]):  # any axis, either side, the last point
        with pytest.raises(ValueError, match="out of range"):
            sp.put(0, Hypotheses.make(np.array([[0.0, 0.0, 0.0], [0.1, 0.2, 0.3], far]), 0.5))
    assert sp.n == keys.size  # the refused clouds added nothing


def test_put_keeps_the_most_likely_of_one_cloud_but_the_newest_cloud_wins():
    sp = HypothesisSpace(0.005)
    pts = np.array([[0.001, 0.001, 0.001], [0.002, 0.002, 0.002]])  # one voxel
    sp.put(0, Hypotheses.make(pts, [0.8, 0.3], stamp=1.0))
    assert sp.lik[0, 0] == pytest.approx(0.8)
    sp.put(0, Hypotheses.make(pts[:1], 0.2, stamp=2.0))
    assert sp.lik[0, 0] == pytest.approx(0.2) and sp.stamp[0, 0] == 2.0


def test_a_put_that_grows_the_rows_midway_keeps_what_it_wrote_before_and_grows_only_to_what_it_needs():
    rng = np.random.default_rng(4)
    pts = rng.uniform(0, 0.5, (4000, 3))
    lik = rng.uniform(0.1, 0.9, 4000)
    # the first 500 again at the end, half less likely and half more: one cloud keeps the most likely per voxel
    again = np.where(np.arange(500) % 2 == 0, lik[:500] * 0.5, lik[:500] + 0.05)
    cloud = Hypotheses.make(np.concatenate([pts, pts[:500]]), np.concatenate([lik, again]),
                            force=rng.uniform(0, 5, 4500), stamp=3.0)
    small, large = HypothesisSpace(0.005, capacity=16), HypothesisSpace(0.005, capacity=1 << 14)
    for sp in (small, large):
        sp.put(0, cloud)
    keys = np.unique(voxel_keys(pts, 0.005))
    assert small.n == large.n == keys.size and small.cap < large.cap  # the small space grew during the put
    a, b = small.index.lookup(keys), large.index.lookup(keys)
    assert np.array_equal(small.rec[a, 0], large.rec[b, 0])
    assert np.allclose(small.centers(a), voxel_centers(keys, 0.005)) and np.allclose(large.centers(b), small.centers(a))
    top = small.lik[0, small.index.lookup(voxel_keys(pts[:500], 0.005))]  # kept across the put's resumes
    assert np.allclose(top, np.maximum(lik[:500], again))
    # a grid moved by one voxel adds one face of new voxels: the rows grow for those, not for the whole cloud
    grid = (np.stack(np.meshgrid(np.arange(20), np.arange(20), np.arange(8), indexing="ij"), -1).reshape(-1, 3) + 0.5) * 0.005
    sp = HypothesisSpace(0.005, capacity=16)
    sp.put(0, Hypotheses.make(grid, 0.5, stamp=0.0))
    cap, size = sp.cap, sp.index.size
    assert (sp.n, cap) == (3200, 4096)
    sp.put(0, Hypotheses.make(grid + [0.005, 0.0, 0.0], 0.5, stamp=1.0))
    assert sp.n == 3360 and (sp.cap, sp.index.size) == (cap, size)


def test_a_space_that_starts_small_fuses_moving_clouds_as_one_that_never_grows():
    # rows are numbered in the order voxels come and reused last freed first, whatever the capacity: a space that
    # grows during its puts must give the same rows, records and fused voxels, cycle by cycle
    rng = np.random.default_rng(6)
    small, large = HypothesisSpace(0.005, capacity=16), HypothesisSpace(0.005, capacity=1 << 15)
    base = [rng.uniform(0, 0.15, (n, 3)) for n in (2500, 1200, 600)]
    for cycle in range(40):
        now = 0.01 * cycle
        for col, pts in enumerate(base):
            step = np.array([0.005 * (cycle % 9), 0.0, 0.0]) * (col + 1)  # each cloud moves at its own pace
            keep = rng.random(len(pts)) < 0.8  # and loses a fifth of its points at random
            h = Hypotheses.make(pts[keep] + step, rng.uniform(0.1, 0.9, keep.sum()), stamp=now)
            small.put(col, h)
            large.put(col, h)
        got, want = small.fuse(3, now - 0.025), large.fuse(3, now - 0.025)
        assert all(np.array_equal(a, b) for a, b in zip(got, want, strict=True)), cycle
        assert small.compact(live_rows=got[-1]) == large.compact(live_rows=want[-1]), cycle
        assert small.n == large.n and np.array_equal(small.rec[: small.n], large.rec[: large.n]), cycle
        assert np.array_equal(small.index.row_keys[: small.n], large.index.row_keys[: large.n]), cycle
    assert small.cap < large.cap
