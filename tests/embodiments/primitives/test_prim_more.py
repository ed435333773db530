"""More primitives on simulated robots: perception, guarded motions, the gripper grasp, slide, push/pull, waits."""

from __future__ import annotations

import numpy as np
import pytest

from contactflow.embodiments import registry
from contactflow.embodiments.primitives.base import matrix6, pose6, top_grasp_pose
from contactflow.embodiments.primitives.detect_objects import observed_fraction, top_centred
from contactflow.embodiments.primitives.explore import Explore, wrench_contact
from contactflow.embodiments.primitives.poke import Poke
from contactflow.embodiments.primitives.runner import LocalPrimitiveRunner, outcome, run_primitive
from contactflow.embodiments.sim_robot import SimRobot
from contactflow.embodiments.world import World, WorldParams, box, cylinder
from contactflow.nodes.params import ParamError, replace_params
from contactflow.nodes.status import Event

TOMB = registry.home("tombatossals")


def vec(T: np.ndarray) -> list[float]:
    v = pose6(T)
    return [v[k] for k in ("x", "y", "z", "roll", "pitch", "yaw")]


def labels(events) -> list[Event]:
    return [e.event for e in events]


def _cylinder_scene() -> tuple[SimRobot, LocalPrimitiveRunner]:
    world = World(WorldParams())
    world.add_table()
    world.add_object(cylinder("cyl", 0.03, 0.12, xyz=(0.55, -0.3, 0.81), mass=0.2, friction=0.8))
    robot = SimRobot(world, "tombatossals")
    return robot, LocalPrimitiveRunner(robot)


@pytest.fixture(scope="module")
def tomba() -> tuple[SimRobot, LocalPrimitiveRunner]:
    return _cylinder_scene()


def test_random_detection_varies_the_hand_yaw_so_a_retry_differs(tomba) -> None:
    robot, runner = tomba

    def hand_x(params: dict) -> np.ndarray:
        ev = outcome(run_primitive(runner, "detect_objects", params, max_time=2.0))
        assert ev.event is Event.SUCCESS, ev.detail
        return matrix6(tuple(ev.values[k] for k in ("x", "y", "z", "roll", "pitch", "yaw")), "approach")[:3, 0]

    # the same object, detected again: "largest" repeats the configured yaw (and so a failed grasp)
    fixed = [hand_x({"standoff": 0.04}) for _ in range(2)]
    assert np.allclose(fixed[0], fixed[1], atol=1e-6)
    drawn = [hand_x({"standoff": 0.04, "select": "random", "seed": 7}) for _ in range(8)]
    turned = [float(np.degrees(np.arccos(np.clip(x @ fixed[0], -1.0, 1.0)))) for x in drawn]
    assert min(turned) < 1.0  # half the draws keep the configured yaw ...
    assert max(turned) > 80.0  # ... the others turn the hand by a quarter or half turn
    assert all(min(abs(t - a) for a in (0.0, 90.0, 180.0)) < 1.0 for t in turned)


def test_observed_fraction_counts_the_region_cells_holding_a_point() -> None:
    region = np.array([0.0, 0.0, 0.7, 0.2, 0.1, 1.0])
    xs, ys = np.meshgrid(np.arange(0.005, 0.1, 0.01), np.arange(0.005, 0.1, 0.01))
    half = np.stack([xs.ravel(), ys.ravel(), np.full(xs.size, 0.75)], axis=1)  # x < 0.1 of 0.2
    assert observed_fraction(half, region) == pytest.approx(0.5)
    assert observed_fraction(np.vstack([half, half + [0.1, 0.0, 0.0]]), region) == pytest.approx(1.0)
    assert observed_fraction(np.zeros((0, 3)), region) == 0.0


