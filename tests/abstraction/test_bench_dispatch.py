"""bench dispatch: stand-in robots in processes of their own are dispatched to, started and cancelled."""

import subprocess
import sys

import pytest
from rich.progress import Progress

from contactflow.abstraction import bench_dispatch


@pytest.mark.timeout(180)
def test_standins_start_on_dispatch_and_end_on_cancel_every_trial():
    with Progress(disable=True) as bar:
        rows = bench_dispatch._standins(4, 2, bring_ups=1, warm=1, bar=bar)
    assert [r["phase"] for r in rows] == ["cold", "warm"]
    for r in rows:
        # every stand-in reported its first state after the dispatch was sent, and the task ended (cancelled)
        assert sorted(r["first_state_s"]) == [f"standin{i:02d}" for i in range(4)]
        assert all(0 < t < 30 for t in r["first_state_s"].values()) and 0 < r["reply_s"] < 30
    summary = bench_dispatch.summarise(rows)
    assert [(s["setup"], s["phase"], s["robots"], s["trials"]) for s in summary] == [
        ("stand-ins", "cold", 4, 1), ("stand-ins", "warm", 4, 1)]
    assert summary[1]["start_max_s"] == max(rows[1]["first_state_s"].values())


def test_warm_imports_the_primitives_a_translation_needs_before_any_dispatch():
    code = ("import sys; from contactflow.abstraction.agent import warm; from contactflow.abstraction.profiles import PROFILES; "
            "m = 'contactflow.embodiments.primitives.robust_grasp'; before = m in sys.modules; "
            "warm(PROFILES['tombatossals']); print(before, m in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True)
    assert out.stdout.split() == ["False", "True"]
