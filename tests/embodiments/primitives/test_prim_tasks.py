"""Thesis task files through the task engine with the in-process runner on the simulated robot."""

from __future__ import annotations

import numpy as np
import pytest

from contactflow.embodiments.primitives.base import pose6, top_grasp_pose
from contactflow.embodiments.primitives.runner import LocalPrimitiveRunner, run_task
from contactflow.embodiments.sim_robot import SimRobot
from contactflow.embodiments.tasks import load
from contactflow.embodiments.testing import gaze_deg
from contactflow.embodiments.world import World, WorldParams, box, cylinder
from contactflow.nodes.status import Event, Status
from contactflow.nodes.taskengine import ProgressKind
from contactflow.nodes.taskgraph import TaskError


def test_task_file_loads_every_thesis_task() -> None:
    tasks, main = load()
    assert main == "pick_and_place"
    assert {"pick", "place", "pick_and_place", "clear_table", "box_attempt", "empty_box_vision",
            "empty_box_random", "empty_box_exploration", "track_object", "look_and_pick_and_place"} <= set(tasks)
    with pytest.raises(TaskError, match="needs parameter 'approach'"):
        from contactflow.nodes.taskgraph import bind_plan

        bind_plan(tasks["pick"], {})


def test_empty_box_strategies_go_on_after_an_attempt_that_ends_in_an_error() -> None:
    # an attempt whose back-off transport faulted ended a vision run with 4 objects left (bench seed 104)
    tasks, _ = load()
    for name in ("empty_box_vision", "empty_box_random", "empty_box_exploration"):
        g = tasks[name]
        attempts = [n for n in g.nodes if n.startswith("attempt")]
        assert attempts, name
        for node in attempts:
            for event in (Event.SUCCESS, Event.FAILURE, Event.ERROR):
                assert any(e.origin == node and event in e.events and not g.nodes[e.dest].kind.terminal
                           for e in g.edges), (name, node, event)


def test_exploration_rises_off_the_object_it_came_down_on_before_approaching_it() -> None:
    # straight from where the downward exploration stopped, 4 of 7 approaches hit an object and aborted the attempt
    g = load()[0]["empty_box_exploration"]
    after_down = [e.dest for e in g.edges if e.origin == "down" and Event.SUCCESS in e.events]
    assert len(after_down) == 1
    rise = g.nodes[after_down[0]]
    assert rise.type == "transport" and rise.params["relative"]
    assert rise.params["target"][2] >= 0.1 and not any(rise.params["target"][k] for k in (0, 1, 3, 4, 5))
    for event in (Event.SUCCESS, Event.FAILURE):
        assert [e.dest for e in g.edges if e.origin == rise.id and event in e.events] == ["aim_down"]


def test_track_object_localizes_the_object_again_when_it_is_lost() -> None:
    from contactflow.nodes.taskengine import TaskEngine
    from contactflow.nodes.testing_tasks import FakeClock, FakeRunner, Step, run_until_done

    tasks = load()[0]
    clock = FakeClock()
    runner = FakeRunner(clock)
    seen = {"cx": 0.6, "cy": 0.2, "cz": 0.8}
    runner.script("detect_objects", [Step(0.1, Event.SUCCESS, seen)], [Step(0.1, Event.FAILURE)],
                  [Step(0.1, Event.SUCCESS, seen | {"cx": 0.5})])
    runner.script("track", [Step(2.0, Event.OBJECT_LOST)], [Step(1.0, Event.SUCCESS)])
    runner.script("wait_event", [Step(0.5, Event.SUCCESS)])
    log: list = []
    engine = TaskEngine(runner, clock, library=tasks, on_progress=log.append)
    res = run_until_done(engine, clock, engine.launch(tasks["track_object"], {"region": [0, 0, 0, 1, 1, 1]}))
    assert res.status is Status.SUCCESS
    entered = [p.node for p in log if p.kind is ProgressKind.ENTERED]
    assert entered == ["localize", "follow", "localize", "pause", "localize", "follow", "done"]
    assert [p["target"] for _, t, p in runner.starts if t == "track"] == [[0.6, 0.2, 0.8], [0.5, 0.2, 0.8]]


