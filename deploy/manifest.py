"""Deployment manifests (YAML): hosts, the nodes on each host, robots and sensors, topology, security.

Example (``deploy/manifests/default.yaml`` is the full thesis layout)::

    site: lab
    zenoh: {topology: mesh, port: 7450, lease_ms: 5000}   # mesh | routers (routers: [host])
    security: {transport: mtls, auth: usrpwd, certs: certs,
               broker: [control], dispatch_clients: [control], observers: [viewer]}
    hosts:
      control:
        address: 10.0.0.1
        roles: [control, broker]
        nodes:
          control:
            robot: tombatossals
            sensors: [arm_left, arm_right]       # checked against robots.<r>.sensors
            clock: lockstep                      # wall | sim | lockstep (the world waits for it each tick)
            cell: tombatossals                   # with sim/lockstep: the world it follows (a site may run several)
            primitives: 2                        # 2 modules of each primitive type the robot's tasks may run
            primitive_inputs:                    # inputs of those modules, per type: [robot/]module.port or cf/...
              detect_objects: {objects: objects.objects, plane: plane.plane}
            contacts: true                       # the robot's contact fusion: cue generators and contact_fusion
            modules:                             # same schema as a node configuration
              - {name: source, type: signal_source, params: {rate_hz: 50}}
    robots:
      tombatossals:
        control: control                         # the host that alone may command the joints
        command_ports: [command, joint_command]  # output ports that carry joint commands
        sensors: {arm_left: control, kinect: vision3d}

High-bandwidth sources stay on the host that owns them (thesis App. A.1.4): a node that
lists a sensor must run on the host the robot entry gives for it. Hosts on a network get
``mtls`` and ``usrpwd`` unless ``security`` says otherwise; plain ``tcp`` between hosts needs
``insecure: true``; a local run (:func:`on_loopback`) is plain tcp on loopback. An input wired
to ``module.port`` must name a module of the site with that output.
"""

from __future__ import annotations

import dataclasses
import ipaddress
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from contactflow.nodes.config import NodeConfig, parse_node_config
from contactflow.nodes.keys import KeyExprError, segment
from contactflow.nodes.yamldoc import ConfigError, PathKey, YamlDoc

_TOP = {"site", "zenoh", "security", "hosts", "robots"}
_ZENOH = {"topology", "routers", "port", "lease_ms"}
_SECURITY = {"transport", "auth", "certs", "broker", "dispatch_clients", "observers", "insecure"}
_HOST = {"address", "roles", "nodes"}
_NODE = {"robot", "clock", "cell", "port", "sensors", "primitives", "primitive_inputs", "contacts", "modules"}
_ROBOT = {"control", "command_ports", "sensors"}
TRANSPORTS = ("tcp", "tls", "mtls")
AUTHS = ("none", "usrpwd")
TOPOLOGIES = ("mesh", "routers")
ROUTER_NODE = "router"
"""Name of the router node the launcher adds on each router host (topology ``routers``)."""


@dataclass(frozen=True)
class NodeSpec:
    host: str
    name: str
    robot: str
    clock: str
    port: int
    sensors: tuple[str, ...]
    modules: tuple[dict[str, Any], ...]  # module entries as written (validated), then the primitives
    line: int = 1
    router: bool = False
    cell: str = ""  # the world (cell) a lockstep or sim node follows

    @property
    def id(self) -> str:
        return f"{self.host}/{self.name}"


@dataclass(frozen=True)
class HostSpec:
    name: str
    address: str
    roles: tuple[str, ...]
    nodes: tuple[NodeSpec, ...]


@dataclass(frozen=True)
class RobotSpec:
    name: str
    control: str
    command_ports: tuple[str, ...]
    sensors: dict[str, str]


