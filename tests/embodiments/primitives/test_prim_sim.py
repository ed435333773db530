"""Primitives on the simulated tombatossals: nominal success and the corrective behaviour in perturbed cases."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from contactflow.embodiments.primitives.base import pose6, top_grasp_pose
from contactflow.embodiments.primitives.robust_grasp import RobustGrasp
from contactflow.embodiments.primitives.runner import LocalPrimitiveRunner, outcome, run_primitive
from contactflow.embodiments.remote import RemoteError
from contactflow.embodiments.sim_robot import SimRobot
from contactflow.embodiments.world import World, WorldParams, box, cylinder
from contactflow.nodes.status import Event

ARM = "right"


def vec(T: np.ndarray) -> list[float]:
    v = pose6(T)
    return [v[k] for k in ("x", "y", "z", "roll", "pitch", "yaw")]


def scene(with_object: bool = True) -> tuple[SimRobot, LocalPrimitiveRunner]:
    world = World(WorldParams())
    world.add_table()
    if with_object:
        world.add_object(cylinder("cyl", 0.03, 0.12, xyz=(0.55, -0.3, 0.81), mass=0.2, friction=0.8))
    robot = SimRobot(world, "tombatossals")
    return robot, LocalPrimitiveRunner(robot)


def labels(events) -> list[Event]:
    return [e.event for e in events]


def test_transport_stops_on_unexpected_contact() -> None:
    robot, runner = scene(with_object=False)
    run_primitive(runner, "move_to", {"arm": ARM, "target": vec(top_grasp_pose((0.55, -0.3, 0.85)))})
    ev = run_primitive(runner, "transport", {"arm": ARM, "target": [0.0, 0.0, -0.2, 0.0, 0.0, 0.0], "relative": True,
                                             "planning_distance_limit": 1.0, "velocity_limits": [0.03, 0.03, 0.03, 0.3, 0.3, 0.3]})
    assert Event.CONTACT in labels(ev) and outcome(ev).event is Event.FAILURE  # eq. 3.3 F/T stop at the table


def test_a_touch_told_by_the_fusion_stops_on_the_table_where_the_touch_s_own_sensors_stop() -> None:
    """The guarded move of §6.3.6 on the robot's fused contacts (its pads' and wrist's clouds fused, ch. 4)
    instead of its own reading of the wrist: it stops on the first contact the fusion places on the hand."""
    travelled = {}
    for sensor in ("own", "fused"):
        robot, runner = scene(with_object=False)
        if sensor == "fused":
            runner.host_contacts()
        run_primitive(runner, "move_to", {"arm": ARM, "target": vec(top_grasp_pose((0.55, -0.3, 0.85)))})
        ev = run_primitive(runner, "touch", {"arm": ARM, "direction": [0, 0, -1], "frame": "world", "sensor": sensor})
        end = outcome(ev)
        assert end.event is Event.SUCCESS, ev
        travelled[sensor] = end.values["travelled"]
        # stopped on a real touch: a finger of the hand on the table
        true = [c.position for c in robot.ground_truth().contacts
                if "table" in (c.body_a, c.body_b) and f"tombatossals/{ARM}_link" in c.body_a + c.body_b]
        assert true
    touched = [e for e in ev if e.event is Event.CONTACT]
    assert len(touched) == 1 and "fused contacts" in touched[0].detail and "/contacts/" in touched[0].detail
    # where the fusion places it: the wrist's wrench alone is told at the thumb's tip and at the palm above it
    # on its line of action; the touch takes the leading one, the tip, 7 mm from the true contact (the palm: 10 cm)
    told = np.array([end.values[f"contact_{k}"] for k in "xyz"])
    assert min(np.linalg.norm(told - t) for t in true) < 0.02, (told, true)
    # a cue cycle and a fusion cycle (<= 0.05 s each) after the wrist's own reading at 3 cm/s: <= 3 mm further
    assert 0.05 < travelled["own"] <= travelled["fused"] <= travelled["own"] + 0.003, travelled


def test_an_exploration_told_by_the_fusion_finds_the_can_where_its_own_sensors_find_it() -> None:
    """Empty-box exploration's guarded sweep (Fig. 3.26) stopping on the fused contacts: the can below the hand
    is an object (its contact above the table), found a fusion cycle after the wrist's own reading finds it."""
    found = {}
    for sensor in ("own", "fused"):
        robot, runner = scene()
        if sensor == "fused":
            runner.host_contacts()
        run_primitive(runner, "move_to", {"arm": ARM, "target": vec(top_grasp_pose((0.55, -0.3, 0.97)))})
        ev = run_primitive(runner, "explore", {"arm": ARM, "direction": [0, 0, -1], "floor_z": 0.75, "sensor": sensor})
        end = outcome(ev)
        assert end.event is Event.SUCCESS and Event.OBJECT_DETECTED in labels(ev), ev
        found[sensor] = end.values
    touched = [e for e in ev if e.event is Event.CONTACT]
    assert len(touched) == 1 and "fused contacts" in touched[0].detail
    # where the fusion places it: over the spot the wrench's line of action locates (the thumb's root on the can's
    # rim, pushing it over a little), 1 mm from it, and at the can's top (0.87 m), where the line of action meets
    # the hand's model (a ball around the palm put it 4.5 cm lower)
    f = found["fused"]
    assert np.hypot(f["fused_x"] - f["contact_x"], f["fused_y"] - f["contact_y"]) < 0.01, f
    assert abs(f["fused_z"] - 0.87) < 0.01, f
    # a cue cycle and a fusion cycle (<= 0.05 s each) later at 3 cm/s: <= 3 mm further down
    assert 0.0 <= found["own"]["z"] - found["fused"]["z"] <= 0.003, found
    for v in found.values():
        assert np.hypot(v["contact_x"] - 0.55, v["contact_y"] + 0.3) < 0.05 and v["contact_z"] > 0.8  # the can's top


