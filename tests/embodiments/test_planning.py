"""OMPL planning around a given or sensed obstacle (both checkers, never the simulator's poses), and execution that stops on an unexpected contact."""

from __future__ import annotations

import numpy as np
import pytest

from contactflow.embodiments.control.kinematics import Kinematics
from contactflow.embodiments.control.planning import (
    ArmPlanner,
    CoalChecker,
    Obstacle,
    PlannerParams,
    SphericalChecker,
    fixtures_from_world,
    sensed_cloud,
)
from contactflow.embodiments.registry import collision_part
from contactflow.embodiments.sim_robot import SimRobot
from contactflow.embodiments.spherical import SphericalModel
from contactflow.embodiments.testing import make_robot
from contactflow.embodiments.transforms import xyz_rpy_to_matrix
from contactflow.embodiments.world import World, box
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
    q = robot.kin_q_cmd()
    idx = kin.q_index(plan.joints)
    for w in plan.waypoints:
        q[idx] = w
        if not check.valid(q):
            return False
    return True


WALL = Obstacle("wall", "box", (0.25, 0.03, 0.2), xyz_rpy_to_matrix((0.45, 0.0, 0.85)))


def _check_detour(robot, arm, plan, b, obstacles, label):
    assert plan is not None and plan.success, f"{label}: no plan"
    assert _swept_clear(robot, plan, obstacles), f"{label}: path collides"
    kin = Kinematics(robot.spec.urdf(), robot.kin.base)
    q = robot.kin_q_cmd()
    q[kin.q_index(plan.joints)] = plan.waypoints[-1]
    kin.update(q)
    assert np.linalg.norm(kin.frame_pose(arm.spec.ee_frame)[:3, 3] - b[:3, 3]) < 2e-3
    # the straight joint-space line would hit the wall
    straight = np.linspace(plan.waypoints[0], plan.waypoints[-1], 50)
    assert not _swept_clear(robot, type(plan)(plan.joints, straight, "line", 0.0, True), obstacles)


@pytest.mark.parametrize("checker", ["coal", "spherical"])
@pytest.mark.parametrize("planner", ["KPIECE1", "RRTConnect"])
def test_planner_finds_a_path_around_a_given_box(scene, planner, checker):
    robot, a, b = scene
    arm = robot.arm("arm")
    for _ in range(2):  # sampling planners are probabilistically complete: one retry is normal use
        plan = arm.plan(b, planner=planner, checker=checker, timeout=10.0, obstacles=(WALL,))
        if plan is not None and plan.success:
            break
    _check_detour(robot, arm, plan, b, [WALL, *fixtures_from_world(robot.world)], f"{planner}/{checker}")


def test_a_failed_plan_says_which_end_is_invalid_or_that_time_ran_out():
    from contactflow.embodiments import registry

    spec = registry.get("melfa")
    kin = Kinematics(spec.urdf(), xyz_rpy_to_matrix(spec.base_xyz, spec.base_rpy))
    joints = spec.arm("arm").joints
    idx = kin.q_index(joints)
    start, goal = kin.q[idx].copy(), kin.q[idx] + 0.5
    blocked = {"start": start, "goal": goal}

    def planner(invalid: str) -> ArmPlanner:
        return ArmPlanner(kin, joints, lambda q: not np.allclose(q[idx], blocked.get(invalid, np.inf)), kin.q)

    for end in ("start", "goal"):
        plan = planner(end).plan(start, goal, planner="RRTConnect", timeout=1.0)
        assert not plan.success and not plan.timed_out and plan.why_not == f"the {end} state is in collision"
    over = planner("").upper + 0.1
    plan = planner("").plan(start, over, planner="RRTConnect", timeout=1.0)
    assert plan.why_not == "the goal state is outside the joint limits" and not plan.timed_out
    islands = ArmPlanner(kin, joints, lambda q: bool(abs(q[idx][0] - 0.25) > 0.05), kin.q)  # joint 1 never crosses 0.25
    plan = islands.plan(start, goal, planner="RRTConnect", timeout=0.3)
    assert not plan.success and plan.timed_out and plan.why_not == "RRTConnect found no path in 0.3 s"
    assert planner("").plan(start, goal, planner="RRTConnect", timeout=5.0).success


