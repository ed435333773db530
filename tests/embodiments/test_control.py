"""Every embodiment holds its home pose and tracks a 10 cm Cartesian line; IK and mixer units."""

from __future__ import annotations

import numpy as np
import pytest

from contactflow.embodiments.control.mixer import JointCommandMixer
from contactflow.embodiments.testing import line_deviation, make_robot
from contactflow.nodes.status import Status


@pytest.mark.parametrize("name", ["tombatossals", "melfa", "baxter"])
def test_holds_home_and_tracks_a_cartesian_line(name):
    robot = make_robot(name, table=False)
    arms = [robot.arm(a) for a in robot.arms]
    assert len(arms) == (1 if name == "melfa" else 2)
    p0 = {arm.name: arm.ee_pose() for arm in arms}
    heads = [c.link for c in robot.spec.cameras]
    h0 = {link: robot.frame_pose(link) for link in heads}
    robot.step(5.0)
    for arm in arms:  # every arm holds its home pose
        assert np.linalg.norm(arm.ee_pose()[:3, 3] - p0[arm.name][:3, 3]) < 1e-3, arm.name
    for link in heads:  # and so does the head carrying the camera
        assert np.linalg.norm(robot.frame_pose(link)[:3, 3] - h0[link][:3, 3]) < 1e-3, link
        assert np.linalg.norm(robot.frame_pose(link)[:3, :3] - h0[link][:3, :3]) < 2e-3, link
    for arm in arms:
        start = arm.ee_pose()
        goal = start.copy()
        goal[:3, 3] += np.array([0.0, -0.06, -0.08])  # 10 cm line
        arm.move_pose(goal, speed=0.1)
        trace = []
        t_end = robot.time + 5.0
        while not arm.done() and robot.time < t_end:
            robot.step(0.01)
            trace.append(arm.ee_pose()[:3, 3])
        assert arm.status == Status.SUCCESS, arm.name
        assert line_deviation(np.array(trace), start[:3, 3], goal[:3, 3]) < 5e-3, arm.name
        assert np.linalg.norm(arm.ee_pose()[:3, 3] - goal[:3, 3]) < 5e-3, arm.name
        assert np.linalg.norm(arm.ee_pose()[:3, :3] - goal[:3, :3]) < 0.02, arm.name
        for other in arms:  # the arm that is not commanded keeps holding
            if other is not arm and other.status == Status.IDLE:
                assert np.linalg.norm(other.ee_pose()[:3, 3] - p0[other.name][:3, 3]) < 1e-3, other.name


def test_twist_in_a_task_frame_and_joint_move(melfa):
    arm = melfa.arm("arm")
    p0 = arm.ee_pose()
    # the tcp z axis points down: +z in the tcp frame is a downward motion in the world
    arm.set_twist(np.array([0.0, 0.0, 0.05, 0.0, 0.0, 0.0]), frame="panda_hand_tcp", duration=1.0)
    assert arm.wait(3.0) == Status.SUCCESS
    melfa.step(0.3)
    moved = arm.ee_pose()[:3, 3] - p0[:3, 3]
    assert moved[2] == pytest.approx(-0.05, abs=3e-3)
    assert np.linalg.norm(moved[:2]) < 3e-3
    arm.move_joints(np.asarray(arm.home))
    assert arm.wait(5.0) == Status.SUCCESS
    assert np.abs(arm.q() - np.asarray(arm.home)).max() < 5e-3


def test_mixer_weights_concurrent_sources():
    m = JointCommandMixer(["a", "b", "c"], timeout=0.1)
    m.hold(np.zeros(3))
    m.submit("ik", ["a", "b"], np.array([1.0, 1.0]), weight=3.0, t=0.0)
    m.submit("teleop", ["b", "c"], np.array([3.0, 2.0]), weight=1.0, t=0.0)
    q, _, mask = m.mix(0.05)
    assert np.allclose(q, [1.0, 1.5, 2.0]) and mask.all()
    q, _, mask = m.mix(0.5)  # both stale: hold the last mixed target
    assert np.allclose(q, [1.0, 1.5, 2.0]) and not mask.any()
    with pytest.raises(ValueError, match="unknown joint 'z'"):
        m.submit("x", ["z"], np.zeros(1))
    with pytest.raises(ValueError, match="non-finite"):
        m.submit("x", ["a"], np.array([np.nan]))
    with pytest.raises(ValueError, match="named twice"):  # one value per joint and source: a repeat is a fault
        m.submit("x", ["a", "a"], np.zeros(2))