def test_top_centred_puts_a_top_grasp_over_the_object_top_not_the_seen_side() -> None:
    from contactflow.recognition.grasp_synthesis import ApproachVector

    # a 5 cm can seen from -x: its whole top and the near half of its side
    a, z = np.meshgrid(np.linspace(0.0, 2 * np.pi, 48, endpoint=False), np.linspace(0.0, 0.07, 15))
    r, t = np.meshgrid(np.linspace(0.0, 0.025, 6), np.linspace(0.0, 2 * np.pi, 48, endpoint=False))
    side = np.stack([0.5 + 0.025 * np.cos(a.ravel()), 0.1 + 0.025 * np.sin(a.ravel()), z.ravel()], axis=1)
    top = np.stack([0.5 + (r * np.cos(t)).ravel(), 0.1 + (r * np.sin(t)).ravel(), np.full(r.size, 0.07)], axis=1)
    pts = np.vstack([side[side[:, 0] < 0.5], top])
    down = ApproachVector(pts.mean(axis=0) + [0.0, 0.0, 0.14], np.array([0.0, 0.0, -1.0]))
    assert 0.5 - down.position[0] > 0.008  # through the centroid of what was seen
    centred = top_centred(down, pts, 0.015)
    # the side's top 1.5 cm still pulls a little
    assert np.hypot(centred.position[0] - 0.5, centred.position[1] - 0.1) < 0.005
    thin = top_centred(down, pts, 0.002).position
    assert np.hypot(thin[0] - 0.5, thin[1] - 0.1) < 0.002
    assert centred.position[2] == down.position[2] and np.array_equal(centred.direction, down.direction)
    sideways = ApproachVector(np.array([0.4, 0.1, 0.04]), np.array([1.0, 0.0, 0.0]))
    assert top_centred(sideways, pts, 0.015) is sideways


def test_detect_objects_does_not_call_a_barely_seen_region_empty(tomba) -> None:
    robot, runner = tomba
    # the table's left half is in view; the same width beyond the table's back edge is floor, below the region
    seen = [0.3, 0.2, 0.74, 0.9, 0.6, 1.2]
    beyond = [0.3, 0.2, 0.74, 2.0, 0.6, 1.2]
    empty = run_primitive(runner, "detect_objects", {"region": seen, "min_observed": 0.7}, max_time=2.0)
    assert Event.OBJECT_NOT_FOUND in labels(empty) and outcome(empty).values["observed"] > 0.9
    unsure = run_primitive(runner, "detect_objects", {"region": beyond, "min_observed": 0.7}, max_time=2.0)
    assert Event.OBJECT_NOT_FOUND not in labels(unsure)
    assert outcome(unsure).event is Event.FAILURE and outcome(unsure).values["observed"] < 0.7
    assert "in view" in outcome(unsure).detail


def test_detect_objects_and_place_location(tomba) -> None:
    robot, runner = tomba
    seen = outcome(run_primitive(runner, "detect_objects", {}, max_time=2.0))
    assert seen.event is Event.SUCCESS and seen.values["count"] == 1
    assert np.hypot(seen.values["cx"] - 0.55, seen.values["cy"] + 0.3) < 0.03
    assert seen.values["top"] == pytest.approx(0.87, abs=0.01)
    empty = run_primitive(runner, "detect_objects", {"region": [0.3, 0.2, 0.74, 0.9, 0.6, 1.2]}, max_time=2.0)
    assert Event.OBJECT_NOT_FOUND in labels(empty)
    spot = outcome(run_primitive(runner, "place_location", {"region": [0.45, -0.4, 0.65, -0.2], "clearance": 0.06}))
    assert spot.event is Event.SUCCESS and np.hypot(spot.values["x"] - 0.55, spot.values["y"] + 0.3) >= 0.06
    rnd = outcome(run_primitive(runner, "place_location", {"mode": "random", "region": [0.4, 0.1, 0.5, 0.2]}))
    hand = matrix6(tuple(rnd.values[k] for k in ("x", "y", "z", "roll", "pitch", "yaw")), "random spot")
    offset = np.eye(4)
    offset[:3, 3] = TOMB.grasp_center
    centre = hand @ offset  # the hand's grasp centre lands on the random spot
    assert 0.4 <= centre[0, 3] <= 0.5 and 0.1 <= centre[1, 3] <= 0.2


