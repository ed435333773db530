"""Health of a deployment: supervisor state files plus node liveliness tokens over zenoh."""

from __future__ import annotations

import tempfile
from dataclasses import dataclass
from pathlib import Path

from contactflow.deploy.launcher import LOCAL, tool_endpoints
from contactflow.deploy.manifest import Manifest, on_loopback
from contactflow.deploy.security import write_json5, zenoh_config
from contactflow.deploy.supervisor import SupervisorState, pid_alive, read_state
from contactflow.nodes.keys import KeySpace
from contactflow.nodes.transport import ZenohSettings, ZenohTransport


@dataclass(frozen=True)
class NodeHealth:
    host: str
    node: str
    scope: str  # run-dir scope that launched it ("" when not launched from this machine)
    pid: int
    process: str  # running | backoff | stopped | dead | unknown
    restarts: int
    alive: bool  # liveliness token seen


def scopes(run_dir: Path) -> dict[str, SupervisorState]:
    out = {}
    if run_dir.is_dir():
        for d in sorted(run_dir.iterdir()):
            st = read_state(d)
            if st is not None:
                out[d.name] = st
    return out


def open_observer(m: Manifest, local: bool, identity: str | None = None) -> ZenohTransport:
    """A peer session joining the deployment as ``identity`` (a host of the manifest)."""
    if local:
        m = on_loopback(m)
    who = identity or next(h for h in m.hosts if h not in m.security.observers)
    node = m.nodes(who)[0] if m.nodes(who) else m.nodes()[0]
    with tempfile.TemporaryDirectory(prefix="cf-status-") as tmp:  # holds a password: gone once read
        zfile = write_json5(Path(tmp) / "tool.json5", zenoh_config(m, node, identity=who))
        settings = ZenohSettings(mode="peer", connect=tuple(tool_endpoints(m, local)), config_file=str(zfile))
        return ZenohTransport(settings).open()


def alive_nodes(m: Manifest, transport: ZenohTransport, timeout: float = 1.0) -> set[str]:
    """``host/node`` of every node whose liveliness token answers."""
    ks = KeySpace(m.site)
    return {"/".join(k.split("/")[-2:]) for k in transport.alive(ks.alive_node(), timeout=timeout)}


def health(m: Manifest, run_dir: Path, alive: set[str]) -> list[NodeHealth]:
    launched = {}
    for scope, st in scopes(run_dir).items():
        for ns in st.nodes.values():
            proc = ns.state
            if ns.state == "running" and not pid_alive(ns.pid):
                proc = "dead"
            if st.state == "running" and not pid_alive(st.pid) and proc != "stopped":
                proc = f"{proc} (supervisor gone)"
            launched[f"{ns.host}/{ns.node}"] = (scope, ns.pid, proc, ns.restarts)
    out = []
    for n in m.nodes():
        scope, pid, proc, restarts = launched.get(n.id, ("", 0, "unknown", 0))
        out.append(NodeHealth(n.host, n.name, scope, pid, proc, restarts, n.id in alive))
    return out


def is_local_run(run_dir: Path) -> bool:
    return (run_dir / LOCAL).is_dir()
