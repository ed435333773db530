"""From a manifest to the files of a run: one node configuration and one zenoh JSON5 per node.

Run directory layout (``status`` and ``stop`` read it from another shell)::

    <run>/<scope>/supervisor.json     pid of the supervisor, and per node: pid, restarts, state
    <run>/<scope>/nodes/<node>.yaml   generated node configuration (``contactflow node``)
    <run>/<scope>/zenoh/<node>.json5  generated zenoh settings (lease, TLS, auth, access control)
    <run>/<scope>/logs/<node>.log     the node's output

``<scope>`` is the host name for ``up --host NAME`` and ``local`` for ``up --local``.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from contactflow.deploy.manifest import Manifest, NodeSpec, on_loopback
from contactflow.deploy.security import endpoint_proto, write_json5, zenoh_config
from contactflow.nodes.procs import write_config

LOCAL = "local"
LOOPBACK = "127.0.0.1"


@dataclass(frozen=True)
class Launch:
    """Everything needed to start and supervise one node process."""

    node: NodeSpec
    config: Path
    log: Path
    endpoint: str


def default_run_dir(m: Manifest) -> Path:
    base = os.environ.get("CONTACTFLOW_RUN_DIR")
    return Path(base) / m.site if base else Path("/tmp") / f"contactflow-{os.getuid()}" / m.site


def endpoints(m: Manifest, local: bool) -> dict[str, str]:
    """The listen endpoint of every node (``host/node`` -> endpoint)."""
    proto = "tcp" if local else endpoint_proto(m)  # a local run is on loopback: plain tcp (manifest.on_loopback)
    out = {}
    for i, n in enumerate(m.nodes()):
        if local:
            out[n.id] = f"{proto}/{LOOPBACK}:{m.topology.port + i}"
        else:
            out[n.id] = f"{proto}/{m.hosts[n.host].address}:{n.port}"
    return out


def _connect(m: Manifest, n: NodeSpec, eps: dict[str, str]) -> list[str]:
    if m.topology.kind == "routers":
        routers = [x for x in m.nodes() if x.router]
        return [eps[r.id] for r in routers if r.id != n.id]
    return [eps[x.id] for x in m.nodes() if x.id != n.id and not x.router]


def node_document(m: Manifest, n: NodeSpec, eps: dict[str, str], zenoh_file: Path,
                  connect: tuple[str, ...] = ()) -> dict:
    mode = "router" if n.router else "client" if m.topology.kind == "routers" else "peer"
    return {
        "site": m.site, "node": n.name, "host": n.host, "robot": n.robot, "clock": n.clock,
        **({"cell": n.cell} if n.cell else {}),
        "zenoh": {"mode": mode, "listen": [eps[n.id]], "connect": _connect(m, n, eps) + list(connect),
                  "multicast_scouting": False, "config_file": str(zenoh_file)},
        "modules": list(n.modules),
    }


def render(m: Manifest, run_dir: Path, host: str | None = None, local: bool = False,
           connect: tuple[str, ...] = ()) -> list[Launch]:
    """Write the configurations of one host's nodes (or all, ``local``) and return launches.

    ``connect``: endpoints outside the manifest every node also connects to (a router of a
    network the deployment joins).
    """
    if local == (host is not None):
        raise ValueError("render: give exactly one of host or local")
    scope = run_dir / (LOCAL if local else host)
    if local:
        m = on_loopback(m)
    eps = endpoints(m, local)
    out = []
    for n in m.nodes(None if local else host):
        zfile = write_json5(scope / "zenoh" / f"{n.name}.json5", zenoh_config(m, n))
        cfg = write_config(scope / "nodes" / f"{n.name}.yaml", node_document(m, n, eps, zfile, connect))
        out.append(Launch(n, cfg, scope / "logs" / f"{n.name}.log", eps[n.id]))
    return out


def tool_endpoints(m: Manifest, local: bool) -> list[str]:
    """Endpoints a tool session connects to in order to observe the deployment."""
    eps = endpoints(m, local)
    if m.topology.kind == "routers":
        return [eps[n.id] for n in m.nodes() if n.router]
    return list(eps.values())
