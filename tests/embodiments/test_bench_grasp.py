"""Smoke run of the grasp benchmark (Table 3.3) in quick mode."""

from __future__ import annotations

import json

from contactflow.embodiments import bench_grasp


def test_bench_grasp_quick(tmp_path) -> None:
    summary = bench_grasp.run(tmp_path, quick=True)
    assert {r["controller"] for r in summary["rows"]} == {"naive", "robust", "naive + error", "robust + error"}
    assert len(summary["trials"]) == 4
    assert json.loads((tmp_path / "grasp.json").read_text())["benchmark"] == "grasp"
    assert (tmp_path / "grasp.png").stat().st_size > 0 and (tmp_path / "grasp.md").exists()
