"""Lockstep delivery: a message a module sends during world tick k is an input at tick k+1, however late it travels."""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import pytest

from contactflow.nodes.config import ModuleConfig, NodeConfig, parse_source
from contactflow.nodes.host import ModuleHost
from contactflow.nodes.keys import KeySpace
from contactflow.nodes.messages import Clock, LockstepAck, Mark, Vector
from contactflow.nodes.module import Layer, Module, Port
from contactflow.nodes.procs import wait_for
from contactflow.nodes.status import Status
from contactflow.nodes.transport import LocalTransport, ZenohSettings
from contactflow.nodes.wire import decode, encode, stamp

DT = 0.005  # s, one world tick
DELAY = 0.03  # s a data message travels, six ticks of a world that would not wait


class SlowDataTransport(LocalTransport):
    """The in-process bus, with module outputs (``.../out``) delivered ``DELAY`` s late, in the order they were
    sent (a link with latency, as zenoh keeps a publisher's order), by a thread of their own."""

    def __init__(self) -> None:
        super().__init__()
        self._late: queue.Queue[tuple[float, Callable[[bytes], None], bytes]] = queue.Queue()
        threading.Thread(target=self._deliver, daemon=True).start()

    def _deliver(self) -> None:
        while True:
            due, put, data = self._late.get()
            time.sleep(max(0.0, due - time.monotonic()))
            put(data)

    def publisher(self, key, reliable=True):
        put = super().publisher(key, reliable)
        if not key.endswith("/out"):
            return put

        def late(data: bytes) -> None:
            self._late.put((time.monotonic() + DELAY, put, data))
        return late


@dataclass(frozen=True)
class EveryTick:
    rate_hz: float = 1.0 / DT  # Hz, every tick


class Producer(Module):
    """Publishes the time of every tick it steps."""

    layer = Layer.SERVICE
    outputs = (Port("out", Vector),)
    Params = EveryTick

    def step(self) -> Status:
        self.io.publish("out", Vector(values=[self.io.now]))
        return Status.RUNNING


class Consumer(Module):
    """Records, at every tick, the producer's values it has by then."""

    layer = Layer.TASK
    inputs = (Port("inp", Vector),)
    Params = EveryTick

    def start(self) -> None:
        self.seen: list[tuple[float, list[float]]] = []

    def step(self) -> Status:
        self.seen.append((self.io.now, [m.values[0] for m in self.io.take("inp")]))
        return Status.RUNNING


def node(name: str, modules: tuple[ModuleConfig, ...]) -> NodeConfig:
    return NodeConfig(site="ls", node=name, host="h", robot="site", clock="lockstep", zenoh=ZenohSettings(),
                      modules=modules)


def run_world(t: LocalTransport, ks: KeySpace, nodes: list[str], ticks: int, pass_marks: bool, lag: int = 0) -> None:
    """What the world module does: tick k+1 once every node acknowledged tick k - lag, with the marks of those acks."""
    acks: dict[str, dict[int, list[Mark]]] = {n: {} for n in nodes}  # node -> tick -> the marks of its answer
    cond = threading.Condition()

    def on_ack(key: str, payload: bytes) -> None:
        ack = decode(payload, LockstepAck, key)
        if ack.working:
            return
        with cond:
            acks[ack.node][ack.tick] = ack.marks
            cond.notify_all()

    sub = t.subscribe(ks.lockstep("*"), on_ack)
    clock = t.publisher(ks.clock())
    marks: list[Mark] = []
    passed = -1  # the last tick whose answers' marks went out
    try:
        for k in range(ticks):
            clock(encode(stamp(Clock(t=k * DT, tick=k, marks=marks if pass_marks else [], lag=lag), "world/clock", k + 1,
                               k * DT)))
            want = max(k - lag, 0)
            with cond:
                assert cond.wait_for(lambda w=want: all(max(acks[n], default=-1) >= w for n in nodes), 10.0)
                marks = [m for n in nodes for j in range(passed + 1, want + 1) for m in acks[n].get(j, [])]
            passed = want
    finally:
        sub.close()


