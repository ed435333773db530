"""Smoke test of ``contactflow bench sim`` in its quick form."""

from __future__ import annotations

import json

import numpy as np
import pytest

from contactflow.embodiments import bench_runtime
from contactflow.embodiments.bench_sim import run


def kept_logs(out) -> str:
    """The ends of the node logs a bench kept (what the nodes of a lockstep run that did not repeat had to say)."""
    return "\n".join(f"{log.parent.name}/{log.name}: {line}" for log in sorted(out.glob("runtime_logs/*/*.log"))
                     for line in log.read_text().splitlines()[-20:])


@pytest.mark.heavy(seconds=65)
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
    # quick: the pipelined cell only (test_runtime_repeat repeats the plain lockstep across process layouts)
    assert list(rt["rtf"]) == ["1 robot, pipelined"]
    row = rt["rtf"]["1 robot, pipelined"]
    one, split = row["one_process"], row["split"]
    assert one["outcomes"] == split["outcomes"] == {"tombatossals": "success"}
    # the same run, exactly, in both layouts: the same events at the same simulated times, no tick overrun
    assert row["repeated"] and one["trace"] == split["trace"] and one["events"] == split["events"] > 10, kept_logs(tmp_path)
    assert one["sim_s"] == split["sim_s"] > 5.0
    assert one["overruns"] == split["overruns"] == 0 and not (tmp_path / "runtime_logs").exists()
    assert {"detect_objects", "move_to", "robust_grasp", "lift", "transport", "place", "release"} <= set(one["visited"])
    # the can left its place and stands on the table near the place target
    x, y, z = one["objects"]["cyl"]
    assert z == pytest.approx(0.81, abs=0.015) and np.hypot(x - 0.55, y + 0.3) > 0.1
    assert one["rtf"] > 0 and split["rtf"] > 0
    # where a tick goes, from the modules' statuses over the wire: the same modules in both layouts, the world's
    # physics and state over 0.1 ms a tick, the robot's fusion there too; no more CPU than two cores give in a tick
    for run_ in (one, split):
        cpu = run_["cpu_ms_per_tick"]
        assert cpu["site/world/world"] > 0.1 and cpu["tombatossals/control_tombatossals/contacts"] > 0, cpu
        assert sum(cpu.values()) < 2 * 5.0 / run_["rtf"], (cpu, run_["rtf"])
    assert set(one["cpu_ms_per_tick"]) == set(split["cpu_ms_per_tick"])
    assert rt["round_trip"]["ticks"] == 90 and 0 < rt["round_trip"]["p50_ms"] <= rt["round_trip"]["p99_ms"]
    assert saved["runtime"]["round_trip"] == rt["round_trip"]


def test_the_node_logs_of_layouts_that_did_not_repeat_are_kept(tmp_path, monkeypatch):
    def rtf_runs(folder, advance, layouts):
        (folder / "1_split").mkdir()
        (folder / "1_split" / "world.log").write_text("tick 11: ...")
        (folder / "1_split" / "cell.yaml").write_text("scene: table")
        return {"1 robot": {"repeated": False}}

    monkeypatch.setattr(bench_runtime, "rtf_runs", rtf_runs)
    monkeypatch.setattr(bench_runtime, "round_trip", lambda ticks, folder: {})
    bench_runtime.run(quick=True, out_dir=tmp_path)
    assert (tmp_path / "runtime_logs" / "1_split" / "world.log").read_text() == "tick 11: ..."
    assert not (tmp_path / "runtime_logs" / "1_split" / "cell.yaml").exists()


def test_a_cell_run_counts_its_ticks_at_the_rate_its_world_ran():
    from contactflow.embodiments.layout import _control_rate, world_node

    assert _control_rate(world_node("s", "cell.yaml", control_rate=100.0)) == 100.0
    assert _control_rate(world_node("s", "cell.yaml")) == 200.0  # the world module's own default (§6.3.1)
