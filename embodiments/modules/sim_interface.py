"""Simulated robot interface (thesis §6.3.1): one SAPIEN world and robot behind a node module.

The module plays "reality" for one robot: in ``setup`` it builds the world of a named scene
and the :class:`~contactflow.embodiments.sim_robot.SimRobot`; each step mixes the joint
commands of every commander, advances the physics by one period in lockstep, publishes the
simulation clock and then runs the interface publishers of ``embodiments/modules`` around
the robot (joint state every step, F/T and tactile at the control rate, the posed robot
model, the camera cloud and the ground truth at their own rates). Their ports are this
module's ports of the same name.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from contactflow.embodiments.messages import (
    DepthImage,
    JointCommand,
    JointState,
    ObjectPoses,
    PointCloud,
    RobotModel,
    TactileArray,
    TaxelPoses,
    TrueContacts,
    Wrench,
)
from contactflow.embodiments.modules.camera_publisher import CameraPublisher
from contactflow.embodiments.modules.ft_publisher import FTPublisher
from contactflow.embodiments.modules.ground_truth_publisher import GroundTruthPublisher
from contactflow.embodiments.modules.joint_command_subscriber import JointCommandSubscriber
from contactflow.embodiments.modules.joint_state_publisher import JointStatePublisher
from contactflow.embodiments.modules.model_publisher import RobotModelPublisher
from contactflow.embodiments.modules.tactile_publisher import TactilePublisher
from contactflow.embodiments.modules.world_clock import WorldClock
from contactflow.nodes.keys import ANY, KeySpace
from contactflow.nodes.messages import Clock, Command, ControlReply, ParamValue
from contactflow.nodes.module import Layer, Module, ModuleIO, Port
from contactflow.nodes.status import Event, Status
from contactflow.nodes.wire import Message, MsgId

COMMAND_PORT = "joint_command"
"""Output port name of commanders: the interface reads every such port of its robot unless wired."""


class _PartIO:
    """The ModuleIO of a composed publisher: its ports are the interface's ports of the same name,
    and an input one part reads (the model publisher's joint state) is what another part published."""

    def __init__(self, io: ModuleIO) -> None:
        self._io = io
        self.published: dict[str, Message] = {}

    @property
    def now(self) -> float:
        return self._io.now

    def latest(self, port: str) -> Message | None:
        msg = self.published.get(port)
        return msg if msg is not None else self._io.latest(port)

    def take(self, port: str) -> list[Message]:
        return self._io.take(port)

    def publish(self, port: str, msg: Message, inputs: list[MsgId] | None = None) -> None:
        self._io.publish(port, msg, inputs)
        self.published[port] = msg

    def emit(self, event: Event, detail: str = "", values: dict[str, float] | None = None) -> None:
        self._io.emit(event, detail, values)

    def command(self, target: str, cmd: Command, params: dict[str, ParamValue] | None = None) -> ControlReply:
        return self._io.command(target, cmd, params)

    def log(self, text: str) -> None:
        self._io.log(text)

    def wake(self) -> None:
        self._io.wake()


@dataclass
class _Part:
    module: Module
    period: float  # s of simulated time between two steps
    due: float = 0.0
    broken: str = ""


class SimInterface(Module):
    """Steps a SAPIEN world with one robot in lockstep; publishes its state, sensors, model, clock and ground truth."""

    layer = Layer.INTERFACE
    inputs = (Port("command", JointCommand, "joint commands of every commander of the robot, mixed by weight"),)
    outputs = (
        Port("joint_state", JointState, "every joint of the robot, each step"),
        Port("mixed", JointCommand, "the mixed command sent to the joints"),
        Port("wrench", Wrench, "wrist wrench, one message per arm with an F/T"),
        Port("tactile", TactileArray, "pressure images, one message per hand with pads"),
        Port("robot_model", RobotModel, "posed spherical model and sensor frames"),
        Port("taxels", TaxelPoses, "world taxel poses, one message per hand with pads"),
        Port("depth", DepthImage, "depth image of the robot's camera"),
        Port("cloud", PointCloud, "world point cloud of the robot's camera"),
        Port("clock", Clock, "simulation clock, on the site's clock key"),
        Port("object_poses", ObjectPoses, "object poses, on the evaluation key"),
        Port("true_contacts", TrueContacts, "physics contacts, on the evaluation key"),
    )
    events = (Event.HARDWARE_FAILURE,)

    @dataclass(frozen=True)
    class Params:
        rate_hz: float = 200.0  # Hz, physics lockstep, joint state and command mixing (§6.3.1)
        robot: str = "melfa"  # embodiment registry name
        scene: str = "table"  # a name of embodiments.scenes.SCENES ("table": a plain table)
        realtime: bool = False  # pace the physics to the wall clock (else as fast as the node steps it)
        settle: float = 0.3  # s of physics before the first step (objects come to rest)
        camera_hz: float = 5.0  # Hz of camera frames (ray casting ~50 ms each); 0 = no camera
        camera_stride: int = 2  # keep every n-th point of the cloud
        model_hz: float = 50.0  # Hz of robot model and taxel poses
        ground_truth_hz: float = 50.0  # Hz of object poses and true contacts
        command_timeout: float = 0.1  # s a commander's joint command stays fresh

    def __init__(self, name: str, params: Params | None = None) -> None:
        super().__init__(name, params)
        self.robot: Any = None
        self.parts: list[_Part] = []
        self.failure = ""

    @classmethod
    def default_input_keys(cls, ks: KeySpace, robot: str, name: str, params: Any) -> dict[str, str]:
        """Without wiring, every module's ``joint_command`` output of this robot commands it."""
        return {"command": ks.output(robot, ANY, ANY, COMMAND_PORT)}

    @classmethod
    def default_output_keys(cls, ks: KeySpace, robot: str, name: str, params: Any) -> dict[str, str]:
        """The clock on the site's clock key; ground truth under ``eval/``, which no primitive reads."""
        keys = {"clock": ks.clock()}
        keys.update(GroundTruthPublisher.default_output_keys(ks, robot, name, params))
        return keys

    def setup(self, io: ModuleIO) -> None:
        super().setup(io)
        from contactflow.embodiments import registry
        from contactflow.embodiments.scenes import SCENES
        from contactflow.embodiments.sim_robot import SimRobot
        from contactflow.embodiments.world import World, WorldParams

        p = self.params
        registry.configured(p.robot, f"{self.name}.params.robot")
        if p.scene not in SCENES:
            raise ValueError(f"{self.name}.params.scene: {p.scene!r} is not one of {sorted(SCENES)}")
        if p.rate_hz <= 0:
            raise ValueError(f"{self.name}.params.rate_hz: {p.rate_hz} is not positive")
        world = World(WorldParams(realtime=p.realtime))
        SCENES[p.scene](world)
        self.robot = robot = SimRobot(world, p.robot)
        robot.step(p.settle)
        self._io = _PartIO(io)
        self.commands = JointCommandSubscriber(
            "command", robot, JointCommandSubscriber.Params(rate_hz=p.rate_hz, timeout=p.command_timeout))
        self.clock = WorldClock("clock", world, WorldClock.Params(rate_hz=p.rate_hz, lockstep=True))
        spec = robot.spec
        every = 1.0 / p.rate_hz
        parts: list[tuple[Module, float]] = [(JointStatePublisher("joint_state", robot), every)]
        parts += [(FTPublisher(f"ft_{a.name}", robot, FTPublisher.Params(rate_hz=p.rate_hz, arm=a.name)), every)
                  for a in spec.arms if a.ft]
        parts += [(TactilePublisher(f"tactile_{h.name}", robot, TactilePublisher.Params(rate_hz=p.rate_hz, hand=h.name)), every)
                  for h in spec.hands if h.pads]
        if p.model_hz > 0:
            parts.append((RobotModelPublisher("model", RobotModelPublisher.Params(rate_hz=p.model_hz),
                                              spec, robot.art.base, robot.name), 1.0 / p.model_hz))
        if p.camera_hz > 0 and spec.cameras:
            parts.append((CameraPublisher("camera", robot, CameraPublisher.Params(
                rate_hz=p.camera_hz, camera=spec.cameras[0].name, stride=p.camera_stride)), 1.0 / p.camera_hz))
        if p.ground_truth_hz > 0:
            parts.append((GroundTruthPublisher("ground_truth", robot, GroundTruthPublisher.Params(rate_hz=p.ground_truth_hz)),
                          1.0 / p.ground_truth_hz))
        for m in (self.commands, self.clock, *(m for m, _ in parts)):
            m.setup(self._io)
        self.parts = [_Part(m, period) for m, period in parts]

    def start(self) -> None:
        self.commands.start()
        for part in self.parts:
            part.module.start()
            part.due = self.robot.time

    def reset(self) -> None:
        for part in self.parts:
            part.module.reset()

    def _fault(self, where: str, exc: Exception) -> None:
        self.failure = f"{where}: {type(exc).__name__}: {exc}"
        self.io.emit(Event.HARDWARE_FAILURE, self.failure[:500])

    def step(self) -> Status:
        if self.failure:
            return Status.RUNNING  # the world is broken: the robot stays stopped, the node lives on
        try:
            self.commands.step()
            self.clock.step()
        except Exception as exc:  # a physics blow-up is a fault of the simulated robot, not of the node
            self._fault("physics", exc)
            return Status.RUNNING
        t = self.robot.time
        for part in self.parts:
            if part.broken or t < part.due - 1e-9:
                continue
            part.due = max(part.due + part.period, t)
            try:
                part.module.step()
            except Exception as exc:  # a sensor that cannot produce a sample is a lost stream
                part.broken = f"{part.module.name}: {type(exc).__name__}: {exc}"
                self.io.emit(Event.HARDWARE_FAILURE, part.broken[:500])
        return Status.RUNNING
