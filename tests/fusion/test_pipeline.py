"""A simulated touch through the real interface publishers, the tactile and F/T generators and the fusion service."""

import numpy as np
import pytest

from contactflow.embodiments.modules.ft_publisher import FTPublisher
from contactflow.embodiments.modules.ground_truth_publisher import GroundTruthPublisher
from contactflow.embodiments.modules.joint_state_publisher import JointStatePublisher
from contactflow.embodiments.modules.model_publisher import RobotModelPublisher
from contactflow.embodiments.modules.tactile_publisher import TactilePublisher
from contactflow.embodiments.sim_robot import SimRobot
from contactflow.embodiments.world import ObjectSpec, ShapeSpec, World, WorldParams
from contactflow.fusion.generators.force_torque import ForceTorqueGenerator, ForceTorqueParams
from contactflow.fusion.generators.tactile import TactileGenerator, TactileParams
from contactflow.fusion.service import ContactFusion, FusionParams
from contactflow.nodes.messages import Command
from contactflow.nodes.status import Event, Status
from contactflow.nodes.task_module import TaskModule
from contactflow.nodes.testing import FakeIO

TABLE_Z = 0.75
BOX_XY = (0.56, 0.11)
HAND_LINKS = ("panda_hand", "panda_leftfinger", "panda_rightfinger")


class Bus:
    """Routes (module, port) outputs to (module, port) inputs, all on FakeIO, stepping in order."""

    def __init__(self) -> None:
        self.modules: list = []
        self.routes: dict[tuple[str, str], list[tuple[FakeIO, str]]] = {}
        self.io: dict[str, FakeIO] = {}

    def add(self, module, **inputs: str | tuple[str, ...]) -> FakeIO:
        io = FakeIO(module=module)
        module.setup(io)
        module.start()
        self.modules.append(module)
        self.io[module.name] = io
        for port, sources in inputs.items():
            for source in (sources,) if isinstance(sources, str) else sources:
                src, out = source.split(".")
                self.routes.setdefault((src, out), []).append((io, port))
        return io

    def step(self, t: float) -> None:
        for m in self.modules:
            io = self.io[m.name]
            io.t = t
            seen = {port: len(msgs) for port, msgs in io.published.items()}
            m.step()
            for port, msgs in list(io.published.items()):
                for msg in msgs[seen.get(port, 0):]:
                    for dest, dport in self.routes.get((m.name, port), []):
                        dest.feed(dport, msg)


def true_contact(msg, robot: str) -> np.ndarray | None:
    """Force-weighted mean of the simulator's hand-object contact points (evaluation only)."""
    pairs = zip(msg.body_a, msg.body_b, strict=True)
    keep = np.array([("obj" in (a, b)) and (a.startswith(robot) or b.startswith(robot)) for a, b in pairs], bool)
    if not keep.any():
        return None
    p, f = msg.positions.numpy()[keep], msg.forces.numpy()[keep]
    return (p * f[:, None]).sum(0) / f.sum()


@pytest.fixture(scope="module")
def touching():
    """A melfa whose open gripper straddles a fixed box and has just pressed one pad on its side."""
    world = World(WorldParams(timestep=0.0025))
    world.add_table()
    world.add_object(ObjectSpec("obj", (ShapeSpec("box", (0.06, 0.06, 0.12)),), 0.2, 0.6,
                                (*BOX_XY, TABLE_Z + 0.06), static=True, category="box"))
    robot = SimRobot(world, "melfa")
    arm = robot.arm("arm")
    above = arm.ee_pose()
    above[:3, 3] = [*BOX_XY, 0.95]
    arm.move_pose(above, speed=0.25)
    arm.wait(6.0)
    straddle = above.copy()
    straddle[2, 3] = 0.84  # the open fingers on either side of the box, pads below its top
    arm.move_pose(straddle, speed=0.25)
    arm.wait(6.0)
    robot.tare_ft("arm")
    # sideways: the inner pad of one finger presses on the box's side
    arm.guarded_move(np.array([-0.04, 0.0, 0.0, 0.0, 0.0, 0.0]), max_force=2.5, duration=5.0)
    while not arm.done() and np.linalg.norm(robot.ft("arm").force) < 1.5:
        robot.step(0.005)
    arm.stop()
    return robot