def test_explore_tells_objects_from_the_support(tomba) -> None:
    robot, runner = tomba
    assert outcome(run_primitive(runner, "move_to", {"arm": "right", "target": vec(top_grasp_pose((0.4, -0.3, 0.9)))})).event is Event.SUCCESS
    floor = run_primitive(runner, "explore", {"arm": "right", "floor_z": 0.78, "velocity": 0.05})
    assert Event.OBJECT_NOT_FOUND in labels(floor)  # the table, by proprioception
    assert not robot.failed and Event.HARDWARE_FAILURE not in labels(floor)  # a guarded touch is no fault
    run_primitive(runner, "transport", {"arm": "right", "target": [0, 0, 0.04, 0, 0, 0], "relative": True})
    # sweep toward the cylinder at the height of its body: the fingers bump into it
    here = robot.frame_pose("right_grasp")[:3, 3]
    ev = run_primitive(runner, "explore", {"arm": "right", "sweep": [0.58, here[1], here[2]], "floor_z": 0.78,
                                           "velocity": 0.04}, max_time=10.0)
    assert outcome(ev).event is Event.SUCCESS and Event.OBJECT_DETECTED in labels(ev)
    run_primitive(runner, "transport", {"arm": "right", "target": [0, 0, 0.15, 0, 0, 0], "relative": True})


def test_push_pull_and_wait_event(tomba) -> None:
    robot, runner = tomba
    p0 = robot.frame_pose("right_grasp")[:3, 3].copy()
    push = outcome(run_primitive(runner, "push", {"arm": "right", "direction": [0, 1, 0], "distance": 0.03}))
    assert push.event is Event.SUCCESS and push.values["moved"] >= 0.03
    pull = outcome(run_primitive(runner, "pull", {"arm": "right", "direction": [0, 1, 0], "distance": 0.03}))
    assert pull.event is Event.SUCCESS
    assert np.linalg.norm(robot.frame_pose("right_grasp")[:3, 3] - p0) < 0.01
    wait = outcome(run_primitive(runner, "wait_event", {"delay": 0.2}))
    assert wait.event is Event.SUCCESS and wait.values["waited"] >= 0.2
    lost = run_primitive(runner, "hold", {"arm": "right", "effort": 0.5}, max_time=3.0)  # empty hand
    assert Event.GRASP_LOST in labels(lost) and outcome(lost).event is Event.FAILURE
    robot.hand("right_hand").open()


def test_slide_moves_an_object_pressed_in_the_force_band() -> None:
    world = World(WorldParams())
    world.add_table()
    world.add_object(box("pad", (0.1, 0.1, 0.08), xyz=(0.5, -0.3, 0.79), mass=0.2, friction=0.2))
    robot = SimRobot(world, "tombatossals")
    runner = LocalPrimitiveRunner(robot)
    run_primitive(runner, "move_to", {"arm": "right", "target": vec(top_grasp_pose((0.5, -0.3, 0.80)))})
    ev = run_primitive(runner, "slide", {"arm": "right", "target": [0.5, -0.29, 0.0], "target_velocity": 0.01,
                                         "contact_velocity": 0.003, "preshape": "", "dwell": 0.1}, max_time=14.0)
    end = outcome(ev)
    assert end.event is Event.SUCCESS, end.detail
    assert Event.CONTACT in labels(ev) and end.values["in_band_steps"] > 5
    assert robot.ground_truth().object_poses["pad"][1, 3] > -0.297  # the pad slid along with the hand


def _melfa_at_a_cube(size: float, friction: float) -> tuple[SimRobot, LocalPrimitiveRunner]:
    """Melfa at the table, a cube of ``size`` m standing at (0.45, 0.1) in front of it."""
    world = World(WorldParams())
    world.add_table()
    world.add_object(box("cube", (size,) * 3, xyz=(0.45, 0.1, 0.75 + size / 2), mass=0.1, friction=friction))
    robot = SimRobot(world, "melfa")
    return robot, LocalPrimitiveRunner(robot)


