"""Manifests: validation with file:line:field, rendering node configurations, generated zenoh security."""

import json
import subprocess
from pathlib import Path

import pytest
import zenoh

from contactflow.deploy.certs import make_ca, make_host_cert, make_passwords
from contactflow.deploy.launcher import endpoints, render
from contactflow.deploy.manifest import DEFAULT_MANIFEST, ConfigError, load_manifest, parse_manifest
from contactflow.deploy.security import SecurityError, access_control, zenoh_config
from contactflow.deploy.seqcheck import SequenceMonitor
from contactflow.deploy.supervisor import backoff_delay
from contactflow.embodiments import registry
from contactflow.nodes.config import load_node_config
from contactflow.nodes.keys import KeySpace
from contactflow.nodes.registry import resolve
from contactflow.nodes.yamldoc import YamlDoc

BASE = """\
site: t
hosts:
  a:
    address: 10.1.0.1
    nodes:
      na:
        robot: r
        sensors: [cam]
        modules:
          - {name: s, type: signal_source}
  b:
    address: 10.1.0.2
    nodes:
      nb:
        robot: r
        modules:
          - {name: f, type: lowpass, inputs: {in: s.signal}}
robots:
  r: {control: a, sensors: {cam: a}}
"""


def parse(text, name="m.yaml"):
    return parse_manifest(YamlDoc.parse(text, name))


def test_default_manifest_is_the_thesis_layout_plus_one_station_per_robot():
    m = load_manifest(DEFAULT_MANIFEST)
    assert {"control", "vision2d", "vision3d", "melfa_station", "baxter_station"} <= set(m.hosts)
    tomb = m.robots["tombatossals"]
    assert tomb.control == "control" and tomb.sensors["kinect"] == "vision3d"
    assert tomb.sensors["stereo_left"] == "vision2d" and tomb.sensors["ft_right"] == "control"
    assert m.robots["melfa"].control == "melfa_station" and m.robots["baxter"].control == "baxter_station"
    assert all(n.modules for n in m.nodes())


def test_default_manifest_runs_the_real_modules_of_the_areas():
    m = load_manifest(DEFAULT_MANIFEST)
    classes = {(n.host, mod["name"]): resolve(mod["type"]) for n in m.nodes() for mod in n.modules}
    assert not [k for k, c in classes.items() if c.__module__.startswith("contactflow.nodes.builtin")], classes
    assert classes[("control", "broker")].__module__ == "contactflow.abstraction.broker_module"
    agents = {n.host: mod["params"]["robot"] for n in m.nodes() for mod in n.modules if mod["type"] == "robot_agent"}
    assert agents == {r.control: r.name for r in m.robots.values()}
    assert {c.__module__.rsplit(".", 1)[-1] for (h, _), c in classes.items() if h == "vision3d"} == {
        "cloud_builder", "plane_detector", "roi_filter", "self_filter", "cluster_extractor", "range"}
    # the range generator on the 3D vision computer (thesis §4.4.4) about tombatossals, whose control node fuses it
    (rng,) = [mod for n in m.nodes() for mod in n.modules if n.host == "vision3d" and mod["type"] == "range_hypotheses"]
    assert rng["params"]["robot"] == "tombatossals" and rng["inputs"]["robot_model"] == "tombatossals/model.robot_model"
    assert classes[("vision2d", "shape")].__module__.endswith("classify_shape")
    # each robot's control node fuses its own contacts: a cue generator per arm with a hand, and contact_fusion
    for r in m.robots.values():
        node = next(n for n in m.nodes() if n.host == r.control and n.robot == r.name)
        fusion = [mod for mod in node.modules if mod["type"] == "contact_fusion"]
        assert [mod["params"]["robot"] for mod in fusion] == [r.name]
        cues = {mod["params"]["arm"] for mod in node.modules if mod["type"] == "contact_cues"}
        assert cues == {a.name for a in registry.get(r.name).arms if a.hand}
        # and where its predictor runs (tombatossals), the support of the contacts it predicts (thesis §4.5.2)
        predicts = any(mod["type"] == "predictor" for mod in node.modules)
        support = [mod["params"]["robot"] for mod in node.modules if mod["type"] == "simulator_support_hypotheses"]
        assert support == ([r.name] if predicts else []), r.name
    assert any(mod["type"] == "predictor" for n in m.nodes() for mod in n.modules)


