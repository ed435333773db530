"""The module host on the in-process transport: scheduling, control, layers, resources, faults."""

import threading
import time
from dataclasses import dataclass

import msgpack
import numpy as np
import pytest

from contactflow.embodiments.messages import JointCommand
from contactflow.nodes.clock import SimClock
from contactflow.nodes.config import ConfigError, parse_node_config
from contactflow.nodes.host import QUEUE_DEPTH, ModuleHost, SeqTracker
from contactflow.nodes.messages import (
    Command,
    ControlReply,
    ControlRequest,
    EventMsg,
    StatusMsg,
    Vector,
)
from contactflow.nodes.module import Layer, LayerError, Module, Port
from contactflow.nodes.status import Event, Status
from contactflow.nodes.transport import LocalTransport
from contactflow.nodes.wire import Header, NDArray, decode, decode_any, encode, stamp
from contactflow.nodes.yamldoc import YamlDoc


class ArmCommander(Module):
    """Primitive that sends joint commands to the shared resource ``arm``."""

    layer = Layer.PRIMITIVE
    outputs = (Port("cmd", JointCommand, resource="arm"),)
    resources = ("arm",)

    def step(self) -> Status:
        self.io.publish("cmd", JointCommand(names=["j1"], position=NDArray.of(np.array([0.3]))))
        return Status.RUNNING


class VectorArm(Module):
    """Commands ``arm`` with a message that has no weight to mix by."""

    layer = Layer.PRIMITIVE
    outputs = (Port("cmd", Vector, resource="arm"),)
    resources = ("arm",)


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


class SlowAliveTransport(LocalTransport):
    """A bus whose liveliness answers arrive a network round trip after they were true."""

    def alive(self, keyexpr, timeout=1.0):
        seen = super().alive(keyexpr, timeout)
        time.sleep(0.05)
        return seen


def make_host(text: str, t=None):
    cfg = parse_node_config(YamlDoc.parse(text, "test.yaml"))
    t = t if t is not None else LocalTransport()
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


def test_a_module_period_counts_from_its_first_step_not_from_the_clock_reading_when_it_started():
    # autostarted before the node heard any clock (it read 0), first stepped at 0.41 s: at 1 Hz the next step is
    # at 1.41 s, as for a node that heard the clock first (a seeded run repeats whatever the process layout)
    host, clock, seen = make_host("site: t\nnode: n\nclock: sim\nmodules:\n"
                                  "  - {name: src, type: signal_source, params: {rate_hz: 1, frequency: 1}}\n")
    run_for(host, clock, 2.0, t0=0.4)
    assert [round(m.hdr.t_sim, 3) for k, m in seen if k.endswith("/src/out/signal")] == [0.41, 1.41]


def test_a_module_knows_which_of_its_inputs_the_configuration_wired():
    host, _, _ = make_host(PIPE.replace("  - {name: sc, type: scale, inputs: {in: lp.out}, params: {gain: 3}}",
                                        "  - {name: sc, type: scale, params: {gain: 3}}"))
    assert host.modules[("site", "lp")].io.wired("in")
    assert not host.modules[("site", "sc")].io.wired("in") and not host.modules[("site", "lp")].io.wired("nope")


def test_primitive_waits_for_run_then_emits_event_and_success():
    host, clock, seen = make_host(PIPE)
    t = run_for(host, clock, 0.5)
    assert not [m for _, m in seen if isinstance(m, EventMsg)], "primitive ran before it was told to"
    reply = host.send_control("th", Command.RUN, {})
    assert reply.ok and reply.state == Status.RUNNING
    run_for(host, clock, 2.0, t0=t)
    events = [m.event for _, m in seen if isinstance(m, EventMsg)]
    assert events == [Event.CONTACT, Event.SUCCESS]  # the module's own event, then the host's for the status
    assert host.modules[("site", "th")].module.state == Status.SUCCESS


