"""Tactile array publisher of one hand (all its pads in one message)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from contactflow.embodiments.messages import TactileArray
from contactflow.embodiments.modules.backend import RobotBackend
from contactflow.nodes.module import Layer, Module, Port
from contactflow.nodes.status import Event, Status
from contactflow.nodes.wire import NDArray


class TactilePublisher(Module):
    """Publishes the pressure images of ``params.hand``."""

    layer = Layer.INTERFACE
    outputs = (Port("tactile", TactileArray, "pressure per taxel, (pads, rows, cols)"),)
    events = (Event.HARDWARE_FAILURE,)

    @dataclass(frozen=True)
    class Params:
        rate_hz: float = 200.0  # Hz (Weiss sensors up to 230 Hz, App. A.1.2)
        hand: str = "left_hand"

    def __init__(self, name: str, robot: RobotBackend, params: Params | None = None) -> None:
        super().__init__(name, params)
        self.robot = robot

    def step(self) -> Status:
        if self.robot.failed:
            return Status.RUNNING
        pads = self.robot.tactile(self.params.hand)
        if not pads:
            return Status.RUNNING
        stack = np.stack([pads[k] for k in pads]).astype(np.float32)
        self.io.publish("tactile", TactileArray(hand=self.params.hand, pads=list(pads), pressure=NDArray.of(stack)))
        return Status.RUNNING