def one_node(t: LocalTransport) -> tuple[ModuleHost, Consumer]:
    """The producer and the consumer on one lockstep node."""
    producer, consumer = Producer("src"), Consumer("dst")
    cfg_p = ModuleConfig("src", "producer", Producer, Producer.Params(), "site")
    cfg_c = ModuleConfig("dst", "consumer", Consumer, Consumer.Params(), "site", inputs={"inp": parse_source("src.out")})
    host = ModuleHost(node("n1", (cfg_p, cfg_c)), t)
    host.add(cfg_p, producer)
    host.add(cfg_c, consumer)
    return host, consumer


@pytest.mark.parametrize("lag", [0, 1])
@pytest.mark.parametrize("layout", ["one node", "two nodes"])
def test_a_lockstep_module_gets_what_another_sent_during_the_tick_before_however_late_it_travels(layout, lag):
    """With a pipelined world (lag 1: it runs tick k+1 while its nodes step tick k) the tick after the next."""
    t = SlowDataTransport()
    ks = KeySpace("ls")
    producer, consumer = Producer("src"), Consumer("dst")
    cfg_p = ModuleConfig("src", "producer", Producer, Producer.Params(), "site")
    cfg_c = ModuleConfig("dst", "consumer", Consumer, Consumer.Params(), "site", inputs={"inp": parse_source("src.out")})
    if layout == "one node":
        hosts = [ModuleHost(node("n1", (cfg_p, cfg_c)), t)]
        hosts[0].add(cfg_p, producer)
        hosts[0].add(cfg_c, consumer)
    else:
        hosts = [ModuleHost(node("n1", (cfg_p,)), t), ModuleHost(node("n2", (cfg_c,)), t)]
        hosts[0].add(cfg_p, producer)
        hosts[1].add(cfg_c, consumer)
    for h in hosts:
        h.start()
    try:
        run_world(t, ks, [h.config.node for h in hosts], 40, pass_marks=True, lag=lag)
    finally:
        for h in hosts:
            h.shutdown()
    steps = consumer.seen[1 + lag:]  # nothing was sent before tick 0
    assert len(steps) >= 38 - lag
    # every tick brings exactly the value the producer sent 1 + lag ticks before, not DELAY (6 ticks) later
    back = (1 + lag) * DT
    assert all(values == [pytest.approx(now - back)] for now, values in steps), [s for s in steps if s[1] != [pytest.approx(s[0] - back)]]
    assert all(h.mark_timeouts == 0 for h in hosts)


def test_without_the_marks_a_late_message_reaches_a_later_tick():
    """The same run with a world that passes no marks on: the layout's delays decide the tick a message is seen."""
    t = SlowDataTransport()
    ks = KeySpace("ls")
    host, consumer = one_node(t)
    host.start()
    try:
        run_world(t, ks, ["n1"], 40, pass_marks=False)
        time.sleep(2 * DELAY)
    finally:
        host.shutdown()
    assert any(values != [pytest.approx(now - DT)] for now, values in consumer.seen[1:])


def test_a_forged_mark_far_ahead_of_its_stream_does_not_hold_the_node():
    """One hostile ack naming seq 2**63-1 of a real stream: the node steps on at once and counts it, not after MARK_WAIT."""
    t = LocalTransport()
    ks = KeySpace("ls")
    host, consumer = one_node(t)
    acks: list[LockstepAck] = []
    sub = t.subscribe(ks.lockstep("*"), lambda key, payload: acks.append(decode(payload, LockstepAck, key)))
    clock = t.publisher(ks.clock())
    host.start()
    try:
        for k in range(20):
            marks = [m for a in acks[-1:] for m in a.marks]
            if k == 10:  # the real mark of the producer's stream, its number made hostile
                marks = [Mark(key=m.key, source=m.source, seq=2**63 - 1) for m in marks]
                assert marks
            t0 = time.monotonic()
            clock(encode(stamp(Clock(t=k * DT, tick=k, marks=marks), "world/clock", k + 1, k * DT)))
            deadline = time.monotonic() + 10.0
            while not (acks and acks[-1].tick >= k) and time.monotonic() < deadline:
                time.sleep(0.001)
            assert acks[-1].tick == k and time.monotonic() - t0 < 1.0, (k, time.monotonic() - t0)
    finally:
        host.shutdown()
        sub.close()
    assert host.marks_refused == 1 and host.mark_timeouts == 0
    assert len(consumer.seen) == 20