def test_a_search_given_a_check_budget_ends_on_its_count_whatever_the_time():
    """What a primitive plans with: a search that ends after so many state checks is the same search on a fast
    machine and on a loaded one (a seeded lockstep run repeats), where a timeout cuts it wherever the clock says."""
    import time

    from contactflow.embodiments import registry

    spec = registry.get("melfa")
    kin = Kinematics(spec.urdf(), xyz_rpy_to_matrix(spec.base_xyz, spec.base_rpy))
    joints = spec.arm("arm").joints
    idx = kin.q_index(joints)
    start, goal = kin.q[idx].copy(), kin.q[idx] + 0.5

    def slow_islands(q: np.ndarray) -> bool:  # joint 1 never crosses 0.25, and every check takes 0.2 ms
        time.sleep(0.0002)
        return bool(abs(q[idx][0] - 0.25) > 0.05)

    plan = ArmPlanner(kin, joints, slow_islands, kin.q).plan(start, goal, planner="RRTConnect", timeout=0.01,
                                                            checks=1500)
    assert not plan.success and plan.timed_out and plan.why_not == "RRTConnect found no path in 1500 state checks"
    assert 1500 <= plan.profile.search_checks < 1700, plan.profile  # the count ended it, at the next iteration
    assert plan.planning_time > 0.3  # far past the timeout, which a budget does not use
    free = ArmPlanner(kin, joints, lambda q: True, kin.q).plan(start, goal, planner="RRTConnect", checks=1500)
    assert free.success and 0 < free.profile.search_checks <= 1500


def test_a_path_found_at_the_search_step_is_searched_again_at_the_check_step_when_it_fails_there():
    from contactflow.embodiments import registry

    spec = registry.get("melfa")
    kin = Kinematics(spec.urdf(), xyz_rpy_to_matrix(spec.base_xyz, spec.base_rpy))
    joints = spec.arm("arm").joints
    idx = kin.q_index(joints)
    start, goal = kin.q[idx].copy(), kin.q[idx].copy()
    goal[0] += 0.6

    def wall(q: np.ndarray) -> bool:  # thinner than the search step, across joint 1's straight way, passable over joint 2
        return not (abs(q[idx][0] - start[0] - 0.2) < 0.015 and abs(q[idx][1] - start[1]) < 0.3)

    planner = ArmPlanner(kin, joints, wall, kin.q, PlannerParams(search_step=0.5))
    searches = []
    for _ in range(40):  # a fine search checks motions at points check_step apart, which can clip the wall's corner
        plan = planner.plan(start, goal, planner="RRTConnect", timeout=5.0)
        assert plan.success and plan.profile.search_checks > 0 and plan.profile.validate > 0
        assert all(wall(planner.full(w)) for w in plan.waypoints)
        assert np.abs(plan.waypoints[:, 1] - start[1]).max() >= 0.3  # went round the wall
        assert np.abs(np.diff(plan.waypoints, axis=0)).max() <= PlannerParams().check_step + 1e-12
        searches.append(plan.profile.searches)
    assert min(searches) == 2 and searches.count(2) >= 34, searches  # 2 % of fine searches clipped a corner

    class RefusingEveryPath(ArmPlanner):
        def _path_free(self, waypoints) -> bool:
            return len(waypoints) == 1 and super()._path_free(waypoints)  # the ends pass

    refused = RefusingEveryPath(kin, joints, wall, kin.q, PlannerParams(search_step=0.5, fine_searches=2))
    plan = refused.plan(start, goal, planner="RRTConnect", timeout=5.0)
    assert not plan.success and plan.profile.searches == 3 and not plan.timed_out
    assert plan.why_not == "RRTConnect's 3 paths each failed the check every 0.02 rad"
    free = ArmPlanner(kin, joints, lambda q: True, kin.q)
    clear = free.plan(start, goal, planner="RRTConnect", timeout=5.0)
    assert clear.success and clear.profile.searches == 1 and clear.profile.path_checks == 2 + len(clear.waypoints)
    assert np.allclose(clear.waypoints[[0, -1]], [start, goal])


def test_planner_does_not_read_the_simulated_objects(scene):
    robot, a, b = scene
    arm = robot.arm("arm")
    if "ghost" not in robot.world.objects:
        # a wall that exists in the simulation but nobody sensed or declared: the planner must not know it
        robot.world.add_object(box("ghost", (0.25, 0.03, 0.2), (0.45, 0.0, 0.85), static=True))
    plan = arm.plan(b, planner="RRTConnect", timeout=5.0)
    assert plan is not None and plan.success
    assert not _swept_clear(robot, plan, [WALL]), "a plan that avoids an obstacle nobody gave it reads ground truth"
    robot.world.remove_object("ghost")


def test_planner_avoids_a_point_cloud_obstacle(scene):
    robot, a, b = scene
    arm = robot.arm("arm")
    g = np.linspace(-0.5, 0.5, 13)
    u, v, w = np.meshgrid(g * 0.25, g * 0.03, g * 0.2)
    cloud = np.stack([u.ravel(), v.ravel(), w.ravel()], 1) + [0.45, 0.0, 0.85]
    for _ in range(2):
        plan = arm.plan(b, planner="RRTConnect", timeout=10.0, cloud=cloud)
        if plan is not None and plan.success:
            break
    _check_detour(robot, arm, plan, b, [WALL, *fixtures_from_world(robot.world)], "cloud")


