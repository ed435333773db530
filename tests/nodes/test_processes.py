"""Real node processes over zenoh on loopback: pipelines, events, control, liveliness, clocks, hostile input."""

import signal
import socket
import sys
import threading
import time

import msgpack
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from rich.console import Console
from typer.testing import CliRunner

from contactflow.deploy import cli
from contactflow.deploy.pipeline_demo import pipeline_configs
from contactflow.embodiments.messages import JointCommand
from contactflow.nodes.config import load_node_config
from contactflow.nodes.host import ModuleHost
from contactflow.nodes.keys import KeySpace
from contactflow.nodes.messages import (
    Clock,
    Command,
    ControlReply,
    ControlRequest,
    EventMsg,
    StatusMsg,
    Vector,
)
from contactflow.nodes.procs import (
    _ephemeral_low,
    free_port,
    free_port_block,
    spawn_node,
    stop_process,
    wait_for,
    write_config,
)
from contactflow.nodes.status import Event, Status
from contactflow.nodes.transport import ZenohSettings, ZenohTransport
from contactflow.nodes.wire import WireError, decode, encode, stamp

SITE = "ptest"
KS = KeySpace(SITE)


def contactflow_ls(monkeypatch, site, endpoint, wait):
    """``contactflow ls`` in this process (no interpreter start-up), printed without wrapping."""
    monkeypatch.setattr(cli, "console", Console(width=400, soft_wrap=True))
    return CliRunner().invoke(cli.app, ["ls", "--site", site, "--wait", str(wait), "--connect", endpoint],
                              catch_exceptions=False)


def single_node(tmp, site, modules, clock="wall"):
    """One node process listening on a free port, and a tool session connected to it."""
    port = free_port()
    cfg = {"site": site, "node": "solo", "host": "box", "clock": clock,
           "zenoh": {"mode": "peer", "listen": [f"tcp/127.0.0.1:{port}"], "multicast_scouting": False},
           "modules": modules}
    proc = spawn_node(write_config(tmp / f"{site}.yaml", cfg), tmp / f"{site}.log")
    tool = ZenohTransport(ZenohSettings(connect=(f"tcp/127.0.0.1:{port}",))).open()
    ks = KeySpace(site)
    if not wait_for(lambda: len(tool.alive(ks.alive_module(), timeout=0.5)) == len(modules), timeout=30):
        tool.close()
        stop_process(proc)
        raise AssertionError((tmp / f"{site}.log").read_text()[-3000:])
    return proc, tool


class Deployment:
    def __init__(self, tmp):
        self.port_a, self.port_b = free_port(), free_port()
        cfg_a, cfg_b = pipeline_configs(SITE, self.port_a, self.port_b)
        cfg_a["clock"] = cfg_b["clock"] = "wall"
        self.procs = {
            "sense": spawn_node(write_config(tmp / "a.yaml", cfg_a), tmp / "a.log"),
            "watch": spawn_node(write_config(tmp / "b.yaml", cfg_b), tmp / "b.log"),
        }
        self.tool = ZenohTransport(ZenohSettings(connect=(f"tcp/127.0.0.1:{self.port_a}",
                                                          f"tcp/127.0.0.1:{self.port_b}"))).open()
        self.lock = threading.Lock()
        self.events: list[EventMsg] = []
        self.outputs: list[Vector] = []
        self.status: dict[str, StatusMsg] = {}
        self.subs = [
            self.tool.subscribe(KS.events(), self._on(EventMsg, self.events)),
            self.tool.subscribe(KS.output("demo", "*", "gain", "out"), self._on(Vector, self.outputs)),
            self.tool.subscribe(KS.status(), self._on_status),
        ]
        up = wait_for(lambda: len(self.tool.alive(KS.alive_module("demo"), timeout=0.5)) >= 4, timeout=40)
        if not up:
            self.close()
            raise AssertionError((tmp / "a.log").read_text()[-2000:] + (tmp / "b.log").read_text()[-2000:])

    def _on(self, cls, sink):
        def cb(key, payload):
            with self.lock:
                sink.append(decode(payload, cls, key))
        return cb

    def _on_status(self, key, payload):
        msg = decode(payload, StatusMsg, key)
        with self.lock:
            self.status[msg.module] = msg

    def control(self, module, cmd, params=None):
        replies = self.tool.query(KS.control("demo", "*", module), encode(ControlRequest(cmd=cmd, params=params or {})))
        assert replies, f"no reply from {module}"
        return decode(replies[0][1], ControlReply)

    def close(self):
        for s in self.subs:
            s.close()
        self.tool.close()
        for p in self.procs.values():
            stop_process(p)


