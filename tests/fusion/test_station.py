"""A station's contact cues on a simulated robot: touching the table makes a fused contact, lifting breaks it; a bent finger is a finger pose contact."""

import numpy as np
import pytest

from contactflow.embodiments.scenes import SCENES
from contactflow.embodiments.sim_robot import SimRobot
from contactflow.embodiments.world import World, WorldParams
from contactflow.fusion.geometry import capsule_distance
from contactflow.fusion.messages import HypothesisCloud
from contactflow.fusion.service import ContactFusion, FusionParams
from contactflow.fusion.sim_sources import stope_capsules
from contactflow.fusion.station import FingerCue, cue_clouds, robot_cues
from contactflow.nodes.status import Event
from contactflow.nodes.testing import FakeIO, run_module
from contactflow.nodes.wire import stamp


def at_table(name: str) -> SimRobot:
    """Robot ``name`` at the table, its arms settled."""
    world = World(WorldParams())
    SCENES["table"](world)
    robot = SimRobot(world, name)
    robot.step(0.3)
    return robot


@pytest.fixture(scope="module")
def melfa():
    return at_table("melfa")


def test_touching_the_table_makes_a_contact_and_lifting_breaks_it(melfa):
    (cue,) = robot_cues(melfa, 1.5)
    assert not FingerCue.applies(melfa, cue)  # a gripper's jaws share their joints: no finger pose
    fusion = ContactFusion("contacts", FusionParams(robot="melfa", sources="melfa/*", timeout=0.3, wait_timeout=0.05,
                                                    source_timeout=0.5, hold=0.3))
    io = FakeIO()
    run_module(fusion, io, steps=0)
    sent: dict[tuple[str, int], HypothesisCloud] = {}

    def run_for(duration: float, arm=None) -> None:
        """Step the robot; every 50 ms (a station's 20 Hz) each cue's cloud goes to the fusion module."""
        end = melfa.time + duration
        while melfa.time < end and not (arm is not None and arm.done()):
            melfa.step(0.05)
            io.t = melfa.time
            for generator, cloud in cue_clouds(melfa, cue, melfa.time):
                msg = stamp(HypothesisCloud.of(cloud, "melfa", generator, cue.hand), f"melfa/control/cues/{generator}",
                            len(sent) + 1, melfa.time)
                sent[(msg.hdr.source, msg.hdr.seq)] = msg
                io.feed("hypotheses", msg)
            fusion.step()

    arm = melfa.arm("arm")
    melfa.tare_ft("arm")
    start = arm.ee_pose()[:3, 3].copy()
    arm.guarded_move([0, 0, -0.05, 0, 0, 0], max_force=5.0, duration=10)
    run_for(12.0, arm)
    run_for(0.2)
    made = [e for e in io.published["events"] if e.event == Event.CONTACT_MADE]
    assert made, "no contact made while pressing on the table"
    assert made[0].robot == "melfa" and made[0].link == "gripper"
    tip = arm.ee_pose()[:3, 3]
    assert np.linalg.norm(np.asarray(made[0].location[:2]) - tip[:2]) < 0.12
    assert abs(made[0].location[2] - 0.75) < 0.08
    # provenance: the event names the clouds behind it, one per source
    assert made[0].sources and set(made[0].sources) <= {"melfa/tactile_arm", "melfa/force_torque_arm"}
    assert len(made[0].hdr.inputs) == len(made[0].sources)
    for i in made[0].hdr.inputs:
        cloud = sent[(i.source, i.seq)]
        assert f"melfa/{cloud.generator}" in made[0].sources and cloud.stamp <= made[0].t
    # the module raises each event for the task engine too
    assert Event.CONTACT_MADE in io.event_labels()
    up = arm.ee_pose().copy()
    up[2, 3] = start[2]
    arm.move_pose(up, speed=0.2)
    run_for(5.0, arm)
    run_for(0.5)
    assert io.published["events"][-1].event == Event.CONTACT_BROKEN
    lists = io.published["contacts"]
    assert lists[-1].contacts == [] and any(c.link == "gripper" for m in lists for c in m.contacts)


@pytest.fixture(scope="module")
def tombatossals():
    return at_table("tombatossals")


def test_the_thumb_the_table_bends_is_a_finger_pose_contact_and_a_driven_hand_is_none(tombatossals):
    """Thesis §4.4.5 on a station: the open allegro hand pressed down onto the table; its hanging thumb, bent by the
    table while the hand is at rest, gets hypotheses over its surface, no other finger does, and none while the
    hand's command runs."""
    robot = tombatossals
    cue = {c.arm: c for c in robot_cues(robot, 1.5)}["right"]
    assert FingerCue.applies(robot, cue)
    fingers = FingerCue(robot, cue)
    hand, arm = robot.hand(cue.hand), robot.arm("right")
    hand.open()
    robot.step(0.5)
    robot.tare_ft("right")
    arm.guarded_move([0, 0, -0.3, 0, 0, 0], max_force=40.0, duration=10)
    clouds = []
    while not arm.done() and robot.time < 15.0:
        robot.step(0.05)
        clouds.append(fingers.cloud(robot, robot.time))
    touched = [c for c in clouds if len(c)]
    assert not any(len(c) for c in clouds[:10]), "hypotheses before the hand reached the table"
    assert touched, "the table bent no finger"
    caps = stope_capsules(robot.spherical, fingers.stopes[3])  # the thumb's
    last = touched[-1]
    assert np.abs(capsule_distance(last.location, caps)).max() < 0.01  # on the thumb's surface only
    assert last.location[:, 2].min() < 0.77  # down to the table top (0.75 m)
    assert np.isclose(last.likelihood.sum(), 1.0)  # one contact somewhere on the finger (uniform law)
    hand.close()
    robot.step(0.05)
    assert len(fingers.cloud(robot, robot.time)) == 0  # the hand is driven: its fingers move on command
