"""The grasp benchmark (Table 3.3): a quick-mode smoke run and single trials of failure modes it once had."""

from __future__ import annotations

import functools
import json
import zlib

import numpy as np

from contactflow.embodiments import bench_grasp


def test_bench_grasp_quick(tmp_path) -> None:
    summary = bench_grasp.run(tmp_path, quick=True)
    assert {r["controller"] for r in summary["rows"]} == {"naive", "robust", "naive + error", "robust + error"}
    assert len(summary["trials"]) == 4
    assert json.loads((tmp_path / "grasp.json").read_text())["benchmark"] == "grasp"
    assert (tmp_path / "grasp.png").stat().st_size > 0 and (tmp_path / "grasp.md").exists()


@functools.cache
def _approach(name: str) -> np.ndarray:
    return bench_grasp.vision_approach(next(s for s in bench_grasp.objects() if s.name == name))


def _trial(name: str, controller: str, error: bool = False, trial: int = 0) -> dict:
    spec = next(s for s in bench_grasp.objects() if s.name == name)
    seed = 1000 * trial + zlib.crc32(name.encode()) % 997 if error else 0  # the benchmark's seed of that trial
    return bench_grasp.run_trial(spec, _approach(name), bench_grasp.Trial(name, controller, error, trial), seed=seed)


def test_naive_grasp_success_means_the_object_is_held() -> None:
    # the ball rolls out from under fingers frozen at their first touch: they stay open by their own
    # targets, which once counted as "held open by the object" (success with no contact at all)
    r = _trial("ball", "naive")
    assert r["grasp"] != "success" or r["success"], r


def test_robust_grasp_alignment_leaves_a_support_contact_to_the_sliding_grasp() -> None:
    # the 3 cm wood block, approach error trial 9: the hanging thumb touches the table first; eq. 3.1
    # used to creep 4 cm sideways on that torque and close beside the block
    r = _trial("wood", "robust", error=True, trial=9)
    assert r["grasp_values"]["support_contacts"] >= 1
    assert r["grasp_values"]["lateral"] < 0.02
    assert r["success"], r["why"]


def test_perturbed_approach_ending_on_the_wrist_limit_still_grasps() -> None:
    # cylinder, approach error trial 0: the planned move leaves joint 7 on its limit; the velocity IK
    # stepped it back in one tick, the F/T read the jerk as a contact and both grasps closed on nothing
    for controller in ("naive", "robust"):
        r = _trial("cylinder", controller, error=True, trial=0)
        assert r["move"] == "success", r
        assert r["grasp_values"]["duration"] > 3.0, r  # no jerk read as a contact at the start
        assert r["grasp"] in ("success", "failure"), r


def _grasp_centred(name: str, **params) -> tuple[bool, str, dict]:
    from contactflow.embodiments.primitives.base import pose6
    from contactflow.embodiments.primitives.runner import outcome, run_primitive

    spec = next(s for s in bench_grasp.objects() if s.name == name)
    _, robot, runner = bench_grasp.scene(spec)
    v = pose6(_approach(name))
    run_primitive(runner, "move_to", {"arm": "right", "target": [v[k] for k in ("x", "y", "z", "roll", "pitch", "yaw")]})
    z0 = float(robot.ground_truth().object_poses[name][2, 3])
    g = outcome(run_primitive(runner, "robust_grasp", {"arm": "right", "pregrasp_type": "open", **params}, max_time=25.0))
    run_primitive(runner, "lift", {"arm": "right", "distance": 0.1, "watch_grasp": False}, max_time=6.0)
    ok, why = bench_grasp.judge(robot, name, z0)
    return ok, why, g.values


def test_allegro_sliding_grasp_keeps_a_light_contact_with_the_table() -> None:
    # the ball, centred: fingers closing at 0.8 rad/s while eq. 3.2 backs off at the thesis's 5 mm/s
    # press the table with tens of N and squeeze the ball out; the allegro profile slows the
    # fingers while the hand backs off and backs off at 1 cm/s
    ok, why, vals = _grasp_centred("ball")
    assert ok, why
    assert vals["slides_back"] > 0  # the sliding grasp did back off the table
    ok_fast, _, _ = _grasp_centred("ball", pressing_closing_velocity=-1.0, correction_velocity=0.005)
    assert not ok_fast, "the ball is held without the slower closing: the test no longer exercises it"
