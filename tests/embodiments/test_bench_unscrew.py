"""The unscrew benchmark (Tables 3.4-3.5): a quick run, and its tables from trial records."""

from __future__ import annotations

import json

import pytest

from contactflow.embodiments import bench_unscrew


@pytest.mark.heavy(seconds=30)
def test_bench_unscrew_quick_removes_the_cap_found_by_the_kinect_with_the_re_centring_off_and_on(tmp_path) -> None:
    summary = bench_unscrew.run(tmp_path, quick=True)
    trials = summary["trials"]
    assert [(t["bottle"], t["reactive"], t["noise"]) for t in trials] == [("bottle4", False, False), ("bottle4", True, False)]
    for t in trials:
        assert t["vision_error"] < 0.004, t  # the cap's top face seen by the Kinect, not the side it faces
        # the thread (0.3 turns) let go under the 30 degree twists and the cap came off the neck in the fingers
        assert t["success"] and t["unscrewed"] and t["turned_deg"] >= 108.0 and t["lift"] >= 0.03, t
        assert t["twists"] >= 3 and t["turned_deg"] <= 30.0 * t["twists"] + 30.0, t  # turned by its 30 degree twists
    assert trials[1]["corrections"] >= 1 and trials[0]["corrections"] == 0
    assert json.loads((tmp_path / "unscrew.json").read_text())["benchmark"] == "unscrew"
    assert (tmp_path / "unscrew.png").stat().st_size > 0 and (tmp_path / "unscrew.md").exists()


def test_the_tables_count_successes_unscrewed_caps_and_failures_by_cause_per_re_centring() -> None:
    def trial(reactive: bool, noise: bool, success: bool, unscrewed: bool, cause: str, t: float, twists: int) -> dict:
        return {"reactive": reactive, "noise": noise, "success": success, "unscrewed": unscrewed, "cause": cause,
                "time": t, "twists": twists}

    rows = bench_unscrew.rows_of([
        trial(False, False, True, True, "", 30.0, 6), trial(False, False, False, True, "every pinch missed the cap", 50.0, 10),
        trial(True, False, True, True, "", 40.0, 8),
        trial(False, True, False, False, "every pinch missed the cap", 5.0, 0), trial(True, True, True, True, "", 60.0, 12),
    ])
    assert [(r["table"], r["reactive"]) for r in rows] == [("table_3_4", "no"), ("table_3_4", "yes"),
                                                           ("table_3_5", "no"), ("table_3_5", "yes")]
    plain = rows[0]
    assert plain["success"]["successes"] == 1 and plain["success"]["trials"] == 2
    assert plain["unscrewed"]["successes"] == 2 and plain["time"] == 40.0 and plain["moves"] == 8.0
    assert plain["failures"] == {"every pinch missed the cap": 1} and rows[1]["failures"] == {}
    assert rows[2]["success"]["successes"] == 0 and rows[3]["success"]["ci95"][1] == 1.0
