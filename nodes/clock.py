"""Clocks a node steps its modules on: the wall clock, or the simulation clock on the key space."""

from __future__ import annotations

import threading
import time

from contactflow.nodes.keys import KeySpace
from contactflow.nodes.messages import Clock
from contactflow.nodes.transport import Handle, Transport
from contactflow.nodes.wire import WireError, decode


class WallClock:
    """Seconds since the Unix epoch, so stamps of different nodes compare."""

    simulated = False

    def now(self) -> float:
        return time.time()

    def wait_until(self, t: float, stop: threading.Event) -> None:
        delay = t - time.time()
        if delay > 0:
            stop.wait(delay)

    def close(self) -> None:
        return None


class SimClock:
    """Follows the :class:`Clock` messages the world publishes; time stands still without them."""

    simulated = True

    def __init__(self, transport: Transport, ks: KeySpace) -> None:
        self._t = 0.0
        self._cond = threading.Condition()
        self.rejected = 0
        self._sub: Handle = transport.subscribe(ks.clock(), self._on_clock)

    def _on_clock(self, key: str, payload: bytes) -> None:
        try:
            msg = decode(payload, Clock, key)
        except WireError:
            self.rejected += 1
            return
        with self._cond:
            if msg.t > self._t:
                self._t = msg.t
                self._cond.notify_all()

    def now(self) -> float:
        return self._t

    def advance(self, t: float) -> None:
        """Move the clock forward by hand (in-process runs drive it directly)."""
        with self._cond:
            self._t = max(self._t, t)
            self._cond.notify_all()

    def wait_until(self, t: float, stop: threading.Event) -> None:
        with self._cond:
            while self._t < t and not stop.is_set():
                self._cond.wait(0.05)

    def close(self) -> None:
        self._sub.close()
