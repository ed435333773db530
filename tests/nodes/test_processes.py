"""Real node processes over zenoh on loopback: pipelines, events, control, liveliness, hostile input."""

import subprocess
import sys
import threading
import time

import msgpack
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from contactflow.deploy.pipeline_demo import pipeline_configs
from contactflow.nodes.keys import KeySpace
from contactflow.nodes.messages import (
    Command,
    ControlReply,
    ControlRequest,
    EventMsg,
    StatusMsg,
    Vector,
)
from contactflow.nodes.procs import free_port, spawn_node, stop_process, wait_for, write_config
from contactflow.nodes.status import Event, Status
from contactflow.nodes.transport import ZenohSettings, ZenohTransport
from contactflow.nodes.wire import decode, encode

SITE = "ptest"
KS = KeySpace(SITE)


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


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=payloads)
def test_malformed_input_never_kills_a_node(deployment, data):
    put = deployment.tool.publisher(KS.output("demo", "sense", "filter", "out"))
    put(data)
    replies = deployment.tool.query(KS.control("demo", "*", "gain"), data, timeout=2.0)
    for key, payload in replies:
        assert not decode(payload, ControlReply, key).ok or data == b""


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


def test_killed_node_is_noticed_within_two_seconds(deployment, tmp_path):
    gone = threading.Event()

    def on_alive(key, alive):
        if not alive and "/watch" in key:
            gone.set()

    watch = deployment.tool.watch_alive(KS.alive_node(), on_alive)
    proc = deployment.procs["watch"]
    t0 = time.monotonic()
    proc.kill()
    assert gone.wait(2.0), "liveliness subscriber did not see the node die"
    assert time.monotonic() - t0 < 2.0
    watch.close()
    ls = subprocess.run(
        [sys.executable, "-m", "contactflow.deploy.cli", "ls", "--site", SITE, "--wait", "0.5",
         "--connect", f"tcp/127.0.0.1:{deployment.port_a}"],
        capture_output=True, text=True, timeout=30, env={"COLUMNS": "200", "PATH": ""},
    )
    assert ls.returncode == 0, ls.stderr
    assert "sense" in ls.stdout and "/watch" not in ls.stdout
    assert "1 nodes" in ls.stdout