def test_sensed_cloud_removes_the_robot_and_the_table():
    world = World()
    world.add_table()
    world.add_object(box("b", (0.06, 0.06, 0.1), (0.55, -0.25, 0.8), static=True))
    robot = SimRobot(world, "tombatossals")
    robot.arm("right").move_joints(np.asarray(robot.arm("right").home) + [0.3, 0.3, 0, 0, 0, 0, 0], speed=2.0)
    robot.step(0.5)
    frame = robot.camera()
    robot_ids = {i for i, n in enumerate(frame.label_names) if n not in ("b", "table", "ground", "")}
    assert np.isin(frame.labels[frame.labels >= 0], list(robot_ids)).any()  # the camera sees the arm
    pts = sensed_cloud(robot)
    assert len(pts) > 50
    T = np.eye(4)
    T[:3, 3] = (0.55, -0.25, 0.8)
    near_box = np.all(np.abs(pts - T[:3, 3]) <= [0.04, 0.04, 0.06], axis=1)
    assert near_box.mean() > 0.9, "the sensed cloud should be the box alone"


def test_unreachable_goal_returns_no_plan(scene):
    robot, a, _ = scene
    far = a.copy()
    far[:3, 3] = [3.0, 0.0, 0.9]
    assert robot.arm("arm").plan(far, timeout=0.5) is None


def test_checker_sees_a_box_on_the_arm():
    robot = make_robot("melfa", table=False)
    kin = Kinematics(robot.spec.urdf(), robot.kin.base)
    q = robot.kin_q_cmd()
    kin.update(q)
    at_hand = kin.frame_pose("panda_hand")
    check = CoalChecker(kin, str(robot.spec.urdf()), [Obstacle("b", "box", (0.05, 0.05, 0.05), at_hand)])
    assert not check.valid(q)
    assert CoalChecker(kin, str(robot.spec.urdf()), []).valid(q)


def test_the_checkers_and_the_planner_see_the_other_arm_as_the_simulation_does():
    # a plan that ignored the left arm drove the right hand into it (empty-box vision run, seed 103)
    robot = make_robot("tombatossals", table=False)
    urdf, parts = str(robot.spec.urdf()), robot.spec.collision_groups
    kin = Kinematics(robot.spec.urdf(), robot.kin.base)
    spec = robot.spec.arm("right")
    idx = kin.q_index(spec.joints)
    q = robot.kin_q_cmd()
    reach = np.asarray(spec.home) + (1.6, 0.6, 0.0, 0.8, 0.0, 0.0, 0.0)  # the right hand inside the left arm
    q_in = q.copy()
    q_in[idx] = reach
    coal_check = CoalChecker(kin, urdf, [], parts=parts)
    spherical = SphericalChecker(kin, SphericalModel.from_urdf(kin, urdf), [], parts=parts)
    assert coal_check.valid(q) and spherical.valid(q)  # at home the parts are apart
    assert not coal_check.valid(q_in) and not spherical.valid(q_in)
    assert CoalChecker(kin, urdf, []).valid(q_in)  # without the parts only the scene counts
    plan = robot.arm("right").plan(reach, timeout=0.5)
    assert not plan.success and plan.why_not == "the goal state is in collision"

    # the simulated arms collide the same way: the right arm driven there is stopped by the left one
    arm = robot.arm("right")
    arm.move_joints(reach, speed=1.0)
    arm.wait(4.0)
    touching = {(c.body_a, c.body_b) for c in robot.ground_truth().contacts}
    left, right = (parts.index(p) for p in ("left_", "right_"))
    assert any({collision_part(a.split("/")[-1], parts), collision_part(b.split("/")[-1], parts)} == {left, right}
               for a, b in touching), touching
    assert np.abs(arm.q() - reach).max() > 0.05


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
    q = robot.kin_q_cmd()
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


def test_rest_posture_gives_one_arm_posture_for_a_pose_whatever_the_start():
    # a 7-joint arm's goal joints otherwise follow the start: an elbow drifted over a box hid it from the head camera
    robot = make_robot("tombatossals")
    arm = robot.arm("right")
    home = np.asarray(arm.spec.home)
    goal = arm.ee_pose()
    goal[:3, 3] += (0.05, -0.05, -0.05)
    finals: dict[bool, list[np.ndarray]] = {True: [], False: []}
    for twist in (-0.6, 0.6):
        arm.move_joints(home + np.array([twist, 0.0, -twist, 0.0, 0.0, 0.0, 0.0]), speed=1.0)
        assert arm.wait(10.0) == Status.SUCCESS
        for rest in (True, False):
            plan = arm.plan(goal, planner="RRTConnect", timeout=3.0, rest=rest)
            assert plan is not None and plan.success
            finals[rest].append(plan.waypoints[-1])
    assert np.abs(finals[True][0] - finals[True][1]).max() < 1e-6
    assert np.abs(finals[False][0] - finals[False][1]).max() > 0.1
