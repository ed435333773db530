"""`contactflow demo` (quick): five node processes, ATD 1 dispatched to all three robots, a report."""

import json

from contactflow.deploy import demo


def test_quick_demo_dispatches_to_every_robot_and_writes_the_report(tmp_path):
    code = demo.run(tmp_path, quick=True)
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert code == 0, summary["tasks"]
    assert len(summary["nodes"]) == 5
    (task,) = summary["tasks"]
    assert task["atd"] == "push_away.xml" and task["dispatched"] and task["finished"]
    assert sorted(task["robots"]) == ["baxter", "melfa", "tombatossals"]
    assert sorted(task["outcomes"]) == ["baxter", "melfa", "tombatossals"]
    entered = {(p["robot"], p["state"]) for p in summary["progress"] if p["kind"] == "entered"}
    assert {r for r, s in entered if s == "approach"} == {"baxter", "melfa", "tombatossals"}
    for name in ("timeline.png", "contacts.png"):
        assert (tmp_path / name).stat().st_size > 10_000
