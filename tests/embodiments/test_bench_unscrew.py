"""The unscrew benchmark (Tables 3.4-3.5): a quick run, and its tables from trial records."""

from __future__ import annotations

import json

import pytest

from contactflow.embodiments import bench_unscrew


@pytest.mark.heavy(seconds=45)
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


def test_a_runtime_trial_is_judged_from_the_bottle_and_cap_poses() -> None:
    from types import SimpleNamespace

    import numpy as np

    spec = bench_unscrew.ScrewBottleSpec("bottle2", (0.5, 0.0, 0.75), thread_turns=0.5)
    neck = np.array([0.0, 0.0, spec.body_height + spec.neck_height + spec.cap_height / 2])

    def at(turn_deg: float, lift: float, tilt_deg: float = 0.0) -> dict:
        body = np.eye(4)
        a = np.radians(tilt_deg)
        body[:3, :3] = [[1.0, 0.0, 0.0], [0.0, np.cos(a), -np.sin(a)], [0.0, np.sin(a), np.cos(a)]]
        body[:3, 3] = (0.5, 0.0, 0.8)
        c, s = np.cos(np.radians(turn_deg)), np.sin(np.radians(turn_deg))
        cap = body.copy()
        cap[:3, :3] = body[:3, :3] @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        cap[:3, 3] = body[:3, 3] + body[:3, :3] @ (neck + [0.0, 0.0, lift])
        return {"bottle2": body, "bottle2_cap": cap}

    def event(name: str, kind: str, t: float, **values: float):
        return SimpleNamespace(module=f"tombatossals/control/{name}", event=kind, detail="", values=values,
                               hdr=SimpleNamespace(t_sim=t))

    trial = bench_unscrew.Trial("bottle2", True, False, 0, "runtime")
    # 30 degree twists sampled every 10 degrees: the turn is unwrapped through +-180 degrees
    opened = [(0.1 * k, at(10.0 * k, 0.0)) for k in range(19)] + [(2.0, at(180.0, 0.04))]
    ends = {"unscrew": event("unscrew", "success", 2.0, twists=6.0, duration=40.0)}
    r = bench_unscrew.runtime_result(trial, spec, opened, ends, "success", 30.0)
    assert r["success"] and r["unscrewed"] and r["turned_deg"] == pytest.approx(180.0) and r["lift"] == pytest.approx(0.04)
    assert (r["twists"], r["time"], r["cause"]) == (6, 40.0, "")
    toppled = opened[:-1] + [(2.0, at(180.0, 0.04, tilt_deg=45.0))]
    r = bench_unscrew.runtime_result(trial, spec, toppled, ends, "success", 30.0)
    assert not r["success"] and r["cause"] == "bottle toppled"
    held_closed = [(0.1 * k, at(3.0 * k, 0.0)) for k in range(10)]
    # the approach stopped short (tolerated, the grasp went on), then finding the cap failed and ended the task
    failed = {"move_to": event("move_to", "failure", 5.0), "robust_grasp": event("robust_grasp", "success", 12.0),
              "detect_objects": event("detect_objects", "failure", 20.0), "task": event("task", "failure", 20.0)}
    r = bench_unscrew.runtime_result(trial, spec, held_closed, failed, "failure", 10.0)
    assert not r["success"] and not r["unscrewed"] and r["cause"] == "detect_objects: failure"