def test_an_outcome_the_module_raised_itself_is_not_repeated_by_the_host():
    host, clock, seen = make_host(PIPE.replace("threshold: 1.5}", "threshold: 1.5, event: success}"))
    assert host.send_control("th", Command.RUN, {}).ok
    t = run_for(host, clock, 2.0)
    outcomes = [m for _, m in seen if isinstance(m, EventMsg)]
    assert [m.event for m in outcomes] == [Event.SUCCESS] and "value" in outcomes[0].values
    # a second run raises its outcome again
    assert host.send_control("th", Command.RUN, {}).ok
    run_for(host, clock, 2.0, t0=t)
    assert [m.event for _, m in seen if isinstance(m, EventMsg)] == [Event.SUCCESS, Event.SUCCESS]


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


def test_a_control_reply_carries_the_module_path_its_own_seq_the_clock_and_the_request():
    host, clock, _ = make_host(PIPE)
    run_for(host, clock, 0.5)
    key = host.ks.control("site", "*", "sc")
    replies = []
    for seq in (1, 2):
        req = stamp(ControlRequest(cmd=Command.SET, params={"gain": 0.25}, issuer="tool"), "site/tool/ctl", seq, 9.0)
        (rkey, payload), = host.transport.query(key, encode(req))
        replies.append(decode(payload, ControlReply, rkey))
    assert all(r.ok for r in replies)
    assert [r.hdr.source for r in replies] == [f"site/{host.config.node}/sc/ctl"] * 2
    assert [r.hdr.seq for r in replies] == [1, 2]
    assert replies[0].hdr.t_sim == pytest.approx(0.5)  # the node's (simulated) clock, not the request's stamp
    assert [(i.source, i.seq) for r in replies for i in r.hdr.inputs] == [("site/tool/ctl", 1), ("site/tool/ctl", 2)]
    garbage = host.transport.query(key, b"\x01")
    bad = decode(garbage[0][1], ControlReply, key)
    assert not bad.ok and bad.hdr.seq == 3 and bad.hdr.inputs == []


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -float("inf")])
def test_a_non_finite_reading_is_refused_and_never_reaches_a_stateful_filter(bad):
    host, clock, seen = make_host(PIPE)
    t = run_for(host, clock, 0.5)
    forged = stamp(Vector(values=[bad]), "site/n/src/signal", 10_000, t)
    host.transport.publisher(host.ks.output("site", "n", "src", "signal"))(encode(forged))
    run_for(host, clock, 1.0, t0=t)
    assert host.modules[("site", "lp")].counters.rejected == 1
    out = [m for k, m in seen if k.endswith("/lp/out/out")]
    assert len(out) >= 15 and all(np.isfinite(m.values).all() for m in out)  # the filter was never poisoned


def test_stop_and_reset():
    host, clock, seen = make_host(PIPE)
    assert host.send_control("src", Command.STOP, {}).state == Status.STOPPED
    run_for(host, clock, 0.5)
    assert not [k for k, _ in seen if k.endswith("/src/out/signal")]
    assert host.send_control("src", Command.RUN, {}).state == Status.RUNNING


ARMS = f"""
site: t
node: n
clock: sim
modules:
  - {{name: a, type: "{__name__}:ArmCommander"}}
  - {{name: b, type: "{__name__}:ArmCommander"}}
  - {{name: m1, type: "{__name__}:ArmCommander", mix: {{arm: 0.5}}}}
  - {{name: m2, type: "{__name__}:ArmCommander", mix: {{arm: 0.25}}}}
"""


def test_second_commander_of_a_resource_is_refused_unless_both_declare_mixing():
    host, clock, _ = make_host(ARMS)
    assert host.send_control("a", Command.RUN, {}).ok
    refused = host.send_control("b", Command.RUN, {})
    assert not refused.ok and refused.state == Status.IDLE
    assert "already commanded by n/a" in refused.error and "mix: {arm: <weight>}" in refused.error
    one_sided = host.send_control("m1", Command.RUN, {})
    assert not one_sided.ok, "a mixing module joined a module that commands the arm alone"
    assert "n/a does not declare weighted mixing" in one_sided.error
    host.send_control("a", Command.STOP, {})
    assert host.send_control("m1", Command.RUN, {}).ok
    assert host.send_control("m2", Command.RUN, {}).ok
    late = host.send_control("a", Command.RUN, {})
    assert not late.ok and "a does not declare weighted mixing" in late.error
    host.send_control("m1", Command.STOP, {})
    host.send_control("m2", Command.STOP, {})
    assert host.send_control("b", Command.RUN, {}).ok