def test_gripper_close_until_force_hold_lift_on_melfa() -> None:
    robot, runner = _melfa_at_a_cube(0.04, 1.0)
    T = robot.arm("arm").ee_pose()
    T[:3, 3] = (0.45, 0.1, 0.775)
    assert outcome(run_primitive(runner, "move_to", {"target": vec(T)})).event is Event.SUCCESS
    grip = run_primitive(runner, "close_until_force", {})
    assert outcome(grip).event is Event.SUCCESS and Event.GRASP_STABLE in labels(grip)
    held = run_primitive(runner, "hold", {"duration": 0.3})
    assert outcome(held).event is Event.SUCCESS
    assert outcome(run_primitive(runner, "lift", {"distance": 0.05})).event is Event.SUCCESS
    assert robot.ground_truth().object_poses["cube"][2, 3] > 0.81
    # declared per-embodiment differences: no unscrew with a parallel gripper
    refused = outcome(run_primitive(runner, "unscrew", {}))
    assert refused.event is Event.ERROR and "parallel" in refused.detail


def test_wrench_contact_finds_the_point_on_the_line_of_action() -> None:
    point, origin = np.array([0.52, -0.30, 0.80]), np.array([0.55, -0.33, 0.95])
    hand = np.eye(4)
    hand[:3, 3] = (0.55, -0.33, 0.83)
    up = np.array([0.0, 0.0, 4.0])  # the hand moving down touches a top
    down = wrench_contact(up, np.cross(point - origin, up), origin, hand, np.array([0.0, 0.0, -1.0]))
    assert np.allclose(down, [point[0], point[1], hand[2, 3]], atol=1e-9)  # the line's point nearest the hand
    push_up = np.array([0.3, -0.2, 4.0])  # with friction
    torque = np.cross(point - origin, push_up)
    # with the hand's box the point is where the line leaves it on the side leading the motion
    on_face = wrench_contact(push_up, torque, origin, hand, np.array([0.0, 0.0, -1.0]), (-0.1, -0.1, -0.03, 0.1, 0.1, 0.2))
    assert np.allclose(on_face, point, atol=0.002)
    side = np.array([0.0, -3.0, 0.2])  # sweeping along +y into an object's side
    lateral = wrench_contact(side, np.cross(point - origin, side), origin, hand, np.array([0.0, 1.0, 0.0]),
                             (-0.1, -0.1, -0.1, 0.1, 0.03, 0.1))
    assert np.allclose(lateral, point, atol=0.002)


def test_explore_locates_an_off_centre_contact_and_approaches_over_it() -> None:
    world = World(WorldParams())
    world.add_table()
    world.add_object(cylinder("can", 0.025, 0.07, xyz=(0.55, -0.37, 0.785), mass=0.15, friction=0.8))
    robot = SimRobot(world, "tombatossals")
    runner = LocalPrimitiveRunner(robot)
    run_primitive(runner, "move_to", {"arm": "right", "target": vec(top_grasp_pose((0.55, -0.32, 0.92)))})
    seen: list[np.ndarray] = []
    original = Explore.halt

    def halt(self) -> None:  # the true contacts when the explore stops (evaluation only)
        hits = [c for c in robot.ground_truth().contacts if "can" in (c.body_a, c.body_b)]
        seen.append(np.average([c.position for c in hits], axis=0, weights=[c.force for c in hits]))
        original(self)

    Explore.halt = halt
    try:
        ev = outcome(run_primitive(runner, "explore", {"arm": "right", "floor_z": 0.75, "floor_margin": 0.035,
                                                       "preshape": "closed"}, max_time=10.0))
    finally:
        Explore.halt = original
    assert ev.event is Event.SUCCESS and seen
    hand = robot.frame_pose("right_grasp")[:3, 3]
    assert np.hypot(*(hand[:2] - seen[0][:2])) > 0.02  # the can touched the side of the hand, not its centre
    contact = np.array([ev.values["contact_x"], ev.values["contact_y"]])
    assert np.hypot(*(contact - seen[0][:2])) < 0.01
    approach = matrix6(tuple(ev.values[k] for k in ("x", "y", "z", "roll", "pitch", "yaw")), "approach")
    centre = approach @ np.r_[TOMB.grasp_center, 1.0]
    assert np.hypot(*(centre[:2] - contact)) < 1e-6  # the hand's grasp centre is put over the contact
    assert [ev.values["object_x"], ev.values["object_y"]] == pytest.approx(list(centre[:2]))  # no lead going down
    assert not robot.failed


