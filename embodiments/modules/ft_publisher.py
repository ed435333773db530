"""Wrist force-torque publisher of one arm."""

from __future__ import annotations

from dataclasses import dataclass

from contactflow.embodiments.messages import Wrench
from contactflow.embodiments.modules.backend import RobotBackend
from contactflow.nodes.module import Layer, Module, Port
from contactflow.nodes.status import Event, Status


class FTPublisher(Module):
    """Publishes the external wrist wrench of ``params.arm`` (world axes, the hand's own weight removed):
    what contact generators explain, untouched by the tares a primitive takes."""

    layer = Layer.INTERFACE
    outputs = (Port("wrench", Wrench, "wrist wrench in world axes"),)
    events = (Event.HARDWARE_FAILURE,)

    @dataclass(frozen=True)
    class Params:
        rate_hz: float = 200.0  # Hz (JR3 up to 200 Hz, App. A.1.2)
        arm: str = "left"

    def __init__(self, name: str, robot: RobotBackend, params: Params | None = None) -> None:
        super().__init__(name, params)
        self.robot = robot

    def step(self) -> Status:
        if self.robot.failed:
            return Status.RUNNING
        r = self.robot.ft(self.params.arm)
        self.io.publish("wrench", Wrench(arm=self.params.arm, sensor_frame=r.frame, force=[float(x) for x in r.external[:3]],
                                         torque=[float(x) for x in r.external[3:]], estimated=r.estimated))
        return Status.RUNNING
