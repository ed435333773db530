"""Unscrew (thesis §3.3.6) on the simulated tombatossals: twists turn a real cap joint, the freed cap comes off, the tactile re-centring fires."""

from __future__ import annotations

import numpy as np

from contactflow.embodiments.primitives.base import pose6, top_grasp_pose
from contactflow.embodiments.primitives.runner import (
    LocalPrimitiveRunner,
    RunnerEvent,
    outcome,
    run_primitive,
)
from contactflow.embodiments.robots.tombatossals import PINCH_CAP, PINCH_CONTACT
from contactflow.embodiments.sensors.ground_truth import read_ground_truth
from contactflow.embodiments.sim_robot import SimRobot
from contactflow.embodiments.world import ScrewBottleSpec, SimScrewBottle, World, WorldParams
from contactflow.nodes.status import Event

ARM = "right"
CAP = np.array([0.55, -0.3, 0.96])  # m, centre of the bottle's cap


def vec(T: np.ndarray) -> list[float]:
    v = pose6(T)
    return [v[k] for k in ("x", "y", "z", "roll", "pitch", "yaw")]


def over_cap(thread_turns: float, offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
             ) -> tuple[SimRobot, LocalPrimitiveRunner, SimScrewBottle, np.ndarray]:
    """A bottle held upright and the right hand over its cap (shifted by ``offset`` in world axes); returns the centred hand pose."""
    world = World(WorldParams())
    world.add_table()
    bottle = world.add_screw_bottle(ScrewBottleSpec("bottle", xyz=(0.55, -0.3, 0.75), thread_turns=thread_turns))
    robot = SimRobot(world, "tombatossals")
    runner = LocalPrimitiveRunner(robot)
    centred = top_grasp_pose(CAP)
    centred[:3, 3] = CAP - centred[:3, :3] @ np.asarray(PINCH_CAP)
    T = centred.copy()
    T[:3, 3] += offset
    above = T.copy()
    above[2, 3] += 0.06
    for target in (above, T):
        assert outcome(run_primitive(runner, "move_to", {"arm": ARM, "target": vec(target)})).event is Event.SUCCESS
    return robot, runner, bottle, centred


def unscrew(robot: SimRobot, runner: LocalPrimitiveRunner, params: dict) -> tuple[list[RunnerEvent], list[np.ndarray]]:
    """Run the primitive to its outcome; also returns the hand pose at every stable pinch (ground truth)."""
    runner.start("unscrew#1", "unscrew", {"arm": ARM, **params})
    events: list[RunnerEvent] = []
    pinches: list[np.ndarray] = []
    while robot.time < 60.0:
        runner.advance()
        robot.step(0.005)
        new = runner.poll()
        events += new
        pinches += [robot.frame_pose("right_grasp") for e in new if e.event is Event.GRASP_STABLE]
        if any(e.event in (Event.SUCCESS, Event.FAILURE, Event.ERROR) for e in new):
            break
    runner.stop("unscrew#1")
    return events, pinches


def test_screw_cap_needs_torque_to_turn_and_comes_free_after_its_thread() -> None:
    world = World(WorldParams())
    bottle = world.add_screw_bottle(ScrewBottleSpec("bottle", xyz=(0.5, 0.0, 0.75), thread_turns=0.25))
    load = {"torque": 0.0, "pull": 0.0}
    world.add_hook(lambda w: bottle.cap_link.add_force_torque([0.0, 0.0, load["pull"]], [0.0, 0.0, load["torque"]]))
    load.update(torque=0.05, pull=2.0)  # below the thread's 0.1 N m; the screwed cap does not lift
    world.run(0.5)
    assert abs(bottle.cap_angle()) < np.deg2rad(3.0) and bottle.cap_lift() < 1e-4
    load.update(torque=0.15, pull=0.0)
    world.run(1.0)
    assert bottle.cap_angle() > np.pi / 2 and bottle.cap_lift() < 1e-4  # a quarter turn: the thread lets go
    load.update(torque=0.0, pull=2.0)
    world.run(0.3)
    assert bottle.cap_lift() > 0.05 and bottle.cap_pose()[2, 3] > 0.96 + 0.05
    # the ground truth (what eval/ and the benches read) has the bottle and its cap where they are
    truth = read_ground_truth(world).object_poses
    assert np.allclose(truth["bottle_cap"], bottle.cap_pose()) and np.allclose(truth["bottle"], bottle.body_pose())


