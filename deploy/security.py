"""Zenoh JSON5 configurations from a manifest: lease, TLS / mTLS, usrpwd and access control.

Access control needs the peer of every link identified on both of its ends. ``transport:
mtls``: certificates identify both sides (subject: certificate common name = host name).
``transport: tls`` with ``auth: usrpwd``: the side that accepted a link knows the opener's
user name (checked against the password file; subject: user name = host name) and the side
that opened it knows the listener's certificate common name, so each host has two subjects.
A usrpwd user without a certificate (a guest) is therefore known only where it connects, and
gets no rule there. Plain ``tcp`` cannot identify the listener, so a manifest with access
rules on it is refused at validation. The generated control denies by default and allows,
per host:

* members (every host that is not an observer): publish / subscribe / liveliness on the
  site's module, contact, clock and evaluation streams; control queries to every module of
  the manifest, except modules that run on a robot's control host, which only that host
  may query; joint-command ports of a robot (``command_ports``) only from its control host
  (an explicit deny for every other host: explicit deny wins in zenoh); a world's clock, its
  robots' sensor streams and its ground truth only from the hosts that run a world module;
* brokers: the dispatch queryable and its replies, queries to every robot's broker
  services; dispatch clients (and brokers) may query dispatch; a robot's control host
  serves that robot's broker services; brokers and control hosts publish progress;
* observers: subscribe to fused contact events and nothing else.

Allow rules name concrete key expressions or exact patterns: zenoh matches a rule only when
the message's key expression is included in the rule's, so a wildcard query such as
``cf/<site>/**`` matches no allow rule and is refused rather than slipping past a deny.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from contactflow.deploy.manifest import Manifest, NodeSpec
from contactflow.nodes.keys import ANY, KeySpace

LIVELINESS = ["liveliness_token", "declare_liveliness_subscriber", "liveliness_query"]
KEEP_ALIVE = 4  # keep-alive messages per lease period


class SecurityError(ValueError):
    """Certificates or passwords a manifest needs are missing."""


def cert_paths(m: Manifest, host: str) -> dict[str, Path]:
    d = m.security.certs
    if d is None:
        raise SecurityError(f"{m.file}: security.certs is not set")
    return {"ca": d / "ca.pem", "cert": d / f"{host}.pem", "key": d / f"{host}.key", "passwords": d / "passwords.txt"}


def read_passwords(path: Path) -> dict[str, str]:
    if not path.exists():
        raise SecurityError(f"{path}: no password file; run `contactflow deploy certs MANIFEST`")
    out = {}
    for line in path.read_text().splitlines():
        user, sep, pw = line.partition(":")
        if sep:
            out[user] = pw
    return out


def endpoint_proto(m: Manifest) -> str:
    return "tcp" if m.security.transport == "tcp" else "tls"


@dataclass
class Grants:
    """What one host may do; each becomes zenoh rules for both directions of its links.

    zenoh checks a message against the rules of the *remote* peer's subject, on ingress
    (what the peer sends us) and on egress (what we send the peer), so "X may read K" is
    ingress ``declare_subscriber`` from X plus egress ``put`` to X, and so on.
    """

    write: list[str] = field(default_factory=list)  # put / delete
    read: list[str] = field(default_factory=list)  # subscribe, receive puts
    call: list[str] = field(default_factory=list)  # query, receive replies
    serve: list[str] = field(default_factory=list)  # declare queryables, reply, receive queries
    live: list[str] = field(default_factory=list)  # liveliness tokens, subscribers, queries
    deny_write: list[str] = field(default_factory=list)  # explicit deny wins over any allow

    def rules(self, host: str) -> list[dict[str, Any]]:
        def rule(kind: str, flow: str, messages: list[str], keys: list[str], permission: str = "allow") -> dict[str, Any] | None:
            if not keys:
                return None
            return {"id": f"{host}-{kind}-{flow}", "messages": messages, "flows": [flow],
                    "permission": permission, "key_exprs": sorted(set(keys))}

        out = [
            rule("write", "ingress", ["put", "delete"], self.write),
            rule("read", "ingress", ["declare_subscriber"], self.read),
            rule("read", "egress", ["put", "delete"], self.read),
            rule("wsub", "egress", ["declare_subscriber"], self.write),
            rule("call", "ingress", ["query"], self.call),
            rule("call", "egress", ["reply", "declare_queryable"], self.call),
            rule("serve", "ingress", ["declare_queryable", "reply"], self.serve),
            rule("serve", "egress", ["query"], self.serve),
            rule("live", "ingress", LIVELINESS, self.live),
            rule("live", "egress", LIVELINESS, self.live),
            rule("denywrite", "ingress", ["put", "delete"], self.deny_write, "deny"),
        ]
        return [r for r in out if r is not None]


def access_control(m: Manifest) -> dict[str, Any]:
    """The ``access_control`` section shared by every node of the manifest."""
    if not m.security.acl:
        raise SecurityError(f"{m.file}: transport {m.security.transport!r} with auth {m.security.auth!r} "
                            "cannot identify peers; access control needs mtls, or tls with usrpwd")
    ks = KeySpace(m.site)
    observers = set(m.security.observers)
    brokers = set(m.security.broker)
    callers = brokers | set(m.security.dispatch_clients)
    controls = {r.control for r in m.robots.values()}
    verbs = ("caps", "translate", "run", "cancel")
    streams = [ks.clock(), ks.clock(ANY), ks.output(ANY, ANY, ANY, ANY), ks.events(), ks.status(), ks.hypotheses(),
               ks.evaluation(), ks.progress(), ks.lockstep(ANY), ks.lockstep(ANY, ANY)]
    streams += [ks.fused(ANY, s) for s in ("hypotheses", "contacts", "events")]
    streams += [ks.robot(ANY, s) for s in ("state", "joints", "camera", "depth")]  # what a world publishes
    # what only a world publishes: its clock, its robots' sensors and ground truth
    world_streams = [ks.clock(), ks.clock(ANY), ks.evaluation(), *(ks.robot(ANY, s) for s in ("state", "joints", "camera", "depth"))]
    worlds = {n.host for n in m.nodes() for mod in n.modules if mod.get("type") == "world"}
    alive = [ks.alive_node(), ks.alive_module(), ks.alive_robot(), ks.claim(ANY, ANY), ks.alive_lockstep(ANY),
             ks.alive_lockstep(ANY, ANY), ks.alive_controller(ANY, ANY)]

    # who may command a module (stop it, change its parameters): the host it runs on, and for a
    # robot's module the robot's control host; a site module (a broker, a shared service) also
    # the control hosts, which run the tasks: never any other member host
    ctl: dict[str, list[str]] = {}
    for n in m.nodes():
        for mod in n.modules:
            robot = mod.get("robot", n.robot)
            key = ks.control(robot, ANY, mod["name"])
            if robot in m.robots:
                allowed = {n.host, m.robots[robot].control}
            elif mod.get("type") == "broker":
                allowed = {n.host}
            else:
                allowed = {n.host} | controls
            for h in allowed:
                ctl.setdefault(h, []).append(key)

    grants: dict[str, Grants] = {}
    for h in m.hosts:
        if h in observers:
            grants[h] = Grants(read=[ks.fused(ANY, "events")])
            continue
        g = Grants(write=list(streams), read=[*streams, ks.robot(ANY, "command")], live=list(alive),
                   call=[*ctl.get(h, []), ks.robot(ANY, "info")], serve=[ks.control(ANY, ANY, ANY), ks.robot(ANY, "info")])
        for r in m.robots.values():
            if r.control == h:  # the robot's controllers: its joint-command ports and its world's command port
                g.serve += [ks.robot_service(r.name, v) for v in verbs]
                g.write.append(ks.robot(r.name, "command"))
            else:
                g.deny_write += [ks.output(r.name, ANY, ANY, p) for p in r.command_ports] + [ks.robot(r.name, "command")]
        if h in brokers:
            g.serve.append(ks.dispatch())
            g.call += [ks.robot_service(ANY, v) for v in verbs]
        if h in callers:
            g.call.append(ks.dispatch())
        if h not in brokers and h not in controls:
            g.deny_write.append(ks.progress())
        if worlds and h not in worlds:  # a forged clock or robot state from any other host is dropped
            g.deny_write += world_streams
        grants[h] = g

    rules: list[dict[str, Any]] = []
    policies = []
    by_user = m.security.transport != "mtls"  # tls + usrpwd: the listener knows only the user name
    for h, g in grants.items():
        rs = g.rules(h)
        rules += rs
        subjects = [f"host-{h}"] + ([f"user-{h}"] if by_user else [])
        policies.append({"id": f"policy-{h}", "rules": [r["id"] for r in rs], "subjects": subjects})
    subjects = [{"id": f"host-{h}", "cert_common_names": [h]} for h in m.hosts]
    if by_user:
        subjects += [{"id": f"user-{h}", "usernames": [h]} for h in m.hosts]
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects, "policies": policies}


def zenoh_config(m: Manifest, node: NodeSpec, identity: str | None = None) -> dict[str, Any]:
    """The JSON5 settings of one node (mode and endpoints come from the node configuration).

    ``identity`` is the host whose certificate and password the session uses (default: the
    node's host); tools such as ``deploy status`` join as one of the manifest's hosts.
    """
    who = identity or node.host
    cfg: dict[str, Any] = {
        # no implicit listener: zenoh peers otherwise listen on plain tcp/[::]:0, which gossip
        # advertises; nodes set their (TLS) endpoint in the node configuration
        "listen": {"endpoints": []},
        "transport": {"link": {"tx": {"lease": m.topology.lease_ms, "keep_alive": KEEP_ALIVE}}},
        "connect": {"exit_on_failure": False,
                    "retry": {"period_init_ms": 200, "period_max_ms": 1000, "period_increase_factor": 2}},
    }
    sec = m.security
    if sec.transport in ("tls", "mtls"):
        p = cert_paths(m, who)
        for f in ("ca", "cert", "key"):
            if not p[f].exists():
                raise SecurityError(f"{p[f]}: missing; run `contactflow deploy certs {m.file}`")
        tls: dict[str, Any] = {"root_ca_certificate": str(p["ca"]), "listen_private_key": str(p["key"]),
                               "listen_certificate": str(p["cert"]), "enable_mtls": sec.transport == "mtls"}
        if sec.transport == "mtls":
            tls |= {"connect_private_key": str(p["key"]), "connect_certificate": str(p["cert"])}
        cfg["transport"]["link"]["tls"] = tls
    if sec.auth == "usrpwd":
        p = cert_paths(m, who)
        pw = read_passwords(p["passwords"])
        if who not in pw:
            raise SecurityError(f"{p['passwords']}: no password for host {who!r}; run `contactflow deploy certs {m.file}`")
        cfg["transport"]["auth"] = {"usrpwd": {"user": who, "password": pw[who], "dictionary_file": str(p["passwords"])}}
    if sec.acl:
        cfg["access_control"] = access_control(m)
    return cfg


def write_json5(path: Path, data: dict[str, Any]) -> Path:
    """JSON is JSON5; the file is private because it may hold a password."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data, indent=2) + "\n")
    path.chmod(0o600)
    return path
