"""Task graphs (thesis §3.2): cyclic, directed, connected, labelled multigraphs of primitives.

A :class:`TaskGraph` has nodes that run one registered primitive type (plus helper
primitives such as event detectors), a nested task, several branches in parallel, or that
end the task (success / failure terminals). Edges are labelled by :class:`Event` conditions
and several edges may join the same pair of nodes. A *plan* is a task whose declared
parameters are bound (:func:`bind_plan`); node parameters may also refer to results of
other nodes with ``${node.key}``, resolved when the node is entered.

Every node has error and timeout exits: faults (failure, error, timeout, hardware failure)
that no edge of the node names lead to the task's fault terminal. :func:`validate` refuses
dangling edges, unknown primitive types or events, unreachable nodes, dead ends and graphs
without a terminal, naming the file and line of the offending element.
"""

from __future__ import annotations

import re
from collections.abc import Collection, Iterable, Mapping
from dataclasses import dataclass, field, replace
from enum import StrEnum
from typing import Any

from contactflow.nodes.status import Event


class _Registered:
    """The primitive types of the module registry (``contactflow.nodes.registry``), looked up when first needed."""

    def __repr__(self) -> str:
        return "REGISTERED"


REGISTERED: Any = _Registered()
"""Default of ``primitives``: the registered primitive types; helpers may also be registered services
(event sources, thesis §6.1.2). None: any type."""


def _known_types(primitives: Collection[str] | None) -> tuple[Collection[str] | None, Collection[str] | None]:
    """(types a node may run, types a helper may run)."""
    if primitives is REGISTERED:
        from contactflow.nodes.module import Layer
        from contactflow.nodes.registry import LayerTypes

        return LayerTypes(Layer.PRIMITIVE), LayerTypes(Layer.PRIMITIVE, Layer.SERVICE)
    return primitives, primitives


FAULTS = frozenset({Event.FAILURE, Event.ERROR, Event.TIMEOUT, Event.HARDWARE_FAILURE})
"""Events that end a node through its implicit fault exit when no edge names them."""

FINAL = FAULTS | {Event.SUCCESS}
"""Events with which a primitive (or a parallel branch) finishes."""

DEFAULT_TIMEOUT = 120.0
"""s, node timeout when neither the node nor its task sets one."""

ANY_SOURCE = "*"
"""Trigger source matching the node's primitive and all of its helpers."""

_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_\-]*$")
_REF = re.compile(r"\$\{([^}]*)\}")


@dataclass(frozen=True, slots=True)
class Where:
    """A place in a task source (file and 1-based line), for error messages."""

    file: str = "<memory>"
    line: int = 0

    def __str__(self) -> str:
        return f"{self.file}:{self.line}" if self.line else self.file


class TaskError(ValueError):
    """A task is invalid; ``issues`` lists every problem as ``file:line: message``."""

    def __init__(self, issues: Iterable[str]) -> None:
        self.issues = list(issues)
        super().__init__("\n".join(self.issues))


class NodeKind(StrEnum):
    PRIMITIVE = "primitive"
    TASK = "task"
    PARALLEL = "parallel"
    SUCCESS = "success"
    FAILURE = "failure"

    @property
    def terminal(self) -> bool:
        return self in (NodeKind.SUCCESS, NodeKind.FAILURE)


class Until(StrEnum):
    """When a parallel node finishes: with its first finished branch, or when all have."""

    ANY = "any"
    ALL = "all"


@dataclass(frozen=True, slots=True)
class Trigger:
    """An event raised by the node's primitive (source ``""``), a helper, or any (``*``)."""

    event: Event
    source: str = ""

    def matches(self, source: str, event: Event) -> bool:
        return self.event == event and (self.source == ANY_SOURCE or self.source == source)

    def __str__(self) -> str:
        return f"{self.source}.{self.event}" if self.source else str(self.event)


