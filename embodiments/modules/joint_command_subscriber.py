"""Joint command subscriber (thesis §6.3.1): mixes concurrent commands with their weights and drives the joints at 200 Hz."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from contactflow.embodiments.control.mixer import JointCommandMixer
from contactflow.embodiments.messages import JointCommand
from contactflow.embodiments.modules.backend import RobotBackend
from contactflow.nodes.module import Layer, Module, Port
from contactflow.nodes.status import Event, Status
from contactflow.nodes.wire import NDArray, WireError


class JointCommandSubscriber(Module):
    """Combines every fresh ``JointCommand`` per joint (weighted mean) and sends the result to the robot."""

    layer = Layer.INTERFACE
    inputs = (Port("command", JointCommand, "joint commands from any number of sources"),)
    outputs = (Port("mixed", JointCommand, "the mixed command sent to the robot"),)
    events = (Event.HARDWARE_FAILURE,)

    @dataclass(frozen=True)
    class Params:
        rate_hz: float = 200.0  # Hz
        timeout: float = 0.1  # s a source's command stays fresh

    def __init__(self, name: str, robot: RobotBackend, params: Params | None = None) -> None:
        super().__init__(name, params)
        self.robot = robot
        self.mixer: JointCommandMixer | None = None
        self.rejected = 0

    def start(self) -> None:
        names, q, _, _ = self.robot.joint_state()
        self.mixer = JointCommandMixer(list(names), timeout=self.params.timeout)
        self.mixer.hold(q)

    def step(self) -> Status:
        t = self.io.now
        for msg in self.io.take("command"):
            try:
                qd = msg.velocity.numpy() if msg.velocity is not None else None
                self.mixer.submit(msg.source or msg.hdr.source, msg.names, msg.position.numpy(), qd, msg.weight, t)
            except (ValueError, WireError) as exc:
                self.rejected += 1
                self.io.log(f"rejected command: {exc}")
        q, qd, mask = self.mixer.mix(t)
        if mask.any():
            names = [n for n, m in zip(self.mixer.joint_names, mask, strict=True) if m]
            self.robot.submit_joint_command(self.name, names, q[mask], qd[mask], 1.0)
            self.io.publish("mixed", JointCommand(names=names, position=NDArray.of(q[mask]),
                                                  velocity=NDArray.of(np.ascontiguousarray(qd[mask])), source=self.name))
        return Status.RUNNING