def _scripted_run(realtime: bool = False) -> np.ndarray:
    from contactflow.embodiments.sim_robot import SimRobot
    from contactflow.embodiments.world import World, WorldParams, box

    w = World(WorldParams(realtime=realtime))
    w.add_table()
    w.add_object(box("b", (0.04, 0.04, 0.04), (0.5, 0.0, 0.77), mass=0.2))
    a = SimRobot(w, "melfa")
    b = SimRobot(w, "baxter", name="baxter", base=np.array([[1, 0, 0, 0], [0, 1, 0, 1.5], [0, 0, 1, 0.85], [0, 0, 0, 1.0]]))
    goal = a.arm("arm").ee_pose()
    goal[2, 3] -= 0.1
    a.arm("arm").move_pose(goal)
    b.arm("left").set_twist(np.array([0.0, 0.0, -0.05, 0, 0, 0]), duration=0.3)
    a.step(0.5)
    return np.concatenate([a.art.qpos(), b.art.qpos(), w.objects["b"].pose().ravel()])


def test_two_robots_in_one_world_are_deterministic():
    first, second = _scripted_run(), _scripted_run()
    assert np.array_equal(first, second)


def test_realtime_mode_follows_the_wall_clock():
    import time

    from contactflow.embodiments.world import World, WorldParams

    w = World(WorldParams(realtime=True))
    t0 = time.perf_counter()
    w.run(0.3)
    assert time.perf_counter() - t0 >= 0.29
    assert w.time == pytest.approx(0.3)


def test_tombatossals_arms_collide_with_each_other():
    robot = make_robot("tombatossals", table=False)
    left, right = robot.arm("left"), robot.arm("right")
    for arm in (left, right):
        goal = arm.ee_pose()
        goal[:3, 3] = [0.45, 0.0, 1.1]  # both hands to the same point
        arm.move_pose(goal, speed=0.2)
    robot.step(3.0)
    gap = left.ee_pose()[1, 3] - right.ee_pose()[1, 3]
    assert gap > 0.05  # they stopped against each other instead of passing through
    pairs = {(c.body_a.split("/")[-1][:5], c.body_b.split("/")[-1][:5]) for c in robot.ground_truth().contacts}
    assert any({a, b} == {"left_", "right"} for a, b in pairs)
    assert not robot.failed


# the right arm after the planned approach of a perturbed grasp (bench grasp, cylinder, error trial 0): the
# joint-space planner ends with the wrist (joint 7) on its hard limit, inside the IK's margin
STALL_Q = np.array([-0.137, 0.425, 0.333, -1.997, -0.294, 2.202, 2.8973])


def _right_arm_ik():
    from contactflow.embodiments import registry
    from contactflow.embodiments.control.ik import VelocityIK
    from contactflow.embodiments.control.kinematics import Kinematics

    spec = registry.get("tombatossals")
    arm = spec.arm("right")
    kin = Kinematics(spec.urdf())
    ik = VelocityIK(kin, arm.joints, arm.ee_frame, posture=np.asarray(arm.home))
    return kin, ik


def _set_arm(kin, ik, q_arm):
    q = np.zeros(kin.nq)
    q[ik.idx] = np.clip(q_arm, kin.lower[ik.idx], kin.upper[ik.idx])
    kin.update(q)
    return q


def test_ik_leaves_a_joint_limit_smoothly_while_realising_the_twist():
    kin, ik = _right_arm_ik()
    _set_arm(kin, ik, STALL_Q)
    dt = 1.0 / 200.0
    assert ik.kin.q[ik.idx][6] > ik.upper[6]  # the wrist starts inside the margin
    twist = np.zeros(6)
    twist[:3] = kin.frame_pose(ik.frame)[:3, 2] * 0.04  # the grasp approach: forward along the hand axis
    qd = ik.solve(twist, dt)
    J = kin.jacobian(ik.frame)[:, ik.idx]
    # it used to step the wrist back out of the margin in one tick (~4 rad/s, scaled down with the whole
    # command): a jerk the F/T read as a contact, and a twist not realised
    assert qd[6] < 0.0
    assert np.abs(qd).max() < 0.5
    assert np.linalg.norm(J @ qd - twist) < 2e-3


def test_ik_keeps_joint_limits_and_pushes_off_them_in_the_null_space():
    kin, ik = _right_arm_ik()
    dt = 1.0 / 200.0
    q = _set_arm(kin, ik, STALL_Q)
    hard_lo, hard_hi = kin.lower[ik.idx], kin.upper[ik.idx]
    # spin the hand about its own axis, which the wrist joint does most directly, until the arm runs out of range
    for _ in range(2000):
        w = kin.frame_pose(ik.frame)[:3, 2] * 0.8
        q[ik.idx] += ik.solve(np.concatenate([np.zeros(3), w]), dt) * dt
        assert np.all(q[ik.idx] >= hard_lo - 1e-9) and np.all(q[ik.idx] <= hard_hi + 1e-9), q[ik.idx]
        kin.update(q)
    # without a task, a joint near its limit is moved away through the redundancy alone, the hand staying put
    from contactflow.embodiments.control.ik import IKParams, VelocityIK

    free = VelocityIK(kin, ik.joints, ik.frame, posture=None, params=IKParams())
    near = STALL_Q.copy()
    near[6] = free.upper[6] - 0.1
    _set_arm(kin, free, near)
    qd = free.solve(np.zeros(6), dt)
    J = kin.jacobian(free.frame)[:, free.idx]
    assert qd[6] < -0.01
    assert np.linalg.norm(J @ qd) < 1e-3