def test_mixing_weight_of_the_configuration_is_written_into_published_commands():
    host, clock, seen = make_host(ARMS)
    for name in ("m1", "m2"):
        assert host.send_control(name, Command.RUN, {}).ok
    run_for(host, clock, 0.5)
    weights = {k.split("/")[-3]: m.weight for k, m in seen if isinstance(m, JointCommand)}
    assert weights == {"m1": 0.5, "m2": 0.25}
    for name in ("m1", "m2"):
        host.send_control(name, Command.STOP, {})
    assert host.send_control("a", Command.RUN, {}).ok
    seen.clear()
    run_for(host, clock, 0.5, t0=0.5)
    assert {m.weight for _, m in seen if isinstance(m, JointCommand)} == {1.0}


@pytest.mark.parametrize(("module", "mix", "problem"), [
    ("ArmCommander", "{gripper: 0.5}", "commands no resource 'gripper'"),
    ("VectorArm", "{arm: 0.5}", "Vector, which has no weight field"),
    ("ArmCommander", "{arm: 1.5}", "not in (0, 1]"),
])
def test_mixing_a_resource_that_cannot_carry_a_weight_is_a_config_error(module, mix, problem):
    text = f"""
site: t
node: n
modules:
  - name: a
    type: "{__name__}:{module}"
    mix: {mix}
"""
    with pytest.raises(ConfigError) as err:
        parse_node_config(YamlDoc.parse(text, "arms.yaml"))
    assert str(err.value).startswith("arms.yaml:7: modules[0].mix.") and problem in str(err.value)


def _run_together(hosts_and_names):
    """RUN several modules from parallel threads, as concurrent control queries do."""
    barrier = threading.Barrier(len(hosts_and_names))
    replies = {}

    def go(host, name):
        barrier.wait()
        replies[name] = host.send_control(name, Command.RUN, {})

    threads = [threading.Thread(target=go, args=hn) for hn in hosts_and_names]
    for th in threads:
        th.start()
    for th in threads:
        th.join(10)
    return replies


def test_concurrent_claims_in_one_node_let_exactly_one_module_command():
    text = "site: t\nnode: n\nmodules:\n" + "".join(
        f"  - {{name: c{i}, type: \"{__name__}:ArmCommander\"}}\n" for i in range(4))
    host, _, _ = make_host(text, SlowAliveTransport())
    replies = _run_together([(host, f"c{i}") for i in range(4)])
    assert sorted(r.ok for r in replies.values()) == [False, False, False, True]
    holders = host.transport.alive(host.ks.claim("site", "arm"))
    assert len(holders) == 1 and holders[0].endswith("/excl")


def test_claims_of_two_nodes_on_one_network_never_both_succeed():
    bus = SlowAliveTransport()
    text = "site: t\nnode: {node}\nmodules:\n  - {{name: {name}, type: \"" + __name__ + ":ArmCommander\"}}\n"
    h1, _, _ = make_host(text.format(node="n1", name="x"), bus)
    h2, _, _ = make_host(text.format(node="n2", name="y"), bus)
    for _ in range(5):
        replies = _run_together([(h1, "x"), (h2, "y")])
        assert not all(r.ok for r in replies.values()), "two nodes command the same arm"
        for h, name in ((h1, "x"), (h2, "y")):
            h.send_control(name, Command.STOP, {})
    assert h1.send_control("x", Command.RUN, {}).ok
    refused = h2.send_control("y", Command.RUN, {})
    assert not refused.ok and "already commanded by n1/x" in refused.error
    assert bus.alive(h1.ks.claim("site", "arm")) == [h1.ks.claim("site", "arm", "n1", "x", "excl")]


