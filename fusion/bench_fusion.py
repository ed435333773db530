"""Benchmark: fusion cycles per second, 3 sources x {1k, 10k, 100k} hypotheses (issue 5).

Each source sends a voxelised cloud every cycle (two regular sources and one support source
over a common region, so clouds overlap about half); a cycle is three ``offer`` calls and one
``cycle`` of the :class:`~contactflow.fusion.integrator.Integrator` (Alg. 4.1 + eq. 4.14 with
the type rules, likelihood-weighted force, timeouts). Two scenes: ``static`` (the same voxels
every cycle, e.g. taxels) and ``moving`` (every cloud shifts by one voxel per cycle, out over 64
positions and back, so voxels are created and expire all the time and a cloud never jumps). The
reference is the same maths written as one numpy expression over the concatenated clouds (unique +
bincount), stateless, in the same run; the two results are compared on the first cycle. The
integrator's rate comes from its median cycle and from its mean: the mean pays the rare long
cycles too (the space growing to the clouds' size, a compaction).
"""

from __future__ import annotations

import json
import pathlib
import platform
import time

import numpy as np
from rich.console import Console
from rich.progress import Progress
from rich.table import Table

from contactflow.fusion.hypotheses import VOXEL_SIZE, Hypotheses, HypothesisType, voxel_keys
from contactflow.fusion.integrator import Integrator, IntegratorParams

SIZES = (1_000, 10_000, 100_000)
KINDS = (HypothesisType.REGULAR, HypothesisType.REGULAR, HypothesisType.SUPPORT)
GOAL_HZ = 1000.0  # at 3 x 10k


def make_clouds(n: int, rng: np.random.Generator) -> list[Hypotheses]:
    """Three clouds of ``n`` distinct voxels each, drawn from a common region of 2n voxels."""
    side = int(np.ceil((2 * n) ** (1 / 3)))
    region = np.stack(np.meshgrid(*[np.arange(side)] * 3, indexing="ij"), -1).reshape(-1, 3)[: 2 * n]
    clouds = []
    for kind in KINDS:
        pick = rng.choice(region.shape[0], n, replace=False)
        loc = (region[pick] + 0.5) * VOXEL_SIZE + np.array([0.3, -0.2, 0.7])
        clouds.append(Hypotheses.make(loc, rng.uniform(0.05, 0.9, n), kind, rng.uniform(0, 5, n),
                                      rng.normal(size=(n, 3)) / np.sqrt(3), 0.0))
    return clouds


def reference(clouds: list[Hypotheses], voxel: float = VOXEL_SIZE) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The fusion maths in one expression: (voxel keys, H(x), mean force) of the kept voxels."""
    keys = np.concatenate([voxel_keys(c.location, voxel) for c in clouds])
    lik = np.concatenate([c.likelihood for c in clouds])
    kind = np.concatenate([c.kind for c in clouds])
    force = np.concatenate([c.force for c in clouds])
    uk, inv = np.unique(keys, return_inverse=True)
    m = uk.size
    keep = (np.bincount(inv, kind == HypothesisType.REGULAR, m) > 0) & ~(np.bincount(inv, kind == HypothesisType.NULL, m) > 0)
    fused = 1.0 - np.exp(np.bincount(inv, np.log1p(-np.minimum(lik, 1 - 1e-12)), m))
    mean_force = np.bincount(inv, lik * force, m) / np.bincount(inv, lik, m)
    return uk[keep], fused[keep], mean_force[keep]


def reference_aligned(lik: np.ndarray, force: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The bare maths on clouds already aligned voxel by voxel, (S, n) arrays: eq. 4.14 and
    the weighted force (a lower bound: no voxel association, no type rules, no state)."""
    return 1.0 - np.prod(1.0 - lik, axis=0), (lik * force).sum(axis=0) / lik.sum(axis=0)


def _shifted(clouds: list[Hypotheses], k: int, stamp: float, moving: bool) -> list[Hypotheses]:
    off = np.array([k * VOXEL_SIZE, 0.0, 0.0]) if moving else None
    return [Hypotheses(c.location + off if moving else c.location, c.likelihood, c.kind, c.force, c.direction,
                       stamp) for c in clouds]


