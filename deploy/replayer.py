"""Republishes a recording on a site at its recorded pace (``contactflow replay``).

Every key-space channel goes back on its key (moved to another site on request), the world's
clock among them, so modules that follow the clock (``clock: sim``) run on the recording's
time: a fusion or vision node then runs again on recorded sensors, whose stamps are of that
time. A recording of wall-clock nodes has no clock channel; the replay then publishes one,
reading the recorded wall time (as ``rosbag play --clock`` does). A site whose live publishers already use
the recorded keys is refused unless forced: two streams on one key would mix.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass

from contactflow.deploy.recording import Recording
from contactflow.nodes.keys import ROOT, KeySpace
from contactflow.nodes.messages import Clock
from contactflow.nodes.transport import Transport
from contactflow.nodes.wire import encode

CLOCK_HZ = 100.0
"""Hz, the rate of the clock a replay publishes for a recording without one, while it waits."""
CLOCK_STEP = 0.001
"""s, the finest step of that clock: a burst of messages within it shares one clock message."""


class ReplayError(RuntimeError):
    """A replay that must not start; the message says why."""


@dataclass
class ReplayStats:
    """What a replay published."""

    messages: int = 0
    clock_ticks: int = 0  # clock messages the replay made (a recording without a clock)
    seconds: float = 0.0  # s, wall time of the replay
    recorded_seconds: float = 0.0  # s, span of the recording replayed

    @property
    def speed(self) -> float:
        """Recorded seconds per wall second (x real time)."""
        return self.recorded_seconds / self.seconds if self.seconds > 0 else 0.0

    def as_dict(self) -> dict[str, float]:
        return {**asdict(self), "speed": self.speed}


def move_key(key: str, site: str) -> str:
    """``key`` of the recorded site on ``site``."""
    parts = key.split("/", 2)
    if len(parts) < 3 or parts[0] != ROOT:
        raise ReplayError(f"recorded key {key!r} is not a contactflow key ({ROOT}/<site>/...)")
    return f"{ROOT}/{site}/{parts[2]}"


class Replayer:
    """Publishes a recording's key-space channels on ``site`` (default: the recorded one)."""

    def __init__(self, transport: Transport, recording: Recording, site: str | None = None, rate: float = 1.0,
                 keys: set[str] | None = None) -> None:
        if rate < 0:
            raise ReplayError(f"rate={rate}: a replay rate is >= 0 (0: as fast as possible)")
        self.transport = transport
        self.recording = recording
        self.site = site or recording.site
        self.ks = KeySpace(self.site)  # a site name that is not one key segment is refused here
        self.rate = rate
        self.keys = keys
        self._pubs: dict[str, Callable[[bytes], None]] = {}
        recorded_clock = KeySpace(recording.site).clock()
        self.makes_clock = not any(k == recorded_clock or k.startswith(recorded_clock + "/") for k in self.replayed())

    def replayed(self) -> list[str]:
        """The recorded keys the replay publishes."""
        return [k for k in self.recording.channels if self.keys is None or k in self.keys]

    def targets(self) -> set[str]:
        """The keys the replay publishes on."""
        return {move_key(k, self.site) for k in self.replayed()}

    def live_keys(self, listen: float = 1.0) -> list[str]:
        """Recorded keys that live publishers of the site use now (heard within ``listen`` s)."""
        targets = self.targets()
        heard: set[str] = set()
        lock = threading.Lock()

        def on_sample(key: str, _payload: bytes) -> None:
            if key in targets:
                with lock:
                    heard.add(key)
        sub = self.transport.subscribe(f"{ROOT}/{self.site}/**", on_sample)
        try:
            time.sleep(listen)
        finally:
            sub.close()
        return sorted(heard)

    def check(self, force: bool = False, listen: float = 1.0) -> list[str]:
        """Refuse (ReplayError) a site with live publishers on the recorded keys, unless ``force``; returns them."""
        live = self.live_keys(listen)
        if live and not force:
            shown = ", ".join(live[:5]) + (f" and {len(live) - 5} more" if len(live) > 5 else "")
            raise ReplayError(f"site {self.site!r} has live publishers on {len(live)} recorded keys ({shown}); "
                              "stop them, replay on another site (--site) or force it (--force)")
        return live

    def run(self, progress: Callable[[int, float], None] | None = None, tail: float = 1.0) -> ReplayStats:
        """Publish every message at its recorded time divided by the rate; ``progress(messages, recorded s)``.

        A clock the replay makes reads the recorded time: before each message, the message's
        own time (so a sim-clock node takes it at the time it was recorded; messages within
        ``CLOCK_STEP`` of the last clock message share it), and every
        ``1 / CLOCK_HZ`` s while the replay waits; ``tail`` s after the last message it runs on,
        so what the last messages start (a contact's break) still happens.
        """
        stats = ReplayStats()
        t_first: int | None = None
        wall0 = time.monotonic()
        tick = self.transport.publisher(self.ks.clock()) if self.makes_clock else None

        last = -math.inf

        def clock(t: float) -> None:
            nonlocal last
            if tick is not None and t >= last + CLOCK_STEP:
                tick(encode(Clock(t=t, real_time_factor=self.rate)))
                stats.clock_ticks += 1
                last = t

        def wait_until(rel: float) -> None:
            """Sleep until recorded second ``rel`` is due, the clock running meanwhile."""
            while (left := wall0 + rel / self.rate - time.monotonic()) > 0:
                time.sleep(min(left, 1.0 / CLOCK_HZ))
                if tick is not None and t_first is not None:
                    clock(t_first / 1e9 + min(rel, (time.monotonic() - wall0) * self.rate))

        rel = 0.0
        for s in self.recording.samples(self.keys):
            if t_first is None:
                t_first = s.log_ns
            rel = (s.log_ns - t_first) / 1e9
            if self.rate > 0:
                wait_until(rel)
            clock(s.log_ns / 1e9)
            key = move_key(s.key, self.site)
            pub = self._pubs.get(key)
            if pub is None:
                pub = self._pubs[key] = self.transport.publisher(key)
            pub(encode(s.msg))
            stats.messages += 1
            stats.recorded_seconds = rel
            if progress is not None and stats.messages % 100 == 0:
                progress(stats.messages, rel)
        stats.seconds = time.monotonic() - wall0
        if tick is not None and self.rate > 0 and t_first is not None:
            wait_until(rel + tail * self.rate)
        return stats