def test_a_densely_sampled_path_runs_at_its_speed_bound_with_one_speed_up_and_slow_down():
    from contactflow.embodiments.control.trajectory import TrajectoryFollower, TrajectoryParams

    # a planner's path: 2 rad of one joint in 0.02 rad steps, plus a small second joint
    s = np.linspace(0.0, 1.0, 101)
    path = np.stack([2.0 * s, 0.2 * s], axis=1)
    per_segment = TrajectoryFollower(path, TrajectoryParams(max_velocity=1.0))
    # each 0.02 rad step lasts the shortest segment time: the 1 rad/s bound never shows
    assert per_segment.duration == pytest.approx(100 * 0.05)
    f = TrajectoryFollower(path, TrajectoryParams(max_velocity=1.0, max_acceleration=2.0))
    # 0.5 s up to 1 rad/s (0.25 rad), 1.5 rad at 1 rad/s, 0.5 s down
    assert f.duration == pytest.approx(2.5)
    ts = np.arange(0.0, f.duration + 0.01, 0.005)
    samples = [f.sample(t) for t in ts]
    q = np.array([x for x, _ in samples])
    qd = np.array([v for _, v in samples])
    assert np.allclose(q[0], path[0]) and np.allclose(q[-1], path[-1])
    assert np.abs(qd).max() <= 1.0 + 1e-9
    assert np.abs(qd[:, 0]).max() == pytest.approx(1.0)
    acc = np.diff(qd[:, 0]) / 0.005
    assert np.abs(acc).max() <= 2.0 + 1e-6
    # the sampled velocity is the derivative of the sampled position
    assert np.allclose(np.diff(q[:, 0]) / 0.005, 0.5 * (qd[1:, 0] + qd[:-1, 0]), atol=0.02)
    # a short path never reaches the speed bound: a triangle of 2 x sqrt(d / a)
    short = TrajectoryFollower(path[:6], TrajectoryParams(max_velocity=1.0, max_acceleration=2.0))
    assert short.duration == pytest.approx(2 * np.sqrt(0.1 / 2.0))


def test_a_profiled_trajectory_passes_a_repeated_waypoint_takes_its_corner_slowly_and_rejects_bad_bounds():
    from contactflow.embodiments.control.trajectory import TrajectoryFollower, TrajectoryParams

    path = np.array([[0.0, 0.0], [0.5, 0.0], [0.5, 0.0], [0.5, 1.0]])
    f = TrajectoryFollower(path, TrajectoryParams(max_velocity=1.0, max_acceleration=4.0, corner_jump=0.1))
    samples = [f.sample(t) for t in np.arange(0.0, f.duration + 0.01, 0.001)]
    q = np.array([x for x, _ in samples])
    # the corner is visited: joint 1 does not move before joint 0 has arrived
    turning = q[:, 1] > 1e-9
    assert turning.sum() > 10 and np.allclose(q[turning, 0], 0.5)
    # and taken slowly: the velocity jumps there by 0.1 rad/s at most, elsewhere it changes at 4 rad/s^2
    jumps = np.abs(np.diff(np.array([v for _, v in samples]), axis=0)).max(axis=1)
    assert 0.09 < jumps.max() <= 0.1 + 4.0 * 0.001
    assert np.sort(jumps)[-2] <= 4.0 * 0.001 + 1e-9
    assert np.allclose(f.sample(f.duration)[0], path[-1])
    with pytest.raises(ValueError, match="max_acceleration"):
        TrajectoryFollower(path, TrajectoryParams(max_acceleration=0.0))