def test_default_manifest_wires_tombatossals_detect_objects_to_the_vision3d_objects(tmp_path):
    m = load_manifest(DEFAULT_MANIFEST)
    ks = KeySpace(m.site)
    docs = {ln.node.name: load_node_config(ln.config) for ln in render(m, tmp_path, local=True)}
    published = {ks.output(mod.robot, node, mod.name, port.name): (node, mod.name)
                 for node, cfg in docs.items() for mod in cfg.modules for port in mod.cls.outputs}

    def source(mod, port):
        key = mod.inputs[port].keyexpr(ks, mod.robot)
        return [v for k, v in published.items() if zenoh.KeyExpr(key).intersects(zenoh.KeyExpr(k))]

    detect = [mod for mod in docs["control"].modules if mod.type == "detect_objects"]
    assert len(detect) == 2
    for mod in detect:
        assert source(mod, "objects") == [("vision3d", "objects")] and source(mod, "plane") == [("vision3d", "plane")]
    # the vision chain is fed by the world's depth stream
    assert docs["vision3d"].modules[0].inputs["depth"].keyexpr(ks, "tombatossals") == ks.robot("tombatossals", "depth")
    # the other primitives, and the robots without a vision3d node, read no port
    assert not [(node, mod.name) for node, cfg in docs.items() for mod in cfg.modules
                if mod.cls.layer == "primitive" and mod.inputs and node != "vision2d" and mod not in detect]


def test_render_local_writes_loadable_node_configs_with_a_loopback_mesh(tmp_path):
    m = load_manifest(DEFAULT_MANIFEST)
    launches = render(m, tmp_path, local=True)
    assert len(launches) == len(m.nodes())
    eps = {ln.endpoint for ln in launches}
    assert len(eps) == len(launches) and all("127.0.0.1" in e for e in eps)
    for ln in launches:
        cfg = load_node_config(ln.config)
        assert cfg.zenoh.listen == (ln.endpoint,)
        assert set(cfg.zenoh.connect) == eps - {ln.endpoint}
        assert zenoh.Config.from_file(cfg.zenoh.config_file) is not None
        assert json.loads(Path(cfg.zenoh.config_file).read_text())["transport"]["link"]["tx"]["lease"] == 5000


INSECURE = BASE.replace("site: t\n", "site: t\nsecurity: {transport: tcp, insecure: true}\n")


def test_render_one_host_uses_the_manifest_addresses(tmp_path):
    m = parse(INSECURE)
    (ln,) = render(m, tmp_path, host="b")
    cfg = load_node_config(ln.config)
    assert cfg.zenoh.listen == ("tcp/10.1.0.2:7450",) and cfg.zenoh.connect == ("tcp/10.1.0.1:7450",)
    assert cfg.modules[0].inputs["in"].module == "s"


def test_routers_topology_adds_router_nodes_and_clients(tmp_path):
    m = parse(INSECURE.replace("site: t", "site: t\nzenoh: {topology: routers, routers: [a], port: 7600}"))
    assert [n.id for n in m.nodes("a")] == ["a/router", "a/na"]
    eps = endpoints(m, local=False)
    assert eps["a/router"] == "tcp/10.1.0.1:7600" and eps["a/na"] == "tcp/10.1.0.1:7601"
    docs = {ln.node.name: load_node_config(ln.config) for ln in render(m, tmp_path, host="a")}
    assert docs["router"].zenoh.mode == "router" and docs["na"].zenoh.mode == "client"
    assert docs["na"].zenoh.connect == ("tcp/10.1.0.1:7600",)


