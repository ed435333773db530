"""The translator (thesis §7.2.2): ATD -> embodiment-specific task description (ESTD).

The translator is the same for every robot; only the :class:`Factory` differs. It maps each
abstract state to one ESTD node and each transition to one ESTD edge, and lets each
abstract event label become one or more concrete labels (the three rules of §7.2.2), then
checks the rules and validates the ESTD against the robot's primitive types. The ESTD is a
plain :class:`~contactflow.nodes.taskgraph.TaskGraph` that the task engine runs as is;
node and edge labels carry the ATD's names, so progress and failures read in ATD terms.
When a factory cannot map something, every reason is collected and reported at once.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass, field

from contactflow.abstraction.atd import Atd
from contactflow.abstraction.concrete import check_params
from contactflow.abstraction.events import AbstractEvent
from contactflow.abstraction.factory import Factory, MappingRefused, PrimitiveChoice
from contactflow.abstraction.frames import to_world
from contactflow.abstraction.primitives import Terminal
from contactflow.nodes.status import Event
from contactflow.nodes.taskengine import Progress, ProgressKind
from contactflow.nodes.taskfile import dump_tasks
from contactflow.nodes.taskgraph import (
    Edge,
    Helper,
    Node,
    NodeKind,
    TaskError,
    TaskGraph,
    Trigger,
    validate,
)

_CONCRETE_TO_ABSTRACT = {
    Event.SUCCESS: AbstractEvent.SUCCESS,
    Event.GRASP_STABLE: AbstractEvent.GRASP_STABLE,
    Event.GRASP_LOST: AbstractEvent.GRASP_LOST,
    Event.TIMEOUT: AbstractEvent.TIMEOUT,
    Event.HARDWARE_FAILURE: AbstractEvent.HARDWARE_FAILURE,
    Event.ERROR: AbstractEvent.ERROR,
    Event.FAILURE: AbstractEvent.ERROR,
    Event.PREDICTION_MISMATCH: AbstractEvent.PREDICTION_MISMATCH,
}


class TranslationError(ValueError):
    """The ATD cannot be translated for ``robot``; ``reasons`` say why, per element."""

    def __init__(self, robot: str, reasons: list[str]) -> None:
        self.robot, self.reasons = robot, reasons
        super().__init__(f"{robot} cannot run this ATD:\n  " + "\n  ".join(reasons))


@dataclass(frozen=True, slots=True)
class AbstractProgress:
    """A progress report in the ATD's terms (state and transition names, abstract event)."""

    kind: ProgressKind
    run: str
    t: float
    state: str = ""
    transition: str = ""
    event: AbstractEvent | None = None
    concrete: Event | None = None
    detail: str = ""
    implicit: bool = False


@dataclass(frozen=True)
class Translation:
    """An ESTD with the book-keeping that traces it back to its ATD."""

    atd: Atd | None  # None when rebuilt from a received ESTD (abstraction/estd.py)
    robot: str
    estd: TaskGraph
    states: Mapping[str, str]  # ESTD node id -> ATD state name
    transitions: Mapping[str, str]  # ESTD edge id -> ATD transition name
    labels: Mapping[str, Mapping[AbstractEvent, tuple[frozenset[Trigger], ...]]]
    notes: tuple[str, ...] = ()
    node_ids: Mapping[str, str] = field(default_factory=dict)  # ATD state name -> node id

    def abstract(self, p: Progress) -> AbstractProgress:
        """Restate an engine progress report of this ESTD in ATD names and events."""
        state = self.states.get(p.node, p.label)
        transition = self.transitions.get(p.edge, "")
        abstract = _CONCRETE_TO_ABSTRACT.get(p.event) if p.event is not None else None
        if p.implicit:
            # a fault exit no transition declares (the ATD's "common edges", §7.2.1)
            transition = f"{state}!{abstract or AbstractEvent.ERROR}"

        if p.kind is ProgressKind.EDGE and p.edge in self.labels and p.event is not None:
            for ab, groups in self.labels[p.edge].items():
                if any(t.event == p.event for g in groups for t in g):
                    abstract = ab
                    break
        return AbstractProgress(kind=p.kind, run=p.run, t=p.t, state=state,
                                transition=transition, event=abstract, concrete=p.event,
                                detail=p.detail, implicit=p.implicit)

    def to_yaml(self) -> str:
        """The ESTD as a task file (what a broker sends to the robot)."""
        return dump_tasks({self.estd.name: self.estd})


def _ident(name: str, taken: set[str]) -> str:
    base = re.sub(r"[^A-Za-z0-9_]", "_", name.strip()) or "state"
    if not re.match(r"[A-Za-z_]", base):
        base = f"s_{base}"
    ident, n = base, 2
    while ident in taken:
        ident, n = f"{base}_{n}", n + 1
    taken.add(ident)
    return ident


