"""Pure dispatch decisions of the broker: rank bids, pick robots, decide failover."""

from __future__ import annotations

from dataclasses import dataclass, field

from contactflow.abstraction.messages import Bid


class DispatchRefused(Exception):
    """No robot can run the task; ``refusals`` says why, per robot."""

    def __init__(self, refusals: dict[str, list[str]]) -> None:
        self.refusals = refusals
        lines = [f"{robot}: {'; '.join(reasons)}" for robot, reasons in sorted(refusals.items())]
        super().__init__("no robot can run this task:\n  " + "\n  ".join(lines or ["no robot answered"]))


def rank(bids: list[Bid]) -> list[Bid]:
    """Capable, idle robots first, then the shortest estimated duration, then the name."""
    return sorted((b for b in bids if b.ok), key=lambda b: (b.busy, b.estimated_duration, b.robot))


def refusals_of(bids: list[Bid], known: list[str] | None = None) -> dict[str, list[str]]:
    out = {b.robot: list(b.reasons) or ["refused without a reason"] for b in bids if not b.ok}
    answered = {b.robot for b in bids}
    for robot in known or []:
        if robot not in answered:
            out[robot] = ["did not answer the dry run in time"]
    return out


def choose(target: str, bids: list[Bid], exclude: set[str] | None = None) -> list[str]:
    """Robots to run on: the best one (``any``), every capable one (``all``) or the named one."""
    exclude = exclude or set()
    usable = [b for b in rank(bids) if b.robot not in exclude]
    if target == "all":
        chosen = [b.robot for b in usable if not b.busy]
    elif target == "any":
        chosen = [usable[0].robot] if usable else []
    else:
        chosen = [b.robot for b in usable if b.robot == target]
    if not chosen:
        refusals = refusals_of([b for b in bids if target in ("any", "all", b.robot)])
        for b in bids:
            if b.robot in exclude and target in ("any", "all", b.robot):
                refusals[b.robot] = ["failed earlier in this task"]
            elif b.ok and b.busy and target == "all":
                refusals[b.robot] = ["busy with another task"]
        if target not in ("any", "all") and not any(b.robot == target for b in bids):
            refusals[target] = ["no such robot answered (is it running?)"]
        raise DispatchRefused(refusals)
    return chosen


@dataclass
class TaskRecord:
    """What the broker remembers about one dispatched task."""

    task_id: str
    atd: str
    file: str
    target: str
    params: dict = field(default_factory=dict)
    running: set[str] = field(default_factory=set)
    finished: dict[str, str] = field(default_factory=dict)  # robot -> outcome
    failed: set[str] = field(default_factory=set)
    attempt: int = 1
    done: bool = False

    def robot_failed(self, robot: str, outcome: str) -> bool:
        """Record a robot's failure; True when the task should move to another robot."""
        self.running.discard(robot)
        self.failed.add(robot)
        self.finished[robot] = outcome
        return self.target != "all" and not self.running

    def robot_finished(self, robot: str, outcome: str) -> bool:
        """Record a robot's end; True when the whole task is over."""
        self.running.discard(robot)
        self.finished[robot] = outcome
        return not self.running
