"""Integrator semantics: noisy-OR, type rules, waiting, timeouts, plug/unplug, reference maths."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from contactflow.fusion.hypotheses import Hypotheses, HypothesisType, voxel_keys, voxelize
from contactflow.fusion.integrator import Integrator, IntegratorParams

P = np.array([[0.5, 0.1, 0.8]])
Q = np.array([[0.6, 0.1, 0.8]])


def cloud(pts, lik, kind=HypothesisType.REGULAR, stamp=0.0, force=0.0, direction=None):
    return Hypotheses.make(pts, lik, kind, force, direction, stamp)


def fused_at(f, point):
    hit = np.flatnonzero(voxel_keys(f.location, 0.005) == voxel_keys(point, 0.005)[0])
    return f.likelihood[hit[0]] if hit.size else None


def test_noisy_or_of_three_sources():
    integ = Integrator()
    for name, lik in (("a", 0.5), ("b", 0.4), ("c", 0.2)):
        integ.offer(name, cloud(P, lik), 0.0)
    f = integ.cycle(0.0)
    assert f is not None and len(f) == 1
    assert f.likelihood[0] == pytest.approx(1 - 0.5 * 0.6 * 0.8)
    assert bin(int(f.sources[0])).count("1") == 3


def test_support_alone_is_discarded_but_raises_regular():
    integ = Integrator()
    integ.offer("tactile", cloud(P, 0.4), 0.0)
    integ.offer("sim", cloud(np.vstack([P, Q]), 0.5, HypothesisType.SUPPORT), 0.0)
    f = integ.cycle(0.0)
    assert len(f) == 1  # Q has only support
    assert fused_at(f, P) == pytest.approx(1 - 0.6 * 0.5)
    assert fused_at(f, Q) is None and f.unsupported == 1


def test_null_vetoes_any_hypothesis_in_its_voxel():
    integ = Integrator()
    integ.offer("ft", cloud(np.vstack([P, Q]), 0.9), 0.0)
    integ.offer("null", cloud(Q, 1.0, HypothesisType.NULL), 0.0)
    f = integ.cycle(0.0)
    assert fused_at(f, P) == pytest.approx(0.9)
    assert fused_at(f, Q) is None and f.vetoed == 1


def test_force_is_likelihood_weighted():
    integ = Integrator()
    integ.offer("a", cloud(P, 0.75, force=4.0, direction=[1, 0, 0]), 0.0)
    integ.offer("b", cloud(P, 0.25, force=8.0, direction=[0, 1, 0]), 0.0)
    f = integ.cycle(0.0)
    assert f.force[0] == pytest.approx(5.0)
    assert np.allclose(f.direction[0], np.array([3, 1, 0]) / np.sqrt(10))


def test_waits_for_slow_source_and_takes_newest_of_fast_one():
    integ = Integrator(IntegratorParams(wait_timeout=1.0))
    integ.plug("fast", now=0.0)
    integ.plug("slow", now=0.0)
    integ.offer("fast", cloud(P, 0.2, stamp=0.0), 0.0)
    assert integ.cycle(0.01) is None  # still waiting for "slow"
    integ.offer("fast", cloud(P, 0.6, stamp=0.02), 0.02)  # newer reading replaces the pending one
    assert integ.cycle(0.03) is None
    integ.offer("slow", cloud(Q, 0.5, stamp=0.04), 0.04)
    f = integ.cycle(0.04)
    assert f is not None and len(f) == 2
    assert fused_at(f, P) == pytest.approx(0.6)
    assert integ.cycle(0.05) is None  # next cycle waits again


def test_an_empty_reading_keeps_a_pending_cloud_the_cycle_has_not_fused_yet():
    # a wrist F/T feels a brief touch while the cycle waits for the tactile source; its next reading
    # feels nothing: the touch is fused anyway, as it would have been had the cycle run in between
    integ = Integrator(IntegratorParams(wait_timeout=1.0))
    integ.plug("force", now=0.0)
    integ.plug("tactile", now=0.0)
    integ.offer("force", cloud(P, 0.6, stamp=0.0), 0.0)
    assert integ.cycle(0.001) is None
    integ.offer("force", Hypotheses.empty(0.005), 0.005)
    integ.offer("tactile", Hypotheses.empty(0.005), 0.005)
    f = integ.cycle(0.005)
    assert f is not None and fused_at(f, P) == pytest.approx(0.6)
    integ.offer("force", Hypotheses.empty(0.01), 0.01)
    integ.offer("tactile", Hypotheses.empty(0.01), 0.01)
    assert fused_at(integ.cycle(0.01), P) == pytest.approx(0.6)  # the space keeps it until it expires


def test_stops_waiting_after_wait_timeout_and_ignores_silent_sources():
    integ = Integrator(IntegratorParams(wait_timeout=0.1, source_timeout=1.0))
    integ.plug("a", now=0.0)
    integ.plug("dead", now=0.0)
    integ.offer("a", cloud(P, 0.5), 0.0)
    assert integ.cycle(0.05) is None
    assert integ.cycle(0.1) is not None  # waited long enough
    integ.offer("a", cloud(P, 0.5, stamp=2.0), 2.0)
    assert [s.name for s in integ.active(2.0)] == ["a"]  # "dead" silent for > source_timeout
    assert integ.cycle(2.0) is not None


def test_hypotheses_time_out():
    integ = Integrator(IntegratorParams(timeout=0.5))
    integ.offer("a", cloud(P, 0.5, stamp=0.0), 0.0)
    integ.offer("b", cloud(Q, 0.5, stamp=0.0), 0.0)
    integ.cycle(0.0)
    integ.offer("a", cloud(P, 0.5, stamp=0.4), 0.4)
    integ.offer("b", cloud(P, 0.5, stamp=0.4), 0.4)
    f = integ.cycle(0.6)
    # Q (only from b at t=0) expired; P has a's and b's fresh readings.
    assert fused_at(f, Q) is None
    assert fused_at(f, P) == pytest.approx(0.75)


def test_plug_unplug_while_running():
    integ = Integrator()
    integ.offer("a", cloud(P, 0.5), 0.0)
    integ.offer("b", cloud(P, 0.5), 0.0)
    assert integ.cycle(0.0).likelihood[0] == pytest.approx(0.75)
    integ.unplug("b")
    integ.offer("a", cloud(P, 0.5, stamp=0.1), 0.1)
    f = integ.cycle(0.1)  # no longer waits for b, and b's hypotheses are gone
    assert f.likelihood[0] == pytest.approx(0.5)
    integ.plug("c", now=0.1)
    integ.offer("a", cloud(P, 0.5, stamp=0.2), 0.2)
    assert integ.cycle(0.2) is None  # c is active: the cycle waits for it
    integ.offer("c", cloud(P, 0.5, stamp=0.2), 0.2)
    assert integ.cycle(0.2).likelihood[0] == pytest.approx(0.75)
    with pytest.raises(KeyError, match="not plugged"):
        integ.unplug("b")


def test_unknown_source_refused_without_auto_plug():
    integ = Integrator(IntegratorParams(auto_plug=False))
    with pytest.raises(KeyError, match="unplugged source"):
        integ.offer("x", cloud(P, 0.5), 0.0)


def test_matches_reference_on_random_clouds():
    rng = np.random.default_rng(3)
    integ = Integrator()
    clouds = []
    for s in range(3):
        kinds = rng.choice([0, 0, 0, 1, 2], 400).astype(np.uint8)
        h = voxelize(Hypotheses.make(rng.uniform(0, 0.05, (400, 3)), rng.uniform(0.01, 1, 400), kinds,
                                     rng.uniform(0, 5, 400), rng.normal(size=(400, 3)), 0.0))
        clouds.append(h)
        integ.offer(f"s{s}", h, 0.0)
    f = integ.cycle(0.0)
    keys = np.concatenate([voxel_keys(c.location, 0.005) for c in clouds])
    lik = np.concatenate([c.likelihood for c in clouds])
    kind = np.concatenate([c.kind for c in clouds])
    force = np.concatenate([c.force for c in clouds])
    uk, inv = np.unique(keys, return_inverse=True)
    fused = 1 - np.exp(np.bincount(inv, np.log1p(-np.minimum(lik, 1 - 1e-15)), uk.size))
    reg = np.bincount(inv, kind == 0, uk.size) > 0
    null = np.bincount(inv, kind == 2, uk.size) > 0
    fmean = np.bincount(inv, lik * force, uk.size) / np.bincount(inv, lik, uk.size)
    keep = reg & ~null
    got = dict(zip(voxel_keys(f.location, 0.005).tolist(), zip(f.likelihood, f.force, strict=True), strict=True))
    assert set(got) == set(uk[keep].tolist())
    for k, fl, fm in zip(uk[keep], fused[keep], fmean[keep], strict=True):
        assert got[int(k)][0] == pytest.approx(fl, rel=1e-9)
        assert got[int(k)][1] == pytest.approx(fm, rel=1e-9)


def test_moving_clouds_recycle_rows():
    integ = Integrator(IntegratorParams(timeout=0.05))
    base = np.random.default_rng(4).uniform(0, 0.1, (500, 3))
    for k in range(40):
        integ.offer("a", cloud(base + [0.01 * k, 0, 0], 0.5, stamp=0.1 * k), 0.1 * k)
        f = integ.cycle(0.1 * k)
        assert len(f) == len(np.unique(voxel_keys(base + [0.01 * k, 0, 0], 0.005)))
    assert integ.space.n < 3 * len(f)  # expired voxels are compacted away


def test_moving_clouds_reuse_the_rows_of_the_voxels_they_leave(monkeypatch):
    integ = Integrator(IntegratorParams(timeout=0.15))
    base = np.random.default_rng(5).uniform(0, 0.1, (2000, 3))
    monkeypatch.setattr(integ.space, "compact", lambda **kw: False)  # no dead row is dropped by a compaction
    rows = []
    for k in range(60):
        moved = base + [0.005 * (k if k < 30 else 60 - k), 0, 0]  # one voxel a cycle, out and back
        integ.offer("a", cloud(moved, 0.5, stamp=0.1 * k), 0.1 * k)
        f = integ.cycle(0.1 * k)
        live = len(integ.space)
        assert len(f) == live and np.isclose(f.likelihood, 0.5).all()  # each live voxel once, none lost
        assert integ.space.n - integ.space.index.nfree == live  # every dead row is free for the next voxels
        rows.append(integ.space.n)
    # over a third of the voxels die and as many are born every cycle; with no compaction the rows stop growing
    # once a cycle's deaths have freed enough for the next cycle's births
    assert len(set(rows[3:])) == 1 and rows[-1] < 2 * live


def test_support_without_force_does_not_dilute_the_force():
    integ = Integrator()
    integ.offer("ft", cloud(P, 0.2, force=6.0, direction=[0, 0, 1]), 0.0)
    integ.offer("sim", cloud(P, 0.5, HypothesisType.SUPPORT), 0.0)
    f = integ.cycle(0.0)
    assert f.force[0] == pytest.approx(6.0) and np.allclose(f.direction[0], [0, 0, 1])
    assert f.likelihood[0] == pytest.approx(1 - 0.8 * 0.5)


@settings(max_examples=40, deadline=None)
@given(st.lists(st.lists(st.tuples(st.integers(0, 6), st.integers(0, 6), st.integers(0, 2),
                                   st.floats(0.01, 0.99), st.sampled_from([0, 0, 1, 2])),
                         min_size=1, max_size=40), min_size=1, max_size=4))
def test_property_space_equals_stateless_fusion(sources):
    integ = Integrator()
    keys, liks, kinds = [], [], []
    for s, rows in enumerate(sources):
        by_voxel = {(i, j, k): (lik, kind) for i, j, k, lik, kind in rows}  # one hypothesis per voxel
        vox = np.array(list(by_voxel), dtype=float)
        lik = np.array([v[0] for v in by_voxel.values()])
        kind = np.array([v[1] for v in by_voxel.values()], dtype=np.uint8)
        h = Hypotheses.make((vox + 0.5) * 0.005, lik, kind)
        integ.offer(f"s{s}", h, 0.0)
        keys.append(voxel_keys(h.location, 0.005))
        liks.append(lik)
        kinds.append(kind)
    f = integ.cycle(0.0)
    k, lk, kd = np.concatenate(keys), np.concatenate(liks), np.concatenate(kinds)
    expected = {}
    for key in np.unique(k):
        m = k == key
        if (kd[m] == 0).any() and not (kd[m] == 2).any():
            expected[int(key)] = 1 - np.prod(1 - lk[m])
    got = dict(zip(voxel_keys(f.location, 0.005).tolist(), f.likelihood.tolist(), strict=True))
    assert got.keys() == expected.keys()
    for key, v in expected.items():
        assert got[key] == pytest.approx(v, rel=1e-9)