@dataclass(frozen=True)
class Topology:
    kind: str = "mesh"
    routers: tuple[str, ...] = ()
    port: int = 7450
    # ms: a lost host is noticed within about one lease; a node starved of CPU for a lease loses its links too
    # (1 s closed links of the demo's nodes on 2 loaded cores: tokens dropped, messages lost)
    lease_ms: int = 5000


@dataclass(frozen=True)
class Security:
    transport: str = "tcp"
    auth: str = "none"
    certs: Path | None = None
    broker: tuple[str, ...] = ()
    dispatch_clients: tuple[str, ...] = ()
    observers: tuple[str, ...] = ()
    insecure: bool = False  # plain tcp between hosts, asked for by name (an isolated test network)

    @property
    def enabled(self) -> bool:
        return self.transport != "tcp" or self.auth != "none"

    @property
    def acl(self) -> bool:
        """Access control needs the peer of every link identified on both of its ends.

        mTLS certificates identify both sides. With ``tls`` + ``usrpwd`` the side that accepted
        a link knows the other's user name (password-checked) and the side that opened it knows
        the listener's certificate common name; plain ``tcp`` leaves the opener blind.
        """
        return self.transport == "mtls" or (self.transport == "tls" and self.auth == "usrpwd")

    @property
    def rules(self) -> bool:
        """The manifest names hosts with special rights (brokers, dispatch clients, observers)."""
        return bool(self.broker or self.dispatch_clients or self.observers)


@dataclass(frozen=True)
class Manifest:
    site: str
    hosts: dict[str, HostSpec]
    robots: dict[str, RobotSpec]
    topology: Topology
    security: Security
    file: str = "<manifest>"

    def host(self, name: str) -> HostSpec:
        if name not in self.hosts:
            raise ConfigError(f"{self.file}: no host {name!r} (hosts: {', '.join(self.hosts)})")
        return self.hosts[name]

    def nodes(self, host: str | None = None) -> list[NodeSpec]:
        hosts = [self.host(host)] if host else list(self.hosts.values())
        return [n for h in hosts for n in h.nodes]

    def hosts_with_role(self, role: str) -> list[str]:
        return [h.name for h in self.hosts.values() if role in h.roles]


def _name(doc: YamlDoc, path: PathKey, value: str, what: str) -> str:
    try:
        return segment(value, what)
    except KeyExprError as exc:
        raise doc.error(path, str(exc)) from None


def _strs(doc: YamlDoc, path: PathKey) -> tuple[str, ...]:
    items = doc.get(path, list, [])
    return tuple(doc.get(path + (i,), str) for i in range(len(items)))


def _choice(doc: YamlDoc, path: PathKey, options: tuple[str, ...], default: str) -> str:
    value = doc.get(path, str, default)
    if value not in options:
        raise doc.error(path, f"{value!r} is not one of {', '.join(options)}")
    return value


def _port(doc: YamlDoc, path: PathKey, default: int) -> int:
    port = doc.get(path, int, default)
    if not 1024 <= port <= 65535:
        raise doc.error(path, f"port {port} is not in 1024..65535")
    return port


def _check_node_modules(doc: YamlDoc, path: PathKey, site: str, host: str, node: str, robot: str, clock: str,
                        modules: list) -> NodeConfig:
    """Validate a node's modules with the node-configuration parser, errors at manifest lines."""
    prefix_len = len(path)
    lines = {p[prefix_len:]: ln for p, ln in doc.lines.items() if p[:prefix_len] == path}
    data = {"site": site, "node": node, "host": host, "robot": robot, "clock": clock, "modules": modules}
    sub = YamlDoc(data=data, file=doc.file, lines=lines)
    try:
        return parse_node_config(sub)
    except ConfigError as exc:
        where, sep, rest = str(exc).partition(": ")
        dotted = "".join(f"[{p}]" if isinstance(p, int) else f".{p}" for p in path).lstrip(".")
        raise ConfigError(f"{where}{sep}{dotted}.{rest}") from None


