"""Primitives in perturbed simulated cases: each one's corrective or stopping behaviour fires."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from contactflow.embodiments.hand_geometry import hand_points
from contactflow.embodiments.primitives.base import pose6, top_grasp_pose
from contactflow.embodiments.primitives.runner import LocalPrimitiveRunner, outcome, run_primitive
from contactflow.embodiments.sim_robot import SimRobot
from contactflow.embodiments.testing import melfa_around_plate
from contactflow.embodiments.world import World, WorldParams, box
from contactflow.nodes.status import Event

FINAL = (Event.SUCCESS, Event.FAILURE, Event.ERROR, Event.TIMEOUT)
MELFA = {"frame": "panda_hand_tcp", "arm": "arm"}


def vec(T: np.ndarray) -> list[float]:
    v = pose6(T)
    return [v[k] for k in ("x", "y", "z", "roll", "pitch", "yaw")]


def scene(*objects) -> tuple[SimRobot, LocalPrimitiveRunner]:
    world = World(WorldParams())
    world.add_table()
    for o in objects:
        world.add_object(o)
    robot = SimRobot(world, "tombatossals")
    return robot, LocalPrimitiveRunner(robot)


def drive(runner: LocalPrimitiveRunner, inst: str, type: str, params: dict, frame: str = "right_grasp",
          arm: str = "right", max_time: float = 30.0, during: Callable[[SimRobot], None] | None = None):
    """Run ``type`` as ``inst`` to its outcome, stepping every other active primitive too.

    Returns the (time, event) pairs of every instance and the trace: times, ``frame`` positions, wrist forces.
    """
    robot = runner.robot
    runner.start(inst, type, params)
    t_end = robot.time + max_time
    events, ts, ps, fs = [], [], [], []
    while robot.time < t_end:
        runner.advance()
        robot.step(0.005)
        if during is not None:
            during(robot)
        events += [(robot.time, e) for e in runner.poll()]
        ts.append(robot.time)
        ps.append(robot.frame_pose(frame)[:3, 3].copy())
        fs.append(np.asarray(robot.ft(arm).force, dtype=np.float64).copy())
        if any(e.instance == inst and e.event in FINAL for _, e in events):
            break
    runner.stop(inst)
    return events, (np.array(ts), np.array(ps), np.array(fs))


def of(events, inst: str) -> list:
    return [e for _, e in events if e.instance == inst]


def held_still(runner: LocalPrimitiveRunner, frame: str = "right_grasp", arm: str = "right",
               duration: float = 0.5) -> tuple[float, float]:
    """How far ``frame`` moves and the wrist force left after ``duration`` s with no primitive running."""
    robot = runner.robot
    p = robot.frame_pose(frame)[:3, 3].copy()
    runner.idle(duration)
    return float(np.linalg.norm(robot.frame_pose(frame)[:3, 3] - p)), float(np.linalg.norm(robot.ft(arm).force))


@pytest.fixture(scope="module")
def tomba() -> tuple[SimRobot, LocalPrimitiveRunner]:
    # a fixed block nothing can move: the immovable thing the pushes run into
    return scene(box("block", (0.12, 0.12, 0.1), xyz=(0.5, -0.1, 0.8), static=True))


def test_touch_without_a_contact_within_max_distance_fails_and_stops(tomba) -> None:
    robot, runner = tomba
    assert outcome(run_primitive(runner, "move_to", {"arm": "right", "target": vec(top_grasp_pose((0.45, -0.35, 0.9)))})).event is Event.SUCCESS
    z0 = robot.frame_pose("right_grasp")[2, 3]
    ev = run_primitive(runner, "touch", {"arm": "right", "max_distance": 0.05})
    end = outcome(ev)
    assert end.event is Event.FAILURE and "no contact within 0.05 m" in end.detail
    assert Event.CONTACT not in [e.event for e in ev]
    assert 0.05 <= end.values["travelled"] < 0.06
    assert z0 - robot.frame_pose("right_grasp")[2, 3] == pytest.approx(end.values["travelled"], abs=0.003)
    moved, _ = held_still(runner)
    assert moved < 0.001  # the guarded motion does not go on after the failure


@pytest.mark.parametrize(("type", "direction"), [("push", [0, 1, 0]), ("pull", [0, -1, 0])])
def test_push_and_pull_into_a_fixed_block_stop_at_the_force_limit_and_wait_event_sees_the_contact(
        tomba, type: str, direction: list[int]) -> None:
    robot, runner = tomba
    assert outcome(run_primitive(runner, "move_to", {"arm": "right", "target": vec(top_grasp_pose((0.45, -0.27, 0.82)))})).event is Event.SUCCESS
    t0 = robot.time
    runner.start("watch", "wait_event", {"arm": "right", "event": "contact", "force_threshold": 5.0})
    events, (ts, _, fs) = drive(runner, "p", type, {"arm": "right", "direction": direction, "distance": 0.1,
                                                   "velocity": 0.03, "force_limit": 15.0})
    runner.stop("watch")
    end = outcome(of(events, "p"))
    # the fingertips are 5 cm from the block: it ends there, not after the 10 cm asked for
    assert end.event is Event.FAILURE and "force limit 15.0 N" in end.detail, end.detail
    assert end.values["force"] >= 15.0 and 0.03 < end.values["moved"] < 0.07
    assert Event.CONTACT in [e.event for e in of(events, "p")]
    moved, force = held_still(runner)
    assert moved < 0.001 and force < 3.0  # stopped and let go: no arm pressing on the block
    # wait_event: CONTACT within a control period of the wrist force passing its threshold, then SUCCESS
    seen = [t for t, e in events if e.instance == "watch" and e.event is Event.CONTACT]
    assert len(seen) == 1
    crossed = ts[np.argmax(np.linalg.norm(fs, axis=1) > 5.0)]
    assert crossed - 0.005 <= seen[0] <= crossed + 0.03
    assert seen[0] - t0 > 1.0  # not at the start: the hand travelled 5 cm at 3 cm/s first
    assert [e.event for e in of(events, "watch")][-1] is Event.SUCCESS


def _plate_pulled_out(after: float, fused: bool = False) -> tuple[list, float]:
    """Melfa closes on a plate, then a grasp-lost wait_event runs while the plate is taken out of the gripper
    ``after`` s later; its events and the time of the pull (``fused``: the robot's contact fusion tells it)."""
    robot = melfa_around_plate(0.1)
    runner = LocalPrimitiveRunner(robot)
    if fused:
        runner.host_contacts()
    assert outcome(run_primitive(runner, "close_until_force", {})).event is Event.SUCCESS
    pulled: list[float] = []
    t0 = robot.time

    def pull_out(r: SimRobot) -> None:
        if not pulled and r.time - t0 >= after:
            away = np.eye(4)
            away[:3, 3] = (0.3, 0.5, 0.78)
            r.world.objects["obj"].set_pose(away)
            pulled.append(r.time)

    params = {"arm": "arm", "event": "grasp_lost", "grace": 0.2, **({"sensor": "fused"} if fused else {})}
    events, _ = drive(runner, "w", "wait_event", params, max_time=after + 3.0, during=pull_out, **MELFA)
    return events, pulled[0]


def test_wait_event_grasp_lost_fires_its_grace_period_after_the_object_is_pulled_out() -> None:
    events, pulled = _plate_pulled_out(0.5)
    lost = [t for t, e in events if e.event is Event.GRASP_LOST]
    assert len(lost) == 1, events
    # held for 0.5 s without an event; lost once the empty grasp held for the 0.2 s grace
    assert 0.2 <= lost[0] - pulled <= 0.25
    end = outcome(of(events, "w"))
    assert end.event is Event.SUCCESS and end.values["waited"] == pytest.approx(0.7, abs=0.05)


def test_wait_event_on_fused_contacts_sees_the_held_object_pulled_out() -> None:
    """The same pull as above, told by the robot's contact fusion (its pads' and wrist's clouds fused) instead
    of the hand's own reading: held while the fused contacts lie on the gripper, lost once they are gone."""
    events, pulled = _plate_pulled_out(1.0, fused=True)
    lost = [(t, e) for t, e in events if e.event is Event.GRASP_LOST]
    assert len(lost) == 1 and "fused contacts" in lost[0][1].detail, events
    # held for the second before the pull; lost once the fused list had emptied and the grace passed: a cue
    # cycle (<= 0.05 s), the hypotheses' 0.3 s lifetime in the voxel space, the 0.2 s grace
    assert 0.5 <= lost[0][0] - pulled <= 0.6
    assert outcome(of(events, "w")).event is Event.SUCCESS


def test_wait_event_on_fused_contacts_fails_when_no_fusion_runs_for_the_robot() -> None:
    robot = melfa_around_plate(0.1)
    runner = LocalPrimitiveRunner(robot)
    t0 = robot.time
    end = outcome(run_primitive(runner, "wait_event", {"arm": "arm", "event": "grasp_lost", "sensor": "fused",
                                                       "fused_timeout": 0.5}))
    # neither a grasp nor its loss is sensed without contact lists: it fails, it does not fire grasp_lost
    assert end.event is Event.FAILURE and "contact_fusion" in end.detail
    assert robot.time - t0 == pytest.approx(0.5, abs=0.05)


def test_lift_raises_grasp_lost_when_the_object_is_pulled_out_on_the_way() -> None:
    robot = melfa_around_plate(0.1)
    runner = LocalPrimitiveRunner(robot)
    assert outcome(run_primitive(runner, "close_until_force", {})).event is Event.SUCCESS
    z0 = robot.frame_pose(MELFA["frame"])[2, 3]
    came_up: list[float] = []

    def pull_out(r: SimRobot) -> None:
        if not came_up and r.frame_pose(MELFA["frame"])[2, 3] - z0 > 0.03:
            came_up.append(r.ground_truth().object_poses["obj"][2, 3])
            away = np.eye(4)
            away[:3, 3] = (0.3, 0.5, 0.78)
            r.world.objects["obj"].set_pose(away)

    events, _ = drive(runner, "l", "lift", {"arm": "arm", "distance": 0.1}, max_time=5.0, during=pull_out, **MELFA)
    assert came_up and came_up[0] > 0.8  # the plate was held up with the gripper until then
    got = [e.event for e in of(events, "l")]
    assert got == [Event.GRASP_LOST, Event.FAILURE], events
    assert 0.03 < outcome(of(events, "l")).values["lifted"] < 0.04  # noticed at once, not at the lift's end
    moved, _ = held_still(runner, **MELFA)
    assert moved < 0.002


def test_place_stops_on_a_support_higher_than_expected() -> None:
    robot = melfa_around_plate(0.1)
    runner = LocalPrimitiveRunner(robot)
    frame = MELFA["frame"]
    here = robot.frame_pose(frame)[:3, 3]
    # a platform 5 cm above the table where the plate is carried: the place meets it 5 cm early
    robot.world.add_object(box("platform", (0.1, 0.1, 0.05), xyz=(here[0], here[1] + 0.15, 0.775), static=True))
    assert outcome(run_primitive(runner, "close_until_force", {})).event is Event.SUCCESS
    assert outcome(run_primitive(runner, "lift", {"distance": 0.08})).event is Event.SUCCESS
    assert outcome(run_primitive(runner, "transport", {"target": [0, 0.15, 0, 0, 0, 0], "relative": True})).event is Event.SUCCESS
    events, _ = drive(runner, "p", "place", {"velocity": 0.01, "max_distance": 0.1}, max_time=15.0, **MELFA)
    end = outcome(of(events, "p"))
    assert end.event is Event.SUCCESS and Event.CONTACT in [e.event for e in of(events, "p")]
    assert end.values["force"] >= 5.0
    assert 0.025 < end.values["travelled"] < 0.04  # the table was 8 cm down
    plate = robot.ground_truth().object_poses["obj"]
    assert plate[2, 3] == pytest.approx(0.83, abs=0.003)  # standing on the platform (top 0.80), not pushed over
    moved, force = held_still(runner, **MELFA)
    assert moved < 0.001 and force < 5.0  # stopped, not pressing on


@pytest.mark.parametrize("platform", [False, True])
def test_a_place_told_where_the_object_rests_goes_down_fast_then_slow_and_still_stops_on_an_early_support(platform) -> None:
    robot = melfa_around_plate(0.1)
    runner = LocalPrimitiveRunner(robot)
    frame = MELFA["frame"]
    assert outcome(run_primitive(runner, "close_until_force", {})).event is Event.SUCCESS
    rest = robot.frame_pose(frame).copy()  # where the hand is with the plate on the table
    rest[1, 3] += 0.15
    if platform:  # 5 cm above the table where the plate goes: the fast descent meets it before the slow one
        robot.world.add_object(box("platform", (0.1, 0.1, 0.05), xyz=(rest[0, 3], rest[1, 3], 0.775), static=True))
    assert outcome(run_primitive(runner, "lift", {"distance": 0.08})).event is Event.SUCCESS
    assert outcome(run_primitive(runner, "transport", {"target": [0, 0.15, 0, 0, 0, 0], "relative": True})).event is Event.SUCCESS
    t0 = robot.time
    events, (ts, ps, _) = drive(runner, "p", "place", {"target": vec(rest)}, max_time=30.0, **MELFA)
    end = outcome(of(events, "p"))
    assert end.event is Event.SUCCESS and end.values["force"] >= 5.0
    plate = robot.ground_truth().object_poses["obj"]
    if platform:
        assert 0.025 < end.values["travelled"] < 0.04
        assert plate[2, 3] == pytest.approx(0.83, abs=0.003)  # on the platform, standing
    else:
        assert 0.075 < end.values["travelled"] < 0.09
        assert plate[2, 3] == pytest.approx(0.78, abs=0.003)
        speed = -np.diff(ps[:, 2]) / np.diff(ts)
        height = ps[1:, 2] - rest[2, 3]
        assert speed[height > 0.05].max() > 0.03  # fast down to 4 cm over it
        assert speed[height < 0.035].max() < 0.01  # then at the thesis's 5 mm/s
        assert robot.time - t0 < 10.0  # at 5 mm/s all the way: 16 s
    moved, force = held_still(runner, **MELFA)
    assert moved < 0.001 and force < 5.0
    for bad in ([0.5, 0.0, 0.8], [0.5, float("nan"), 0.8, 0.0, 0.0, 0.0]):  # refused before the hand moves
        (err,) = run_primitive(runner, "place", {"target": bad})
        assert err.event is Event.ERROR and "params.target" in err.detail, err.detail


def test_slide_presses_into_the_force_band_and_loosens_up_a_rising_support() -> None:
    slope = 0.2  # rad: the support rises 2 cm per 10 cm of sliding toward +y
    ramp = box("ramp", (0.2, 0.2, 0.05), xyz=(0.5, -0.28, 0.83 - 0.025 / np.cos(slope)), rpy=(slope, 0.0, 0.0),
               static=True, friction=0.3)
    robot, runner = scene(ramp)
    top = 0.83 - 0.02 * np.tan(slope)  # the ramp's top under the start
    # the open fingertips 1 cm above the ramp: no force, below the band
    assert outcome(run_primitive(runner, "move_to", {"arm": "right", "target": vec(top_grasp_pose((0.5, -0.3, top + 0.01)))})).event is Event.SUCCESS
    fmin, fmax = 5.0, 9.0
    events, (ts, ps, fs) = drive(runner, "s", "slide", {
        "arm": "right", "target": [0.5, -0.27, 0.0], "target_velocity": 0.02, "contact_velocity": 0.005,
        "preshape": "", "dwell": 0.1, "lower_force_threshold": fmin, "upper_force_threshold": fmax})
    end = outcome(of(events, "s"))
    assert end.event is Event.SUCCESS, end.detail
    fz = fs[:, 2]
    k = int(np.argmax(fz > fmin))
    assert k > 0
    # eq. 3.6 below the band: pressed straight down (along -n) until the force came into the band
    assert ps[0, 2] - ps[k, 2] > 0.007 and np.linalg.norm(ps[k, :2] - ps[0, :2]) < 0.003
    # above the band: loosened along +n, so the hand climbed with the ramp rather than jamming into it
    assert ps[-1, 1] - ps[k, 1] > 0.025 and ps[-1, 2] - ps[k, 2] > 0.0025
    above = np.r_[False, fz[k:] >= fmax, False].astype(int)
    starts, stops = np.nonzero(np.diff(above) == 1)[0], np.nonzero(np.diff(above) == -1)[0]
    assert len(starts) > 0  # the rising support did push the force over the band ...
    assert (ts[k + stops - 1] - ts[k + starts]).max() < 0.15  # ... and each time it was back under Fmax at once
    assert end.values["in_band_steps"] > 100


def test_move_to_stops_at_an_unexpected_obstacle_planned_or_straight_and_a_guarded_move_succeeds() -> None:
    # a wall across the path the planner was not told about
    robot, runner = scene(box("wall", (0.3, 0.03, 0.2), xyz=(0.5, -0.22, 0.85), static=True))
    start = vec(top_grasp_pose((0.45, -0.35, 0.88)))
    goal = vec(top_grasp_pose((0.45, -0.1, 0.88)))
    for planning, guarded in ((True, False), (False, False), (False, True)):
        assert outcome(run_primitive(runner, "move_to", {"arm": "right", "target": start})).event is Event.SUCCESS
        events, (_, ps, fs) = drive(runner, "m", "move_to", {"arm": "right", "target": goal, "planning": planning,
                                                             "guarded": guarded})
        ev = of(events, "m")
        end = outcome(ev)
        assert Event.CONTACT in [e.event for e in ev], (planning, guarded)
        assert end.event is (Event.SUCCESS if guarded else Event.FAILURE), (planning, guarded, end.detail)
        if guarded:
            assert end.values["contact"] == 1.0
        # the fingertips (6.6 cm ahead of the grasp frame) stopped at the wall's face at y = -0.235
        assert ps[:, 1].max() < -0.29
        # the stop came at the contact, not after the arm had pushed the wall with hundreds of N
        assert np.linalg.norm(fs, axis=1).max() < 100.0, (planning, guarded)
        moved, force = held_still(runner)
        assert moved < 0.001 and force < 3.0, (planning, guarded)


def test_transport_plans_beyond_the_planning_distance_and_out_of_a_local_minimum() -> None:
    robot, runner = scene()
    near, far = top_grasp_pose((0.45, -0.1, 0.95)), top_grasp_pose((0.45, -0.3, 0.95))
    assert outcome(run_primitive(runner, "move_to", {"arm": "right", "target": vec(far)})).event is Event.SUCCESS
    # 20 cm, beyond planning_distance_limit and unconstrained: the OMPL plan takes it there
    events, _ = drive(runner, "t", "transport", {"arm": "right", "target": vec(near)})
    end = outcome(of(events, "t"))
    assert end.event is Event.SUCCESS and end.values["plans"] == 1.0
    assert Event.STUCK not in [e.event for e in of(events, "t")]
    # a wall of obstacle points across the straight way back: the force field holds the hand in a local minimum
    cloud = np.array([(x, -0.2, z) for x in np.linspace(0.42, 0.48, 4) for z in np.linspace(0.92, 0.98, 4)])
    hand = hand_points(robot, "right", edge_step=0.01)  # the hand's collision surface, in the grasp frame
    clearance: list[float] = []

    def measure(r: SimRobot) -> None:
        if round(r.time / 0.005) % 4:
            return  # every 20 ms: the hand moves 2 mm at most in between
        T = r.frame_pose("right_grasp")
        clearance.append(float(np.linalg.norm((hand @ T[:3, :3].T + T[:3, 3])[:, None] - cloud[None], axis=2).min()))

    events, (ts, ps, _) = drive(runner, "t", "transport", {"arm": "right", "target": vec(far),
                                                         "obstacles": [float(v) for v in cloud.ravel()]},
                                during=measure)
    got = [e.event for e in of(events, "t")]
    assert got == [Event.STUCK, Event.SUCCESS], events
    assert outcome(of(events, "t")).values["plans"] == 1.0
    stuck = ps[ts <= next(t for t, e in events if e.event is Event.STUCK)]
    assert stuck[:, 1].min() > -0.15  # held short of the points by the repulsion until STUCK
    # the planned path took the hand around the points (the straight line goes through them)
    assert min(clearance) > 0.005
    assert np.linalg.norm(robot.frame_pose("right_grasp")[:3, 3] - far[:3, 3]) < 0.006


def test_the_factories_grasp_detectors_reach_wait_event_and_hold_squeezes_with_the_force_given() -> None:
    """Tables 7.3-7.4: each robot's grasp sensing is wait_event's own typed parameters, none dropped."""
    robot = melfa_around_plate(0.1)
    runner = LocalPrimitiveRunner(robot)
    assert outcome(run_primitive(runner, "close_until_force", {"grip_force": 2.5})).event is Event.SUCCESS
    pressure = sum(float(v.sum()) for v in robot.tactile("gripper").values())
    assert pressure > 2.5

    def stable(params: dict) -> bool:
        events, _ = drive(runner, "w", "wait_event", {"arm": "arm", "event": "grasp_stable", **params},
                          max_time=0.6, **MELFA)
        return any(e.event is Event.GRASP_STABLE for _, e in events)

    assert stable({"sensor": "tactile", "threshold": 0.5 * pressure})
    assert not stable({"sensor": "tactile", "threshold": 2.0 * pressure})  # the threshold is read, not dropped
    assert not stable({"sensor": "tactile", "threshold": 0.5 * pressure, "min_contacts": 3})  # two pads only
    # the jaws are held open by the plate: the gripper's motor effort tells the grip
    assert stable({"sensor": "gripper_effort", "threshold": 1.0})
    assert not stable({"sensor": "gripper_effort", "threshold": 1e4})
    with pytest.raises(ValueError, match="sensor: 'skin' is not one of"):
        runner.create("bad", "wait_event", {"sensor": "skin"})
    with pytest.raises(ValueError, match="region: 'thumbnail' is not one of \\['finger', 'palm', 'held_object'\\]"):
        runner.create("bad", "wait_event", {"sensor": "fused", "region": "thumbnail"})
    with pytest.raises(ValueError, match="region: 'palm' needs sensor fused"):
        runner.create("bad", "wait_event", {"sensor": "tactile", "region": "palm"})
    force = 5.0
    events, _ = drive(runner, "h", "hold", {"arm": "arm", "force": force, "duration": 0.3}, **MELFA)
    limit = robot.spec.hand("gripper").force_limit
    assert robot.hand("gripper").effort == pytest.approx(force / limit)
    assert [e.event for _, e in events if e.instance == "h"][-1] is Event.SUCCESS  # still held at that squeeze
