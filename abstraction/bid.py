"""A robot's bid for an ATD: can it translate it (reach, sensors, primitives) and how long.

The broker asks each candidate robot for a bid (a dry-run translation) and picks the best.
The duration is a nominal estimate along the shortest path from the start state to a
success terminal: arm motions at the robot's nominal speed, fixed times for hand actions.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

from contactflow.abstraction.atd import Atd
from contactflow.abstraction.factory import MappingRefused, factory_for
from contactflow.abstraction.profiles import RobotProfile
from contactflow.abstraction.translator import Translation, TranslationError, translate
from contactflow.nodes.taskgraph import REQUIRED, NodeKind

HAND_TIME = {"robust_grasp": 4.0, "naive_grasp": 2.0, "close_until_force": 2.0, "close_until_stall": 2.0, "release": 1.0,
             "hold": 0.5}
"""s, nominal duration of hand primitives (robust grasp includes its corrections)."""
SETTLE = 0.5  # s added to every arm motion (acceleration, contact checks)
UNKNOWN_DISTANCE = 0.3  # m, assumed when a motion's goal is bound only at run time


@dataclass(frozen=True, slots=True)
class Bid:
    robot: str
    ok: bool
    duration: float = math.inf  # s, nominal
    reasons: tuple[str, ...] = ()
    translation: Translation | None = None


def _goal(params: dict, task_params: dict) -> tuple[float, float, float] | None:
    target = params.get("target")
    if isinstance(target, str) and target.startswith("${params.") and target.endswith("}"):
        target = task_params.get(target[len("${params."):-1])
    if isinstance(target, list) and len(target) == 3 and target is not REQUIRED:
        return (float(target[0]), float(target[1]), float(target[2]))
    return None


def estimate_duration(tr: Translation, robot: RobotProfile) -> float:
    """Nominal seconds along the shortest start -> success path of the ESTD."""
    estd = tr.estd
    prev: dict[str, str | None] = {estd.start: None}
    todo = deque([estd.start])
    goal = ""
    while todo:
        cur = todo.popleft()
        if estd.nodes[cur].kind is NodeKind.SUCCESS:
            goal = cur
            break
        for e in estd.out_edges(cur):
            if e.dest not in prev:
                prev[e.dest] = cur
                todo.append(e.dest)
    if not goal:
        return math.inf
    path: list[str] = []
    node: str | None = goal
    while node is not None:
        path.append(node)
        node = prev[node]
    here = robot.workspace.center
    total = 0.0
    for nid in reversed(path):
        n = estd.nodes[nid]
        if n.kind is not NodeKind.PRIMITIVE:
            continue
        if n.type in HAND_TIME:
            total += HAND_TIME[n.type]
            continue
        target = _goal(dict(n.params), dict(estd.params))
        dist = math.dist(here, target) if target is not None else UNKNOWN_DISTANCE
        total += dist / robot.speed + SETTLE
        here = target if target is not None else here
    return round(total, 2)


def bid(atd: Atd, robot: RobotProfile) -> Bid:
    """Translate ``atd`` for ``robot`` as a dry run; a refusal carries every reason."""
    try:
        tr = translate(atd, factory_for(robot))
    except TranslationError as exc:
        return Bid(robot.name, False, reasons=tuple(exc.reasons))
    except MappingRefused as exc:
        return Bid(robot.name, False, reasons=(exc.reason,))
    return Bid(robot.name, True, estimate_duration(tr, robot), translation=tr)