@pytest.fixture(scope="module")
def deployment(tmp_path_factory):
    d = Deployment(tmp_path_factory.mktemp("nodes"))
    yield d
    d.close()


def test_pipeline_of_three_services_across_two_processes_is_traced(deployment):
    assert wait_for(lambda: len(deployment.outputs) >= 5, timeout=10)
    with deployment.lock:
        out = deployment.outputs[-1]
    assert out.hdr.source == "demo/watch/gain/out"
    assert [i.source for i in out.hdr.inputs] == ["demo/sense/filter/out"]
    assert out.hdr.t_wall > 0 and out.hdr.seq > 0


def test_control_and_events_cross_processes(deployment):
    reply = deployment.control("watch", Command.RUN, {"threshold": 1.2})
    assert reply.ok and reply.state == Status.RUNNING and reply.params["threshold"] == 1.2
    assert wait_for(lambda: any(e.event == Event.SUCCESS for e in deployment.events), timeout=15)
    with deployment.lock:
        labels = [e.event for e in deployment.events if e.module == "demo/watch/watch"]
    assert labels.index(Event.CONTACT) < labels.index(Event.SUCCESS)
    bad = deployment.control("gain", Command.SET, {"gain": "much"})
    assert not bad.ok and "gain" in bad.error


payloads = st.one_of(
    st.binary(max_size=256),
    st.dictionaries(st.sampled_from(["type", "values", "hdr", "cmd", "params", "names"]),
                    st.one_of(st.integers(-1000, 1000), st.text(max_size=5), st.lists(st.integers(0, 3), max_size=3),
                              st.just({"schema": 99})), max_size=5).map(msgpack.packb),
)


def _is_control_request(data):
    try:
        decode(data, ControlRequest)
    except WireError:
        return False
    return True


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=payloads)
def test_malformed_input_never_kills_a_node(deployment, data):
    assume(not _is_control_request(data))  # a valid request is no garbage (and might stop the module)
    put = deployment.tool.publisher(KS.output("demo", "sense", "filter", "out"))
    put(data)
    replies = deployment.tool.query(KS.control("demo", "*", "gain"), data, timeout=2.0)
    assert len(replies) == 1, "the node did not answer garbage on its control key"
    assert not decode(replies[0][1], ControlReply, replies[0][0]).ok
    after = deployment.control("gain", Command.DESCRIBE)
    assert after.ok and after.state == Status.RUNNING


def test_rejects_are_counted_and_nodes_survive(deployment):
    put = deployment.tool.publisher(KS.output("demo", "sense", "filter", "out"))
    put(b"\xc1\xc1")
    put(msgpack.packb({"type": "vector", "values": [1.0], "hdr": {"schema": 77}}))
    put(b"\x91" * (10 << 20))
    time.sleep(1.5)
    assert all(p.poll() is None for p in deployment.procs.values())
    with deployment.lock:
        gain = deployment.status["demo/watch/gain"]
    assert gain.rejected >= 3 and gain.state == Status.RUNNING
    n = len(deployment.outputs)
    assert wait_for(lambda: len(deployment.outputs) > n + 3, timeout=5), "pipeline stopped after bad input"