def _wire_primitives(doc: YamlDoc, path: PathKey, modules: list[dict[str, Any]]) -> None:
    """Give the generated primitive ``modules`` the inputs of the node's ``primitive_inputs`` (per type), in place.

    The entries are checked with the node's other modules (ports, sources).
    """
    wp = path + ("primitive_inputs",)
    wiring = doc.get(wp, dict, {})
    types = {m["type"] for m in modules}
    for t in wiring:
        if t not in types:
            raise doc.error(wp + (t,), f"the node's `primitives` host no {t!r} module "
                            f"(they host: {', '.join(sorted(types)) or 'none'})")
        inputs = {port: doc.get(wp + (t, port), str) for port in doc.get(wp + (t,), dict)}
        for m in modules:
            if m["type"] == t:
                m["inputs"] = dict(inputs)


def _parse_node(doc: YamlDoc, path: PathKey, site: str, host: str, name: str, port: int,
                wired: dict[PathKey, tuple[NodeConfig, int]]) -> NodeSpec:
    doc.mapping(path, _NODE)
    robot = _name(doc, path + ("robot",), doc.get(path + ("robot",), str, "site"), "robot")
    clock = _choice(doc, path + ("clock",), ("wall", "sim", "lockstep"), "wall")
    cell = doc.get(path + ("cell",), str, "")
    if cell:
        _name(doc, path + ("cell",), cell, "cell")
    port = _port(doc, path + ("port",), port)
    modules = list(doc.get(path + ("modules",), list, []))
    pool = doc.get(path + ("primitives",), int, 0)
    generated: list[dict[str, Any]] = []
    if pool:
        # every primitive the robot's translations may run, ``pool`` modules of each (parallel branches, helpers)
        from contactflow.embodiments.layout import primitive_modules

        if not 1 <= pool <= 8:
            raise doc.error(path + ("primitives",), f"{pool} modules per primitive type is not in 1..8")
        try:
            generated = primitive_modules(robot, pool=pool)
        except KeyError as exc:
            raise doc.error(path + ("robot",), str(exc).strip("'\"")) from None
    _wire_primitives(doc, path, generated)
    if doc.get(path + ("contacts",), bool, False):
        from contactflow.embodiments.layout import contact_modules

        if robot == "site":
            raise doc.error(path + ("contacts",), "contact fusion needs the node's robot")
        try:
            # a node that hosts the robot's predictor fuses its predicted contacts too (simulator support)
            generated += contact_modules(robot, predictor=any(isinstance(m, dict) and m.get("type") == "predictor"
                                                              for m in modules))
        except KeyError as exc:
            raise doc.error(path + ("robot",), str(exc).strip("'\"")) from None
    written = len(modules)
    modules += generated
    parsed = _check_node_modules(doc, path, site, host, name, robot, clock, modules)
    wired[path] = (parsed, written)
    return NodeSpec(host, name, robot, clock, port, _strs(doc, path + ("sensors",)), tuple(modules), doc.line(path),
                    cell=cell)


def _check_site_wiring(doc: YamlDoc, wired: dict[PathKey, tuple[NodeConfig, int]]) -> None:
    """Every input wired to ``module.port`` names a module of the site that has that output (on any node)."""
    site = {(m.robot, m.name): m for cfg, _ in wired.values() for m in cfg.modules}
    for path, (cfg, written) in wired.items():
        for i, m in enumerate(cfg.modules):
            for port, src in m.inputs.items():
                if src.key is not None:
                    continue
                where = path + ("modules", i, "inputs", port) if i < written else path + ("primitive_inputs", m.type, port)
                robot = src.robot or m.robot
                source = site.get((robot, src.module))
                if source is None:
                    raise doc.error(where, f"no module {src.module!r} of robot {robot!r} runs in this manifest")
                outs = {p.name for p in source.cls.outputs}
                if src.port not in outs:
                    raise doc.error(where, f"module {source.name!r} ({source.cls.__name__}) has no output "
                                           f"{src.port!r} (outputs: {sorted(outs)})")