def test_a_path_timed_per_segment_comes_to_rest_where_it_turns_back_and_nowhere_else():
    from contactflow.embodiments.control.trajectory import TrajectoryFollower, TrajectoryParams

    # out 0.1 rad in 0.02 rad steps, then back 0.06 rad: waypoint 5 turns back (its neighbours' directions are opposed)
    path = np.array([[0.02 * k, 0.01 * k] for k in range(6)] + [[0.1 - 0.02 * k, 0.05] for k in range(1, 4)])
    f = TrajectoryFollower(path, TrajectoryParams(max_velocity=1.0))
    step = 0.05  # s, each 0.02 rad step lasts the shortest segment time (0.4 rad/s)
    assert np.allclose(f.durations, [step] * 4 + [2 * step] * 2 + [step] * 2)
    ts = np.arange(0.0, f.duration, 0.001)
    q = np.array([f.sample(t)[0] for t in ts])
    qd = np.array([f.sample(t)[1] for t in ts])
    assert np.allclose(f.sample(f.times[5])[1], 0.0)  # at rest where it turns back
    # the velocity never jumps there: it runs down from the 0.4 rad/s of the way out and up to that of the way back
    around = (ts > f.times[4] + 1e-6) & (ts < f.times[6] - 1e-6)
    assert np.abs(np.diff(qd[around], axis=0)).max() < 0.4 * 0.001 / step + 1e-9
    assert np.allclose(f.sample(f.times[4] + 1e-9)[1], f.sample(f.times[4] - 1e-9)[1], atol=1e-6)
    assert np.allclose(f.sample(f.times[6] + 1e-9)[1], f.sample(f.times[6] - 1e-9)[1], atol=1e-6)
    # the sampled velocity is the derivative of the sampled position
    assert np.allclose(np.diff(q, axis=0) / 0.001, 0.5 * (qd[1:] + qd[:-1]), atol=0.01)
    assert np.allclose(f.sample(f.times[5])[0], path[5]) and np.allclose(f.sample(f.duration)[0], path[-1])
    # a path with a turn under 90 degrees keeps each segment at its own pace
    bent = np.array([[0.0, 0.0], [0.02, 0.0], [0.04, 0.0], [0.05, 0.02], [0.06, 0.04]])
    assert np.allclose(TrajectoryFollower(bent, TrajectoryParams(max_velocity=1.0)).durations, step)


def test_an_arm_turning_back_along_its_path_does_not_jolt_its_wrist_into_a_contact_abort():
    """A planned path that turns back: at 0.4 rad/s the reversal read 29 N on the wrist and aborted the path."""
    robot = make_robot("tombatossals", table=False)
    arm = robot.arm("right")
    robot.step(0.5)
    q0 = arm.q_cmd.copy()
    out = np.array([-0.0157, -0.0184, -0.0055, 0.0177, 0.0124, 0.0008, -0.0198])  # rad per waypoint
    back = np.array([0.0073, 0.0132, -0.0001, -0.0195, -0.0098, 0.0004, 0.0052])  # a plan's turn, 153 degrees
    path = np.array([q0 + k * out for k in range(1, 9)] + [q0 + 8 * out + k * back for k in range(1, 9)])
    arm.execute_waypoints(path, abort_force=15.0)  # transport's contact threshold
    turn = arm.ctl.traj.times[8]  # s, into the path (waypoint 0 is the joints it starts from)
    t0, ts, fs = robot.time, [], []
    while not arm.done() and robot.time < t0 + 5.0:
        robot.step(0.005)
        ts.append(robot.time - t0)
        fs.append(float(np.linalg.norm(robot.ft("right").force)))
    assert arm.status == Status.SUCCESS, arm.abort_reason
    near = np.abs(np.array(ts) - turn) < 0.15
    assert near.sum() > 40 and np.array(fs)[near].max() < 8.0
    assert np.abs(arm.q() - path[-1]).max() < 5e-3


def test_the_drives_hold_every_target_given_whether_it_changed_or_not():
    from contactflow.embodiments.sim_robot import SimRobot
    from contactflow.embodiments.world import World, WorldParams

    art = SimRobot(World(WorldParams()), "melfa").art
    drives = lambda: np.array([float(j.get_drive_target()[0]) for j in art.joints])  # noqa: E731
    n = len(art.joints)
    q = np.clip(np.linspace(-0.2, 0.2, n), art.lower, art.upper)
    art.set_targets(np.arange(n), q)
    assert np.allclose(drives(), q, atol=1e-6)
    q2 = q.copy()
    q2[[0, 3]] += 0.05  # a partial update: the joints not written keep theirs
    art.set_targets(np.array([0, 1, 3]), q2[[0, 1, 3]])
    assert np.allclose(drives(), q2, atol=1e-6)
    art.freeze()  # holds where the arm is (teleported zeros: home), whatever was sent before
    assert np.allclose(drives(), art.qpos(), atol=1e-6)
    art.set_targets(np.arange(n), q2)  # frozen: refused
    assert np.allclose(drives(), art.qpos(), atol=1e-6)
    art.unfreeze()
    art.set_targets(np.arange(n), q2)  # the values sent before the freeze are sent again
    assert np.allclose(drives(), q2, atol=1e-6)
