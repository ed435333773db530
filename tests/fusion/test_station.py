"""A station's own fusion on a simulated robot: touching the table makes a contact, lifting breaks it."""

import numpy as np
import pytest

from contactflow.embodiments.scenes import SCENES
from contactflow.embodiments.sim_robot import SimRobot
from contactflow.embodiments.world import World, WorldParams
from contactflow.fusion.station import StationFusion
from contactflow.nodes.status import Event


@pytest.fixture(scope="module")
def melfa():
    world = World(WorldParams())
    SCENES["table"](world)
    robot = SimRobot(world, "melfa")
    robot.step(0.3)
    return robot


def run_until(robot, station, arm, limit):
    while not arm.done() and robot.time < limit:
        robot.step(0.005)
        station(robot)


def test_touching_the_table_makes_a_contact_and_lifting_breaks_it(melfa):
    events = []
    station = StationFusion(melfa, events.append)
    arm = melfa.arm("arm")
    melfa.tare_ft("arm")
    start = arm.ee_pose()[:3, 3].copy()
    arm.guarded_move([0, 0, -0.05, 0, 0, 0], max_force=5.0, duration=10)
    run_until(melfa, station, arm, melfa.time + 12)
    for _ in range(40):
        melfa.step(0.005)
        station(melfa)
    made = [e for e in events if e.event == Event.CONTACT_MADE]
    assert made, "no contact made while pressing on the table"
    assert made[0].robot == "melfa" and made[0].link == "gripper"
    tip = arm.ee_pose()[:3, 3]
    assert np.linalg.norm(made[0].location[:2] - tip[:2]) < 0.12
    assert abs(made[0].location[2] - 0.75) < 0.08
    up = arm.ee_pose().copy()
    up[2, 3] = start[2]
    arm.move_pose(up, speed=0.2)
    run_until(melfa, station, arm, melfa.time + 5)
    for _ in range(100):
        melfa.step(0.005)
        station(melfa)
    assert events[-1].event == Event.CONTACT_BROKEN