def test_sequence_gaps_are_counted_per_input_and_reported_in_status():
    host, clock, seen = make_host(PIPE)
    put = host.transport.publisher("cf/t/m/site/n/src/out/signal")
    host.send_control("src", Command.STOP, {})
    for source, seq in (("fake/a", 1), ("fake/a", 2), ("fake/a", 5), ("fake/b", 7), ("fake/a", 6),
                        ("fake/b", 8), ("fake/b", 8), ("fake/a", 9), ("fake/a", 1), ("fake/a", 2)):
        put(encode(stamp(Vector(values=[0.0]), source, seq, 0.0)))
    lp = host.modules[("site", "lp")]
    assert lp.counters.gaps == {"in": 4}  # 3, 4 and 7, 8 of fake/a; the duplicate and the restart are no loss
    assert host.modules[("site", "sc")].counters.gaps == {"in": 0}
    run_for(host, clock, 1.1)
    status = [m for _, m in seen if isinstance(m, StatusMsg) and m.module == "site/n/lp"][-1]
    assert status.gaps == {"in": 4}
    statuses = [m.hdr for _, m in seen if isinstance(m, StatusMsg) and m.module == "site/n/lp"]
    assert [h.seq for h in statuses] == list(range(1, len(statuses) + 1))
    assert {h.source for h in statuses} == {"site/n/lp/status"}


