"""Node configurations of the runtime layout: a world node, and a control node per robot (thesis §2.2, App. A).

The world node hosts the ``world`` module (the cell: robots, table, objects). A robot's
control node hosts, with the node's clock in lockstep with the world, the task module and
one module per primitive type its tasks use (a small pool of each, so parallel branches and
helpers run side by side), each configured with the robot's embodiment profile. The
configurations are plain node documents (``nodes.procs.write_config`` writes one): the same
document runs in a process of its own (``contactflow node``) or beside others in one.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import yaml

from contactflow.nodes.taskgraph import NodeKind, TaskGraph

CELLS = Path(__file__).parent / "cells"


def primitive_types(tasks: Mapping[str, TaskGraph], main: str) -> list[str]:
    """Every primitive type ``main`` runs, through nested tasks, parallel branches and helpers."""
    seen: set[str] = set()
    out: set[str] = set()
    todo = [main]
    while todo:
        name = todo.pop()
        if name in seen:
            continue
        seen.add(name)
        for node in tasks[name].nodes.values():
            for n in (node, *node.branches):
                if n.kind is NodeKind.PRIMITIVE:
                    out.add(n.type)
                elif n.kind is NodeKind.TASK:
                    todo.append(n.type)
                out.update(h.type for h in n.helpers)
    return sorted(out)


def _plain(v: Any) -> Any:
    if isinstance(v, tuple | list):
        return [_plain(x) for x in v]
    return v


def zenoh(listen: str = "", connect: tuple[str, ...] = ()) -> dict[str, Any]:
    z: dict[str, Any] = {"mode": "peer", "multicast_scouting": False}
    if listen:
        z["listen"] = [listen]
    if connect:
        z["connect"] = list(connect)
    return z


def world_node(site: str, scene_file: str | Path, node: str = "world", clock: str = "lockstep",
               listen: str = "", connect: tuple[str, ...] = (), **params: Any) -> dict[str, Any]:
    """The world node: one ``world`` module building the cell of ``scene_file`` (``params``: its Params)."""
    params = {k: list(v) if isinstance(v, tuple) else v for k, v in params.items()}
    return {"site": site, "node": node, "clock": "wall", "zenoh": zenoh(listen, connect),
            "modules": [{"name": "world", "type": "world",
                         "params": {"scene_file": str(scene_file), "clock": clock, **params}}]}


def control_node(site: str, robot: str, embodiment: str, task_file: str | Path, task: str = "",
                 plan: Mapping[str, Any] | None = None, node: str = "", clock: str = "lockstep",
                 listen: str = "", connect: tuple[str, ...] = (), pool: int = 2,
                 autostart: bool = False) -> dict[str, Any]:
    """A robot's control node: the task module and the primitive modules of its task, in lockstep.

    With ``autostart`` the task starts with the node, at the first tick it steps (a world
    that waits for the node makes that tick 0); else on a RUN control message.
    """
    from contactflow.embodiments.primitives.profiles import profile
    from contactflow.nodes.taskfile import load_tasks

    tasks, main = load_tasks(str(task_file))
    name = task or main
    defaults = profile(embodiment)
    modules: list[dict[str, Any]] = []
    for t in primitive_types(tasks, name):
        params = {k: _plain(v) for k, v in defaults.get(t, {}).items()}
        for k in range(1, pool + 1):
            modules.append({"name": t if k == 1 else f"{t}_{k}", "type": t, "robot": robot, "autostart": False,
                            **({"params": params} if params else {})})
    modules.append({"name": "task", "type": "task", "robot": robot, "autostart": autostart,
                    "inputs": {"events": f"cf/{site}/m/{robot}/*/*/evt"},
                    "params": {"task_file": str(task_file), "task": name, "robot": robot,
                               "plan": yaml.safe_dump(dict(plan or {}), default_flow_style=True).strip(),
                               "pool": pool}})
    return {"site": site, "node": node or f"control_{robot}", "clock": clock, "zenoh": zenoh(listen, connect),
            "modules": modules}
