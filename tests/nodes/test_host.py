"""The module host on the in-process transport: scheduling, control, layers, resources, faults."""

from dataclasses import dataclass

import msgpack
import pytest

from contactflow.nodes.clock import SimClock
from contactflow.nodes.config import parse_node_config
from contactflow.nodes.host import ModuleHost
from contactflow.nodes.messages import Command, ControlReply, EventMsg, StatusMsg, Vector
from contactflow.nodes.module import Layer, LayerError, Module, Port
from contactflow.nodes.status import Event, Status
from contactflow.nodes.transport import LocalTransport
from contactflow.nodes.wire import decode, decode_any, encode
from contactflow.nodes.yamldoc import YamlDoc


class ArmCommander(Module):
    """Primitive that commands the shared resource ``arm``."""

    layer = Layer.PRIMITIVE
    outputs = (Port("cmd", Vector),)
    resources = ("arm",)

    def step(self) -> Status:
        self.io.publish("cmd", Vector(values=[1.0]))
        return Status.RUNNING


class Exploding(Module):
    layer = Layer.SERVICE
    outputs = (Port("out", Vector),)

    @dataclass(frozen=True)
    class Params:
        rate_hz: float = 10.0
        explode_at: int = 3

    def start(self) -> None:
        self.n = 0

    def step(self) -> Status:
        self.n += 1
        if self.n == self.params.explode_at:
            raise RuntimeError("boom")
        self.io.publish("out", Vector(values=[self.n]))
        return Status.RUNNING


class RogueService(Module):
    layer = Layer.SERVICE
    outputs = (Port("out", Vector),)

    def step(self) -> Status:
        self.io.command("other", Command.STOP)
        return Status.RUNNING


def make_host(text: str):
    cfg = parse_node_config(YamlDoc.parse(text, "test.yaml"))
    t = LocalTransport()
    seen: list[tuple[str, object]] = []
    t.subscribe("cf/**", lambda k, p: seen.append((k, decode_any(p))))
    clock = SimClock(t, cfg.keyspace)
    host = ModuleHost(cfg, t, clock)
    for m in cfg.modules:
        host.add(m)
    host.start_autostart()
    return host, clock, seen


def run_for(host, clock, seconds, dt=0.01, t0=0.0):
    steps = round(seconds / dt)
    for i in range(1, steps + 1):
        clock.advance(t0 + i * dt)
        host.tick()
    return t0 + steps * dt


PIPE = """
site: t
node: n
clock: sim
modules:
  - {name: src, type: signal_source, params: {rate_hz: 20, frequency: 1}}
  - {name: lp, type: lowpass, inputs: {in: src.signal}, params: {rate_hz: 20}}
  - {name: sc, type: scale, inputs: {in: lp.out}, params: {gain: 3}}
  - {name: th, type: threshold_watch, inputs: {in: sc.out}, params: {threshold: 1.5}}
"""


def test_services_run_at_their_rate_and_outputs_are_traced():
    host, clock, seen = make_host(PIPE)
    run_for(host, clock, 1.0)
    src = [m for k, m in seen if k.endswith("/src/out/signal")]
    assert 19 <= len(src) <= 21
    scaled = [m for k, m in seen if k.endswith("/sc/out/out")]
    assert scaled, "pipeline produced nothing"
    last = scaled[-1]
    assert last.hdr.inputs[0].source == "site/n/lp/out"
    lp_by_seq = {m.hdr.seq: m for k, m in seen if k.endswith("/lp/out/out")}
    assert lp_by_seq[last.hdr.inputs[0].seq].hdr.inputs[0].source == "site/n/src/signal"
    assert last.values[0] == pytest.approx(3 * lp_by_seq[last.hdr.inputs[0].seq].values[0])


def test_primitive_waits_for_run_then_emits_event_and_success():
    host, clock, seen = make_host(PIPE)
    t = run_for(host, clock, 0.5)
    assert not [m for _, m in seen if isinstance(m, EventMsg)], "primitive ran before it was told to"
    reply = host.send_control("th", Command.RUN, {})
    assert reply.ok and reply.state == Status.RUNNING
    run_for(host, clock, 2.0, t0=t)
    events = [m.event for _, m in seen if isinstance(m, EventMsg)]
    assert events[:2] == [Event.CONTACT, Event.SUCCESS]
    assert host.modules[("site", "th")].module.state == Status.SUCCESS


