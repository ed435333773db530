"""Security across namespaces: mTLS + usrpwd + access control generated from a manifest."""

import time

import pytest
from typer.testing import CliRunner

from contactflow.deploy.launcher import tool_endpoints
from contactflow.deploy.launcher_cli import app
from contactflow.deploy.security import write_json5, zenoh_config
from contactflow.deploy.testing import LabDeployment, ProbeClient, lab_manifest
from contactflow.nodes.keys import KeySpace

SITE = "seclab"
KS = KeySpace(SITE)
HUB_PORT = 7460
HOSTS = {
    "h1": {"roles": ["broker"]},
    "h2": {"roles": ["control"], "nodes": {"arm": {"robot": "r1", "modules": [
        {"name": "src", "type": "signal_source", "params": {"rate_hz": 50}}]}}},
    "h3": {"roles": ["vision"]},
    "obs": {"roles": ["observer"]},
}


@pytest.fixture(scope="module")
def secure(tmp_path_factory, lab_factory):
    tmp = tmp_path_factory.mktemp("security")
    lab = lab_factory(["h1", "h2", "h3", "obs", "guest"])
    dep = None
    probes = {}
    try:
        m = lab_manifest(tmp / "secure.yaml", lab, HOSTS, site=SITE, zenoh={"lease_ms": 1000},
                         security={"transport": "mtls", "auth": "usrpwd", "certs": str(tmp / "certs"),
                                   "broker": ["h1"], "dispatch_clients": ["h2"], "observers": ["obs"]},
                         robots={"r1": {"control": "h2", "command_ports": ["command"]}})
        res = CliRunner().invoke(app, ["certs", m.file, "--extra", "guest"])
        assert res.exit_code == 0, res.output
        dep = LabDeployment(lab, m, tmp / "run")
        (tmp / "run").mkdir()
        dep.up("h2")

        def config(who):
            return write_json5(tmp / f"{who}.json5", zenoh_config(m, m.nodes("h2")[0], identity=who))

        hub_ep = f"tls/{lab.addresses['h1']}:{HUB_PORT}"
        eps = tool_endpoints(m, local=False)
        hub_cfg = zenoh_config(m, m.nodes("h2")[0], identity="h1")
        hub_cfg["listen"] = {"endpoints": [hub_ep]}
        hub = ProbeClient(lab.wrap("h1", []), eps, write_json5(tmp / "hub.json5", hub_cfg), name="hub")
        probes["hub"] = hub
        alive = hub.send("alive", key=KS.alive_node())
        assert hub.wait(lambda e: e.get("id") == alive and e["ev"] == "alive" and e["up"], 30), dep.logs()
        for who, ns in (("h2", "h2"), ("h3", "h3"), ("obs", "obs"), ("guest", "guest")):
            probes[who] = ProbeClient(lab.wrap(ns, []), eps + [hub_ep], config(who), name=who)
        for who in ("h2", "h3", "obs", "guest"):
            assert probes[who].wait_peers(2), f"{who} did not join the node and the hub"
        yield lab, m, dep, probes
    finally:
        for p in probes.values():
            p.close()
        if dep is not None:
            dep.down()
        lab.close()



def test_tls_only_listener_refuses_plain_tcp_and_peers_without_credentials(secure):
    lab, m, dep, probes = secure
    plain = ProbeClient(lab.wrap("guest", []), [f"tcp/{lab.addresses['h2']}:7450", f"tcp/{lab.addresses['h1']}:{HUB_PORT}"], name="plain")
    try:
        assert probes["guest"].wait_peers(2), "the credentialed guest should connect (its rights come from the ACL)"
        assert all(probes[w].peers() == 2 for w in ("h2", "h3", "obs", "guest")), "tools open no extra (plain) links"
        time.sleep(1.5)
        assert plain.peers() == 0
        sub = plain.send("sub", key=KS.everything())
        time.sleep(0.5)
        assert plain.count(sub) == 0
    finally:
        plain.close()


def test_only_the_control_host_commands_the_joints(secure):
    lab, m, dep, probes = secure
    hub = probes["hub"]
    got = hub.send("sub", key=KS.output("r1", "*", "*", "command"))
    key = KS.output("r1", "intruder", "ctl", "command")
    probes["h3"].send("put", key=key, values=[3.0])
    probes["guest"].send("put", key=key, values=[4.0])
    probes["obs"].send("put", key=key, values=[5.0])
    for _ in range(20):
        probes["h2"].send("put", key=KS.output("r1", "arm", "ctl", "command"), values=[1.0])
        if hub.wait(lambda e: e.get("id") == got and e["ev"] == "sample", 0.25):
            break
    time.sleep(0.5)
    senders = {e["source"].split("/")[0] for e in hub.events(got)}
    assert senders == {"h2"}, senders


def test_only_the_broker_serves_and_only_clients_query_dispatch(secure):
    lab, m, dep, probes = secure
    hub = probes["hub"]
    served = {who: probes[who].send("queryable", key=KS.dispatch()) for who in ("hub", "guest", "h3")}
    time.sleep(0.5)
    replies = []
    for _ in range(10):
        replies = probes["h2"].query(KS.dispatch(), timeout=0.5)
        if replies:
            break
    assert [r["source"] for r in replies] == ["hub"], replies
    assert {who: probes[who].count(cid, "queried") > 0 for who, cid in served.items()} == {"hub": True, "guest": False, "h3": False}
    n_served = hub.count(served["hub"], "queried")
    for who in ("h3", "guest", "obs"):  # a session's own queryable answers it locally: not a breach
        assert [r for r in probes[who].query(KS.dispatch(), timeout=0.5) if r["source"] != who] == [], who
        assert probes[who].query(KS.robot_service("r1", "run"), timeout=0.3) == []
    assert hub.count(served["hub"], "queried") == n_served, "a query from h3, guest or obs reached the broker"


def test_protected_control_and_reads(secure):
    lab, m, dep, probes = secure
    ctl = KS.control("r1", "*", "src")
    assert probes["h2"].query(ctl, cmd="describe", timeout=2.0), "the control host may command its robot's modules"
    for who in ("h3", "guest", "obs"):
        assert probes[who].query(ctl, cmd="stop", timeout=0.5) == [], who

    subs = {who: (probes[who].send("sub", key=KS.fused("*", "events")),
                  probes[who].send("sub", key=KS.output("r1", "*", "src", "signal")),
                  probes[who].send("sub", key=KS.events()))
            for who in ("h3", "obs", "guest")}
    time.sleep(0.5)
    for i in range(50):
        probes["hub"].send("put", key=KS.fused("r1", "events"), kind="event", values=[float(i)])
        probes["hub"].send("put", key=KS.events("r1", "hub", "m"), kind="event", values=[float(i)])
        if probes["obs"].count(subs["obs"][0]) and all(probes["h3"].count(c) for c in subs["h3"]):
            break
        time.sleep(0.1)
    time.sleep(0.5)
    fused, signal, events = (probes["h3"].count(c) for c in subs["h3"])
    assert fused and signal and events, "members read every stream"
    fused, signal, events = (probes["obs"].count(c) for c in subs["obs"])
    assert fused and not signal and not events, ("observers read contact events and nothing else", fused, signal, events, probes["obs"].peers())
    assert [probes["guest"].count(c) for c in subs["guest"]] == [0, 0, 0], "credentials without a rule read nothing"
