"""A robot's broker agent as a module on the robot's control node (``type: robot_agent``)."""

from __future__ import annotations

from dataclasses import dataclass

from contactflow.abstraction.agent import RobotAgent
from contactflow.abstraction.profiles import PROFILES
from contactflow.abstraction.testing import fake_executor
from contactflow.nodes.module import Layer, Module, ModuleIO
from contactflow.nodes.params import ParamError
from contactflow.nodes.status import Status


class RobotAgentModule(Module):
    """Advertises the robot, bids on ATDs and runs the ESTDs it is given.

    ``executor: sim`` runs the task on the robot's simulated embodiment (primitives reading
    physics sensors); ``executor: scripted`` plays every primitive as succeeding after
    ``primitive_duration`` s — for exercising dispatch and failover without physics.
    """

    layer = Layer.TASK
    autostart = True

    @dataclass(frozen=True)
    class Params:
        rate_hz: float = 1.0  # Hz, status heartbeat
        robot: str = "tombatossals"  # embodiment name
        executor: str = "sim"  # sim | scripted
        realtime: float = 1.0  # pace of the task loop (1 = real time, 0 = as fast as possible)
        primitive_duration: float = 1.0  # s, scripted executor only

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

        return SimExecutor(p.robot, realtime=p.realtime)

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