def test_online_parameter_change_and_errors():
    host, clock, _ = make_host(PIPE)
    assert host.send_control("sc", Command.SET, {"gain": "0.5"}).ok
    assert host.modules[("site", "sc")].module.params.gain == 0.5
    bad = host.send_control("sc", Command.SET, {"gain": "lots"})
    assert not bad.ok and "gain" in bad.error
    unknown = host.send_control("sc", Command.SET, {"colour": 1})
    assert not unknown.ok and "unknown parameter" in unknown.error
    missing = host.send_control("nobody", Command.RUN, {})
    assert not missing.ok and "no module answers" in missing.error
    desc = host.send_control("sc", Command.DESCRIBE, {})
    assert "layer: service" in desc.description and "gain" in desc.description


def test_stop_and_reset():
    host, clock, seen = make_host(PIPE)
    assert host.send_control("src", Command.STOP, {}).state == Status.STOPPED
    run_for(host, clock, 0.5)
    assert not [k for k, _ in seen if k.endswith("/src/out/signal")]
    assert host.send_control("src", Command.RUN, {}).state == Status.RUNNING


def test_second_commander_of_a_resource_is_refused_unless_mixing_is_declared():
    text = f"""
site: t
node: n
modules:
  - {{name: a, type: "{__name__}:ArmCommander"}}
  - {{name: b, type: "{__name__}:ArmCommander"}}
  - {{name: c, type: "{__name__}:ArmCommander", mix: {{arm: 0.5}}}}
"""
    host, clock, _ = make_host(text)
    assert host.send_control("a", Command.RUN, {}).ok
    refused = host.send_control("b", Command.RUN, {})
    assert not refused.ok
    assert "already commanded by n/a" in refused.error and "mix" in refused.error
    assert host.send_control("c", Command.RUN, {}).ok
    host.send_control("a", Command.STOP, {})
    host.send_control("c", Command.STOP, {})
    assert host.send_control("b", Command.RUN, {}).ok


def test_a_raising_module_is_stopped_and_reported_while_others_go_on():
    text = f"""
site: t
node: n
clock: sim
modules:
  - {{name: bad, type: "{__name__}:Exploding"}}
  - {{name: src, type: signal_source, params: {{rate_hz: 10}}}}
"""
    host, clock, seen = make_host(text)
    run_for(host, clock, 1.0)
    assert host.modules[("site", "bad")].module.state == Status.ERROR
    errors = [m for _, m in seen if isinstance(m, EventMsg) and m.event == Event.ERROR]
    assert errors and "boom" in errors[0].detail
    statuses = [m for _, m in seen if isinstance(m, StatusMsg) and m.module == "site/n/bad"]
    assert statuses[-1].state == Status.ERROR
    assert len([k for k, _ in seen if k.endswith("/src/out/signal")]) >= 9


def test_a_service_may_not_send_control_messages():
    text = f"""
site: t
node: n
clock: sim
modules:
  - {{name: rogue, type: "{__name__}:RogueService"}}
"""
    host, clock, seen = make_host(text)
    run_for(host, clock, 0.3)
    hm = host.modules[("site", "rogue")]
    assert hm.module.state == Status.ERROR and "may not send control" in hm.detail
    with pytest.raises(LayerError):
        hm.io.command("x", Command.RUN)


def test_malformed_inputs_and_control_are_counted_and_dropped():
    host, clock, _ = make_host(PIPE)
    t = host.transport
    put = t.publisher("cf/t/m/site/n/src/out/signal")
    for payload in (b"\x93\x01", msgpack.packb({"type": "vector", "values": "x"}),
                    msgpack.packb({"type": "vector", "values": [1.0], "hdr": {"schema": 42}}), b"\0" * (10 << 20)):
        put(payload)
    assert host.modules[("site", "lp")].counters.rejected == 4
    replies = t.query("cf/t/m/site/n/sc/ctl", b"garbage")
    reply = decode(replies[0][1], ControlReply)
    assert not reply.ok and "invalid ControlRequest" in reply.error
    run_for(host, clock, 0.5)
    lp = host.modules[("site", "lp")]
    assert lp.module.state == Status.RUNNING
    before = lp.counters.received
    put(encode(Vector(values=[0.1])))
    assert lp.counters.received == before + 1 and lp.counters.rejected == 4