def test_sequence_gaps_of_an_input_reach_status_and_ls(deployment, monkeypatch):
    put = deployment.tool.publisher(KS.output("demo", "sense", "filter", "out"))
    for seq in (1, 2, 6, 7):  # a sender that lost 3, 4 and 5
        put(encode(stamp(Vector(values=[0.0]), "fake/gapper", seq, 0.0)))

    def gaps():
        with deployment.lock:
            status = deployment.status.get("demo/watch/gain")
        return status.gaps.get("in", 0) if status else 0

    assert wait_for(lambda: gaps() >= 3, timeout=5), "the gap never reached the status stream"
    ls = contactflow_ls(monkeypatch, SITE, f"tcp/127.0.0.1:{deployment.port_a}", 1.3)
    row = next(line for line in ls.stdout.splitlines() if "demo/gain" in line)
    assert f"in:{gaps()}" in row


def test_killed_node_is_noticed_within_two_seconds(deployment, monkeypatch):
    gone = []

    def on_alive(key, alive):
        if not alive and "/watch" in key:
            gone.append(time.monotonic())

    watch = deployment.tool.watch_alive(KS.alive_node(), on_alive)
    proc = deployment.procs["watch"]
    t0 = time.monotonic()
    proc.kill()
    ls = contactflow_ls(monkeypatch, SITE, f"tcp/127.0.0.1:{deployment.port_a}", 0.0)
    ls_done = time.monotonic() - t0
    assert ls.exit_code == 0, ls.stdout
    assert "sense" in ls.stdout and "/watch" not in ls.stdout and "1 nodes" in ls.stdout, ls.stdout
    assert ls_done < 2.0, f"contactflow ls took until {ls_done:.2f} s after the kill to report it"
    assert wait_for(lambda: gone, timeout=2.0 - (time.monotonic() - t0)), "liveliness subscriber missed the death"
    assert gone[0] - t0 < 2.0
    watch.close()


def test_sigterm_shuts_a_node_down_cleanly(tmp_path):
    site = "pterm"
    proc, tool = single_node(tmp_path, site, [{"name": "src", "type": "signal_source"}])
    ks = KeySpace(site)
    withdrawn = []
    watch = tool.watch_alive(f"cf/{site}/alive/**", lambda key, alive: None if alive else withdrawn.append(key))
    try:
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(10) == 0
        assert wait_for(lambda: not tool.alive(f"cf/{site}/alive/**", timeout=0.5), timeout=2)
        assert set(withdrawn) >= {ks.alive_node("box", "solo"), ks.alive_module("site", "solo", "src")}
    finally:
        watch.close()
        tool.close()
        stop_process(proc)
    assert "signal 15, shutting down" in (tmp_path / f"{site}.log").read_text()


def test_a_node_s_log_names_a_peer_whose_transport_closed(tmp_path):
    """A liveliness token that drops or a lost message follows a transport that closed: the node's log says which."""
    site = "plink"
    proc, tool = single_node(tmp_path, site, [{"name": "src", "type": "signal_source"}])
    try:
        peer = str(tool.session.info.zid())
        tool.close()  # the peer goes: the node's transport with it closes
        log = tmp_path / f"{site}.log"
        assert wait_for(lambda: f"Closing transport with peer: {peer}" in log.read_text(), timeout=5), log.read_text()[-2000:]
        assert proc.poll() is None
        assert "\x1b[" not in log.read_text()  # a log file gets no colour codes
    finally:
        stop_process(proc)