def _rates(fn, min_time: float, min_iter: int) -> tuple[float, float]:
    """Cycles per second from the median time of one call (robust to a busy machine), and from the
    mean (what a loop sustains: it pays the rare long cycles, a compaction's, too)."""
    times = []
    k, t0 = 0, time.perf_counter()
    while True:
        t = time.perf_counter()
        fn(k)
        times.append(time.perf_counter() - t)
        k += 1
        if time.perf_counter() - t0 >= min_time and k >= min_iter:
            return 1.0 / float(np.median(times)), 1.0 / float(np.mean(times))


def run_size(n: int, moving: bool, min_time: float, rng: np.random.Generator) -> dict:
    clouds = make_clouds(n, rng)
    dt = 0.001
    integ = Integrator(IntegratorParams(timeout=2.5 * dt))
    names = ("tactile", "force_torque", "simulator")
    # Moving clouds are prepared ahead so the timing holds fusion only.
    frames = [_shifted(clouds, k, k * dt, moving) for k in range(64)] if moving else None

    def fuse(k: int):
        now = k * dt
        batch = frames[63 - abs(63 - k % 126)] if frames is not None else _shifted(clouds, 0, now, False)
        for name, c in zip(names, batch, strict=True):
            if frames is not None:
                c = Hypotheses(c.location, c.likelihood, c.kind, c.force, c.direction, now)
            integ.offer(name, c, now)
        return integ.cycle(now)

    first = fuse(0)
    rk, rf, rm = reference(clouds)
    got = voxel_keys(first.location, VOXEL_SIZE)
    order = np.argsort(got)
    same = bool(np.array_equal(got[order], rk))
    err = float(max(np.abs(first.likelihood[order] - rf).max(), np.abs(first.force[order] - rm).max())) if same else float("nan")
    integ_hz, integ_mean_hz = _rates(lambda k: fuse(k + 1), min_time, 5)
    ref_batches = frames if frames is not None else [clouds]
    ref_hz, _ = _rates(lambda k: reference(ref_batches[k % len(ref_batches)]), min_time, 5)
    lik = np.stack([c.likelihood for c in clouds])
    force = np.stack([c.force for c in clouds])
    bare_hz, _ = _rates(lambda k: reference_aligned(lik, force), min_time, 5)
    return {"hypotheses_per_source": n, "scene": "moving" if moving else "static", "fused_voxels": int(len(first)),
            "integrator_hz": integ_hz, "integrator_mean_hz": integ_mean_hz, "reference_hz": ref_hz, "speedup": integ_hz / ref_hz,
            "aligned_maths_hz": bare_hz,
            "same_voxels": same, "max_abs_diff": err}


def run(out_dir: pathlib.Path, quick: bool = False) -> dict:
    out_dir = pathlib.Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(0)
    sizes = SIZES[:2] if quick else SIZES
    min_time = 0.1 if quick else 1.0
    rows = []
    with Progress(transient=True) as progress:
        task = progress.add_task("fusion cycles", total=2 * len(sizes))
        for n in sizes:
            for moving in (False, True):
                rows.append(run_size(n, moving, min_time, rng))
                progress.advance(task)
    table = Table(title="Fusion cycles per second, 3 sources (one core)")
    for col in ("hyp/source", "scene", "fused voxels", "integrator Hz (median)", "integrator Hz (mean)", "numpy ref Hz",
                "speed-up", "aligned maths Hz", "same result"):
        table.add_column(col, justify="right")
    for r in rows:
        table.add_row(f"{r['hypotheses_per_source']:,}", r["scene"], f"{r['fused_voxels']:,}",
                      f"{r['integrator_hz']:,.0f}", f"{r['integrator_mean_hz']:,.0f}", f"{r['reference_hz']:,.0f}",
                      f"{r['speedup']:.1f}x",
                      f"{r['aligned_maths_hz']:,.0f}",
                      "yes" if r["same_voxels"] and r["max_abs_diff"] < 1e-9 else f"NO ({r['max_abs_diff']:.1e})")
    Console().print(table)
    at10k = [r for r in rows if r["hypotheses_per_source"] == 10_000]
    summary = {
        "benchmark": "fusion",
        "quick": quick,
        "machine": {"python": platform.python_version(), "numpy": np.__version__, "cpu": platform.processor()},
        "goal_hz_at_3x10k": GOAL_HZ,
        "results": rows,
        "static_3x10k_hz": next((r["integrator_hz"] for r in at10k if r["scene"] == "static"), None),
        "moving_3x10k_hz": next((r["integrator_hz"] for r in at10k if r["scene"] == "moving"), None),
    }
    (out_dir / "fusion.json").write_text(json.dumps(summary, indent=2))
    return summary