def wire(robot, fusion_name: str = "fusion") -> Bus:
    """Interface publishers -> robot model, tactile and F/T generators -> contact fusion, on one bus."""
    bus = Bus()
    bus.add(JointStatePublisher("joint_state", robot))
    bus.add(RobotModelPublisher("model", spec=robot.spec, base=robot.art.base), joint_state="joint_state.joint_state")
    bus.add(TactilePublisher("tactile_pub", robot, TactilePublisher.Params(hand="gripper")))
    bus.add(FTPublisher("ft_pub", robot, FTPublisher.Params(arm="arm")))
    bus.add(GroundTruthPublisher("truth", robot))
    bus.add(TactileGenerator("tactile", TactileParams(robot="melfa")),
            tactile="tactile_pub.tactile", taxels="model.taxels")
    bus.add(ForceTorqueGenerator("force_torque", ForceTorqueParams(robot="melfa", links=HAND_LINKS, link="gripper",
                                                                    surface_band=0.02, min_force=1.0)),
            wrench="ft_pub.wrench", robot_model="model.robot_model")
    bus.add(ContactFusion(fusion_name, FusionParams(robot="melfa")),
            hypotheses=("tactile.hypotheses", "force_torque.hypotheses"))
    return bus


def test_a_simulated_touch_is_fused_within_3_cm_of_the_true_contact(touching):
    robot = touching
    bus = wire(robot)
    truth_io, fusion_io = bus.io["truth"], bus.io["fusion"]
    for _ in range(10):  # 0.2 s of the hand held against the box, the fusion cycling at 50 Hz
        bus.step(robot.time)
        robot.step(0.02)
    clouds = {m.generator: m for g in ("tactile", "force_torque") for m in bus.io[g].published["hypotheses"]}
    assert {"tactile", "force_torque"} <= set(clouds)
    assert all(c.robot == "melfa" and c.link == "gripper" for c in clouds.values())
    truth = true_contact(truth_io.published["true_contacts"][-1], "melfa/")
    assert truth is not None, "the hand does not touch the box"
    made = [e for e in fusion_io.published["events"] if e.event == Event.CONTACT_MADE]
    assert made, "no contact made"
    # each cue on its own already points at the touch: the F/T line of action passes near it
    # (the wrench is converted from world axes to the sensor frame posed from the joint state)
    ft = clouds["force_torque"].hypotheses()
    tac = clouds["tactile"].hypotheses()
    assert len(ft) and np.linalg.norm(ft.location - truth, axis=1).min() < 0.03
    assert len(tac) and np.linalg.norm(tac.location - truth, axis=1).min() < 0.01
    fused = fusion_io.published["hypotheses"][-1]
    assert {"melfa/tactile", "melfa/force_torque"} <= set(fused.columns)
    best = min(np.linalg.norm(np.array(e.location) - truth) for e in made)
    assert best < 0.03, f"fused contact {best * 100:.1f} cm from the true contact"
    assert Event.CONTACT_MADE in fusion_io.event_labels()



TASK = """
nodes:
  approach:
    primitive: touch
    helpers:
      contacts: {primitive: contact_fusion}
  grasp: {primitive: close_until_force, params: {grasp_force: 5.0}}
  done: {terminal: success}
edges:
  - {from: approach, to: grasp, on: contacts.contact_made}
  - {from: grasp, to: done, on: success}
"""


def test_a_fused_contact_made_drives_a_task_transition(touching, tmp_path):
    robot = touching
    task_file = tmp_path / "touch.yaml"
    task_file.write_text(TASK)
    task = TaskModule("task", TaskModule.Params(task_file=str(task_file), robot="melfa"))
    tio = FakeIO(module=task)
    tio.t = robot.time
    task.setup(tio)
    task.start()
    assert ("melfa/contact_fusion", Command.RUN, {}) in tio.commands  # the helper runs the fusion service
    bus = wire(robot, fusion_name="contact_fusion")
    fusion_io = bus.io["contact_fusion"]
    for _ in range(10):
        bus.step(robot.time)
        robot.step(0.02)
        for ev in fusion_io.events:
            tio.feed("events", ev)
        fusion_io.events.clear()
        tio.t = robot.time
        assert task.step() is Status.RUNNING
    edges = [m for m in tio.published["progress"] if m.kind == "edge"]
    assert [(e.node, e.event) for e in edges] == [("approach", "contact_made")]
    assert tio.commands[-1] == ("melfa/close_until_force", Command.RUN, {})
    assert ("melfa/contact_fusion", Command.STOP, {}) in tio.commands
