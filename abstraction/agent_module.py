"""A robot's broker agent as a module on the robot's control node (``type: robot_agent``)."""

from __future__ import annotations

from dataclasses import dataclass

from contactflow.abstraction.agent import RobotAgent
from contactflow.abstraction.profiles import PROFILES
from contactflow.embodiments.messages import DepthImage, ObjectPoses
from contactflow.nodes.module import Layer, Module, ModuleIO, Port
from contactflow.nodes.params import ParamError
from contactflow.nodes.status import Status
from contactflow.nodes.wire import NDArray, encode, stamp


class RobotAgentModule(Module):
    """Advertises the robot, bids on ATDs and runs the ESTDs it is given.

    The task runs on the robot's simulated embodiment (primitives reading physics sensors).
    The station also publishes its world's object poses on the evaluation keys (ground truth
    no primitive reads) when the world is built and whenever a task ends, so a deployment can
    check what a task physically did.
    """

    layer = Layer.TASK
    autostart = True
    outputs = (Port("depth", DepthImage, "the robot camera's depth frames while a task runs"),)

    @dataclass(frozen=True)
    class Params:
        rate_hz: float = 1.0  # Hz, status heartbeat
        robot: str = "tombatossals"  # embodiment name
        executor: str = "sim"  # sim (the only one: the robot's simulated embodiment)
        realtime: float = 1.0  # pace of the task loop (1 = real time, 0 = as fast as possible)
        scene: str = "thesis_7_3"  # the station's world (embodiments/scenes.py)
        fusion: bool = True  # fuse the robot's contact cues and publish contact events
        camera_hz: float = 1.0  # Hz of simulated time, depth frames of the robot's camera (0 = none)

        def validate(self) -> None:
            if self.robot not in PROFILES:
                raise ValueError(f"robot: {self.robot!r} is not one of {sorted(PROFILES)}")
            if self.executor != "sim":
                raise ValueError(f"executor: {self.executor!r} is not sim")
            if self.realtime < 0:
                raise ValueError(f"realtime: {self.realtime} is negative")

    def setup(self, io: ModuleIO) -> None:
        super().setup(io)
        self._agent: RobotAgent | None = None
        self._truth_seq = 0
        self._truth_pub = None

    def _executor(self):
        from contactflow.abstraction.sim_executor import SimExecutor

        p = self.params
        sim = SimExecutor(p.robot, scene=p.scene, realtime=p.realtime, monitor_factory=self._station_monitor)

        def run(translation, report, cancel, params):
            try:
                return sim(translation, report, cancel, params)
            finally:
                # before the agent's final report: whoever waits for the end finds the world as it left it
                if sim.robot is not None:
                    self._publish_truth(sim.robot)

        return run

    def _publish_truth(self, robot) -> None:
        import numpy as np

        gt = robot.ground_truth()
        names = sorted(gt.object_poses)
        poses = np.stack([gt.object_poses[n] for n in names]) if names else np.zeros((0, 4, 4))
        self._truth_seq += 1
        msg = stamp(ObjectPoses(names=names, poses=NDArray.of(np.asarray(poses, dtype=np.float64))),
                    f"{self.params.robot}/{self.io.node}/{self.name}/truth", self._truth_seq, robot.time)
        if self._truth_pub is None:
            self._truth_pub = self.io.transport.publisher(self.io.keyspace.evaluation(self.params.robot, "object_poses"))
        self._truth_pub(encode(msg))

    def _station_monitor(self, robot):
        """Called once the world exists: the per-tick hook publishing contact events and depth."""
        self._publish_truth(robot)
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
        from contactflow.fusion.station import StationFusion, cloud_publisher

        pub = self.io.transport.publisher(self.io.keyspace.fused(self.params.robot, "events"))
        seq = 0

        def publish(event) -> None:
            nonlocal seq
            seq += 1
            msg = stamp(ContactEventMsg.of(event), f"{self.params.robot}/{self.io.node}/{self.name}/fusion",
                        seq, event.t)
            pub(encode(msg))

        source = f"{self.params.robot}/{self.io.node}/{self.name}"
        return StationFusion(robot, publish, publish_cloud=cloud_publisher(self.io.transport, source),
                             keyspace=self.io.keyspace)

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
