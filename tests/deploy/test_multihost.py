"""Three hosts in network namespaces deployed from one manifest: flow, link cut/heal, supervision."""

import os
import signal
import time

import pytest

from contactflow.deploy.launcher import tool_endpoints
from contactflow.deploy.seqcheck import SequenceMonitor
from contactflow.deploy.testing import BEACON, TAP_PAD, LabDeployment, ProbeClient, lab_manifest
from contactflow.nodes.keys import KeySpace

SITE = "nslab"
KS = KeySpace(SITE)
HOSTS = {
    "h1": {"roles": ["sensing"], "nodes": {"n1": {"robot": "r1", "sensors": ["ft"], "modules": [
        {"name": "src", "type": "signal_source", "params": {"rate_hz": 50, "amplitude": 1.0, "frequency": 1.0}},
        {"name": "beacon", "type": BEACON, "params": {"rate_hz": 50}, "autostart": True},
        # a pad pressed and released every 0.4 s, fused by the real tactile generator and contact
        # fusion: a contact_made / contact_broken stream (~5 events/s) on the fused events key
        {"name": "pad", "type": TAP_PAD, "params": {"robot": "r1", "press_s": 0.2, "release_s": 0.2}},
        {"name": "tactile", "type": "tactile_hypotheses", "inputs": {"tactile": "pad.tactile", "taxels": "pad.taxels"},
         "params": {"robot": "r1"}},
        {"name": "fusion", "type": "contact_fusion",
         "params": {"robot": "r1", "sources": "r1/*", "rate_hz": 50, "timeout": 0.1, "hold": 0.05}}]}}},
    "h2": {"roles": ["processing"], "nodes": {"n2": {"robot": "r1", "modules": [
        {"name": "gain", "type": "scale", "inputs": {"in": "src.signal"}, "params": {"rate_hz": 100, "gain": 2.0}}]}}},
    "h3": {"roles": ["control"], "nodes": {"n3": {"robot": "r1", "modules": [
        {"name": "smooth", "type": "lowpass", "inputs": {"in": "gain.out"}, "params": {"rate_hz": 100}},
        {"name": "watch", "type": "threshold_watch", "inputs": {"in": "gain.out"},
         "params": {"rate_hz": 100, "threshold": 1.5, "timeout": 0}}]}}},
}


@pytest.fixture(scope="module")
def deployment(tmp_path_factory, lab_factory):
    tmp = tmp_path_factory.mktemp("multihost")
    lab = lab_factory(["h1", "h2", "h3", "obs"])
    dep = None
    probes = []
    try:
        m = lab_manifest(tmp / "lab.yaml", lab, HOSTS, site=SITE, zenoh={"topology": "mesh", "lease_ms": 1000},
                         robots={"r1": {"control": "h3", "sensors": {"ft": "h1"}}},
                         security={"transport": "tcp", "insecure": True})  # the lab's namespaces are isolated
        dep = LabDeployment(lab, m, tmp / "run")
        (tmp / "run").mkdir()
        for h in ("h1", "h2", "h3"):
            dep.up(h)
        eps = tool_endpoints(m, local=False)
        obs = ProbeClient(lab.wrap("obs", []), eps, name="obs", messages=("contactflow.fusion.messages",), ready_timeout=40)
        probes.append(obs)
        alive = obs.send("alive", key=KS.alive_node())
        wanted = {"h1/n1", "h2/n2", "h3/n3"}
        end = time.monotonic() + 40
        while time.monotonic() < end and {"/".join(e["key"].split("/")[-2:]) for e in obs.events(alive, "alive") if e["up"]} < wanted:
            time.sleep(0.1)
        seen = {"/".join(e["key"].split("/")[-2:]) for e in obs.events(alive, "alive") if e["up"]}
        assert seen >= wanted, f"nodes up: {seen}\n{dep.logs()}"
        # a member on h2 connects to every node, as the site's tools do (tool_endpoints): zenoh 1.10
        # sometimes does not relay a token declared again after a heal to a session that reaches
        # h1 only through h2's node (seen in 1 of ~10 runs, while h1's data flowed through h2 again)
        peer = ProbeClient(lab.wrap("h2", []), eps, name="h2probe")
        probes.append(peer)
        yield lab, m, dep, obs, alive, peer
    finally:
        for p in probes:
            p.close()
        if dep is not None:
            dep.down()
        lab.close()


def _ups(probe, cid, node, start=0):
    return [e for e in probe.events(cid, "alive")[start:] if e["key"].endswith("/" + node)]


def test_data_events_and_control_flow_between_hosts(deployment):
    lab, m, dep, obs, alive, _ = deployment
    smooth = obs.send("sub", key=KS.output("r1", "*", "smooth", "out"))
    gain = obs.send("sub", key=KS.output("r1", "*", "gain", "out"))
    events = obs.send("sub", key=KS.events("r1", "*", "watch"))
    assert obs.wait(lambda e: e.get("id") == smooth and e["ev"] == "sample", 10), "h1 -> h2 -> h3 data did not arrive"
    assert obs.wait(lambda e: e.get("id") == gain and e["ev"] == "sample", 10), "h2's output did not arrive"
    assert all(abs(e["values"][0]) <= 2.0 + 1e-9 for e in obs.events(gain))

    replies = obs.query(KS.control("r1", "*", "watch"), cmd="run", timeout=3.0)
    assert replies and replies[0]["ok"], replies
    ev = obs.wait(lambda e: e.get("id") == events and e["ev"] == "sample" and e.get("event") == "contact", 10)
    assert ev is not None and abs(ev["values"]["value"]) >= 1.5

    replies = obs.query(KS.control("r1", "*", "gain"), cmd="set", params={"gain": 0.0, "offset": 5.0}, timeout=3.0)
    assert replies and replies[0]["ok"], replies
    got = obs.wait(lambda e: e.get("id") == gain and e["ev"] == "sample" and e["values"] == [5.0], 10)
    assert got is not None, f"no output with the new parameters ({obs.count(gain)} outputs seen)"
    obs.query(KS.control("r1", "*", "gain"), cmd="set", params={"gain": 2.0, "offset": 0.0}, timeout=3.0)