def test_a_touch_told_by_the_fusion_fails_when_no_fusion_runs_for_the_robot() -> None:
    robot, runner = scene(with_object=False)
    run_primitive(runner, "move_to", {"arm": ARM, "target": vec(top_grasp_pose((0.55, -0.3, 0.95)))})
    t0 = robot.time
    end = outcome(run_primitive(runner, "touch", {"arm": ARM, "direction": [0, 0, -1], "frame": "world",
                                                  "sensor": "fused", "fused_timeout": 0.5}))
    assert end.event is Event.FAILURE and "contact_fusion" in end.detail
    assert robot.time - t0 == pytest.approx(0.5, abs=0.05)
    t0 = robot.time
    end = outcome(run_primitive(runner, "explore", {"arm": ARM, "direction": [0, 0, -1], "sensor": "fused",
                                                    "fused_timeout": 0.5}))
    assert end.event is Event.FAILURE and "contact_fusion" in end.detail
    assert robot.time - t0 == pytest.approx(0.5, abs=0.05)
    with pytest.raises(ValueError, match="sensor: 'wrist' is not one of"):
        runner.create("bad", "touch", {"sensor": "wrist"})
    with pytest.raises(ValueError, match="region: 'palm' needs sensor fused"):
        runner.create("bad", "touch", {"region": "palm"})


def test_release_backs_off_when_fingers_hit_the_table() -> None:
    robot, runner = scene(with_object=False)
    run_primitive(runner, "move_to", {"arm": ARM, "target": vec(top_grasp_pose((0.55, -0.3, 0.9)))})
    robot.hand("right_hand").close()
    robot.hand("right_hand").wait(1.0)
    touch = run_primitive(runner, "touch", {"arm": ARM})
    assert outcome(touch).event is Event.SUCCESS
    ev = run_primitive(runner, "release", {"arm": ARM})
    end = outcome(ev)
    assert end.event is Event.SUCCESS
    assert Event.CONTACT in labels(ev) and end.values["backoff_steps"] > 0 and end.values["backoff"] > 0.001


def test_release_opens_at_its_opening_velocity() -> None:
    robot, runner = scene(with_object=False)
    hand = robot.hand("right_hand")
    took = {}
    for speed in (0.5, 1.5):  # rad/s: the default smooth opening, and a fast one
        hand.close()
        hand.wait(1.5)
        t0 = robot.time
        assert outcome(run_primitive(runner, "release", {"arm": ARM, "opening_velocity": speed})).event is Event.SUCCESS
        took[speed] = robot.time - t0
    # the allegro opens by 1.3 rad at most: 2.5 s and 0.9 s measured
    assert 2.2 < took[0.5] < 3.2 and took[1.5] < 1.2


def test_in_process_primitives_are_hosted_as_on_a_node_one_per_arm() -> None:
    robot, runner = scene(with_object=False)
    far = vec(top_grasp_pose((0.55, -0.3, 1.0)))
    runner.start("first", "move_to", {"arm": ARM, "target": far})
    runner.start("second", "move_to", {"arm": ARM, "target": far})  # the same arm: the host refuses the claim
    refused = [e for e in runner.poll() if e.event is Event.ERROR]
    assert [e.instance for e in refused] == ["second"]
    assert "resource 'arm_right' of robot 'tombatossals' is already commanded by" in refused[0].detail
    runner.start("left", "move_to", {"arm": "left", "target": vec(top_grasp_pose((0.55, 0.3, 1.0)))})
    runner.stop("first")  # the arm is free again
    runner.start("third", "move_to", {"arm": ARM, "target": far})
    assert not [e for e in runner.poll() if e.event is Event.ERROR]


