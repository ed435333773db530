"""A sensor-like service producing a noisy sine wave (the head of demo pipelines)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from contactflow.nodes.messages import Vector
from contactflow.nodes.module import Layer, Module, Port
from contactflow.nodes.status import Status


class SignalSource(Module):
    """Publishes ``amplitude * sin(2 pi f t) + noise`` on ``signal``."""

    layer = Layer.SERVICE
    outputs = (Port("signal", Vector, "the sampled value"),)

    @dataclass(frozen=True)
    class Params:
        rate_hz: float = 50.0  # Hz
        amplitude: float = 1.0  # signal units
        frequency: float = 0.5  # Hz
        noise: float = 0.0  # standard deviation, signal units
        seed: int = 0

    def start(self) -> None:
        self._rng = np.random.default_rng(self.params.seed)

    def step(self) -> Status:
        p = self.params
        t = self.io.now
        value = p.amplitude * math.sin(2 * math.pi * p.frequency * t) + p.noise * self._rng.standard_normal()
        self.io.publish("signal", Vector(values=[value], names=["value"]))
        return Status.RUNNING