def test_a_source_that_floods_an_input_pushes_out_its_own_messages_not_a_quieter_sources():
    host, clock, seen = make_host(PIPE)
    put = host.transport.publisher("cf/t/m/site/n/src/out/signal")
    host.send_control("src", Command.STOP, {})
    for k in range(1, 601):  # between two steps: 600 messages of one source, 5 of another among the first
        put(encode(stamp(Vector(values=[float(k)]), "fake/flood", k, 0.0)))
        if k % 10 == 0 and k <= 50:
            put(encode(stamp(Vector(values=[-float(k)]), "fake/quiet", k // 10, 0.0)))
    lp = host.modules[("site", "lp")]
    queued = lp.io.take("in")
    assert len(queued) == QUEUE_DEPTH and lp.counters.dropped == {"in": 605 - QUEUE_DEPTH}
    assert [m.hdr.seq for m in queued if m.hdr.source == "fake/quiet"] == [1, 2, 3, 4, 5]
    # the flooder kept its newest, in order
    assert [m.hdr.seq for m in queued if m.hdr.source == "fake/flood"] == list(range(600 - QUEUE_DEPTH + 6, 601))
    run_for(host, clock, 1.1)
    status = [m for _, m in seen if isinstance(m, StatusMsg) and m.module == "site/n/lp"][-1]
    assert status.dropped == {"in": 605 - QUEUE_DEPTH}


class Burner(Module):
    """Spins for ``busy_s`` of CPU per step, then sleeps ``idle_s`` (a wait, which costs no CPU)."""

    layer = Layer.SERVICE
    outputs = (Port("out", Vector),)

    @dataclass(frozen=True)
    class Params:
        rate_hz: float = 10.0
        busy_s: float = 0.0
        idle_s: float = 0.0

    def step(self) -> Status:
        end = time.thread_time() + self.params.busy_s
        while time.thread_time() < end:  # a spin: CPU time, not a wait
            pass
        time.sleep(self.params.idle_s)
        return Status.RUNNING


def test_a_module_s_status_says_the_cpu_time_its_steps_took_and_not_its_waits():
    host, clock, seen = make_host(f"""
site: t
node: n
clock: sim
modules:
  - {{name: busy, type: "{__name__}:Burner", params: {{busy_s: 0.004}}}}
  - {{name: waits, type: "{__name__}:Burner", params: {{idle_s: 0.004}}}}
""")
    run_for(host, clock, 1.05)
    last = {m.module: m for _, m in seen if isinstance(m, StatusMsg)}
    busy, waits = last["site/n/busy"], last["site/n/waits"]
    assert busy.steps >= 10 and waits.steps >= 10
    assert busy.steps * 0.004 <= busy.cpu_s < busy.steps * 0.004 + 0.02, busy  # its spin, and little besides
    assert waits.cpu_s < 0.005, waits  # 40 ms and more asleep: no CPU


def test_sequence_tracker_bounds_its_memory_and_ignores_unnumbered_messages():
    tr = SeqTracker(max_sources=2)
    assert tr.observe(Header(source="a", seq=0)) == 0 and tr.observe(Header(source="a", seq=0)) == 0
    assert [tr.observe(Header(source=s, seq=q)) for s, q in (("a", 1), ("b", 1), ("c", 1), ("a", 5))] == [0, 0, 0, 0]
    assert tr.observe(Header(source="c", seq=3)) == 1
    assert len(tr.last) == 2


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


def test_a_flood_of_malformed_control_requests_is_answered_counted_and_logged_ten_times(caplog):
    from contactflow.nodes.messages import ControlReply
    from contactflow.nodes.wire import decode

    host, _, _ = make_host(PIPE)
    key = host.ks.control("site", "n", "sc")
    with caplog.at_level("WARNING", logger="contactflow"):
        replies = [host.transport.query(key, b"\xc1 not msgpack") for _ in range(50)]
    assert all(not decode(p, ControlReply, k).ok for ((k, p),) in replies)  # each one refused, none unanswered
    assert host.modules[("site", "sc")].counters.rejected == 50
    assert len([r for r in caplog.records if "rejected control request" in r.getMessage()]) == 10
    assert host.send_control("sc", Command.SET, {"gain": 2.0}).ok  # and the module still answers


def test_forged_sequence_numbers_at_the_edge_of_their_range_are_no_loss_and_the_loop_lives():
    from contactflow.nodes.host import MAX_SEQ_JUMP, SeqTracker
    from contactflow.nodes.messages import Vector
    from contactflow.nodes.wire import Header, encode, stamp

    tracker = SeqTracker()
    assert tracker.observe(Header(source="s", seq=1)) == 0
    assert tracker.observe(Header(source="s", seq=4)) == 2  # a real gap
    assert tracker.observe(Header(source="s", seq=2**64 - 1)) == 0  # a new numbering, not 2^64 lost messages
    assert tracker.observe(Header(source="s", seq=1)) == 0  # a restart
    assert tracker.observe(Header(source="s", seq=2 + MAX_SEQ_JUMP)) == 0
    host, clock, seen = make_host(PIPE)
    key = host.modules[("site", "lp")].in_keys["in"].replace("*", "n")
    send = host.transport.publisher(key)
    for seq in (1, 2**64 - 1) * 3:  # three forged wraps summed past what a status message can carry
        send(encode(stamp(Vector(values=[0.1]), "forger/out", seq, 0.0)))
    run_for(host, clock, 2.0)  # the status messages go out: the tick does not raise
    assert host.modules[("site", "lp")].counters.gaps["in"] == 0


def test_a_node_whose_loop_dies_takes_its_liveliness_down():
    host, clock, _ = make_host(PIPE)
    host.start()
    node_key = host.ks.alive_node(host.config.host, host.config.node)
    assert host.transport.alive(node_key)

    def broken() -> float:
        raise RuntimeError("the loop broke")

    host.tick = broken
    clock.advance(1.0)
    assert host.dead.wait(5.0)
    assert not host.transport.alive(node_key) and not host.transport.alive(host.ks.alive_module())
    host.shutdown()


class _Hook:
    """A tick hook that records what the modules of the tick had done when it ran."""

    rate_hz = 200.0

    def __init__(self, host):
        self.host, self.seen, self.working = host, [], False

    def after_tick(self):
        src = self.host.modules[("site", "src")]
        self.seen.append(src.counters.steps)

    def active(self):
        return self.working


def test_a_tick_hook_runs_after_the_ticks_modules_once_per_key_and_sets_a_wall_clock_nodes_pace():
    host, clock, _ = make_host(PIPE)
    hook = _Hook(host)
    host.attach("robot/r", hook)
    host.attach("robot/r", _Hook(host))  # a second facade of the same robot: still one hook
    run_for(host, clock, 0.5, dt=0.05)
    # every tick, after the source stepped in it: the hook sees the count of steps the tick made
    assert len(hook.seen) == 10 and hook.seen == list(range(1, 11))
    hook.working = True
    # a wall-clock node comes back at the hook's rate while it works, whatever its modules' rates; a
    # lockstep node still acks idle (a world with idle: pause stands still, the hook's time with it)
    assert not host._busy()
    assert host.tick() == pytest.approx(clock.now() + 1.0 / hook.rate_hz)


class _Broken(_Hook):
    def after_tick(self):
        raise RuntimeError("controller bug")


def test_a_tick_hook_that_raises_is_logged_and_the_node_ticks_on(caplog):
    host, clock, seen = make_host(PIPE)
    host.attach("robot/x", _Broken(host))
    run_for(host, clock, 0.5, dt=0.05)
    assert len([m for k, m in seen if k.endswith("/src/out/signal")]) >= 9
    assert "tick hook robot/x raised" in caplog.text
