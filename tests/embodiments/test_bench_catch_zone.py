"""The catch-zone benchmark: grasps of one object in the box from a grid of offsets, classified by how they ended."""

from __future__ import annotations

import json

import pytest

from contactflow.embodiments import bench_catch_zone as cz
from contactflow.nodes.status import Event


@pytest.mark.heavy(seconds=50)
def test_quick_catch_zone_on_the_runtime_holds_the_centred_can_and_not_the_one_beside_the_wall(tmp_path) -> None:
    """The attempt task run by a control node against a world node per grasp, two grasps at once, judged from the
    progress stream and eval/; the summary, table and plot written from those runs."""
    summary = cz.run(tmp_path, quick=True, jobs=2, executor="runtime")
    by_cell = {(t["dx"], t["dy"]): t for t in summary["trials"]}
    assert set(by_cell) == {(dx, dy) for dx in cz.QUICK_OFFSETS for dy in cz.QUICK_OFFSETS}
    assert {t["executor"] for t in summary["trials"]} == {"runtime"}
    centred = by_cell[(0.0, 0.0)]
    assert centred["outcome"] == "held" and centred["rise"] > cz.LIFTED
    # 6 cm toward -x the flat fingers reach over the box wall and close on its top: no grasp
    beside = by_cell[(-0.06, 0.0)]
    assert beside["outcome"] == "grasp_failed" and beside["node"] == "grasp" and beside["rise"] < 0.01
    (row,) = summary["rows"]
    assert row["object"] == "can" and row["held"] == 1 and row["held_centre"] == [0.0, 0.0]
    assert row["area_cm2"] == pytest.approx(36.0) and row["executor"] == "runtime"  # one 6 x 6 cm cell
    saved = json.loads((tmp_path / "catch_zone.json").read_text())
    assert saved["benchmark"] == "catch_zone" and len(saved["trials"]) == 4 and saved["executors"] == ["runtime"]
    assert "| can | centre | 0.00 | runtime | 1/4 | 36 |" in (tmp_path / "catch_zone.md").read_text()
    assert (tmp_path / "catch_zone.png").stat().st_size > 0


def test_outcome_is_the_first_ending_and_the_lift_is_checked_on_the_object() -> None:
    assert cz._outcome({}, 0.0) is cz.Outcome.TIMEOUT
    assert cz._outcome({"node": "approach", "event": Event.FAILURE}, 0.0) is cz.Outcome.APPROACH_FAILED
    assert cz._outcome({"node": "grasp", "event": Event.ERROR}, 0.0) is cz.Outcome.GRASP_FAILED
    assert cz._outcome({"node": "lift", "event": Event.SUCCESS}, 0.15) is cz.Outcome.HELD
    # the lift ran its distance but the object stayed behind (a grasp of the box, not of the object)
    assert cz._outcome({"node": "lift", "event": Event.SUCCESS}, 0.01) is cz.Outcome.LOST
    assert cz._outcome({"node": "lift", "event": Event.GRASP_LOST}, 0.0) is cz.Outcome.LOST
    assert cz._outcome({"node": "lift", "event": Event.FAILURE}, 0.0) is cz.Outcome.LIFT_BLOCKED


def test_summary_counts_the_held_area_and_where_the_held_cells_are() -> None:
    trials = [{"object": "cube", "dx": dx, "dy": dy, "outcome": cz.Outcome.HELD if dx >= 0 else cz.Outcome.LOST}
              for dx in (-0.02, 0.0, 0.02) for dy in (0.0, 0.02)]
    (row,) = cz.summarize(trials, (-0.02, 0.0, 0.02))
    assert row["held"] == 4 and row["area_cm2"] == pytest.approx(16.0)
    assert row["held_centre"] == pytest.approx([0.01, 0.01])
    assert row["outcomes"]["lost"] == 2 and row["outcomes"]["grasp_failed"] == 0 and row["at"] == [0.0, 0.0]
    # the same object beside a wall is a case of its own
    wall = [{**t, "at": [0.08, 0.0], "outcome": cz.Outcome.GRASP_FAILED} for t in trials]
    centre, beside = cz.summarize(trials + wall, (-0.02, 0.0, 0.02))
    assert (centre["held"], beside["held"], beside["at"]) == (4, 0, [0.08, 0.0])
    assert beside["held_centre"] is None and cz._where(beside) == "+8, +0 cm" and cz._where(centre) == "centre"


def test_unknown_object_is_named() -> None:
    with pytest.raises(ValueError, match="unknown object 'vase'"):
        cz.trial("vase", 0.0, 0.0)