@pytest.mark.parametrize("edit, where, words", [
    (("    address: 10.1.0.2\n", "    address: 10.1.0.2\n    colour: red\n"), "m.yaml:13: hosts.b.colour", "unknown field"),
    (("type: lowpass", "type: no_such_module"), "m.yaml:17: hosts.b.nodes.nb.modules[0].type", "unknown module type"),
    (("inputs: {in: s.signal}", "inputs: {nope: s.signal}"), "m.yaml:17: hosts.b.nodes.nb.modules[0].inputs.nope", "no input"),
    # wired across nodes: the source module must run somewhere in the manifest and have the output
    (("inputs: {in: s.signal}", "inputs: {in: s.nosuch}"), "m.yaml:17: hosts.b.nodes.nb.modules[0].inputs.in",
     "has no output 'nosuch'"),
    (("inputs: {in: s.signal}", "inputs: {in: zz.signal}"), "m.yaml:17: hosts.b.nodes.nb.modules[0].inputs.in",
     "no module 'zz' of robot 'r'"),
    (("{cam: a}", "{cam: b}"), "m.yaml:8: hosts.a.nodes.na.sensors[0]", "high-bandwidth"),
    (("        sensors: [cam]\n", "        sensors: [cam]\n        primitive_inputs: {detect_objects: {objects: o.objects}}\n"),
     "m.yaml:9: hosts.a.nodes.na.primitive_inputs.detect_objects", "host no 'detect_objects'"),
    (("        sensors: [cam]\n", "        sensors: [cam]\n        contacts: true\n"), "m.yaml:7: hosts.a.nodes.na.robot",
     "unknown robot 'r'"),
    (("        sensors: [cam]\n", "        sensors: [cam]\n        contacts: yes please\n"),
     "m.yaml:9: hosts.a.nodes.na.contacts", "expected bool"),
    (("control: a,", "control: z,"), "m.yaml:19: robots.r.control", "not in hosts"),
    (("site: t\n", "site: t\nsecurity: {transport: ssl}\n"), "m.yaml:2: security.transport", "not one of"),
    (("address: 10.1.0.2", "address: 10.1.0.1"), "m.yaml:12: hosts.b.address", "already host"),
    (("      nb:", "      na:"), "m.yaml:14: hosts.b.nodes.na", "already defined"),
    (("site: t\n", "site: t\nsecurity: {transport: tcp, auth: usrpwd, insecure: true, broker: [a]}\n"),
     "m.yaml:2: security.broker", "identified"),
    (("site: t\n", "site: t\nsecurity:\n  transport: tls\n  auth: none\n  observers: [b]\n"), "m.yaml:5: security.observers",
     "tls with auth usrpwd"),
    (("site: t\n", "site: t\nsecurity: {transport: tcp}\n"), "m.yaml:2: security.transport", "only loopback runs it"),
])
def test_bad_manifests_name_file_line_and_field(edit, where, words):
    with pytest.raises(ConfigError) as err:
        parse(BASE.replace(*edit))
    assert str(err.value).startswith(where) and words in str(err.value), str(err.value)


def secure_manifest(tmp_path):
    text = BASE.replace("site: t\n", f"site: t\nsecurity: {{transport: mtls, auth: usrpwd, certs: {tmp_path}, broker: [b], observers: [c]}}\n")
    text = text.replace("robots:", "  c:\n    address: 10.1.0.3\nrobots:")
    return parse(text)


def _grants(acl, host):
    policy = next(p for p in acl["policies"] if p["subjects"] == [f"host-{host}"])
    return [r for r in acl["rules"] if r["id"] in policy["rules"]]


