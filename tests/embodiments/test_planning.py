"""OMPL planning around a box obstacle (both checkers), and execution that stops on an unexpected contact."""

from __future__ import annotations

import numpy as np
import pytest

from contactflow.embodiments.control.kinematics import Kinematics
from contactflow.embodiments.control.planning import CoalChecker, Obstacle, obstacles_from_world
from contactflow.embodiments.testing import make_robot
from contactflow.embodiments.world import box
from contactflow.nodes.status import Event, Status


@pytest.fixture(scope="module")
def scene():
    robot = make_robot("melfa")
    arm = robot.arm("arm")
    T0 = arm.ee_pose()
    a, b = T0.copy(), T0.copy()
    a[:3, 3] = [0.45, 0.22, 0.85]
    b[:3, 3] = [0.45, -0.22, 0.85]
    arm.move_pose(a, speed=0.3)
    assert arm.wait(5.0) == Status.SUCCESS
    return robot, a, b


def _swept_clear(robot, plan, obstacles) -> bool:
    kin = Kinematics(robot.spec.urdf(), robot.kin.base)
    check = CoalChecker(kin, str(robot.spec.urdf()), obstacles, padding=0.0)
    q = robot._kin_q_cmd()
    idx = kin.q_index(plan.joints)
    for w in plan.waypoints:
        q[idx] = w
        if not check.valid(q):
            return False
    return True


@pytest.mark.parametrize("checker", ["coal", "spherical"])
@pytest.mark.parametrize("planner", ["KPIECE1", "RRTConnect"])
def test_planner_finds_a_path_around_a_box(scene, planner, checker):
    robot, a, b = scene
    arm = robot.arm("arm")
    if "wall" not in robot.world.objects:
        robot.world.add_object(box("wall", (0.25, 0.03, 0.2), (0.45, 0.0, 0.85), static=True))
    for _ in range(2):  # sampling planners are probabilistically complete: one retry is normal use
        plan = arm.plan(b, planner=planner, checker=checker, timeout=10.0)
        if plan is not None and plan.success:
            break
    assert plan is not None and plan.success, f"{planner}/{checker}: no plan"
    obstacles = obstacles_from_world(robot.world)
    assert _swept_clear(robot, plan, obstacles), f"{planner}/{checker}: path collides"
    kin = Kinematics(robot.spec.urdf(), robot.kin.base)
    q = robot._kin_q_cmd()
    q[kin.q_index(plan.joints)] = plan.waypoints[-1]
    kin.update(q)
    assert np.linalg.norm(kin.frame_pose(arm.spec.ee_frame)[:3, 3] - b[:3, 3]) < 2e-3
    # the straight joint-space line would hit the wall
    straight = np.linspace(plan.waypoints[0], plan.waypoints[-1], 50)
    assert not _swept_clear(robot, type(plan)(plan.joints, straight, "line", 0.0, True), obstacles)


def test_unreachable_goal_returns_no_plan(scene):
    robot, a, _ = scene
    far = a.copy()
    far[:3, 3] = [3.0, 0.0, 0.9]
    assert robot.arm("arm").plan(far, timeout=0.5) is None


def test_checker_sees_a_box_on_the_arm():
    robot = make_robot("melfa", table=False)
    kin = Kinematics(robot.spec.urdf(), robot.kin.base)
    q = robot._kin_q_cmd()
    kin.update(q)
    at_hand = kin.frame_pose("panda_hand")
    check = CoalChecker(kin, str(robot.spec.urdf()), [Obstacle("b", "box", (0.05, 0.05, 0.05), at_hand)])
    assert not check.valid(q)
    assert CoalChecker(kin, str(robot.spec.urdf()), []).valid(q)


def test_execution_stops_on_unexpected_contact():
    robot = make_robot("melfa")
    arm = robot.arm("arm")
    start = arm.ee_pose()
    goal = start.copy()
    goal[:3, 3] = [0.45, -0.2, 0.85]
    plan = arm.plan(goal, planner="RRTConnect", timeout=3.0)
    assert plan is not None and plan.success
    # an obstacle the planner did not know about, in the path of the fingers
    mid = plan.waypoints[(3 * len(plan.waypoints)) // 4]
    kin = Kinematics(robot.spec.urdf(), robot.kin.base)
    q = robot._kin_q_cmd()
    q[kin.q_index(plan.joints)] = mid
    kin.update(q)
    p = kin.frame_pose("panda_hand_tcp")[:3, 3]
    assert np.linalg.norm(p - start[:3, 3]) > 0.1
    robot.world.add_object(box("surprise", (0.06, 0.06, 0.06), tuple(p), static=True))
    t0 = robot.time
    arm.execute(plan, abort_force=8.0)
    status = arm.wait(10.0)
    assert status == Status.FAILURE and arm.abort_reason == "contact"
    assert robot.time - t0 > 0.2
    assert np.linalg.norm(arm.ee_pose()[:3, 3] - start[:3, 3]) > 0.03  # it was on its way
    assert any(e == Event.CONTACT for _, e, _ in robot.events)
    robot.step(0.3)
    assert np.abs(arm.qd()).max() < 0.05  # stopped
    assert np.linalg.norm(arm.ee_pose()[:3, 3] - goal[:3, 3]) > 0.05
