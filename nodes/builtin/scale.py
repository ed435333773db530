"""Affine map service ``gain * x + offset`` over a Vector stream."""

from __future__ import annotations

from dataclasses import dataclass

from contactflow.nodes.messages import Vector
from contactflow.nodes.module import Layer, Module, Port
from contactflow.nodes.status import Status


class Scale(Module):
    """Scales every new input message; one output per input, provenance kept."""

    layer = Layer.SERVICE
    inputs = (Port("in", Vector),)
    outputs = (Port("out", Vector),)

    @dataclass(frozen=True)
    class Params:
        rate_hz: float = 100.0  # Hz
        gain: float = 1.0
        offset: float = 0.0

    def step(self) -> Status:
        for m in self.io.take("in"):
            out = Vector(values=[self.params.gain * v + self.params.offset for v in m.values], names=m.names)
            self.io.publish("out", out, inputs=[m.hdr.id])
        return Status.RUNNING
