"""A robot's broker agent as a module on the robot's control node (``type: robot_agent``)."""

from __future__ import annotations

from dataclasses import dataclass

from contactflow.abstraction.agent import RobotAgent
from contactflow.abstraction.profiles import PROFILES
from contactflow.abstraction.testing import fake_executor
from contactflow.embodiments.messages import DepthImage
from contactflow.nodes.module import Layer, Module, ModuleIO, Port
from contactflow.nodes.params import ParamError
from contactflow.nodes.status import Status
from contactflow.nodes.wire import NDArray, encode, stamp


class RobotAgentModule(Module):
    """Advertises the robot, bids on ATDs and runs the ESTDs it is given.

    ``executor: sim`` runs the task on the robot's simulated embodiment (primitives reading
    physics sensors); ``executor: scripted`` plays every primitive as succeeding after
    ``primitive_duration`` s — for exercising dispatch and failover without physics.
    """

    layer = Layer.TASK
    autostart = True
    outputs = (Port("depth", DepthImage, "the robot camera's depth frames while a task runs"),)

    @dataclass(frozen=True)
    class Params:
        rate_hz: float = 1.0  # Hz, status heartbeat
        robot: str = "tombatossals"  # embodiment name
        executor: str = "sim"  # sim | scripted
        realtime: float = 1.0  # pace of the task loop (1 = real time, 0 = as fast as possible)
        primitive_duration: float = 1.0  # s, scripted executor only
        scene: str = "thesis_7_3"  # sim executor: the station's world (embodiments/scenes.py)
        fusion: bool = True  # sim executor: fuse the robot's contact cues and publish contact events
        camera_hz: float = 1.0  # Hz of simulated time, depth frames of the robot's camera (0 = none)

        def validate(self) -> None:
            if self.robot not in PROFILES:
                raise ValueError(f"robot: {self.robot!r} is not one of {sorted(PROFILES)}")
            if self.executor not in ("sim", "scripted"):
                raise ValueError(f"executor: {self.executor!r} is not sim or scripted")

    def setup(self, io: ModuleIO) -> None:
        super().setup(io)
        self._agent: RobotAgent | None = None

    def _executor(self):
        p = self.params
        if p.executor == "scripted":
            return fake_executor(duration=p.primitive_duration, realtime=p.realtime)
        from contactflow.abstraction.sim_executor import SimExecutor

        return SimExecutor(p.robot, scene=p.scene, realtime=p.realtime, monitor_factory=self._station_monitor)

    def _station_monitor(self, robot):
        """Called once the world exists: the per-tick hook publishing contact events and depth."""
        hooks = []
        if self.params.fusion:
            hooks.append(self._contact_monitor(robot))
        if self.params.camera_hz > 0 and robot.spec.cameras:
            hooks.append(self._camera_monitor(robot))

        def monitor(r) -> None:
            for hook in hooks:
                hook(r)

        return monitor

    def _camera_monitor(self, robot):
        camera = robot.spec.cameras[0].name
        period = 1.0 / self.params.camera_hz
        state = {"next": 0.0}

        def publish(r) -> None:
            if r.time + 1e-9 < state["next"]:
                return
            state["next"] = r.time + period
            frame = r.camera(camera)
            self.io.publish("depth", DepthImage(camera=camera, depth=NDArray.of(frame.depth.astype("float32")),
                                                K=[float(v) for v in frame.K.ravel()],
                                                T_world_cam=[float(v) for v in frame.T_world_cam.ravel()]))

        return publish

    def _contact_monitor(self, robot):
        from contactflow.fusion.messages import ContactEventMsg
        from contactflow.fusion.station import StationFusion

        pub = self.io.transport.publisher(self.io.keyspace.fused(self.params.robot, "events"))
        seq = 0

        def publish(event) -> None:
            nonlocal seq
            seq += 1
            msg = stamp(ContactEventMsg.of(event), f"{self.params.robot}/{self.io.node}/{self.name}/fusion",
                        seq, event.t)
            pub(encode(msg))

        return StationFusion(robot, publish)

    def start(self) -> None:
        try:
            self.params.validate()
        except ValueError as exc:
            raise ParamError(str(exc)) from None
        self._agent = RobotAgent(PROFILES[self.params.robot], self.io.transport, self.io.keyspace,
                                 self._executor(), node=self.io.node)
        self._agent.start()

    def step(self) -> Status:
        return Status.RUNNING

    def stop(self) -> None:
        if self._agent is not None:
            self._agent.stop()
            self._agent = None