@dataclass(frozen=True, slots=True)
class Edge:
    """A labelled edge. It fires when every group has seen at least one of its triggers.

    ``when`` is a conjunction of disjunctions: ``((success,), (watch.grasp_stable,))`` means
    "the primitive succeeded and the watcher saw a stable grasp", ``((error, failure),)``
    means "either". Triggers count from the moment the origin node was entered.
    """

    id: str
    origin: str
    dest: str
    when: tuple[frozenset[Trigger], ...]
    label: str = ""  # the caller's name (e.g. the ATD transition), for progress reports
    where: Where = field(default_factory=Where)

    def fires(self, seen: Collection[tuple[str, Event]]) -> bool:
        return all(any(t.matches(s, e) for t in group for s, e in seen) for group in self.when)

    def handles(self, source: str, event: Event) -> bool:
        """Whether some trigger of this edge waits for ``event`` from ``source``."""
        return any(t.matches(source, event) for group in self.when for t in group)

    @property
    def events(self) -> frozenset[Event]:
        return frozenset(t.event for group in self.when for t in group)


@dataclass(frozen=True, slots=True)
class Helper:
    """A primitive started and stopped with its node: an event detector or a companion."""

    name: str
    type: str
    params: Mapping[str, Any] = field(default_factory=dict)
    where: Where = field(default_factory=Where)


@dataclass(frozen=True, slots=True)
class Node:
    """One state of a task.

    ``type`` is the primitive type name (PRIMITIVE) or the nested task's name (TASK).
    ``branches`` are the parallel branches (PARALLEL; each a PRIMITIVE or TASK node).
    ``event`` of a terminal is what the task reports to its parent (default success or
    failure). ``timeout`` in s (None: the task's default).
    """

    id: str
    kind: NodeKind
    type: str = ""
    params: Mapping[str, Any] = field(default_factory=dict)
    helpers: tuple[Helper, ...] = ()
    branches: tuple[Node, ...] = ()
    until: Until = Until.ANY
    timeout: float | None = None
    event: Event | None = None
    label: str = ""
    where: Where = field(default_factory=Where)

    @property
    def name(self) -> str:
        return self.label or self.id

    def result_event(self) -> Event:
        if self.event is not None:
            return self.event
        return Event.SUCCESS if self.kind is NodeKind.SUCCESS else Event.FAILURE


_REQUIRED = object()


@dataclass(frozen=True, slots=True)
class TaskGraph:
    """A task: nodes, edges, the start node, declared parameters and default timeout.

    ``params`` maps each declared parameter to its default; :data:`REQUIRED` marks one that
    a plan must bind. ``fault`` names the terminal reached through implicit fault exits
    (default: the first failure terminal).
    """

    name: str
    nodes: Mapping[str, Node]
    edges: tuple[Edge, ...]
    start: str
    params: Mapping[str, Any] = field(default_factory=dict)
    timeout: float = DEFAULT_TIMEOUT
    fault: str = ""
    label: str = ""
    where: Where = field(default_factory=Where)

    def out_edges(self, node: str) -> list[Edge]:
        return [e for e in self.edges if e.origin == node]

    @property
    def fault_terminal(self) -> str:
        if self.fault:
            return self.fault
        for n in self.nodes.values():
            if n.kind is NodeKind.FAILURE:
                return n.id
        return ""

    def unbound(self) -> list[str]:
        return [k for k, v in self.params.items() if v is REQUIRED]

    def timeout_of(self, node: Node) -> float:
        return node.timeout if node.timeout is not None else self.timeout


REQUIRED: Any = _REQUIRED
"""Default of a task parameter that has none: the plan must bind it."""


# -- parameter references ------------------------------------------------------------------
def references(value: Any) -> list[str]:
    """Every ``${...}`` reference inside a parameter value (nested lists and mappings too)."""
    if isinstance(value, str):
        return [m.group(1).strip() for m in _REF.finditer(value)]
    if isinstance(value, Mapping):
        return [r for v in value.values() for r in references(v)]
    if isinstance(value, list | tuple):
        return [r for v in value for r in references(v)]
    return []


