"""A session refuses at once the queries the site's access rules refuse it, naming the key and the host."""

import json
import time

import pytest

from contactflow.deploy.certs import make_ca, make_host_cert, make_passwords
from contactflow.deploy.manifest import parse_manifest
from contactflow.deploy.security import access_control, zenoh_config
from contactflow.nodes.acl import AccessDenied, AccessRules
from contactflow.nodes.config import parse_node_config
from contactflow.nodes.host import ModuleHost
from contactflow.nodes.keys import KeySpace
from contactflow.nodes.messages import Command
from contactflow.nodes.transport import ZenohSettings, ZenohTransport
from contactflow.nodes.yamldoc import YamlDoc

KS = KeySpace("t")
MANIFEST = """\
site: t
security: {{transport: mtls, auth: usrpwd, certs: {certs}, broker: [b], dispatch_clients: [a]}}
hosts:
  a:
    address: 10.1.0.1
    nodes:
      na:
        robot: r
        modules:
          - {{name: s, type: signal_source}}
  b:
    address: 10.1.0.2
    nodes:
      nb:
        robot: site
        modules:
          - {{name: brk, type: broker, robot: site}}
  c:
    address: 10.1.0.3
    nodes:
      nc:
        robot: r
        modules:
          - {{name: f, type: lowpass}}
robots:
  r: {{control: a}}
"""


@pytest.fixture
def manifest(tmp_path):
    return parse_manifest(YamlDoc.parse(MANIFEST.format(certs=tmp_path), str(tmp_path / "m.yaml")))


def test_the_rules_of_a_host_allow_what_the_manifest_grants_it_and_name_what_they_refuse(manifest):
    section = access_control(manifest)
    a, c = AccessRules.of(section, "a", by_user=False), AccessRules.of(section, "c", by_user=False)
    a.check("query", KS.control("r", "*", "f"))  # the robot's control host commands its modules
    a.check("query", KS.dispatch())  # a dispatch client
    with pytest.raises(AccessDenied, match=r"cf/t/m/site/\*/brk/ctl: .*host 'a'"):
        a.check("query", KS.control("site", "*", "brk"))  # only the broker's own host commands it
    with pytest.raises(AccessDenied, match="host 'c'"):
        c.check("query", KS.dispatch())
    with pytest.raises(AccessDenied, match="deny host 'c' a put"):
        c.check("put", KS.output("r", "*", "*", "command"))  # joints: only from the control host
    nobody = AccessRules.of(section, "stranger", by_user=False)
    with pytest.raises(AccessDenied):
        nobody.check("query", KS.control("r", "*", "f"))


def _secure_files(manifest, tmp_path, host):
    make_ca(tmp_path, "test CA")
    for h in manifest.hosts:
        make_host_cert(tmp_path, h, [manifest.hosts[h].address])
    make_passwords(tmp_path / "passwords.txt", list(manifest.hosts))
    path = tmp_path / f"{host}.json5"
    path.write_text(json.dumps(zenoh_config(manifest, manifest.nodes(host)[0])))
    return path


def test_a_guarded_session_refuses_a_query_at_once_and_a_host_reports_it_as_a_control_error(manifest, tmp_path):
    zfile = _secure_files(manifest, tmp_path, "c")
    assert AccessRules.load(zfile).identity == "c"
    t = ZenohTransport(ZenohSettings(config_file=str(zfile))).open()
    try:
        t0 = time.monotonic()
        with pytest.raises(AccessDenied, match="host 'c'"):
            t.query(KS.control("site", "*", "brk"), b"", timeout=5.0)
        assert time.monotonic() - t0 < 0.5  # not the query's timeout
        assert t.query(KS.control("r", "*", "f"), b"", timeout=0.2) == []  # allowed: it goes out (nobody answers)
        cfg = parse_node_config(YamlDoc.parse("site: t\nnode: nc\nhost: c\nmodules: []\n", "nc.yaml"))
        host = ModuleHost(cfg, t)
        reply = host.send_control("site/brk", Command.STOP, {}, issuer="r/nc/task", timeout=5.0)
        assert not reply.ok and "access rules" in reply.error and "brk/ctl" in reply.error
    finally:
        t.close()
    probe = ZenohTransport(ZenohSettings(config_file=str(zfile)), guard=False).open()  # it tests the network's rules
    try:
        assert probe.rules is None
    finally:
        probe.close()
