"""A grasp approach that starts with the wrist on its joint limit (where a planned move can end) moves, smoothly."""

from __future__ import annotations

import numpy as np

from contactflow.embodiments.primitives.runner import LocalPrimitiveRunner, outcome, run_primitive
from contactflow.embodiments.sim_robot import SimRobot
from contactflow.embodiments.world import World, WorldParams, cylinder
from contactflow.nodes.status import Event, Status

ARM = "right"
# where the planned move of a perturbed approach left the arm (bench grasp, cylinder, error trial 0):
# joint 7 on its hard limit, inside the velocity IK's margin
STALL_Q = np.array([-0.137, 0.425, 0.333, -1.997, -0.294, 2.202, 2.8973])


def at_wrist_limit() -> tuple[SimRobot, LocalPrimitiveRunner]:
    world = World(WorldParams())
    world.add_table()
    world.add_object(cylinder("cylinder", 0.03, 0.12, xyz=(0.55, -0.3, 0.81), mass=0.2, friction=0.8))
    robot = SimRobot(world, "tombatossals")
    arm = robot.arm(ARM)
    q = np.minimum(STALL_Q, robot.kin.upper[robot.kin.q_index(arm.joints)])
    arm.move_joints(q)
    assert arm.wait(8.0) == Status.SUCCESS
    robot.step(0.3)
    assert arm.q()[6] > arm.ctl.ik.upper[6]  # the case under test: the wrist inside the IK's limit margin
    return robot, LocalPrimitiveRunner(robot)


def test_approach_from_the_wrist_limit_does_not_jerk_the_wrist_sensor() -> None:
    robot, _ = at_wrist_limit()
    arm = robot.arm(ARM)
    robot.tare_ft(ARM)
    T0 = arm.ee_pose()
    arm.set_twist(np.array([0.0, 0.0, 0.04, 0.0, 0.0, 0.0]), frame=arm.spec.ee_frame)
    peak = 0.0
    for _ in range(60):
        robot.step(0.005)
        peak = max(peak, float(np.linalg.norm(robot.ft(ARM).force)))
    # the grasps take 2 N on the F/T for a contact: leaving the limit in one control tick read as one
    assert peak < 1.0, peak
    travelled = float((arm.ee_pose()[:3, 3] - T0[:3, 3]) @ T0[:3, 2])
    assert travelled > 0.008, travelled
    assert np.all(arm.q() <= robot.kin.upper[robot.kin.q_index(arm.joints)] + 1e-3)


def test_robust_grasp_from_the_wrist_limit_reaches_the_object() -> None:
    robot, runner = at_wrist_limit()
    z0 = float(robot.ground_truth().object_poses["cylinder"][2, 3])
    # the thesis's closing (the case was recorded with it; the allegro profile's slower one closes elsewhere)
    params = {"arm": ARM, "pregrasp_type": "open", "closing_velocity": 0.8, "pressing_closing_velocity": -1.0,
              "correction_velocity": 0.005}
    ev = outcome(run_primitive(runner, "robust_grasp", params, max_time=25.0))
    # it used to take the first-tick jerk for a contact and close the hand on nothing, 2 s in
    assert ev.event is Event.SUCCESS, ev
    lift = outcome(run_primitive(runner, "lift", {"arm": ARM, "distance": 0.1, "watch_grasp": False}, max_time=6.0))
    assert lift.event is Event.SUCCESS, lift
    assert float(robot.ground_truth().object_poses["cylinder"][2, 3]) - z0 > 0.06
