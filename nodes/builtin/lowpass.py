"""First-order low-pass filter service over a Vector stream."""

from __future__ import annotations

import math
from dataclasses import dataclass

from contactflow.nodes.messages import Vector
from contactflow.nodes.module import Layer, Module, Port
from contactflow.nodes.status import Status


class LowPass(Module):
    """Exponential smoothing of every element of the input vector."""

    layer = Layer.SERVICE
    inputs = (Port("in", Vector),)
    outputs = (Port("out", Vector),)

    @dataclass(frozen=True)
    class Params:
        rate_hz: float = 50.0  # Hz
        cutoff_hz: float = 2.0  # Hz, -3 dB frequency

    def start(self) -> None:
        self._state: list[float] | None = None

    def reset(self) -> None:
        self._state = None

    def step(self) -> Status:
        msgs = self.io.take("in")
        if not msgs:
            return Status.RUNNING
        alpha = 1.0 - math.exp(-2 * math.pi * self.params.cutoff_hz / self.params.rate_hz)
        for m in msgs:
            if self._state is None or len(self._state) != len(m.values):
                self._state = list(m.values)
            else:
                self._state = [s + alpha * (v - s) for s, v in zip(self._state, m.values, strict=True)]
        self.io.publish("out", Vector(values=list(self._state), names=msgs[-1].names), inputs=[m.hdr.id for m in msgs])
        return Status.RUNNING