def test_access_control_rules_follow_the_manifest(tmp_path):
    m = secure_manifest(tmp_path)
    ks = KeySpace("t")
    acl = access_control(m)
    assert acl["default_permission"] == "deny"
    assert {s["id"]: s["cert_common_names"] for s in acl["subjects"]} == {"host-a": ["a"], "host-b": ["b"], "host-c": ["c"]}
    obs = _grants(acl, "c")
    assert {k for r in obs for k in r["key_exprs"]} == {ks.fused("*", "events")}
    assert {m_ for r in obs for m_ in r["messages"]} == {"declare_subscriber", "put", "delete"}
    joints = ks.output("r", "*", "*", "command")
    deny_b = [r for r in _grants(acl, "b") if r["permission"] == "deny"]
    assert any(joints in r["key_exprs"] and "put" in r["messages"] and r["flows"] == ["ingress"] for r in deny_b)
    assert not any(joints in r["key_exprs"] for r in _grants(acl, "a") if r["permission"] == "deny")
    # a world's robot: every member reads its state and depth; only the control host commands it
    reads = {k for r in _grants(acl, "b") if "declare_subscriber" in r["messages"] and r["flows"] == ["ingress"]
             for k in r["key_exprs"]}
    assert {ks.robot("*", "state"), ks.robot("*", "depth"), ks.clock(), ks.lockstep("*")} <= reads
    assert any(ks.robot("r", "command") in r["key_exprs"] for r in deny_b)
    writes_a = {k for r in _grants(acl, "a") if r["permission"] == "allow" and "put" in r["messages"]
                and r["flows"] == ["ingress"] for k in r["key_exprs"]}
    assert ks.robot("r", "command") in writes_a
    serve = lambda h: {k for r in _grants(acl, h) if "declare_queryable" in r["messages"] and r["flows"] == ["ingress"] for k in r["key_exprs"]}  # noqa: E731
    assert ks.dispatch() in serve("b") and ks.dispatch() not in serve("a")
    call = lambda h: {k for r in _grants(acl, h) if "query" in r["messages"] and r["flows"] == ["ingress"] for k in r["key_exprs"]}  # noqa: E731
    assert ks.control("r", "*", "s") in call("a") and ks.control("r", "*", "s") not in call("b")
    assert ks.control("r", "*", "f") in call("a") | call("b") and ks.dispatch() in call("b")
    assert not any("*" in k.split("/")[-1] and k.endswith("**") for r in acl["rules"] for k in r["key_exprs"])


def test_tls_with_passwords_identifies_listeners_by_certificate_and_openers_by_user(tmp_path):
    m = parse(BASE.replace("site: t\n", f"site: t\nsecurity: {{transport: tls, auth: usrpwd, certs: {tmp_path}, broker: [b]}}\n"))
    acl = access_control(m)
    assert {s["id"]: s.get("cert_common_names") or s.get("usernames") for s in acl["subjects"]} == {
        "host-a": ["a"], "host-b": ["b"], "user-a": ["a"], "user-b": ["b"]}
    assert {p["id"]: p["subjects"] for p in acl["policies"]} == {"policy-a": ["host-a", "user-a"], "policy-b": ["host-b", "user-b"]}
    plain = parse(BASE.replace("site: t\n", "site: t\nsecurity: {transport: tls, auth: usrpwd}\n"))
    assert plain.security.acl and not parse(INSECURE).security.acl
    with pytest.raises(SecurityError, match="cannot identify peers"):
        access_control(parse(INSECURE))