def test_robust_grasp_alignment_fires_when_offset_3cm() -> None:
    robot, runner = scene()
    # 3 cm along the hand x axis (world y for this yaw): the approach touches the object off-centre
    run_primitive(runner, "move_to", {"arm": ARM, "target": vec(top_grasp_pose((0.535, -0.27, 0.92)))})
    ev = run_primitive(runner, "robust_grasp", {"arm": ARM, "pregrasp_type": "open", "torque_threshold": 0.1})
    assert outcome(ev).values["alignments"] >= 1
    assert outcome(ev).values["support_contacts"] == 0  # the object edge came closer: no support contact
    assert Event.CONTACT in labels(ev)
    # the correction pays off: the grasp holds and the cylinder comes up with the hand
    assert outcome(ev).event is Event.SUCCESS and Event.GRASP_STABLE in labels(ev)
    assert outcome(run_primitive(runner, "lift", {"arm": ARM, "distance": 0.08, "watch_grasp": False})).event is Event.SUCCESS
    assert robot.ground_truth().object_poses["cyl"][2, 3] > 0.87


@pytest.mark.heavy(seconds=110)
def test_robust_grasp_that_closed_on_nothing_looks_for_the_object_and_grasps_it(caplog) -> None:
    def block_scene() -> tuple[SimRobot, LocalPrimitiveRunner]:
        world = World(WorldParams())
        world.add_table()
        world.add_object(box("blk", (0.05, 0.05, 0.05), xyz=(0.55, -0.3, 0.776), mass=0.2, friction=0.8))
        robot = SimRobot(world, "tombatossals")
        return robot, LocalPrimitiveRunner(robot)

    for camera in ("kinect", ""):
        robot, runner = block_scene()
        # 12 cm beside the block: the hand descends to the table and closes on nothing
        run_primitive(runner, "move_to", {"arm": ARM, "target": vec(top_grasp_pose((0.55, -0.42, 0.92)))})
        ev = run_primitive(runner, "robust_grasp", {"arm": ARM, "pregrasp_type": "open", "search_camera": camera,
                                                    "search_offsets": []}, max_time=60)
        end = outcome(ev)
        if camera:
            # the kinect's frame showed the block; the hand went over it and grasped it at the second descent
            assert end.event is Event.SUCCESS and end.values["looks"] == 1 and end.values["searches"] == 1, end
            lift = run_primitive(runner, "lift", {"arm": ARM, "distance": 0.08, "watch_grasp": False})
            assert outcome(lift).event is Event.SUCCESS
            assert robot.ground_truth().object_poses["blk"][2, 3] > 0.776 + 0.06
        else:  # without the camera, and no search offsets, the miss is the grasp's failure
            assert end.event is Event.FAILURE and end.values["looks"] == 0 and end.values["searches"] == 0, end
    # a camera that gives no frame: the look sees nothing and the grasp goes on with its offsets, no error
    robot, runner = block_scene()

    def no_frame(name: str = "kinect", labels: bool = True):
        raise RemoteError(f"robot tombatossals: camera {name!r} lost its stream")

    robot.camera = no_frame
    run_primitive(runner, "move_to", {"arm": ARM, "target": vec(top_grasp_pose((0.55, -0.42, 0.92)))})
    with caplog.at_level(logging.INFO):
        ev = run_primitive(runner, "robust_grasp", {"arm": ARM, "pregrasp_type": "open", "search_camera": "kinect",
                                                    "search_offsets": []}, max_time=60)
    end = outcome(ev)
    assert end.event is Event.FAILURE and end.values["looks"] == 2 and "sees no object" in end.detail, end
    # the world answered the request with why it has no frame (the look did not wait out a timeout)
    assert "gave no frame: RemoteError: robot tombatossals: camera 'kinect' lost its stream" in caplog.text


def _hand_efforts(robot: SimRobot) -> float:
    names, _, _, efforts = robot.joint_state()
    joints = set(robot.spec.hand("right_hand").joints)
    return float(sum(abs(e) for n, e in zip(names, efforts, strict=True) if n in joints))


# eq. 3.2 as in the thesis (the allegro profile slows the fingers while backing off: test_bench_grasp.py)
THESIS_SLIDING = {"closing_velocity": 0.8, "pressing_closing_velocity": -1.0, "correction_velocity": 0.005}