def test_exploration_pulls_a_blocked_hand_free_and_starts_over() -> None:
    from contactflow.nodes.taskengine import TaskEngine
    from contactflow.nodes.testing_tasks import FakeClock, FakeRunner, Step, run_until_done

    # a run ended with 5 objects left when the sweep's arm was blocked: no edge took that failure
    tasks = load()[0]
    clock = FakeClock()
    runner = FakeRunner(clock)
    runner.script("move_to", [Step(0.1, Event.SUCCESS)]).script("transport", [Step(0.1, Event.SUCCESS)])
    runner.script("down", [Step(0.1, Event.FAILURE)], [Step(0.1, Event.OBJECT_NOT_FOUND)])
    runner.script("sweep", [Step(0.1, Event.FAILURE)], [Step(0.1, Event.OBJECT_NOT_FOUND)])
    runner.script("explore", [Step(0.1, Event.OBJECT_NOT_FOUND)])  # the corner probes' descents
    log: list = []
    engine = TaskEngine(runner, clock, library=tasks, on_progress=log.append)
    params = {"start": [0.55, -0.32, 0.9, np.pi, 0.0, 0.0], "bottom": 0.76, "sweep": [0.5, -0.4, 0.8], "target": [0.55, 0.0, 0.8]}
    params |= {f"{k}_{i}": [0.5, -0.3, 0.9, np.pi, 0.0, 0.0][: 6 if k == "corner" else 3] for k in ("corner", "drag") for i in range(1, 5)}
    run = engine.launch(tasks["empty_box_exploration"], params)
    res = run_until_done(engine, clock, run)
    assert res.status is Status.SUCCESS and res.terminal == "done"
    entered = [p.node for p in log if p.kind is ProgressKind.ENTERED]
    probes = [n for k in range(1, 5) for n in (f"probe_{k}", "over", "down", "rise", "nothing")]
    assert entered == ["above", "down", "free", "above", "down", "rise", "sweep", "free",
                       "above", "down", "rise", "sweep", "leave", *probes, "done"]


def test_empty_box_vision_approach_leaves_the_pregrasp_room_above_the_object() -> None:
    # the fingers take the pregrasp at the approach start: the cylindrical one reaches 6.6 cm below the grasp
    # centre, and 5 cm above an object's top it came down on it and its neighbours (first attempts in the
    # 5-object box: 9/64 removed an object, 17/64 from 10 cm with the grasp centred on the object's top)
    from contactflow.embodiments import registry
    from contactflow.embodiments.hand_geometry import hand_points

    tasks, _ = load()
    standoff = tasks["empty_box_vision"].nodes["detect"].params["standoff"]
    pregrasp = tasks["box_attempt"].nodes["grasp"].params["pregrasp_type"]
    robot = SimRobot(World(WorldParams()), "tombatossals")
    robot.hand(robot.spec.arm("right").hand).preshape(pregrasp)
    robot.step(1.5)
    reach = hand_points(robot, "right")[:, 2].max() - registry.home("tombatossals").grasp_center[2]  # the hand's z points down
    assert reach > 0.005, "the pregrasp's fingertips were not measured below the grasp centre"
    assert reach + 0.02 < standoff  # at least 2 cm of room between the fingertips and the object's top


PLACE_TARGET = list(pose6(top_grasp_pose((0.55, -0.12, 0.93))).values())  # 18 cm left of the can, top grasp


def can_on_the_table() -> SimRobot:
    """tombatossals before a table with a 0.2 kg can (r 3 cm, 12 cm tall) standing at (0.55, -0.3)."""
    world = World(WorldParams())
    world.add_table()
    world.add_object(cylinder("cyl", 0.03, 0.12, xyz=(0.55, -0.3, 0.81), mass=0.2, friction=0.8))
    return SimRobot(world, "tombatossals")


def test_pick_and_place_runs_end_to_end_while_the_head_tracks_the_object() -> None:
    # Fig. 6.3: the pick and place task and the tracking task (Fig. 6.2) run side by side
    robot = can_on_the_table()
    tasks, main = load()
    visited: list[str] = []
    gaze: dict[str, float] = {"start": gaze_deg(robot, "cyl")}

    def entered(p) -> None:
        if p.kind is ProgressKind.ENTERED:
            visited.append(p.label)
            gaze[p.label] = gaze_deg(robot, "cyl")

    res, engine = run_task(tasks["look_and_pick_and_place"], robot, {"target": PLACE_TARGET},
                           library=tasks, max_time=60.0, runner=LocalPrimitiveRunner(robot), on_progress=entered)
    assert res.status is Status.SUCCESS and res.terminal == "done", (res, visited)
    for node in ("localize", "follow", "detect", "approach", "grasp", "lift", "carry", "put", "open", "retreat"):
        assert node in visited
    # the head turned onto the object and stayed on it while the arm carried it 18 cm
    assert gaze["start"] > 10.0 and max(gaze[n] for n in ("grasp", "lift", "carry", "put", "retreat")) < 6.0, gaze
    assert not engine.runner.active, "the tracking branch is stopped with the pick and place"
    obj = robot.ground_truth().object_poses["cyl"]
    assert obj[2, 3] == pytest.approx(0.81, abs=0.015)  # standing on the table again
    assert np.hypot(obj[0, 3] - 0.55, obj[1, 3] + 0.3) > 0.1  # somewhere else


