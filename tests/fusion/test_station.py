"""A station's own fusion on a simulated robot: touching the table makes a contact, lifting breaks it."""

import numpy as np
import pytest

from contactflow.embodiments.scenes import SCENES
from contactflow.embodiments.sim_robot import SimRobot
from contactflow.embodiments.world import World, WorldParams
from contactflow.fusion.messages import HypothesisCloud
from contactflow.fusion.service import ContactFusion, FusionParams
from contactflow.fusion.station import StationFusion, cloud_publisher
from contactflow.nodes.keys import KeySpace
from contactflow.nodes.status import Event
from contactflow.nodes.testing import FakeIO, run_module
from contactflow.nodes.transport import LocalTransport
from contactflow.nodes.wire import MsgId, decode

KS = KeySpace("station")


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
    bus = LocalTransport()
    heard = []
    bus.subscribe(KS.hypotheses("*", "*"), lambda key, data: heard.append((key, decode(data, HypothesisCloud, key))))
    provenance = []

    def publish(event, inputs):
        events.append(event)
        provenance.append(inputs)

    station = StationFusion(melfa, publish, publish_cloud=cloud_publisher(bus, "melfa/station"), keyspace=KS,
                            readings=lambda: [MsgId(source="melfa/world/state", seq=round(melfa.time * 200))])
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
    # provenance: the event names the clouds behind it, each cloud the robot state it was read from
    first = events.index(made[0])
    assert made[0].sources and set(made[0].sources) <= {"melfa/tactile_arm", "melfa/force_torque_arm"}
    clouds = {(m.hdr.source, m.hdr.seq): m for _, m in heard}
    assert len(provenance[first]) == len(made[0].sources)
    for i in provenance[first]:
        cloud = clouds[(i.source, i.seq)]
        assert f"melfa/{cloud.generator}" in made[0].sources and cloud.stamp <= made[0].t
        assert [r.source for r in cloud.hdr.inputs] == ["melfa/world/state"]
    tip = arm.ee_pose()[:3, 3]
    assert np.linalg.norm(made[0].location[:2] - tip[:2]) < 0.12
    assert abs(made[0].location[2] - 0.75) < 0.08
    touching = len(heard)
    up = arm.ee_pose().copy()
    up[2, 3] = start[2]
    arm.move_pose(up, speed=0.2)
    run_until(melfa, station, arm, melfa.time + 5)
    for _ in range(100):
        melfa.step(0.005)
        station(melfa)
    assert events[-1].event == Event.CONTACT_BROKEN
    # every cycle each generator's cloud went out on contacts/<robot>/<generator>; another
    # integrator listening there finds the same contact
    keys = {k for k, _ in heard}
    assert keys == {KS.hypotheses("melfa", "tactile_arm"), KS.hypotheses("melfa", "force_torque_arm")}
    assert all(m.robot == "melfa" and m.link == "gripper" and m.hdr.source.startswith("melfa/station/")
               for _, m in heard)
    fusion = ContactFusion("fusion", FusionParams(robot="site"))
    io = FakeIO()
    run_module(fusion, io, steps=0)
    for _, msg in heard[:touching]:
        io.t = msg.stamp
        io.feed("hypotheses", msg)
        fusion.step()
    remote = [e for e in io.published["events"] if e.event == Event.CONTACT_MADE]
    assert remote and np.linalg.norm(np.array(remote[0].location) - made[0].location) < 0.03
    assert remote[0].sources and {(i.source, i.seq) for i in remote[0].hdr.inputs} <= set(clouds)
    assert {clouds[(i.source, i.seq)].generator for i in remote[0].hdr.inputs} == {
        s.split("/", 1)[1] for s in remote[0].sources}
