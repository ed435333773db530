"""The broker as a module, so any node can host it (``type: broker``)."""

from __future__ import annotations

from dataclasses import dataclass

from contactflow.abstraction.broker import Broker
from contactflow.nodes.module import Layer, Module, ModuleIO
from contactflow.nodes.status import Status


class BrokerModule(Module):
    """Answers ``broker/dispatch`` and supervises dispatched tasks (thesis ch. 7)."""

    layer = Layer.TASK
    autostart = True

    @dataclass(frozen=True)
    class Params:
        rate_hz: float = 1.0  # Hz, only the status heartbeat
        bid_timeout: float = 3.0  # s to wait for robots' dry runs

    def setup(self, io: ModuleIO) -> None:
        super().setup(io)
        self._broker: Broker | None = None

    def start(self) -> None:
        self._broker = Broker(self.io.transport, self.io.keyspace, bid_timeout=self.params.bid_timeout,
                              source=f"{self.io.robot}/{self.io.node}/{self.name}", now=lambda: self.io.now)
        self._broker.start()

    def step(self) -> Status:
        return Status.RUNNING

    def busy(self) -> bool:
        """Never: the broker works on its queryable's threads, on no robot's clock (a paused world stays paused)."""
        return False

    def stop(self) -> None:
        if self._broker is not None:
            self._broker.stop()
            self._broker = None
