"""Two robots' generators in two node processes, fused into their cell's map by one integrator, over zenoh on loopback;
a robot of another cell talks on the same site and is refused."""

import threading

import numpy as np

from contactflow.fusion.messages import ContactEventMsg
from contactflow.fusion.testing import one_pad_hand
from contactflow.nodes.keys import KeySpace
from contactflow.nodes.procs import free_port, spawn_node, stop_process, wait_for, write_config
from contactflow.nodes.status import Event
from contactflow.nodes.transport import ZenohSettings, ZenohTransport
from contactflow.nodes.wire import decode, encode

SITE = "fusionproc"
KS = KeySpace(SITE)


def taxel_key(robot, stream="taxels"):
    return f"{KS.prefix}/test/{robot}/{stream}"


def configs(port_a, port_b):
    zen_a = {"mode": "peer", "listen": [f"tcp/127.0.0.1:{port_a}"], "multicast_scouting": False}
    zen_b = {"mode": "peer", "listen": [f"tcp/127.0.0.1:{port_b}"], "connect": [f"tcp/127.0.0.1:{port_a}"],
             "multicast_scouting": False}

    def tactile(robot):
        return {"name": "tactile", "type": "tactile_hypotheses", "robot": robot,
                "params": {"robot": robot, "rate_hz": 100},
                "inputs": {"taxels": taxel_key(robot), "tactile": taxel_key(robot, "tactile")},
                "outputs": {"hypotheses": KS.hypotheses(robot, "tactile")}}

    a = {"site": SITE, "node": "arm1", "host": "h1", "robot": "r1", "clock": "wall", "zenoh": zen_a,
         "modules": [tactile("r1"), {**tactile("r3"), "name": "tactile_r3"}]}
    fusion = {"name": "fusion", "type": "cell_fusion", "robot": "site",
              "params": {"robot": "table", "robots": ["r1", "r2"], "hold": 0.3, "timeout": 0.3}}
    b = {"site": SITE, "node": "arm2", "host": "h2", "robot": "r2", "clock": "wall", "zenoh": zen_b,
         "modules": [tactile("r2"), fusion]}
    return a, b


def test_two_robots_fused_across_processes(tmp_path):
    port_a, port_b = free_port(), free_port()
    cfg_a, cfg_b = configs(port_a, port_b)
    procs = [spawn_node(write_config(tmp_path / "a.yaml", cfg_a), tmp_path / "a.log"),
             spawn_node(write_config(tmp_path / "b.yaml", cfg_b), tmp_path / "b.log")]
    tool = ZenohTransport(ZenohSettings(connect=(f"tcp/127.0.0.1:{port_a}", f"tcp/127.0.0.1:{port_b}"))).open()
    lock = threading.Lock()
    events: list[ContactEventMsg] = []

    def on_event(key, payload):
        with lock:
            events.append(decode(payload, ContactEventMsg, key))

    sub = tool.subscribe(KS.fused("table", "events"), on_event)  # the cell's map
    try:
        up = wait_for(lambda: len(tool.alive(KS.alive_module(), timeout=0.3)) >= 4, timeout=40)
        logs = lambda: (tmp_path / "a.log").read_text()[-1500:] + (tmp_path / "b.log").read_text()[-1500:]  # noqa: E731
        assert up, logs()
        pub = {r: (tool.publisher(taxel_key(r)), tool.publisher(taxel_key(r, "tactile"))) for r in ("r1", "r2", "r3")}
        where = {"r1": [0.5, 0.3, 0.8], "r2": [0.5, -0.3, 0.8], "r3": [0.9, 0.0, 0.8]}

        def touch(robots):
            for r in ("r1", "r2", "r3"):
                tactile, poses = one_pad_hand([where[r]], [2.0 if r in robots else 0.0], robot=r)
                pub[r][0](encode(poses))
                pub[r][1](encode(tactile))

        def made():
            with lock:
                return {e.robot for e in events if e.event == Event.CONTACT_MADE}

        ok = wait_for(lambda: (touch({"r1", "r2", "r3"}), made() == {"r1", "r2"})[1], timeout=20, interval=0.05)
        assert ok, logs()
        # r3, a robot of another cell talking on the same site, touched too: refused, never in the cell's map
        said = " ".join((tmp_path / "b.log").read_text().split())  # the log's lines are wrapped
        assert "refused #1 (robot): a cloud about robot 'r3', not of this cell ['r1', 'r2']" in said, said
        with lock:
            first = {e.robot: e for e in events if e.event == Event.CONTACT_MADE}
        assert np.linalg.norm(np.array(first["r1"].location) - where["r1"]) < 0.01
        assert np.linalg.norm(np.array(first["r2"].location) - where["r2"]) < 0.01

        def broken():
            with lock:
                return {e.robot for e in events if e.event == Event.CONTACT_BROKEN}

        ok = wait_for(lambda: (touch({"r2"}), broken() == {"r1"})[1], timeout=10, interval=0.05)
        assert ok, logs()
        assert made() == {"r1", "r2"}
    finally:
        sub.close()
        tool.close()
        for p in procs:
            stop_process(p)