class Unbound(LookupError):
    """A ``${...}`` reference cannot be resolved yet."""


def _lookup(ref: str, params: Mapping[str, Any], results: Mapping[str, Mapping[str, Any]]) -> Any:
    head, _, rest = ref.partition(".")
    if not rest:
        raise Unbound(f"${{{ref}}}: expected ${{params.NAME}} or ${{NODE.KEY}}")
    if head == "params":
        scope: Any = params
    elif head in results:
        scope = results[head]
    else:
        raise Unbound(f"${{{ref}}}: node {head!r} has produced no results yet")
    for part in rest.split("."):
        if isinstance(scope, Mapping) and part in scope:
            scope = scope[part]
        elif isinstance(scope, list | tuple) and part.isdigit() and int(part) < len(scope):
            scope = scope[int(part)]
        else:
            raise Unbound(f"${{{ref}}}: no value {part!r}")
    if scope is REQUIRED:
        raise Unbound(f"${{{ref}}}: parameter is not bound")
    return scope


def resolve(value: Any, params: Mapping[str, Any], results: Mapping[str, Mapping[str, Any]],
            only_params: bool = False) -> Any:
    """Replace ``${...}`` references; a value that is exactly one reference keeps its type.

    With ``only_params`` node-result references are left in place (plan binding).
    """
    if isinstance(value, str):
        refs = list(_REF.finditer(value))
        if not refs:
            return value
        if only_params and not all(m.group(1).strip().startswith("params.") for m in refs):
            return value
        if len(refs) == 1 and refs[0].span() == (0, len(value)):
            return _lookup(refs[0].group(1).strip(), params, results)
        return _REF.sub(lambda m: str(_lookup(m.group(1).strip(), params, results)), value)
    if isinstance(value, Mapping):
        return {k: resolve(v, params, results, only_params) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [resolve(v, params, results, only_params) for v in value]
    return value


def bind_plan(task: TaskGraph, params: Mapping[str, Any] | None = None) -> TaskGraph:
    """A plan: ``task`` with its parameters bound (unknown or missing ones refused).

    ``${params.X}`` references are substituted; ``${NODE.KEY}`` stay for run time.
    """
    given = dict(params or {})
    unknown = sorted(set(given) - set(task.params))
    issues = [f"{task.where}: task {task.name!r} has no parameter {k!r} (declared: "
              f"{sorted(task.params)})" for k in unknown]
    bound = {**task.params, **given}
    issues += [f"{task.where}: task {task.name!r} needs parameter {k!r}"
               for k, v in bound.items() if v is REQUIRED]
    if issues:
        raise TaskError(issues)

    def bind_node(n: Node) -> Node:
        try:
            return replace(
                n,
                params=resolve(n.params, bound, {}, only_params=True),
                helpers=tuple(replace(h, params=resolve(h.params, bound, {}, only_params=True))
                              for h in n.helpers),
                branches=tuple(bind_node(b) for b in n.branches),
            )
        except Unbound as exc:
            raise TaskError([f"{n.where}: node {n.id!r}: {exc}"]) from None

    return replace(task, nodes={k: bind_node(n) for k, n in task.nodes.items()}, params=bound)


# -- validation ------------------------------------------------------------------------------
def _check_refs(task: TaskGraph, node: Node, value: Any, issues: list[str]) -> None:
    for ref in references(value):
        head, _, rest = ref.partition(".")
        if not rest:
            issues.append(f"{node.where}: node {node.id!r}: reference ${{{ref}}} must be "
                          "${params.NAME} or ${NODE.KEY}")
        elif head == "params":
            if rest.split(".")[0] not in task.params:
                issues.append(f"{node.where}: node {node.id!r}: ${{{ref}}} names an undeclared "
                              f"task parameter (declared: {sorted(task.params)})")
        elif head not in task.nodes:
            issues.append(f"{node.where}: node {node.id!r}: ${{{ref}}} names no node of task "
                          f"{task.name!r}")


def _check_runnable(task: TaskGraph, node: Node, primitives: Collection[str] | None,
                    tasks: Mapping[str, TaskGraph], issues: list[str],
                    watchers: Collection[str] | None) -> None:
    if node.kind is NodeKind.PRIMITIVE:
        if not node.type:
            issues.append(f"{node.where}: node {node.id!r} names no primitive type")
        elif primitives is not None and node.type not in primitives:
            issues.append(f"{node.where}: node {node.id!r}: unknown primitive type "
                          f"{node.type!r} (known: {', '.join(sorted(primitives))})")
    elif node.kind is NodeKind.TASK and node.type not in tasks:
        issues.append(f"{node.where}: node {node.id!r}: unknown task {node.type!r} "
                      f"(known: {', '.join(sorted(tasks)) or 'none'})")
    elif node.kind is NodeKind.PARALLEL:
        if len(node.branches) < 2:
            issues.append(f"{node.where}: parallel node {node.id!r} needs at least two branches")
        seen: set[str] = set()
        for b in node.branches:
            if b.kind not in (NodeKind.PRIMITIVE, NodeKind.TASK):
                issues.append(f"{b.where}: branch {b.id!r} of {node.id!r} must be a primitive "
                              "or a task")
            if b.id in seen:
                issues.append(f"{b.where}: duplicate branch name {b.id!r} in {node.id!r}")
            seen.add(b.id)
            _check_runnable(task, b, primitives, tasks, issues, watchers)
            _check_refs(task, b, b.params, issues)
    for h in node.helpers:
        if watchers is not None and h.type not in watchers:
            issues.append(f"{h.where}: helper {h.name!r} of node {node.id!r}: unknown primitive "
                          f"type {h.type!r}")
        _check_refs(task, node, h.params, issues)
    if node.timeout is not None and not node.timeout > 0:
        issues.append(f"{node.where}: node {node.id!r}: timeout must be > 0 s, got {node.timeout}")


def validate(task: TaskGraph, primitives: Collection[str] | None = REGISTERED,
             tasks: Mapping[str, TaskGraph] | None = None) -> None:
    """Raise :class:`TaskError` listing every problem of ``task`` (with file:line).

    ``primitives`` is the set of primitive types nodes and helpers may run (default: the
    registry's, see :data:`REGISTERED`; None: any); ``tasks`` the
    tasks that nested nodes may name (nesting must not be recursive).
    """
    primitives, watchers = _known_types(primitives)
    tasks = dict(tasks or {})
    issues: list[str] = []
    if not _NAME.match(task.name):
        issues.append(f"{task.where}: task name {task.name!r} is not an identifier")
    if not task.nodes:
        raise TaskError([f"{task.where}: task {task.name!r} has no nodes"])
    for key, node in task.nodes.items():
        if key != node.id:
            issues.append(f"{node.where}: node key {key!r} differs from its id {node.id!r}")
        if not _NAME.match(node.id):
            issues.append(f"{node.where}: node name {node.id!r} is not an identifier")
        _check_runnable(task, node, primitives, tasks, issues, watchers)
        _check_refs(task, node, node.params, issues)
        helper_names = [h.name for h in node.helpers]
        for h in node.helpers:
            if helper_names.count(h.name) > 1 or not _NAME.match(h.name):
                issues.append(f"{h.where}: helper name {h.name!r} of node {node.id!r} is "
                              "duplicated or not an identifier")
    if task.start not in task.nodes:
        issues.append(f"{task.where}: task {task.name!r}: start node {task.start!r} does not exist")
    if task.fault and (task.fault not in task.nodes or not task.nodes[task.fault].kind.terminal):
        issues.append(f"{task.where}: task {task.name!r}: fault node {task.fault!r} is not a "
                      "terminal of the task")
    terminals = [n for n in task.nodes.values() if n.kind.terminal]
    if not terminals:
        issues.append(f"{task.where}: task {task.name!r} has no terminal state (a node of kind "
                      "success or failure)")
    edge_ids: set[str] = set()
    for e in task.edges:
        if e.id in edge_ids:
            issues.append(f"{e.where}: duplicate edge name {e.id!r}")
        edge_ids.add(e.id)
        for end, what in ((e.origin, "origin"), (e.dest, "destination")):
            if end not in task.nodes:
                issues.append(f"{e.where}: edge {e.id!r}: dangling {what} {end!r} (no such node)")
        if e.origin in task.nodes:
            origin = task.nodes[e.origin]
            if origin.kind.terminal:
                issues.append(f"{e.where}: edge {e.id!r} leaves terminal state {e.origin!r}")
            known = {h.name for h in origin.helpers} | {b.id for b in origin.branches}
            for group in e.when:
                for t in group:
                    if t.source not in ("", ANY_SOURCE) and t.source not in known:
                        issues.append(f"{e.where}: edge {e.id!r}: trigger {t} names no helper "
                                      f"of node {e.origin!r} (helpers: {sorted(known)})")
        if not e.when or any(not g for g in e.when):
            issues.append(f"{e.where}: edge {e.id!r} has no event label")
        for group in e.when:
            for t in group:
                if not isinstance(t.event, Event):
                    issues.append(f"{e.where}: edge {e.id!r}: unknown event {t.event!r}")
    for node in task.nodes.values():
        if not node.kind.terminal and not task.out_edges(node.id):
            issues.append(f"{node.where}: node {node.id!r} is not terminal and has no outgoing "
                          "edge (dead end)")
    if task.start in task.nodes:
        adj: dict[str, set[str]] = {k: set() for k in task.nodes}
        for e in task.edges:
            if e.origin in adj and e.dest in adj:
                adj[e.origin].add(e.dest)
        fault = task.fault_terminal
        reach, todo = {task.start}, [task.start]
        while todo:
            for nxt in adj[todo.pop()] | ({fault} if fault else set()):
                if nxt not in reach:
                    reach.add(nxt)
                    todo.append(nxt)
        for node in task.nodes.values():
            if node.id not in reach:
                issues.append(f"{node.where}: node {node.id!r} is unreachable from start "
                              f"{task.start!r}")
        if terminals and not any(t.id in reach for t in terminals):
            issues.append(f"{task.where}: task {task.name!r}: no terminal state is reachable")
    issues += _nesting_cycles(task, tasks)
    if issues:
        raise TaskError(issues)


def _nested(node: Node) -> list[str]:
    out = [node.type] if node.kind is NodeKind.TASK else []
    return out + [t for b in node.branches for t in _nested(b)]


def _nesting_cycles(task: TaskGraph, tasks: Mapping[str, TaskGraph]) -> list[str]:
    lib = {**tasks, task.name: task}
    issues: list[str] = []

    def visit(name: str, chain: tuple[str, ...]) -> None:
        for node in lib[name].nodes.values():
            for sub in _nested(node):
                if sub in chain:
                    issues.append(f"{node.where}: task nesting is recursive: "
                                  f"{' -> '.join((*chain, sub))}")
                elif sub in lib:
                    visit(sub, (*chain, sub))

    visit(task.name, (task.name,))
    return sorted(set(issues))


def validate_library(tasks: Mapping[str, TaskGraph],
                     primitives: Collection[str] | None = REGISTERED) -> None:
    """Validate every task of a library; nested nodes may name any task in it."""
    issues: list[str] = []
    for t in tasks.values():
        try:
            validate(t, primitives, tasks)
        except TaskError as exc:
            issues += exc.issues
    if issues:
        raise TaskError(issues)