def test_a_can_taken_from_the_hand_during_the_carry_ends_the_place_on_fused_contacts() -> None:
    # thesis Table 7.2, grasp lost during transport, told by the robot's contact fusion: the carry tares
    # the wrist with the can in hand, so only the external wrench (the hand's own weight and motion
    # removed) reads the hand as empty once the can is gone
    robot = can_on_the_table()
    world = robot.world
    runner = LocalPrimitiveRunner(robot)
    runner.host_contacts()
    tasks, _ = load()
    taken: list[float] = []
    lost: list = []

    def watch(p) -> None:
        if p.kind is ProgressKind.ENTERED and p.label == "carry":
            away = np.eye(4)
            away[:3, 3] = (0.3, 0.5, 0.8)
            world.objects["cyl"].set_pose(away)
            taken.append(robot.time)
        if p.kind is ProgressKind.EVENT and p.event is Event.GRASP_LOST and p.node == "carry":
            lost.append((robot.time, p.detail))

    res, _ = run_task(tasks["pick_and_place"], robot, {"target": PLACE_TARGET, "sensor": "fused"},
                      library=tasks, max_time=40.0, runner=runner, on_progress=watch)
    assert res.status is Status.FAILURE and taken and len(lost) == 1, (res, taken, lost)
    t, detail = lost[0]
    assert "fused contacts" in detail
    # a cue cycle (<= 0.05 s), the hypotheses' 0.3 s lifetime, the 0.2 s grace, a fusion cycle (<= 0.05 s):
    # the carry's start (the arm's jerk reads 10 N on the tared wrist) kept no contact alive
    assert 0.5 <= t - taken[0] <= 0.6, (t, taken)


def test_clear_the_table_cycles_until_no_object_is_left() -> None:
    # two grasps in a row are contact-chaotic: a tenth of a millimetre in the first cluster's
    # centroid (rendered vs ray-cast cylinder tessellation) changes where the second object ends
    world = World(WorldParams(camera_backend="raycast"))
    world.add_table()
    world.add_object(cylinder("cyl", 0.03, 0.12, xyz=(0.55, -0.3, 0.81), mass=0.2, friction=0.8))
    world.add_object(box("cube", (0.055, 0.055, 0.07), xyz=(0.5, -0.15, 0.785), mass=0.15, friction=0.8))
    robot = SimRobot(world, "tombatossals")
    tasks, _ = load()
    picks: list[str] = []
    res, _ = run_task(tasks["clear_table"], robot, {}, library=tasks, max_time=90.0,
                      on_progress=lambda p: picks.append(p.node) if p.kind is ProgressKind.ENTERED
                      and p.node == "grasp" else None)
    assert res.status is Status.SUCCESS and res.label == "done", res
    assert len(picks) == 2  # one grasp per object, then detect found nothing (Fig. 3.1c)
    poses = robot.ground_truth().object_poses
    assert all(poses[n][1, 3] > -0.02 for n in ("cyl", "cube"))  # both in the drop region



def test_a_cube_in_a_corner_no_sweep_reaches_is_found_and_dragged_out() -> None:
    from contactflow.embodiments import bench_empty_box as b

    (cx, cy), (ix, iy) = b.BOX_CENTER, b.INNER
    at = (cx + ix / 2 - 0.0245, cy + iy / 2 - 0.0245)  # 2 mm from the +x and the +y wall
    robot = b.box_scene([box("cube", (0.045, 0.045, 0.045), xyz=(*at, b.BOTTOM + 0.0225), mass=0.1, friction=0.8)])
    tasks, _ = load()
    p = b.task_params("exploration", 100)
    probe = {"arm": p["arm"], "bottom": p["bottom"], "floor_margin": p["corner_margin"]}
    empty, _ = run_task(tasks["probe_corner"], robot, {**probe, "pose": p["corner_3"], "to": p["drag_3"]},
                        library=tasks, max_time=60.0)
    assert empty.event is Event.OBJECT_NOT_FOUND, empty  # the -x/-y corner: the walls' top stopped the hand
    res, _ = run_task(tasks["probe_corner"], robot, {**probe, "pose": p["corner_1"], "to": p["drag_1"]},
                      library=tasks, max_time=90.0)
    assert res.label == "dragged", res
    T = robot.ground_truth().object_poses["cube"]
    gaps = np.array([cx + ix / 2 - T[0, 3], cy + iy / 2 - T[1, 3]]) - 0.0225
    assert np.all(gaps > 0.015), gaps  # out of the corner, within reach of the sweep (maybe tipped on a side)
    assert T[2, 3] == pytest.approx(b.BOTTOM + 0.0225, abs=0.004)  # on the bottom, not on the hand or a wall
