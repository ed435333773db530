"""Track (Figs. 6.2-6.3) on the simulated tombatossals: the head keeps an object in view, follows it, reports it lost."""

from __future__ import annotations

import numpy as np
import pytest

from contactflow.embodiments.primitives.base import PrimitiveError
from contactflow.embodiments.primitives.runner import LocalPrimitiveRunner, outcome, run_primitive
from contactflow.embodiments.primitives.track import Track
from contactflow.embodiments.sim_robot import SimRobot
from contactflow.embodiments.testing import gaze_deg
from contactflow.embodiments.world import World, WorldParams, box
from contactflow.nodes.status import Event

START = (0.6, 0.25, 0.78)


def test_track_turns_the_head_onto_the_object_follows_it_and_reports_it_lost() -> None:
    world = World(WorldParams())
    world.add_table()
    cube = world.add_object(box("cube", (0.03, 0.03, 0.03), xyz=START, mass=0.2))
    robot = SimRobot(world, "tombatossals")
    runner = LocalPrimitiveRunner(robot)
    before = gaze_deg(robot, "cube")
    ev = run_primitive(runner, "track", {"target": list(START), "duration": 2.0}, max_time=4.0)
    assert outcome(ev).event is Event.SUCCESS
    assert Event.OBJECT_DETECTED in [e.event for e in ev]
    assert before > 10.0 and gaze_deg(robot, "cube") < 2.0, before
    assert outcome(ev).values["seen"] == outcome(ev).values["looks"] >= 9  # 5 Hz for 2 s, seen every time

    # moved 5 cm while tracked: the head follows it (started where it was first seen)
    moved = cube.pose()
    moved[:2, 3] -= (0.04, 0.05)
    ev = []
    runner.start("follow", "track", {"target": list(START)})
    t_move, t_end = robot.time + 0.5, robot.time + 4.0
    while robot.time < t_end:
        runner.advance()
        robot.step(0.005)
        ev += runner.poll()
        if t_move <= robot.time < t_move + 0.004:
            cube.set_pose(moved)
    assert np.allclose(cube.pose()[:2, 3], moved[:2, 3], atol=0.005) and gaze_deg(robot, "cube") < 2.0
    # taken away: lost once it was not seen for lost_after (1 s), within one more look (0.2 s)
    gone = np.eye(4)
    gone[:3, 3] = (0.6, 1.5, 0.76)
    cube.set_pose(gone)
    t_gone = robot.time
    while not any(e.event is Event.OBJECT_LOST for e in ev) and robot.time < t_gone + 3.0:
        runner.advance()
        robot.step(0.005)
        ev += runner.poll()
    lost = [e for e in ev if e.event is Event.OBJECT_LOST]
    assert lost and 0.9 <= robot.time - t_gone <= 1.5
    assert lost[0].values["x"] == pytest.approx(moved[0, 3], abs=0.02)  # last seen where it was moved to
    assert lost[0].values["y"] == pytest.approx(moved[1, 3], abs=0.02)


def test_track_needs_a_camera_and_a_target() -> None:
    with pytest.raises(PrimitiveError, match="t: Track needs a camera on melfa"):
        Track("t", Track.Params(target=START)).bind(SimRobot(World(WorldParams()), "melfa"))
    robot = SimRobot(World(WorldParams()), "tombatossals")
    prim = Track("t", Track.Params(target=(0.5, 0.1))).bind(robot)
    with pytest.raises(PrimitiveError, match=r"t: params.target must be \[x, y, z\]"):
        prim.start()