def test_a_node_whose_log_pipe_broke_still_stops_on_sigterm(tmp_path):
    """Whatever ends a node's main thread stops its loop: a loop left running kept the process (a world: ticking) alive."""
    import subprocess

    cfg = {"site": "ppipe", "node": "solo", "clock": "wall",
           "zenoh": {"mode": "peer", "listen": [f"tcp/127.0.0.1:{free_port()}"], "multicast_scouting": False},
           "modules": [{"name": "src", "type": "signal_source"}]}
    proc = subprocess.Popen([sys.executable, "-m", "contactflow.deploy.cli", "node", str(write_config(tmp_path / "n.yaml", cfg))],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    try:
        for line in proc.stdout:
            if b" up (site" in line:
                break
        proc.stdout.close()  # as a log piped into a pager the user quit: the node's next line cannot be written
        proc.send_signal(signal.SIGTERM)
        proc.wait(10)
    finally:
        stop_process(proc)


def test_a_sim_clock_node_steps_its_modules_on_the_clock_of_the_key_space(tmp_path):
    site = "psim"
    proc, tool = single_node(tmp_path, site, [{"name": "src", "type": "signal_source", "params": {"rate_hz": 10}}],
                             clock="sim")
    ks = KeySpace(site)
    stamps = []
    sub = tool.subscribe(ks.output("site", "solo", "src", "signal"),
                         lambda k, p: stamps.append(decode(p, Vector, k).hdr.t_sim))
    try:
        time.sleep(0.5)
        assert set(stamps) <= {0.0}, "modules ran on wall time while the simulation clock stood still"
        before = len(stamps)
        put = tool.publisher(ks.clock())
        ticks = [round(0.05 * i, 2) for i in range(1, 21)]  # 1 s of simulated time in about 0.3 s
        for i, t in enumerate(ticks, 1):
            put(encode(stamp(Clock(t=t, real_time_factor=3.0), "test/world", i, t)))
            time.sleep(0.015)
        assert wait_for(lambda: stamps and stamps[-1] == 1.0, timeout=5), stamps
        stepped = stamps[before:]
        assert 8 <= len(stepped) <= 11 and set(stepped) <= set(ticks), stepped
        assert stepped == sorted(stepped)
        settled = len(stamps)
        time.sleep(0.5)
        assert len(stamps) == settled, "the node stepped without the clock advancing"
    finally:
        sub.close()
        tool.close()
        assert stop_process(proc) == 0


PARALLEL_WATCH = """
nodes:
  both:
    parallel:
      - {name: low, primitive: threshold_watch, params: {threshold: 0.3}}
      - {name: high, primitive: threshold_watch, params: {threshold: 0.9}}
    until: all
  done: {terminal: success}
  failed: {terminal: failure}
edges:
  - {from: both, to: done, on: success}
  - {from: both, to: failed, on: [[failure, timeout]]}
"""


def test_a_task_module_runs_parallel_branches_on_the_modules_of_its_node(tmp_path):
    # the task layer in a real node: each branch runs on its own module of the type, commanded by control
    # queries, and the task ends on the events the modules publish
    site = "ptask"
    ks = KeySpace(site)
    (tmp_path / "watch.yaml").write_text(PARALLEL_WATCH)
    watch = {"type": "threshold_watch", "inputs": {"in": "src.signal"}, "params": {"timeout": 20.0}}
    proc, tool = single_node(tmp_path, site, [
        {"name": "src", "type": "signal_source", "params": {"rate_hz": 50, "frequency": 0.5}},
        {"name": "threshold_watch", **watch},
        {"name": "threshold_watch_2", **watch},
        {"name": "task", "type": "task", "inputs": {"events": ks.events()},
         "params": {"task_file": str(tmp_path / "watch.yaml")}},
    ])
    events: list[EventMsg] = []
    sub = tool.subscribe(ks.events(), lambda k, p: events.append(decode(p, EventMsg, k)))
    try:
        reply = decode(tool.query(ks.control("*", "solo", "task"), encode(ControlRequest(cmd=Command.RUN)))[0][1],
                       ControlReply)
        assert reply.ok and reply.state == Status.RUNNING
        assert wait_for(lambda: any(e.module.endswith("/task") for e in events), timeout=20)
        by = {m: [e for e in events if e.module.endswith("/" + m)] for m in ("threshold_watch", "threshold_watch_2", "task")}
        assert [e.event for e in by["task"]] == [Event.SUCCESS]
        low, high = (next(e for e in by[m] if e.event is Event.CONTACT) for m in ("threshold_watch", "threshold_watch_2"))
        assert abs(low.values["value"]) >= 0.3 and abs(high.values["value"]) >= 0.9
        for module, threshold in (("threshold_watch", 0.3), ("threshold_watch_2", 0.9)):  # each ran its branch's params
            desc = tool.query(ks.control("*", "solo", module), encode(ControlRequest(cmd=Command.DESCRIBE)))
            assert decode(desc[0][1], ControlReply).params["threshold"] == threshold
        assert low.hdr.t_wall <= high.hdr.t_wall <= by["task"][0].hdr.t_wall  # until: all
    finally:
        sub.close()
        tool.close()
        assert stop_process(proc) == 0


ARM_MODULE = '''"""A primitive sending joint commands to the shared resource ``arm``."""

import numpy as np

from contactflow.embodiments.messages import JointCommand
from contactflow.nodes.module import Layer, Module, Port
from contactflow.nodes.status import Status
from contactflow.nodes.wire import NDArray


class ArmCmd(Module):
    """Commands joint j1 of ``arm``."""

    layer = Layer.PRIMITIVE
    outputs = (Port("cmd", JointCommand, resource="arm"),)
    resources = ("arm",)

    def step(self):
        self.io.publish("cmd", JointCommand(names=["j1"], position=NDArray.of(np.array([0.1]))))
        return Status.RUNNING
'''


def test_a_resource_is_arbitrated_between_two_nodes_and_mixing_weights_reach_the_wire(tmp_path, monkeypatch):
    site = "parm"
    ks = KeySpace(site)
    (tmp_path / "arm_cmd.py").write_text(ARM_MODULE)
    proc, tool = single_node(tmp_path, site, [{"name": "a", "type": "arm_cmd:ArmCmd", "mix": {"arm": 0.5}}])
    host = None
    weights = {}
    sub = tool.subscribe(ks.output("site", "*", "*", "cmd"),
                         lambda k, p: weights.setdefault(k.split("/")[-3], decode(p, JointCommand, k).weight))
    try:
        reply = decode(tool.query(ks.control("site", "*", "a"), encode(ControlRequest(cmd=Command.RUN)))[0][1],
                       ControlReply)
        assert reply.ok, reply.error
        conf = write_config(tmp_path / "other.yaml", {"site": site, "node": "other", "modules": [
            {"name": "c", "type": "arm_cmd:ArmCmd"},
            {"name": "d", "type": "arm_cmd:ArmCmd", "mix": {"arm": 0.25}}]})
        host = ModuleHost(load_node_config(conf), tool)
        for m in host.config.modules:
            host.add(m)
        host.start()
        refused = host.send_control("c", Command.RUN, {})
        assert not refused.ok and "already commanded by solo/a and c does not declare weighted mixing" in refused.error
        assert host.send_control("d", Command.RUN, {}).ok
        assert wait_for(lambda: len(weights) == 2, timeout=5), weights
        assert weights == {"a": 0.5, "d": 0.25}
    finally:
        sub.close()
        if host is not None:
            host.shutdown()
        tool.close()
        monkeypatch.delitem(sys.modules, "arm_cmd", raising=False)
        assert stop_process(proc) == 0


def test_a_port_block_is_free_and_below_the_ephemeral_range():
    base = free_port_block(16)
    assert base >= 20000 and base + 16 <= _ephemeral_low()
    held = [socket.socket() for _ in range(16)]
    try:
        for i, s in enumerate(held):
            s.bind(("127.0.0.1", base + i))  # every port of the block binds
    finally:
        for s in held:
            s.close()
