"""Perceptual primitive: wait until a value crosses a threshold, then raise an event."""

from __future__ import annotations

from dataclasses import dataclass

from contactflow.nodes.messages import Vector
from contactflow.nodes.module import Layer, Module, Port
from contactflow.nodes.status import Event, Status


class ThresholdWatch(Module):
    """Raises ``event`` and succeeds when ``|value| >= threshold``; fails after ``timeout``."""

    layer = Layer.PRIMITIVE
    inputs = (Port("in", Vector),)
    outputs = (Port("level", Vector, "the last value seen"),)
    events = (Event.CONTACT, Event.SUCCESS, Event.TIMEOUT)

    @dataclass(frozen=True)
    class Params:
        rate_hz: float = 50.0  # Hz
        threshold: float = 0.8  # signal units
        timeout: float = 10.0  # s, 0 = never
        event: Event = Event.CONTACT

    def start(self) -> None:
        self._t0 = self.io.now

    def step(self) -> Status:
        p = self.params
        for m in self.io.take("in"):
            self.io.publish("level", Vector(values=list(m.values)), inputs=[m.hdr.id])
            if m.values and abs(m.values[0]) >= p.threshold:
                self.io.emit(p.event, detail=f"|{m.values[0]:.3f}| >= {p.threshold}", values={"value": m.values[0]})
                return Status.SUCCESS
        if p.timeout > 0 and self.io.now - self._t0 > p.timeout:
            self.io.emit(Event.TIMEOUT, detail=f"no crossing within {p.timeout} s")
            return Status.FAILURE
        return Status.RUNNING