def test_link_cut_is_seen_within_2s_and_heal_resumes_traffic_without_silent_loss(deployment):
    lab, m, dep, obs, alive, peer = deployment
    beacon = obs.send("sub", key=KS.events("r1", "*", "beacon"))
    contacts = obs.send("sub", key=KS.fused("r1", "events"))
    palive = peer.send("alive", key=KS.alive_node())
    pdata = peer.send("sub", key=KS.output("r1", "*", "src", "signal"))
    assert obs.wait(lambda e: e.get("id") == beacon and e["ev"] == "sample", 10)
    assert obs.wait(lambda e: e.get("id") == contacts and e["ev"] == "sample", 10), "no contact events from h1\n" + dep.logs()
    assert peer.wait(lambda e: e.get("id") == pdata and e["ev"] == "sample", 10)
    i_obs, i_peer = len(obs.events(alive, "alive")), len(peer.events(palive, "alive"))

    t_cut = time.time()
    lab.cut("h1")
    gone_obs = obs.wait(lambda e: e.get("id") == alive and e["ev"] == "alive" and not e["up"] and e["key"].endswith("h1/n1"), 5)
    gone_peer = peer.wait(lambda e: e.get("id") == palive and e["ev"] == "alive" and not e["up"] and e["key"].endswith("h1/n1"), 5)
    assert gone_obs is not None and gone_peer is not None, "h1 was not seen gone"
    assert gone_obs["t"] - t_cut < 2.0 and gone_peer["t"] - t_cut < 2.0, (gone_obs["t"] - t_cut, gone_peer["t"] - t_cut)
    assert not [e for e in _ups(obs, alive, "h1/n1", i_obs) if not e["up"] and e["key"].endswith(("h2/n2", "h3/n3"))]
    time.sleep(1.0)
    n_beacon, n_data, n_contacts = obs.count(beacon), peer.count(pdata), obs.count(contacts)

    lab.heal("h1")
    back = obs.wait(lambda e: e.get("id") == alive and e["ev"] == "alive" and e["up"] and e["key"].endswith("h1/n1") and e["t"] > t_cut, 20)
    assert back is not None, "h1 was not rediscovered after healing\n" + dep.logs()
    assert peer.wait(lambda e: e.get("id") == palive and e["ev"] == "alive" and e["up"] and e["key"].endswith("h1/n1") and e["t"] > t_cut, 10)
    end = time.monotonic() + 10
    while time.monotonic() < end and (obs.count(beacon) < n_beacon + 20 or peer.count(pdata) < n_data + 20
                                      or obs.count(contacts) < n_contacts + 4):
        time.sleep(0.1)
    assert obs.count(beacon) >= n_beacon + 20 and peer.count(pdata) >= n_data + 20, "traffic did not resume"
    assert obs.count(contacts) >= n_contacts + 4, "contact events did not resume"

    # the link is down for over 1 s: >= 50 beacon and ~5 contact events are published meanwhile
    for cid, least in ((beacon, 25), (contacts, 3)):
        mon = SequenceMonitor()
        for e in obs.events(cid):
            mon.observe(e["source"], e["seq"])
        (source,) = mon.sources
        track = mon.sources[source]
        assert mon.accounted(source), track
        assert track.gaps, f"{source}: the outage must show as a reported gap, not disappear"
        assert sum(g.count for g in track.gaps) >= least, track.gaps
    received = obs.events(contacts)
    assert {e["type"] for e in received} == {"contact_event"}
    for a, b in zip(received, received[1:], strict=False):  # made and broken alternate where nothing was lost
        if b["seq"] == a["seq"] + 1:
            assert {a["event"], b["event"]} == {"contact_made", "contact_broken"}, (a, b)
    assert i_peer <= len(peer.events(palive, "alive"))


def test_killed_node_is_restarted_by_the_supervisor_and_reannounced(deployment):
    lab, m, dep, obs, alive, _ = deployment
    pid = dep.node_pid("h2", "n2")
    assert pid > 0
    start = len(obs.events(alive, "alive"))
    t_kill = time.time()
    os.kill(pid, signal.SIGKILL)
    gone = obs.wait(lambda e: e.get("id") == alive and e["ev"] == "alive" and not e["up"] and e["key"].endswith("h2/n2") and e["t"] >= t_kill, 5)
    assert gone is not None, "the killed node's liveliness did not go"
    back = obs.wait(lambda e: e.get("id") == alive and e["ev"] == "alive" and e["up"] and e["key"].endswith("h2/n2") and e["t"] > gone["t"], 20)
    assert back is not None, "the node was not re-announced\n" + dep.logs()
    assert len(obs.events(alive, "alive")) > start
    assert dep.restarts("h2", "n2") == 1
    assert dep.node_pid("h2", "n2") not in (0, pid)
