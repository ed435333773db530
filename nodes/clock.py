"""Clocks a node steps its modules on: the wall clock, or the simulation clock on the key space."""

from __future__ import annotations

import logging
import threading
import time

from contactflow.nodes.keys import KeySpace
from contactflow.nodes.messages import Clock, LockstepAck, Mark
from contactflow.nodes.transport import Handle, Transport
from contactflow.nodes.wire import WireError, decode, encode, stamp

log = logging.getLogger("contactflow.clock")

MAX_TIME_JUMP = 3600.0  # s of simulated time one clock message may move a running clock ahead
MAX_TICK_JUMP = 1 << 24  # world ticks one clock message may move a running lockstep clock ahead
"""A clock message beyond these is refused and counted (``rejected``): one forged far-ahead time
or tick would otherwise become the clock, every real message after it would look old, and the
node would stay up with a dead loop. The first message of a clock is taken as it is (a node may
join a world that has run for hours)."""


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

    def __init__(self, transport: Transport, ks: KeySpace, cell: str = "") -> None:
        self._t = 0.0
        self._heard = False  # a clock message was taken: later ones are bounded by MAX_TIME_JUMP
        self._cond = threading.Condition()
        self.rejected = 0
        self._sub: Handle = transport.subscribe(ks.clock(cell), self._on_clock)

    def _on_clock(self, key: str, payload: bytes) -> None:
        try:
            msg = decode(payload, Clock, key)
        except WireError:
            self.rejected += 1
            return
        with self._cond:
            if self._heard and msg.t > self._t + MAX_TIME_JUMP:
                self._refuse(key, f"t={msg.t:g} s is more than {MAX_TIME_JUMP:g} s ahead of {self._t:g} s")
                return
            if self._advance(msg):
                self._heard = True
                self._cond.notify_all()

    def _refuse(self, key: str, why: str) -> None:
        """Count a clock message that would move the clock too far; log the first ten and every thousandth."""
        self.rejected += 1
        if self.rejected <= 10 or self.rejected % 1000 == 0:
            log.warning("%s: clock message refused (%d so far): %s", key, self.rejected, why)

    def _advance(self, msg: Clock) -> bool:
        """Take the time of ``msg`` (under the lock); whether the clock moved."""
        if msg.t > self._t:
            self._t = msg.t
            return True
        return False

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


class LockstepClock(SimClock):
    """The simulation clock of a node the world waits for: one host tick per world tick, then an ack.

    The node announces itself on ``alive/lockstep/<node>``; the world publishes tick k's
    sensor messages and then the clock, this node steps every module due at that time, and
    :meth:`ack` tells the world it may advance (thesis §6.3: one control cycle). Messages a
    module sends during the tick leave before the ack, on the same session, so the world
    applies them before tick k+1 whatever the process layout. Messages between nodes (or
    between two modules of one node) travel on their own: the ack names the last one of each
    stream (:class:`Mark`), the world passes the marks on with tick k+1, and the host steps
    tick k+1 once its inputs have them, so a module sees a message at the same tick in any layout.
    """

    def __init__(self, transport: Transport, ks: KeySpace, node: str, cell: str = "") -> None:
        self._tick = -1  # the latest tick heard
        self._done = -1  # the last tick handed to the host
        self._ticks: dict[int, tuple[float, list[Mark], int]] = {}  # heard, not yet stepped: tick -> (t, marks, lag)
        self._stepped: float | None = None  # the time of the tick handed to the host
        super().__init__(transport, ks, cell)
        self.node = node
        self._ack = transport.publisher(ks.lockstep(node, cell))
        self._seq = 0
        self._transport, self._key = transport, ks.alive_lockstep(node, cell)
        self._token: Handle | None = None

    def announce(self) -> None:
        """Tell the world to wait for this node (its liveliness token): once its modules are set up and its
        autostarted tasks have started, so a world that waits for the node ticks only then and the tasks start
        at the same tick whatever the layout and the machine's speed."""
        if self._token is None:
            self._token = self._transport.token(self._key)

    def _advance(self, msg: Clock) -> bool:
        if self._tick >= 0 and msg.tick > self._tick + MAX_TICK_JUMP:
            self._refuse("clock", f"tick {msg.tick} is more than {MAX_TICK_JUMP} ahead of tick {self._tick}")
            return False
        if msg.tick > self._tick:
            self._tick, self._t = msg.tick, max(self._t, msg.t)
            self._ticks[msg.tick] = (msg.t, msg.marks, max(0, msg.lag))
            if len(self._ticks) > 8:  # a node whose loop has not started yet steps from the latest anyway
                self._ticks = {j: v for j, v in self._ticks.items() if j > msg.tick - 4}
            return True
        return False

    def now(self) -> float:
        """The time of the tick the node steps: a pipelined world publishes the next one meanwhile."""
        return self._t if self._stepped is None else self._stepped

    def wait_tick(self, stop: threading.Event) -> tuple[int, list[Mark], int] | None:
        """Block until the world publishes a tick this node has not stepped: (tick, its marks, the world's lag);
        None when ``stop`` is set. Ticks come in order, but never more than the lag behind the latest: a node that
        fell behind (the world went on without it) goes on from the latest, as without a pipeline."""
        with self._cond:
            while self._tick <= self._done and not stop.is_set():
                self._cond.wait(0.05)
            if stop.is_set():
                return None
            latest = self._ticks[self._tick]
            k = max(min(j for j in self._ticks if j > self._done), self._tick - latest[2])
            t, marks, lag = self._ticks[k]
            self._ticks = {j: v for j, v in self._ticks.items() if j > k}
            self._done, self._stepped = k, t
            return k, marks, lag

    def ack(self, tick: int, marks: list[Mark] | None = None, busy: bool = False, working: bool = False) -> None:
        """Answer ``tick``; with ``working``, tell the world the node is still stepping it (not an answer: it waits on)."""
        self._seq += 1
        msg = stamp(LockstepAck(node=self.node, tick=tick, marks=marks or [], busy=busy, working=working),
                    f"lockstep/{self.node}", self._seq, self._t)
        self._ack(encode(msg))

    def close(self) -> None:
        if self._token is not None:
            self._token.close()
        super().close()
