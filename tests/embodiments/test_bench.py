"""Smoke test of ``contactflow bench sim`` in its quick form."""

from __future__ import annotations

import json

import pytest

from contactflow.embodiments.bench_sim import run


@pytest.mark.heavy(seconds=60)
def test_quick_bench_writes_its_summary(tmp_path):
    summary = run(tmp_path, quick=True)
    saved = json.loads((tmp_path / "sim.json").read_text())
    assert set(saved["single"]) == {"tombatossals", "melfa", "baxter"}
    assert all(r["rtf"] > 0 and not r["failed"] for r in saved["single"].values())
    assert saved["pair"]["two_processes_two_cores"]["rtf"] > 0
    assert summary["kinematics"]["wrapper_us"] > 0
    assert set(summary["planning"]) == {"KPIECE1", "RRTConnect"}
    assert all(0.0 <= p["success"]["rate"] <= 1.0 for p in summary["planning"].values())
    rt = summary["runtime"]
    row = rt["rtf"]["1 robot"]
    assert row["one_process"]["outcomes"] == row["split"]["outcomes"] == {"tombatossals": "success"}
    assert row["one_process"]["sim_s"] == row["split"]["sim_s"] > 5.0  # the same run, exactly, in both layouts
    assert row["one_process"]["rtf"] > 0 and row["split"]["rtf"] > 0
    assert rt["round_trip"]["ticks"] == 90 and 0 < rt["round_trip"]["p50_ms"] <= rt["round_trip"]["p99_ms"]
    assert saved["runtime"]["round_trip"] == rt["round_trip"]