def test_detection_puts_where_the_grasp_s_preshape_catches_an_object_on_the_object() -> None:
    robot, runner = _cylinder_scene()
    hands = {}
    for preshape in ("", "claw"):
        ev = outcome(run_primitive(runner, "detect_objects", {"standoff": 0.04, "preshape": preshape}, max_time=2.0))
        assert ev.event is Event.SUCCESS, ev.detail
        hands[preshape] = matrix6(tuple(ev.values[k] for k in ("x", "y", "z", "roll", "pitch", "yaw")), "approach")
    target = hands[""] @ np.r_[TOMB.grasp_center, 1.0]
    assert hands["claw"] @ np.r_[TOMB.center("claw"), 1.0] == pytest.approx(target, abs=1e-6)
    assert np.linalg.norm(hands["claw"][:3, 3] - hands[""][:3, 3]) > 0.02  # the claw's hand stands elsewhere


def test_detection_and_random_spot_beside_a_wall_turn_the_hand_side_measured_for_walls() -> None:
    robot, runner = _cylinder_scene()  # the cylinder where it was put (the shared scene's sweep may knock it over)
    walls = [0.4, -0.5, 0.58, -0.1]  # the cylinder at x 0.55 is 3 cm from the +x wall
    side = np.array([*TOMB.wall_side, 0.0])
    ev = outcome(run_primitive(runner, "detect_objects", {"standoff": 0.04, "walls": walls}, max_time=2.0))
    assert ev.event is Event.SUCCESS, ev.detail
    hand = matrix6(tuple(ev.values[k] for k in ("x", "y", "z", "roll", "pitch", "yaw")), "approach")
    assert hand[:3, :3] @ side == pytest.approx([1.0, 0.0, 0.0], abs=1e-6)
    spot = outcome(run_primitive(runner, "place_location", {"mode": "random", "region": [0.45, -0.48, 0.5, -0.47],
                                                           "walls": walls}))
    hand = matrix6(tuple(spot.values[k] for k in ("x", "y", "z", "roll", "pitch", "yaw")), "random spot")
    assert hand[:3, :3] @ side == pytest.approx([0.0, -1.0, 0.0], abs=1e-6)  # 2-3 cm from the -y wall


def test_a_given_spot_gets_the_grasp_centre_over_it_turned_for_a_near_wall(tomba) -> None:
    robot, runner = tomba
    side = np.array([*TOMB.wall_side, 0.0])
    params = {"mode": "at", "spot": [0.5, -0.3], "support_z": 0.75, "height": 0.1, "yaw": 0.0}

    def hand(extra: dict) -> np.ndarray:
        ev = outcome(run_primitive(runner, "place_location", {**params, **extra}))
        assert ev.event is Event.SUCCESS, ev.detail
        return matrix6(tuple(ev.values[k] for k in ("x", "y", "z", "roll", "pitch", "yaw")), "spot")

    free = hand({})
    assert free @ np.r_[TOMB.grasp_center, 1.0] == pytest.approx([0.5, -0.3, 0.85, 1.0], abs=1e-6)
    assert free[:3, 0] == pytest.approx([1.0, 0.0, 0.0], abs=1e-6)  # the given yaw, far from every wall
    walled = hand({"walls": [0.3, -0.32, 0.7, 0.0]})  # 2 cm from the -y wall
    assert walled @ np.r_[TOMB.grasp_center, 1.0] == pytest.approx([0.5, -0.3, 0.85, 1.0], abs=1e-6)
    assert walled[:3, :3] @ side == pytest.approx([0.0, -1.0, 0.0], abs=1e-6)
    bad = outcome(run_primitive(runner, "place_location", {**params, "spot": [0.5]}))
    assert bad.event is Event.ERROR and "params.spot must be [x, y]" in bad.detail