def test_zenoh_config_needs_certificates_then_zenoh_accepts_it(tmp_path):
    m = secure_manifest(tmp_path)
    with pytest.raises(SecurityError, match="deploy certs"):
        zenoh_config(m, m.nodes("a")[0])
    make_ca(tmp_path, "test CA")
    for h in m.hosts:
        make_host_cert(tmp_path, h, [m.hosts[h].address])
    make_passwords(tmp_path / "passwords.txt", list(m.hosts))
    cfg = zenoh_config(m, m.nodes("a")[0])
    tls = cfg["transport"]["link"]["tls"]
    assert tls["enable_mtls"] and tls["connect_certificate"].endswith("a.pem")
    assert cfg["transport"]["auth"]["usrpwd"]["user"] == "a"
    assert cfg["listen"]["endpoints"] == []  # no implicit plain-TCP listener next to the TLS one
    assert zenoh.Config.from_json5(json.dumps(cfg)) is not None
    out = subprocess.run(["openssl", "verify", "-CAfile", str(tmp_path / "ca.pem"), str(tmp_path / "b.pem")],
                         capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    text = subprocess.run(["openssl", "x509", "-in", str(tmp_path / "b.pem"), "-noout", "-text"], capture_output=True, text=True).stdout
    assert "IP Address:10.1.0.2" in text and "CN = b" in text and "TLS Web Client Authentication" in text


def test_backoff_doubles_up_to_a_cap():
    assert [backoff_delay(n, 0.5, 4.0) for n in range(0, 6)] == [0.0, 0.5, 1.0, 2.0, 4.0, 4.0]


def test_sequence_monitor_reports_gaps_and_accounts_for_every_number():
    mon = SequenceMonitor()
    for s in (5, 6, 7, 10, 11, 11, 12):
        mon.observe("a", s)
    (gap,) = mon.gaps()
    assert (gap.first_missing, gap.last_missing, gap.count) == (8, 9, 2)
    t = mon.sources["a"]
    assert t.duplicates == 1 and t.received == 6 and mon.accounted("a")
    assert mon.observe("a", 1) is None and mon.sources["a"].restarts == 1


def test_a_site_module_is_commanded_only_by_its_host_and_the_control_hosts_and_the_broker_by_its_host(tmp_path):
    text = BASE.replace("site: t\n", f"site: t\nsecurity: {{transport: mtls, auth: usrpwd, certs: {tmp_path}, broker: [b]}}\n")
    text = text.replace("          - {name: f, type: lowpass, inputs: {in: s.signal}}\n",
                        "          - {name: f, type: lowpass, inputs: {in: s.signal}}\n"
                        "          - {name: brk, type: broker, robot: site}\n"
                        "          - {name: svc, type: signal_source, robot: site}\n")
    text = text.replace("robots:", "  c:\n    address: 10.1.0.3\n    nodes:\n      nc:\n        robot: r\n"
                        "        modules:\n          - {name: g, type: signal_source}\nrobots:")
    acl = access_control(parse(text))
    ks = KeySpace("t")
    call = lambda h: {k for r in _grants(acl, h) if "query" in r["messages"] and r["flows"] == ["ingress"] for k in r["key_exprs"]}  # noqa: E731
    broker, service = ks.control("site", "*", "brk"), ks.control("site", "*", "svc")
    assert broker in call("b") and broker not in call("a") and broker not in call("c")
    assert service in call("b") and service in call("a") and service not in call("c")
    # a robot's module: its own host and the robot's control host (a), nobody else
    assert ks.control("r", "*", "g") in call("c") and ks.control("r", "*", "g") in call("a")
    assert ks.control("r", "*", "g") not in call("b")


def test_a_manifest_across_hosts_gets_mutual_tls_and_passwords_by_default_and_plain_tcp_only_on_loopback(tmp_path):
    m = parse(BASE)  # no security section, hosts on a network
    assert (m.security.transport, m.security.auth) == ("mtls", "usrpwd") and m.security.acl
    with pytest.raises(SecurityError, match="deploy certs"):
        render(m, tmp_path, host="a")  # the one extra step: certificates and passwords
    local = parse(BASE.replace("10.1.0.1", "127.0.0.1").replace("10.1.0.2", "127.0.0.2"))
    assert local.security.transport == "tcp" and not local.security.enabled
    insecure = parse(INSECURE)
    assert insecure.security.transport == "tcp" and insecure.security.insecure and insecure.security.auth == "none"
    # a local run of a secure manifest is on loopback: plain tcp, no certificates needed
    launches = render(load_manifest(DEFAULT_MANIFEST), tmp_path / "local", local=True)
    assert all(ln.endpoint.startswith("tcp/127.0.0.1:") for ln in launches)
    files = {json.loads(Path(load_node_config(ln.config).zenoh.config_file).read_text()).get("access_control") is None
             for ln in launches}
    assert files == {True}
    assert load_manifest(DEFAULT_MANIFEST).security.transport == "mtls"


def test_only_the_hosts_that_run_a_world_publish_clocks_robot_sensors_and_ground_truth():
    m = load_manifest(DEFAULT_MANIFEST)
    ks = KeySpace(m.site)
    acl = access_control(m)
    worlds = {"tombatossals_robot", "melfa_station", "baxter_station"}
    forged = {ks.clock(), ks.clock("*"), ks.evaluation(), ks.robot("*", "state"), ks.robot("*", "depth")}

    def denied(h):
        return {k for r in _grants(acl, h) if r["permission"] == "deny" and "put" in r["messages"]
                and r["flows"] == ["ingress"] for k in r["key_exprs"]}
    for h in m.hosts:
        if h in worlds:
            assert not forged & denied(h), h
        else:
            assert forged <= denied(h), h
    # the control host still commands its robot and publishes what a controller does
    assert ks.robot("tombatossals", "command") not in denied("control")