class Slow(Module):
    """Takes ``hold_s`` of wall time over its step at ``at`` (a first plan on a loaded machine)."""

    layer = Layer.TASK
    Params = EveryTick

    def start(self) -> None:
        self.at, self.hold_s, self.steps = 3, 2.6, 0

    def step(self) -> Status:
        if self.steps == self.at:
            time.sleep(self.hold_s)
        self.steps += 1
        return Status.RUNNING


def test_a_node_slow_over_one_tick_tells_the_world_every_second_that_it_is_still_working_on_it(caplog):
    t = LocalTransport()
    ks = KeySpace("ls")
    cfg = ModuleConfig("slow", "slow", Slow, Slow.Params(), "site")
    host = ModuleHost(node("n1", (cfg,)), t)
    host.add(cfg, Slow("slow"))
    got: list[tuple[float, LockstepAck]] = []
    sub = t.subscribe(ks.lockstep("*"), lambda key, payload: got.append((time.monotonic(), decode(payload, LockstepAck, key))))
    host.start()
    try:
        with caplog.at_level("WARNING", logger="contactflow.node.n1"):
            run_world(t, ks, ["n1"], 6, pass_marks=False)
    finally:
        host.shutdown()
        sub.close()
    notes = [(when, a) for when, a in got if a.working]
    answers = [a.tick for _, a in got if not a.working]
    assert answers == list(range(6))  # every tick answered once; the notes are not answers
    # two notes during the 2.6 s step of tick 3 (at about 1 and 2 s), none for another tick
    assert [a.tick for _, a in notes] == [3, 3] and 0.7 < notes[1][0] - notes[0][0] < 1.3, notes
    assert all(a.node == "n1" and not a.marks for _, a in notes)
    assert any("site/n1/slow: one step took 2.6 s (tick 3)" in r.getMessage() for r in caplog.records), caplog.text


class SlowStart(Module):
    """An autostarted module whose start takes a while (a task binding its robot) and records what it saw then."""

    layer = Layer.TASK
    Params = EveryTick

    def start(self) -> None:
        time.sleep(0.3)
        self.announced_at_start = self.io.transport.alive(self.io.keyspace.alive_lockstep("*"))


def test_a_lockstep_node_tells_the_world_to_wait_for_it_only_once_its_autostarted_modules_started():
    """A world that waits for the node ticks only then: an autostarted task starts at the same tick in any layout
    and on any machine (its start read the world's time as tick 0 on one run and tick 1 on another)."""
    t, ks = LocalTransport(), KeySpace("ls")
    cfg = ModuleConfig("slow", "slow", SlowStart, SlowStart.Params(), "site", autostart=True)
    host = ModuleHost(node("n1", (cfg,)), t)
    slow = SlowStart("slow")
    host.add(cfg, slow)
    assert t.alive(ks.alive_lockstep("*")) == []  # set up, its tasks not started: not to be waited for yet
    host.start()
    try:
        assert slow.announced_at_start == []
        assert wait_for(lambda: t.alive(ks.alive_lockstep("*")) == [ks.alive_lockstep("n1")], timeout=5)
    finally:
        host.shutdown()
    assert t.alive(ks.alive_lockstep("*")) == []
