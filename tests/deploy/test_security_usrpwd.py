"""Security across namespaces without client certificates: TLS + user/password + access control by user name."""

import time

import pytest
from typer.testing import CliRunner

from contactflow.deploy.launcher import tool_endpoints
from contactflow.deploy.launcher_cli import app
from contactflow.deploy.security import cert_paths, read_passwords, write_json5, zenoh_config
from contactflow.deploy.testing import LabDeployment, ProbeClient, lab_manifest
from contactflow.nodes.keys import KeySpace

SITE = "pwlab"
KS = KeySpace(SITE)
HUB_PORT = 7470
HOSTS = {
    "h1": {"roles": ["broker"]},
    "h2": {"roles": ["control"], "nodes": {"arm": {"robot": "r1", "modules": [
        {"name": "src", "type": "signal_source", "params": {"rate_hz": 50}}]}}},
}



@pytest.fixture(scope="module")
def secure(tmp_path_factory, lab_factory):
    tmp = tmp_path_factory.mktemp("usrpwd")
    lab = lab_factory(["h1", "h2", "guest"])
    dep = None
    probes = {}
    try:
        m = lab_manifest(tmp / "pw.yaml", lab, HOSTS, site=SITE, zenoh={"lease_ms": 1000},
                         security={"transport": "tls", "auth": "usrpwd", "certs": str(tmp / "certs"),
                                   "broker": ["h1"], "dispatch_clients": ["h2"]},
                         robots={"r1": {"control": "h2", "command_ports": ["command"]}})
        res = CliRunner().invoke(app, ["certs", m.file, "--extra", "guest"])
        assert res.exit_code == 0, res.output
        dep = LabDeployment(lab, m, tmp / "run")
        (tmp / "run").mkdir()
        dep.up("h2")
        node = m.nodes("h2")[0]
        password = read_passwords(cert_paths(m, "h2")["passwords"])["guest"]

        def guest(name, user="guest", pw=password):
            """A session with the CA but no certificate of its own, and no access control of its own."""
            cfg = zenoh_config(m, node, identity="h2")
            tls = cfg["transport"]["link"]["tls"]
            del tls["listen_private_key"], tls["listen_certificate"]
            cfg.pop("access_control", None)
            if user is None:
                cfg["transport"].pop("auth")
            else:
                cfg["transport"]["auth"]["usrpwd"] = {"user": user, "password": pw}
            return write_json5(tmp / f"{name}.json5", cfg)

        hub_ep = f"tls/{lab.addresses['h1']}:{HUB_PORT}"
        eps = tool_endpoints(m, local=False)
        hub_cfg = zenoh_config(m, node, identity="h1")
        hub_cfg["listen"] = {"endpoints": [hub_ep]}
        probes["hub"] = hub = ProbeClient(lab.wrap("h1", []), eps, write_json5(tmp / "hub.json5", hub_cfg), name="hub")
        alive = hub.send("alive", key=KS.alive_node())
        assert hub.wait(lambda e: e.get("id") == alive and e["ev"] == "alive" and e["up"], 30), dep.logs()
        both = eps + [hub_ep]
        probes["h2"] = ProbeClient(lab.wrap("h2", []), both, write_json5(tmp / "h2.json5", zenoh_config(m, node)), name="h2")
        probes["guest"] = ProbeClient(lab.wrap("guest", []), both, guest("guest"), name="guest")
        probes["badpw"] = ProbeClient(lab.wrap("guest", []), both, guest("badpw", pw=password + "x"), name="badpw")
        probes["nopw"] = ProbeClient(lab.wrap("guest", []), both, guest("nopw", user=None), name="nopw")
        for who in ("h2", "guest"):
            assert probes[who].wait_peers(2), f"{who} did not join the node and the hub"
        yield lab, m, dep, probes
    finally:
        for p in probes.values():
            p.close()
        if dep is not None:
            dep.down()
        lab.close()


def test_a_wrong_or_missing_password_is_refused(secure):
    lab, m, dep, probes = secure
    assert probes["guest"].peers() == 2, "the right password (no certificate) opens both links"
    subs = {who: probes[who].send("sub", key=KS.everything()) for who in ("badpw", "nopw")}
    for i in range(10):
        probes["hub"].send("put", key=KS.events("r1", "hub", "m"), kind="event", values=[float(i)])
        time.sleep(0.1)
    assert probes["badpw"].peers() == 0 and probes["nopw"].peers() == 0
    assert [probes[who].count(cid) for who, cid in subs.items()] == [0, 0]


def test_credentials_without_a_rule_cannot_command_joints_or_touch_dispatch(secure):
    lab, m, dep, probes = secure
    hub, h2, guest = probes["hub"], probes["h2"], probes["guest"]
    got = hub.send("sub", key=KS.output("r1", "*", "*", "command"))
    served = hub.send("queryable", key=KS.dispatch())
    intruder = guest.send("queryable", key=KS.dispatch())
    guest.send("put", key=KS.output("r1", "intruder", "ctl", "command"), values=[4.0])
    for _ in range(20):
        h2.send("put", key=KS.output("r1", "arm", "ctl", "command"), values=[1.0])
        if hub.wait(lambda e: e.get("id") == got and e["ev"] == "sample", 0.25):
            break
    guest.send("put", key=KS.output("r1", "intruder", "ctl", "command"), values=[4.0])
    time.sleep(0.5)
    assert {e["source"].split("/")[0] for e in hub.events(got)} == {"h2"}, "only the control host commands r1"

    replies = []
    for _ in range(10):
        replies = h2.query(KS.dispatch(), timeout=0.5)
        if replies:
            break
    assert [r["source"] for r in replies] == ["hub"], replies
    assert hub.count(served, "queried") >= 1 and guest.count(intruder, "queried") == 0, "the guest serves no dispatch"
    n_served = hub.count(served, "queried")
    # the guest's own queryable answers its query locally: only replies from elsewhere are a breach
    assert [r for r in guest.query(KS.dispatch(), timeout=0.5) if r["source"] != "guest"] == []
    assert guest.query(KS.robot_service("r1", "run"), timeout=0.3) == []
    assert hub.count(served, "queried") == n_served, "the guest's dispatch query reached the broker"


def test_credentials_without_a_rule_read_nothing(secure):
    lab, m, dep, probes = secure
    subs = {who: probes[who].send("sub", key=KS.events()) for who in ("h2", "guest")}
    time.sleep(0.5)
    for i in range(50):
        probes["hub"].send("put", key=KS.events("r1", "hub", "m"), kind="event", values=[float(i)])
        if probes["h2"].count(subs["h2"]):
            break
        time.sleep(0.1)
    time.sleep(0.5)
    assert probes["h2"].count(subs["h2"]) > 0, "members read the event stream"
    assert probes["guest"].count(subs["guest"]) == 0
