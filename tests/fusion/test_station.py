"""A station's contact cues on a simulated robot, fused: touching the table makes a contact, lifting breaks it."""

import numpy as np
import pytest

from contactflow.embodiments.scenes import SCENES
from contactflow.embodiments.sim_robot import SimRobot
from contactflow.embodiments.world import World, WorldParams
from contactflow.fusion.messages import HypothesisCloud
from contactflow.fusion.service import ContactFusion, FusionParams
from contactflow.fusion.station import cue_clouds, robot_cues
from contactflow.nodes.status import Event
from contactflow.nodes.testing import FakeIO, run_module
from contactflow.nodes.wire import stamp


@pytest.fixture(scope="module")
def melfa():
    world = World(WorldParams())
    SCENES["table"](world)
    robot = SimRobot(world, "melfa")
    robot.step(0.3)
    return robot


def test_touching_the_table_makes_a_contact_and_lifting_breaks_it(melfa):
    (cue,) = robot_cues(melfa, 1.5)
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
