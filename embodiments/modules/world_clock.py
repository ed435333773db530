"""World clock: steps the physics world in lockstep with the node and publishes the simulation clock."""

from __future__ import annotations

import time
from dataclasses import dataclass

from contactflow.nodes.messages import Clock
from contactflow.nodes.module import Layer, Module, Port
from contactflow.nodes.status import Status


class WorldClock(Module):
    """Each step advances the world by one period (1/rate_hz) and publishes its time and real-time factor."""

    layer = Layer.INTERFACE
    outputs = (Port("clock", Clock, "simulation clock"),)

    @dataclass(frozen=True)
    class Params:
        rate_hz: float = 200.0  # Hz, the joint control rate (§6.3.1)
        lockstep: bool = False  # publish the time as a running sum of periods: exactly the sum a sim-clock
        # host schedules its next step at (the world's steps * timestep can miss it by a rounding error)

    def __init__(self, name: str, world, params: Params | None = None) -> None:
        super().__init__(name, params)
        self.world = world
        self._wall = None
        self._t: float | None = None

    def step(self) -> Status:
        t0 = time.perf_counter()
        self.world.run(1.0 / self.params.rate_hz)
        wall = time.perf_counter() - t0
        rtf = (1.0 / self.params.rate_hz) / wall if wall > 0 else 0.0
        t = self.world.time
        if self.params.lockstep:
            period = 1.0 / self.params.rate_hz
            if self._t is not None and abs(self._t + period - t) < 0.5 * period:
                t = self._t + period
            self._t = t
        self.io.publish("clock", Clock(t=t, real_time_factor=rtf))
        return Status.RUNNING