def test_robust_grasp_sliding_backs_off_the_table_and_force_adaptation_tightens() -> None:
    world = World(WorldParams())
    world.add_table()
    # a low box: the approach lands with the fingertips on the table (eq. 3.2, Fig. 3.5a)
    world.add_object(box("low", (0.04, 0.04, 0.04), xyz=(0.565, -0.355, 0.77), mass=0.1, friction=0.8))
    robot = SimRobot(world, "tombatossals")
    runner = LocalPrimitiveRunner(robot)
    run_primitive(runner, "move_to", {"arm": ARM, "target": vec(top_grasp_pose((0.55, -0.3, 0.88)))})
    # eq. 3.2 and the force adaptation alone: the box ends up between the ring finger and the thumb,
    # which the finger-lost correction (tested below) would turn into a regrasp
    runner.start("g", "robust_grasp", {"arm": ARM, "pregrasp_type": "open", "alignment": False, "finger_lost": False,
                                       **THESIS_SLIDING})
    prim = runner.active["g"].prim
    trace: list[tuple[str, float, float]] = []
    events = []
    while robot.time < 30.0 and not any(e.event in (Event.SUCCESS, Event.FAILURE, Event.ERROR) for e in events):
        runner.advance()
        robot.step(0.005)
        events += runner.poll()
        trace.append((str(prim.phase), robot.frame_pose("right_grasp")[2, 3], _hand_efforts(robot)))
    end = outcome(events)
    assert end.event is Event.SUCCESS, end.detail
    slide = [(z, f) for ph, z, f in trace if ph == "slide"]
    adapt = [(z, f) for ph, z, f in trace if ph == "adapt"]
    assert slide and adapt
    # F_z from the fingers pressing on the table drove the hand back (up) while they closed
    assert end.values["slides_back"] >= 1
    assert max(z for z, _ in slide) - slide[0][0] > 0.01
    # force adaptation: the fingers squeeze harder than during the light sliding closure
    assert adapt[-1][1] > 1.2 * slide[-1][1]
    assert outcome(run_primitive(runner, "lift", {"arm": ARM, "distance": 0.08, "watch_grasp": False})).event is Event.SUCCESS
    assert robot.ground_truth().object_poses["low"][2, 3] > 0.83


def test_naive_grasp_lifts_a_cylinder_from_the_vision_approach() -> None:
    robot, runner = scene()
    seen = outcome(run_primitive(runner, "detect_objects", {"standoff": 0.04}, max_time=2.0))
    approach = [seen.values[k] for k in ("x", "y", "z", "roll", "pitch", "yaw")]
    assert outcome(run_primitive(runner, "move_to", {"arm": ARM, "target": approach})).event is Event.SUCCESS
    grasp = run_primitive(runner, "naive_grasp", {"arm": ARM, "pregrasp_type": "open"})
    assert Event.CONTACT in labels(grasp)
    lift = run_primitive(runner, "lift", {"arm": ARM, "distance": 0.08})
    assert outcome(lift).event is Event.SUCCESS
    assert robot.ground_truth().object_poses["cyl"][2, 3] > 0.87  # came up with the hand


def test_transport_waypoints_limits_and_force_field_avoidance() -> None:
    robot, runner = scene(with_object=False)
    start = top_grasp_pose((0.45, -0.3, 0.95))
    run_primitive(runner, "move_to", {"arm": ARM, "target": vec(start)})
    goal = top_grasp_pose((0.57, -0.3, 0.95))
    via = top_grasp_pose((0.51, -0.3, 1.0))
    # an obstacle cloud just beside the straight line from the waypoint to the goal
    obstacle = [v for x in np.linspace(0.53, 0.55, 3) for v in (x, -0.33, 0.975)]
    runner.start("t", "transport", {"arm": ARM, "target": vec(goal), "waypoints": vec(via),
                                    "velocity_limits": [0.05, 0.05, 0.05, 0.3, 0.3, 0.3], "obstacles": obstacle,
                                    "repulsion": 0.0002})
    ys, zs, events = [], [], []
    while robot.time < 30.0 and not any(e.event in (Event.SUCCESS, Event.FAILURE, Event.ERROR) for e in events):
        runner.advance()
        robot.step(0.01)
        events += runner.poll()
        p = robot.frame_pose("right_grasp")[:3, 3]
        ys.append(p[1])
        zs.append(p[2])
    runner.stop("t")
    assert events[-1].event is Event.SUCCESS, events[-1].detail
    assert max(zs) > 0.99  # went through the waypoint
    assert max(ys) > -0.295  # pushed away from the obstacle points (they sit at y = -0.33)
    assert np.linalg.norm(robot.frame_pose("right_grasp")[:3, 3] - goal[:3, 3]) < 0.01


