"""Joint state publisher (thesis §6.3.1): every joint of the robot in one message at 200 Hz."""

from __future__ import annotations

from dataclasses import dataclass

from contactflow.embodiments.messages import JointState
from contactflow.embodiments.modules.backend import RobotBackend
from contactflow.nodes.module import Layer, Module, Port
from contactflow.nodes.status import Event, Status
from contactflow.nodes.wire import NDArray


class JointStatePublisher(Module):
    """Publishes the robot's joint state; raises ``hardware_failure`` once when the robot faults."""

    layer = Layer.INTERFACE
    outputs = (Port("joint_state", JointState, "positions, velocities, efforts of every joint"),)
    events = (Event.HARDWARE_FAILURE,)

    @dataclass(frozen=True)
    class Params:
        rate_hz: float = 200.0  # Hz

    def __init__(self, name: str, robot: RobotBackend, params: Params | None = None) -> None:
        super().__init__(name, params)
        self.robot = robot
        self._reported = False

    def step(self) -> Status:
        if self.robot.failed and not self._reported:
            self._reported = True
            self.io.emit(Event.HARDWARE_FAILURE, self.robot.failure)
        names, q, qd, tau = self.robot.joint_state()
        self.io.publish("joint_state", JointState(robot=self.robot.name, names=names, position=NDArray.of(q),
                                                  velocity=NDArray.of(qd), effort=NDArray.of(tau)))
        return Status.RUNNING

    def reset(self) -> None:
        self._reported = False