def translate(atd: Atd, factory: Factory) -> Translation:
    """Translate ``atd`` for ``factory.robot``; raises :class:`TranslationError` with reasons."""
    robot = factory.robot.name
    atd = to_world(atd, factory.robot.task_frame)
    factory.begin(atd)
    reasons: list[str] = []
    notes: list[str] = []
    ids: dict[str, str] = {}
    taken: set[str] = set()
    for s in atd.states:
        ids[s.name] = _ident(s.name, taken)
    choices: dict[str, PrimitiveChoice] = {}
    for s in atd.states:
        if s.terminal:
            continue
        try:
            choices[s.name] = factory.node(s, atd)
            notes += [f"{s.where}: state {s.name!r}: {n}" for n in choices[s.name].notes]
        except MappingRefused as exc:
            reasons.append(f"{s.where}: state {s.name!r} ({s.type}): {exc.reason}")

    helpers: dict[str, dict[str, Helper]] = {name: {h.name: h for h in c.helpers}
                                             for name, c in choices.items()}
    timeouts: dict[str, float] = {}
    edges: list[Edge] = []
    edge_names: dict[str, str] = {}
    labels: dict[str, dict[AbstractEvent, tuple[frozenset[Trigger], ...]]] = {}
    edge_taken: set[str] = set()
    for t in atd.transitions:
        eid = _ident(t.name if "->" not in t.name else f"{ids[t.origin]}__{ids[t.destination]}",
                     edge_taken)
        if t.origin not in choices:
            continue  # its state was refused; the reason is already listed
        groups: list[frozenset[Trigger]] = []
        mapped: dict[AbstractEvent, tuple[frozenset[Trigger], ...]] = {}
        for ev in t.events:
            try:
                choice = factory.event(ev, atd.state(t.origin), choices[t.origin], atd)
            except MappingRefused as exc:
                reasons.append(f"{ev.where}: transition {t.name!r}: event {ev.event}: {exc.reason}")
                continue
            if not choice.groups or any(not g for g in choice.groups):
                reasons.append(f"{ev.where}: transition {t.name!r}: the factory mapped {ev.event} "
                               "to no concrete label (rule 3)")
                continue
            mapped[ev.event] = choice.groups
            groups += choice.groups
            notes += [f"{ev.where}: transition {t.name!r}: {n}" for n in choice.notes]
            for h in choice.helpers:
                known = helpers[t.origin].get(h.name)
                if known is not None and known != h:
                    reasons.append(f"{ev.where}: transition {t.name!r}: helper {h.name!r} is "
                                   "configured twice differently")
                helpers[t.origin][h.name] = h
            if choice.timeout is not None:
                timeouts[t.origin] = min(timeouts.get(t.origin, choice.timeout), choice.timeout)
        edges.append(Edge(eid, ids[t.origin], ids[t.destination], tuple(groups), label=t.name,
                          where=t.where))
        edge_names[eid] = t.name
        labels[eid] = mapped
    if reasons:
        raise TranslationError(robot, reasons)

    nodes: dict[str, Node] = {}
    for s in atd.states:
        nid = ids[s.name]
        if s.terminal:
            kind = NodeKind.SUCCESS if s.type is Terminal.SUCCESS else NodeKind.FAILURE
            nodes[nid] = Node(nid, kind, label=s.name, where=s.where)
            continue
        c = choices[s.name]
        timeout = min(x for x in (c.timeout, timeouts.get(s.name)) if x is not None) \
            if (c.timeout is not None or s.name in timeouts) else None
        nodes[nid] = Node(nid, NodeKind.PRIMITIVE, type=c.type, params=c.node_params(),
                          helpers=tuple(helpers[s.name].values()), timeout=timeout,
                          label=s.name, where=s.where)
    estd = TaskGraph(
        name=_ident(atd.name, set()), nodes=nodes, edges=tuple(edges), start=ids[atd.start],
        params=factory.task_params(atd), timeout=factory.default_timeout, label=atd.name,
        where=atd.where,
    )
    # the three rules of §7.2.2, checked on the result whatever the factory did
    if len(estd.nodes) != len(atd.states):
        reasons.append(f"rule 1 broken: {len(atd.states)} ATD states gave {len(estd.nodes)} nodes")
    if len(estd.edges) != len(atd.transitions):
        reasons.append(f"rule 2 broken: {len(atd.transitions)} transitions gave {len(estd.edges)} edges")
    for t, e in zip(atd.transitions, estd.edges, strict=False):
        missing = {ev.event for ev in t.events} - set(labels[e.id])
        if missing:
            reasons.append(f"rule 3 broken: transition {t.name!r} lost labels {sorted(missing)}")
    try:
        validate(estd, primitives=factory.robot.capabilities)
    except TaskError as exc:
        reasons += [f"ESTD invalid: {i}" for i in exc.issues]
    reasons += [f"ESTD invalid: {i}" for i in check_params(estd)]
    if reasons:
        raise TranslationError(robot, reasons)
    return Translation(atd=atd, robot=robot, estd=estd,
                       states={ids[s.name]: s.name for s in atd.states},
                       transitions=edge_names, labels=labels, notes=tuple(notes),
                       node_ids=dict(ids))