def test_robust_grasp_finger_lost_correction_fires_and_shifts_toward_the_contacts() -> None:
    assert RobustGrasp.Params().finger_lost  # part of the robust grasp in the thesis (Fig. 3.2)
    world = World(WorldParams())
    world.add_table()
    # a slim cylinder under the index side: the index and thumb close on it, the middle and ring close on nothing
    world.add_object(cylinder("slim", 0.02, 0.12, xyz=(0.59, -0.36, 0.81), mass=0.3, friction=0.8))
    robot = SimRobot(world, "tombatossals")
    runner = LocalPrimitiveRunner(robot)
    run_primitive(runner, "move_to", {"arm": ARM, "target": vec(top_grasp_pose((0.535, -0.27, 0.92)))})
    # without the alignment (it centres the cylinder first) and with the fingers closing at one speed (the
    # profile slows them while backing off the table, and they then meet the slim cylinder later)
    runner.start("g", "robust_grasp", {"arm": ARM, "pregrasp_type": "open", "alignment": False, "finger_lost": True,
                                       "pressing_closing_velocity": -1.0})
    prim = runner.active["g"].prim
    events: list = []
    at_reopen = None
    shift = None
    while robot.time < 30.0 and shift is None:
        runner.advance()
        robot.step(0.005)
        events += runner.poll()
        if prim.phase == "reopen" and at_reopen is None:
            at_reopen = robot.frame_pose("right_grasp")[:3, 3].copy()
            index_side = robot.frame_pose("right_link_3.0_tip")[:3, 3] - robot.frame_pose("right_link_11.0_tip")[:3, 3]
        if prim.phase == "align" and at_reopen is not None:
            shift = robot.frame_pose("right_grasp")[:3, 3] - at_reopen
        if any(e.event in (Event.SUCCESS, Event.FAILURE, Event.ERROR) for e in events):
            break
    assert prim.regrasps == 1 and shift is not None, "the finger-lost correction did not fire"
    along = float(shift @ index_side / np.linalg.norm(index_side))
    assert 0.015 < along < 0.035  # toward the finger that kept the contact, by about finger_lost_shift
    assert shift[2] > 0.01  # backed off before the new approach
    runner.stop("g")


def test_a_parallel_gripper_refuses_the_finger_lost_correction() -> None:
    from contactflow.embodiments.primitives.base import PrimitiveError

    robot = SimRobot(World(WorldParams()), "melfa")
    runner = LocalPrimitiveRunner(robot)
    with pytest.raises(PrimitiveError, match=r"g: params.finger_lost: melfa's parallel hand 'gripper' allows only "
                                             r"\['alignment', 'force_adaptation', 'sliding'\]"):
        RobustGrasp("g", RobustGrasp.Params(finger_lost=True)).bind(robot).start()
    # the embodiment's profile leaves it out: the same primitive through the runner starts and runs
    runner.start("g", "robust_grasp", {"max_distance": 0.02})
    robot.step(0.1)
    runner.advance()
    assert "g" in runner.active and not [e for e in runner.poll() if e.event is Event.ERROR]
    runner.stop("g")


def test_the_joint_configuration_tells_where_a_grasped_cylinder_sits_in_the_hand() -> None:
    from contactflow.embodiments import registry
    from contactflow.embodiments.primitives.base import hand_pose_for
    from contactflow.embodiments.primitives.hands import held_center

    robot, runner = scene()
    # the hand closes on the can from over it (a plain close: what this measures is the estimate, not a grasp)
    for z in (0.93, 0.87):
        above = hand_pose_for("tombatossals", top_grasp_pose((0.55, -0.3, z)))
        assert outcome(run_primitive(runner, "move_to", {"arm": ARM, "target": vec(above)})).event is Event.SUCCESS
    robot.hand(robot.spec.arm(ARM).hand).close(effort=0.5)
    runner.idle(2.0)
    T = robot.arm(ARM).ee_pose()
    truth = (np.linalg.inv(T) @ robot.ground_truth().object_poses["cyl"])[:3, 3]
    assert robot.ground_truth().object_poses["cyl"][2, 3] > 0.81  # held off the table
    est = held_center(robot, ARM)
    assert est is not None
    # across the approach axis the closing fingers hold the can 3.6 cm from where grasps usually put it;
    # the estimate from the fingertips on it is 0.6 cm off
    prior = np.linalg.norm(np.asarray(registry.home("tombatossals").grasp_center[:2]) - truth[:2])
    assert np.linalg.norm(est[:2] - truth[:2]) < 0.3 * prior, (est, truth)
