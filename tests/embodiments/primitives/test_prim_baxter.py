"""close_until_stall on Baxter's tactile-less parallel gripper: stall on an object = grasp, closing fully = miss."""

from __future__ import annotations

import numpy as np
import pytest

from contactflow.embodiments.primitives.runner import LocalPrimitiveRunner, outcome, run_primitive
from contactflow.embodiments.sim_robot import SimRobot
from contactflow.embodiments.world import World, WorldParams, box
from contactflow.nodes.status import Event, Status


def _gripper_around(width: float) -> tuple[SimRobot, LocalPrimitiveRunner]:
    """Baxter's right gripper opened and lowered to z = 0.80, around a ``width`` box (no box if 0)."""
    world = World(WorldParams())
    world.add_table()
    robot = SimRobot(world, "baxter")
    G = robot.frame_pose("right_gripper")
    if width > 0:
        world.add_object(box("b", (width, width, 0.08), (G[0, 3], G[1, 3], 0.79), mass=0.1, friction=0.9))
    hand = robot.hand("right_gripper")
    hand.open()
    assert hand.wait(2.0) == Status.SUCCESS
    T = G.copy()
    T[2, 3] = 0.80
    arm = robot.arm("right")
    arm.move_pose(T, speed=0.1)
    assert arm.wait(4.0) == Status.SUCCESS
    return robot, LocalPrimitiveRunner(robot)


@pytest.mark.parametrize("width", [0.03])
def test_close_until_stall_grasps_a_box_on_baxter(width: float) -> None:
    robot, runner = _gripper_around(width)
    ev = run_primitive(runner, "close_until_stall", {"arm": "right"})
    end = outcome(ev)
    assert end.event is Event.SUCCESS, end.detail
    assert Event.GRASP_STABLE in [e.event for e in ev]
    # each jaw stops on the box: the gripper stays open by about the box width
    assert 0.5 * width < 2 * end.values["opening"] < 1.2 * width
    lift = outcome(run_primitive(runner, "lift", {"arm": "right", "distance": 0.08, "watch_grasp": False}))
    assert lift.event is Event.SUCCESS
    assert robot.ground_truth().object_poses["b"][2, 3] > 0.85  # came up with the gripper


def test_close_until_stall_fails_when_closing_on_nothing() -> None:
    robot, runner = _gripper_around(0.0)
    ev = run_primitive(runner, "close_until_stall", {"arm": "right"})
    end = outcome(ev)
    assert end.event is Event.FAILURE and "without meeting an object" in end.detail
    assert Event.GRASP_STABLE not in [e.event for e in ev]
    assert np.abs(robot.hand("right_gripper").positions()).max() < 0.002