def test_unscrew_turns_the_cap_until_it_comes_off() -> None:
    robot, runner, bottle, _ = over_cap(thread_turns=0.2)  # the thread lets go after 72 degrees
    a0 = bottle.cap_angle()
    events, pinches = unscrew(robot, runner, {"max_cycles": 6})
    end = outcome(events)
    assert end.event is Event.SUCCESS, end.detail
    turned = np.rad2deg(bottle.cap_angle() - a0)
    # counter-clockwise seen from above (unscrewing), by the 30 degree twists, regrasping in between
    assert turned >= 72.0 and end.values["twists"] >= 2 and len(pinches) == end.values["twists"]
    assert turned <= 30.0 * end.values["twists"] + 30.0
    assert end.values["pulled"] >= 0.04 and bottle.cap_lift() >= 0.035  # the freed cap left the neck in the hand


def test_screwed_cap_is_regrasped_and_recentred_when_pinched_1cm_off() -> None:
    turned, offsets = {}, {}
    for recenter in (True, False):
        # 1 cm along the pinch line: the first pinch closes around a cap off the fingers' centre
        robot, runner, bottle, centred = over_cap(thread_turns=5.0, offset=(0.0, -0.01, 0.0))
        a0 = bottle.cap_angle()
        events, pinches = unscrew(robot, runner, {"max_cycles": 3, "pinch_center": PINCH_CONTACT, "recenter": recenter})
        end = outcome(events)
        assert end.event is Event.FAILURE and "not removed" in end.detail  # still screwed: every pull was resisted
        assert end.values["twists"] == 3 and (end.values["corrections"] >= 1) == recenter
        turned[recenter] = np.rad2deg(bottle.cap_angle() - a0)
        offsets[recenter] = [float(np.linalg.norm(T[:2, 3] - centred[:2, 3])) for T in pinches]
        assert len(offsets[recenter]) == 3 and 0.008 < offsets[recenter][0] < 0.012
    assert max(offsets[False]) > 0.009  # without the correction every pinch stays 1 cm off
    assert offsets[True][-1] < 0.0075  # the corrected pinches sit nearer the cap axis
    assert min(turned.values()) > 20.0  # the twists turn the cap either way


def test_a_pinch_that_slips_off_a_screwed_cap_is_not_a_removed_cap() -> None:
    # pinched 1 cm off and 4 mm high without re-centring, after 0.1 s of settling: the fingers slip off the cap
    # while twisting and the hand pulls 4 cm away with nothing in it (this was reported as the cap removed)
    robot, runner, bottle, _ = over_cap(thread_turns=5.0, offset=(0.0, -0.01, 0.004))
    runner.idle(0.1)
    events, _ = unscrew(robot, runner, {"max_cycles": 3, "pinch_center": PINCH_CONTACT, "recenter": False})
    end = outcome(events)
    assert end.event is Event.FAILURE and "not removed" in end.detail
    assert end.values["slips"] >= 1  # the empty pull was told apart and led to a regrasp
    assert bottle.cap_lift() < 1e-3


def test_a_pinch_that_closes_beside_the_cap_is_tried_again_and_the_re_centring_moves_it_to_the_side_touched() -> None:
    # 1.5 cm off (Table 3.5's approach error): the fingers close beside the cap; the thesis opens, goes back and
    # grasps again, and with the re-centring the averaged fingertip contacts (here one pad's) move the start pose
    ends = {}
    for recenter in (False, True):
        robot, runner, bottle, _ = over_cap(thread_turns=0.2, offset=(0.0, 0.015, 0.0))
        events, _ = unscrew(robot, runner, {"max_cycles": 4, "pinch_center": PINCH_CONTACT, "recenter": recenter})
        ends[recenter] = (outcome(events), np.rad2deg(bottle.cap_angle()))
    plain, turned = ends[False]
    assert plain.event is Event.FAILURE and "not removed" in plain.detail
    assert plain.values["misses"] == plain.values["cycles"] == 4 and plain.values["twists"] == 0 and abs(turned) < 10.0
    recentred, turned = ends[True]
    assert recentred.event is Event.SUCCESS, recentred.detail
    assert recentred.values["misses"] >= 1 and recentred.values["corrections"] >= 1 and turned >= 72.0