def test_explore_runs_its_alternate_sweep_on_a_coin_flip(tomba) -> None:
    robot, runner = tomba
    here = robot.frame_pose("right_grasp")[:3, 3].copy()
    there = here + [0.0, 0.02, 0.0]
    params = {"arm": "right", "sweep": list(here), "alternate": list(there), "velocity": 0.04}
    ends = []
    for seed in range(10):  # a sweep of one waypoint ends there without a contact (in the air)
        last = outcome(run_primitive(runner, "explore", {**params, "seed": seed}, max_time=5.0))
        assert last.event is Event.FAILURE
        at = robot.frame_pose("right_grasp")[:3, 3]
        took = last.values["alternate"]
        assert np.linalg.norm(at - (there if took else here)) < 0.006, "the hand went where the chosen sweep leads"
        ends.append(took)
    assert 0.0 in ends and 1.0 in ends
    bad = outcome(run_primitive(runner, "explore", {**params, "alternate": [0.1, 0.2]}))
    assert bad.event is Event.ERROR and "params.alternate: expected a multiple of 3 values, got 2" in bad.detail


def test_a_primitive_run_again_with_another_arm_drives_that_arm(tomba) -> None:
    from contactflow.embodiments.primitives.hold import Hold

    robot, _ = tomba
    hold = Hold("hold", Hold.Params(arm="left")).bind(robot)
    hold.start()
    assert (hold.arm_name, hold.hand_name) == ("left", "left_hand")
    # a node's pooled module is re-run with the next node's params (a move of the left arm, then of the right)
    hold.set_params({"arm": "right"})
    hold.start()
    assert (hold.arm_name, hold.hand_name, hold.ee_frame) == ("right", "right_hand", "right_grasp")


def test_poke_touches_down_at_each_spot_and_counts_what_stood_there() -> None:
    robot, runner = _melfa_at_a_cube(0.045, 0.8)
    floor, height = 0.75 + 0.035 + 0.005, 0.75 + 0.035 + 0.09  # the closed gripper's tips 3.5 cm below its frame
    start = vec(top_grasp_pose((0.45, 0.0, height), 0.0))
    assert outcome(run_primitive(runner, "move_to", {"target": start})).event is Event.SUCCESS
    poked = run_primitive(runner, "poke", {"spots": [0.45, 0.0, 0.45, 0.1, 0.45, 0.2], "height": height, "floor_z": floor},
                          max_time=60)
    assert outcome(poked).event is Event.SUCCESS and outcome(poked).values["touches"] == 1.0
    (touch,) = [e for e in poked if e.event is Event.CONTACT]
    assert touch.values["spot"] == 1.0  # the cube's, not the bare table's beside it
    cube = robot.ground_truth().object_poses["cube"][:3, 3]
    assert np.linalg.norm(cube[:2] - (0.45, 0.1)) < 0.01  # touched, not pushed away
    assert robot.arm("arm").ee_pose()[2, 3] == pytest.approx(height, abs=0.01)  # back up at the end
    nothing = run_primitive(runner, "poke", {"spots": [0.45, 0.2], "height": height, "floor_z": floor}, max_time=30)
    assert Event.OBJECT_NOT_FOUND in labels(nothing)
    with pytest.raises(ParamError, match="slow_down"):  # at 0 every move would crawl at 1 cm/s
        replace_params(Poke.Params(), {"slow_down": 0.0})
