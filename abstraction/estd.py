"""The ESTD on the wire: what a bid carries and the broker sends, and the robot's checks on arrival.

The broker sends the robot the very translation its bid carried (the robot does not
translate again). The robot still refuses, with every reason, an ESTD it cannot trust: made
for another robot, no valid task file, primitives it does not have, or an event map that
does not match the task's edges.
"""

from __future__ import annotations

from contactflow.abstraction.concrete import check_params
from contactflow.abstraction.events import AbstractEvent
from contactflow.abstraction.messages import EdgeEvents, Estd
from contactflow.abstraction.profiles import RobotProfile
from contactflow.abstraction.translator import Translation
from contactflow.nodes.status import Event
from contactflow.nodes.taskfile import parse_tasks
from contactflow.nodes.taskgraph import TaskError, Trigger, validate


class EstdError(ValueError):
    """A received ESTD is refused; ``reasons`` say why."""

    def __init__(self, where: str, reasons: list[str]) -> None:
        self.reasons = reasons
        super().__init__(f"{where}: ESTD refused:\n  " + "\n  ".join(reasons))


def estd_message(tr: Translation) -> Estd:
    """The wire form of a translation: its task file and its edges' abstract events."""
    events = [EdgeEvents(edge=edge, event=str(ab), groups=[sorted(str(t) for t in g) for g in groups])
              for edge, mapped in tr.labels.items() for ab, groups in mapped.items()]
    return Estd(robot=tr.robot, task=tr.to_yaml(), events=events)


def _trigger(text: str) -> Trigger:
    source, _, label = text.rpartition(".")
    return Trigger(Event(label), source)


def received(msg: Estd, profile: RobotProfile, where: str) -> Translation:
    """Check an ESTD sent to ``profile``'s robot; the translation to run, or :class:`EstdError`."""
    if msg.robot != profile.name:
        raise EstdError(where, [f"it was translated for {msg.robot!r}, not for {profile.name!r}"])
    try:
        tasks, main = parse_tasks(msg.task, f"{where} estd")
        if len(tasks) != 1:
            raise TaskError([f"{where}: an ESTD is one task, got {sorted(tasks)}"])
        estd = tasks[main]
        validate(estd, primitives=profile.capabilities)
    except TaskError as exc:
        raise EstdError(where, exc.issues) from None
    issues = check_params(estd)
    if issues:
        raise EstdError(where, issues)
    edges = {e.id: e for e in estd.edges}
    reasons: list[str] = []
    labels: dict[str, dict[AbstractEvent, tuple[frozenset[Trigger], ...]]] = {e: {} for e in edges}
    for i, m in enumerate(msg.events):
        what = f"events[{i}] (edge {m.edge!r}, {m.event!r})"
        if m.edge not in edges:
            reasons.append(f"{what}: the task has no such edge")
            continue
        try:
            ab = AbstractEvent(m.event)
            groups = tuple(frozenset(_trigger(t) for t in g) for g in m.groups)
        except ValueError as exc:
            reasons.append(f"{what}: {exc}")
            continue
        if not groups or any(not g for g in groups):
            reasons.append(f"{what}: maps to no concrete label")
            continue
        on_edge = {t for g in edges[m.edge].when for t in g}
        stray = sorted(str(t) for g in groups for t in g if t not in on_edge)
        if stray:
            reasons.append(f"{what}: labels {stray} are not on that edge")
            continue
        labels[m.edge][ab] = groups
    if reasons:
        raise EstdError(where, reasons)
    return Translation(atd=None, robot=profile.name, estd=estd,
                       states={nid: n.label or nid for nid, n in estd.nodes.items()},
                       transitions={e.id: e.label or e.id for e in estd.edges}, labels=labels,
                       node_ids={n.label or nid: nid for nid, n in estd.nodes.items()})
