"""Smoke run of the empty-a-box benchmark (Table 3.6) in quick mode."""

from __future__ import annotations

import json

from contactflow.embodiments import bench_empty_box


def test_bench_empty_box_quick(tmp_path) -> None:
    summary = bench_empty_box.run(tmp_path, quick=True)
    assert [r["method"] for r in summary["rows"]] == ["random", "exploration", "vision"]
    assert all(r["runs"] == 1 for r in summary["rows"])
    assert all(run["attempts"] >= 1 for run in summary["runs"])  # every strategy found something to try
    saved = json.loads((tmp_path / "empty_box.json").read_text())
    assert saved["benchmark"] == "empty_box" and len(saved["runs"]) == 3
    assert (tmp_path / "empty_box.png").stat().st_size > 0 and (tmp_path / "empty_box.md").exists()


def test_sweep_covers_the_box_bottom() -> None:
    pts = bench_empty_box.sweep_points(0.8)
    xy = [(pts[i], pts[i + 1]) for i in range(0, len(pts), 3)]
    xs = sorted({round(x, 3) for x, _ in xy})
    assert len(xs) == 4 and xs[-1] - xs[0] > 0.1
    assert all(abs(pts[i + 2] - 0.8) < 1e-9 for i in range(0, len(pts), 3))