def parse_manifest(doc: YamlDoc) -> Manifest:
    doc.mapping((), _TOP)
    site = _name(doc, ("site",), doc.get(("site",), str, "default"), "site")
    topo = Topology()
    if doc.get(("zenoh",), dict, None) is not None:
        doc.mapping(("zenoh",), _ZENOH)
        lease = doc.get(("zenoh", "lease_ms"), int, Topology.lease_ms)
        if not 200 <= lease <= 60000:
            raise doc.error(("zenoh", "lease_ms"), f"{lease} ms is not in 200..60000")
        topo = Topology(_choice(doc, ("zenoh", "topology"), TOPOLOGIES, "mesh"),
                        _strs(doc, ("zenoh", "routers")), _port(doc, ("zenoh", "port"), 7450), lease)

    hosts: dict[str, HostSpec] = {}
    addresses: dict[str, str] = {}
    node_names: dict[str, str] = {}
    wired: dict[PathKey, tuple[NodeConfig, int]] = {}  # node path -> its modules, and how many the YAML lists
    for hname in doc.get(("hosts",), dict):
        hp: PathKey = ("hosts", hname)
        _name(doc, hp, hname, "host")
        doc.mapping(hp, _HOST)
        address = doc.get(hp + ("address",), str, "127.0.0.1")
        if address in addresses and address != "127.0.0.1":
            raise doc.error(hp + ("address",), f"address {address} is already host {addresses[address]!r}")
        addresses[address] = hname
        nodes = []
        next_port = topo.port + (1 if hname in topo.routers else 0)
        for nname in doc.get(hp + ("nodes",), dict, {}):
            np_: PathKey = hp + ("nodes", nname)
            _name(doc, np_, nname, "node")
            if nname in node_names:
                raise doc.error(np_, f"node {nname!r} is already defined on host {node_names[nname]!r} (node names are site-wide)")
            if nname == ROUTER_NODE:
                raise doc.error(np_, f"node name {ROUTER_NODE!r} is reserved for the routers the launcher adds")
            node_names[nname] = hname
            spec = _parse_node(doc, np_, site, hname, nname, next_port, wired)
            if any(n.port == spec.port for n in nodes):
                raise doc.error(np_ + ("port",), f"port {spec.port} is used by another node of host {hname!r}")
            nodes.append(spec)
            next_port = max(next_port, spec.port) + 1
        if hname in topo.routers:
            nodes.insert(0, NodeSpec(hname, ROUTER_NODE, "site", "wall", topo.port, (), (), doc.line(hp), router=True))
        hosts[hname] = HostSpec(hname, address, _strs(doc, hp + ("roles",)), tuple(nodes))
    if not hosts:
        raise doc.error(("hosts",), "a manifest needs at least one host")
    _check_site_wiring(doc, wired)
    for i, r in enumerate(topo.routers):
        if r not in hosts:
            raise doc.error(("zenoh", "routers", i), f"router host {r!r} is not in hosts")
    if topo.kind == "routers" and not topo.routers:
        raise doc.error(("zenoh", "routers"), "topology routers needs at least one router host")

    robots: dict[str, RobotSpec] = {}
    for rname in doc.get(("robots",), dict, {}):
        rp: PathKey = ("robots", rname)
        _name(doc, rp, rname, "robot")
        doc.mapping(rp, _ROBOT)
        control = doc.get(rp + ("control",), str)
        if control not in hosts:
            raise doc.error(rp + ("control",), f"host {control!r} is not in hosts")
        sensors: dict[str, str] = {}
        for sname in doc.get(rp + ("sensors",), dict, {}):
            owner = doc.get(rp + ("sensors", sname), str)
            if owner not in hosts:
                raise doc.error(rp + ("sensors", sname), f"host {owner!r} is not in hosts")
            sensors[sname] = owner
        ports = _strs(doc, rp + ("command_ports",)) or ("command", "joint_command")
        for i, p in enumerate(ports):
            _name(doc, rp + ("command_ports", i), p, "port")
        robots[rname] = RobotSpec(rname, control, ports, sensors)

    for h in hosts.values():
        for n in h.nodes:
            np_ = ("hosts", h.name, "nodes", n.name)
            if n.router:
                continue
            for i, s in enumerate(n.sensors):
                r = robots.get(n.robot)
                if r is None or s not in r.sensors:
                    raise doc.error(np_ + ("sensors", i), f"robot {n.robot!r} declares no sensor {s!r} under robots.{n.robot}.sensors")
                if r.sensors[s] != h.name:
                    raise doc.error(np_ + ("sensors", i), f"sensor {s!r} is attached to host {r.sensors[s]!r}; "
                                    f"high-bandwidth sources must be read on the host that has them")

    remote = [f"{h.name} ({h.address})" for h in hosts.values() if not _loopback(h.address)]
    spans = len(hosts) > 1 and bool(remote)  # links cross a network: TLS and passwords unless asked otherwise
    sec = Security("mtls", "usrpwd", (Path(doc.file).parent / "certs").resolve()) if spans else Security()
    if doc.get(("security",), dict, None) is not None:
        sp: PathKey = ("security",)
        doc.mapping(sp, _SECURITY)
        certs = doc.get(sp + ("certs",), str, "certs")
        certs_path = Path(certs) if Path(certs).is_absolute() else Path(doc.file).parent / certs
        lists = {}
        for fld in ("broker", "dispatch_clients", "observers"):
            lists[fld] = _strs(doc, sp + (fld,))
            for i, hname in enumerate(lists[fld]):
                if hname not in hosts:
                    raise doc.error(sp + (fld, i), f"host {hname!r} is not in hosts")
        transport = _choice(doc, sp + ("transport",), TRANSPORTS, "mtls" if spans else "tcp")
        sec = Security(transport, _choice(doc, sp + ("auth",), AUTHS, "usrpwd" if spans and transport != "tcp" else "none"),
                       certs_path.resolve(), lists["broker"], lists["dispatch_clients"], lists["observers"],
                       doc.get(sp + ("insecure",), bool, False))
        if spans and sec.transport == "tcp" and not sec.insecure:
            raise doc.error(sp + ("transport",), f"plain tcp would cross the network between hosts "
                            f"{', '.join(remote)}: only loopback runs it. Use mtls (the default) or tls, and "
                            f"`contactflow deploy certs {doc.file}`; or set `insecure: true` for an isolated test network")
        if sec.rules and not sec.acl:
            fld = next(f for f in ("broker", "dispatch_clients", "observers") if lists[f])
            raise doc.error(sp + (fld,), f"access rules need every link's peer identified on both ends, which transport "
                            f"{sec.transport!r} with auth {sec.auth!r} cannot do: use transport mtls, or transport tls "
                            f"with auth usrpwd (or drop broker, dispatch_clients and observers to run without access control)")
    return Manifest(site, hosts, robots, topo, sec, doc.file)


def _loopback(address: str) -> bool:
    try:
        return ipaddress.ip_address(address).is_loopback
    except ValueError:
        return address == "localhost"


def on_loopback(m: Manifest) -> Manifest:
    """The manifest as a local run sees it (``--local``, the demo): every node on this machine's
    loopback, over plain tcp; TLS, passwords and access rules guard the network between hosts."""
    return dataclasses.replace(m, security=Security())


def load_manifest(path: str | Path) -> Manifest:
    return parse_manifest(YamlDoc.load(path))


DEFAULT_MANIFEST = Path(__file__).parent / "manifests" / "default.yaml"

__all__ = ["DEFAULT_MANIFEST", "ConfigError", "HostSpec", "Manifest", "NodeSpec", "RobotSpec", "Security",
           "Topology", "load_manifest", "on_loopback", "parse_manifest"]
