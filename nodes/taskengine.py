"""Deterministic executor of task graphs (thesis §3.2, §6.1.4), driven by a primitive runner.

The engine owns no threads and does no I/O: :meth:`TaskEngine.tick` polls the
:class:`PrimitiveRunner` for events, checks node timeouts against the provided clock and
moves every running task along its edges. The same engine runs on fakes in tests
(:mod:`contactflow.nodes.testing_tasks`) and over zenoh in production, where the runner
starts and stops primitive modules with control messages and forwards their events.

Several tasks run at once (``launch`` more than one, or a parallel node, Fig. 6.3); nested
tasks run as child frames; node parameters are resolved on entry from the plan's bound
parameters and the results (event values) of nodes that already ran. Progress is reported
to callbacks with both the graph's ids and the caller's labels (e.g. the ATD names).
"""

from __future__ import annotations

import itertools
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any, Protocol

from contactflow.nodes.status import Event, Status
from contactflow.nodes.taskgraph import (
    FAULTS,
    FINAL,
    Node,
    NodeKind,
    TaskError,
    TaskGraph,
    Unbound,
    Until,
    bind_plan,
    resolve,
    validate,
)

MAX_TRANSITIONS_PER_TICK = 10_000
"""A cycle that never waits for a primitive would spin forever inside one tick."""


@dataclass(frozen=True, slots=True)
class RunnerEvent:
    """An event raised by a running primitive instance; ``values`` are its results."""

    instance: str
    event: Event
    values: Mapping[str, Any] = field(default_factory=dict)
    detail: str = ""


class PrimitiveRunner(Protocol):
    """What the engine needs from the world: start/stop primitive instances, read events."""

    def start(self, instance: str, type: str, params: Mapping[str, Any]) -> None:
        """Run a primitive of registered ``type`` as ``instance`` (unique per activation)."""
        ...

    def stop(self, instance: str) -> None:
        ...

    def poll(self) -> list[RunnerEvent]:
        """Every event raised since the last poll, oldest first."""
        ...


class ProgressKind(StrEnum):
    STARTED = "started"
    ENTERED = "entered"
    EVENT = "event"
    EDGE = "edge"
    FINISHED = "finished"


@dataclass(frozen=True, slots=True)
class Progress:
    """One progress report. ``path`` is the chain of task names and nested node ids.

    ``label``/``edge_label`` are the caller's names for the node and edge (the ATD state
    and transition names for a translated task); ``implicit`` marks a fault exit that no
    edge of the graph declares.
    """

    kind: ProgressKind
    run: str
    path: tuple[str, ...]
    t: float
    node: str = ""
    label: str = ""
    edge: str = ""
    edge_label: str = ""
    event: Event | None = None
    source: str = ""
    detail: str = ""
    implicit: bool = False


@dataclass(frozen=True, slots=True)
class RunResult:
    run: str
    status: Status
    event: Event
    terminal: str
    label: str
    t: float
    detail: str = ""


@dataclass(eq=False)
class _Frame:
    run: str
    path: tuple[str, ...]
    graph: TaskGraph
    parent: _Frame | None = None
    parent_source: str = ""
    current: str = ""
    entered: float = 0.0
    activation: int = 0
    timed_out: bool = False
    finished: bool = False
    seen: set[tuple[str, Event]] = field(default_factory=set)
    results: dict[str, dict[str, Any]] = field(default_factory=dict)
    instances: dict[str, str] = field(default_factory=dict)  # instance -> source
    children: dict[str, _Frame] = field(default_factory=dict)  # source -> frame
    branch_done: dict[str, Event] = field(default_factory=dict)
    ended: set[str] = field(default_factory=set)  # sources whose nested task has ended

    @property
    def node(self) -> Node:
        return self.graph.nodes[self.current]


@dataclass(frozen=True, slots=True)
class _Post:
    frame: _Frame
    activation: int
    source: str
    event: Event
    values: Mapping[str, Any]
    detail: str


class TaskEngine:
    """Runs plans on a :class:`PrimitiveRunner`; see the module docstring.

    ``library`` holds the tasks that nested nodes name; ``clock`` returns the current time
    in s (simulated or wall); ``on_progress`` callbacks receive every :class:`Progress`.
    """

    def __init__(self, runner: PrimitiveRunner, clock: Callable[[], float],
                 library: Mapping[str, TaskGraph] | None = None,
                 on_progress: Callable[[Progress], None] | None = None) -> None:
        self.runner = runner
        self.clock = clock
        self.library = dict(library or {})
        self._callbacks: list[Callable[[Progress], None]] = [on_progress] if on_progress else []
        self._routes: dict[str, tuple[_Frame, str]] = {}
        self._frames: list[_Frame] = []
        self._roots: dict[str, _Frame] = {}
        self._results: dict[str, RunResult] = {}
        self._queue: deque[_Post] = deque()
        self._ids = itertools.count(1)
        self._spent: dict[str, int] = {}  # transitions per run in the current tick
        self.history: deque[Progress] = deque(maxlen=10_000)
        self.stale_events = 0

    # -- public API ----------------------------------------------------------------------
    def subscribe(self, callback: Callable[[Progress], None]) -> None:
        self._callbacks.append(callback)

    def launch(self, task: TaskGraph, params: Mapping[str, Any] | None = None,
               run_id: str | None = None) -> str:
        """Validate ``task``, bind it into a plan and start it; returns the run id."""
        validate(task, primitives=None, tasks=self.library)
        plan = bind_plan(task, params)
        run = run_id or f"run{next(self._ids)}"
        if run in self._roots:
            raise ValueError(f"run id {run!r} is already in use")
        frame = _Frame(run=run, path=(plan.name,), graph=plan)
        self._roots[run] = frame
        self._frames.append(frame)
        self._report(ProgressKind.STARTED, frame, label=plan.label or plan.name)
        self._spent[run] = 0
        self._enter(frame, plan.start)
        self._drain()
        return run

    def tick(self) -> None:
        """Process runner events and timeouts; call this at the task layer's rate."""
        self._spent.clear()
        for ev in self.runner.poll():
            route = self._routes.get(ev.instance)
            if route is None:
                self.stale_events += 1
                continue
            frame, source = route
            self._queue.append(_Post(frame, frame.activation, source, ev.event, ev.values, ev.detail))
        self._drain()
        now = self.clock()
        for frame in list(self._frames):
            if frame.finished or frame.timed_out or frame.node.kind.terminal:
                continue
            limit = frame.graph.timeout_of(frame.node)
            if now - frame.entered >= limit:
                frame.timed_out = True
                self._queue.append(_Post(frame, frame.activation, "", Event.TIMEOUT, {},
                                         f"no exit after {limit:g} s"))
        self._drain()

    def cancel(self, run: str, detail: str = "cancelled") -> None:
        frame = self._roots[run]
        if frame.finished:
            return
        self._close(frame)
        self._finish_root(frame, Event.ERROR, "", detail)

    def done(self, run: str) -> bool:
        return run in self._results

    def result(self, run: str) -> RunResult | None:
        return self._results.get(run)

    @property
    def running(self) -> list[str]:
        return [r for r in self._roots if r not in self._results]

    def results_of(self, run: str) -> dict[str, dict[str, Any]]:
        """Node results (event values) of a run's top-level task, by node id."""
        return {k: dict(v) for k, v in self._roots[run].results.items()}

    def state(self, run: str) -> list[str]:
        """The active node path of a run: root node, then nested nodes, by label."""
        out: list[str] = []
        frame: _Frame | None = self._roots[run]
        while frame is not None and frame.current:
            out.append(frame.node.name)
            frame = next(iter(frame.children.values()), None) if frame.children else None
        return out

    # -- internals -----------------------------------------------------------------------
    def _report(self, kind: ProgressKind, frame: _Frame, **kw: Any) -> None:
        p = Progress(kind=kind, run=frame.run, path=frame.path, t=self.clock(), **kw)
        self.history.append(p)
        for cb in self._callbacks:
            cb(p)

    def _post(self, frame: _Frame, source: str, event: Event, detail: str = "",
              values: Mapping[str, Any] | None = None) -> None:
        self._queue.append(_Post(frame, frame.activation, source, event, values or {}, detail))

    def _drain(self) -> None:
        while self._queue:
            p = self._queue.popleft()
            if p.frame.finished or p.frame.activation != p.activation:
                continue
            self._deliver(p.frame, p.source, p.event, p.values, p.detail)

    def _instance(self, frame: _Frame, node: str, suffix: str = "") -> str:
        return f"{frame.run}/{'/'.join(frame.path[1:] + (node,))}{suffix}#{frame.activation}"

    def _enter(self, frame: _Frame, node_id: str, cause: Event | None = None) -> None:
        spent = self._spent[frame.run] = self._spent.get(frame.run, 0) + 1
        if spent > MAX_TRANSITIONS_PER_TICK:
            root = self._roots[frame.run]
            if root.finished:
                return
            self._close(root)
            self._finish_root(root, Event.ERROR, node_id,
                              f"more than {MAX_TRANSITIONS_PER_TICK} transitions in one tick: "
                              "a cycle never waits for a primitive")
            return
        frame.current, frame.entered = node_id, self.clock()
        frame.activation += 1
        frame.timed_out = False
        frame.seen = set()
        frame.branch_done = {}
        frame.ended = set()
        node = frame.node
        self._report(ProgressKind.ENTERED, frame, node=node.id, label=node.name, event=cause)
        if node.kind.terminal:
            self._finish(frame, node, cause)
            return
        try:
            for h in node.helpers:
                params = resolve(h.params, frame.graph.params, frame.results)
                self._start_primitive(frame, self._instance(frame, node.id, f".{h.name}"),
                                      h.name, h.type, params)
            if node.kind is NodeKind.PARALLEL:
                act = frame.activation
                for b in node.branches:
                    if frame.finished or frame.activation != act:
                        return  # the run was stopped while starting (transition budget)
                    self._start_activity(frame, b, b.id, f".{b.id}")
            else:
                self._start_activity(frame, node, "", "")
        except (Unbound, TaskError) as exc:
            self._post(frame, "", Event.ERROR, f"node {node.name!r}: {exc}")

    def _start_activity(self, frame: _Frame, node: Node, source: str, suffix: str) -> None:
        params = resolve(node.params, frame.graph.params, frame.results)
        if node.kind is NodeKind.PRIMITIVE:
            self._start_primitive(frame, self._instance(frame, frame.current, suffix), source,
                                  node.type, params)
            return
        if node.type not in self.library:
            raise TaskError([f"{node.where}: unknown task {node.type!r}"])
        sub = bind_plan(self.library[node.type], params)
        child = _Frame(run=frame.run, path=frame.path + ((source and f"{frame.current}.{source}")
                                                         or frame.current,),
                       graph=sub, parent=frame, parent_source=source)
        frame.children[source] = child
        self._frames.append(child)
        self._enter(child, sub.start)

    def _start_primitive(self, frame: _Frame, instance: str, source: str, type_: str,
                         params: Mapping[str, Any]) -> None:
        self._routes[instance] = (frame, source)
        frame.instances[instance] = source
        self.runner.start(instance, type_, params)

    def _stop_source(self, frame: _Frame, source: str) -> None:
        for inst, src in list(frame.instances.items()):
            if src == source:
                self.runner.stop(inst)
                self._routes.pop(inst, None)
                del frame.instances[inst]
        child = frame.children.pop(source, None)
        if child is not None:
            self._close(child)

    def _close(self, frame: _Frame) -> None:
        """Stop everything the frame's current node runs (recursively); keep the frame."""
        for inst in list(frame.instances):
            self.runner.stop(inst)
            self._routes.pop(inst, None)
        frame.instances.clear()
        for child in list(frame.children.values()):
            self._close(child)
            child.finished = True
            self._frames.remove(child)
        frame.children.clear()

    def _deliver(self, frame: _Frame, source: str, event: Event, values: Mapping[str, Any],
                 detail: str) -> None:
        node = frame.node
        self._report(ProgressKind.EVENT, frame, node=node.id, label=node.name, event=event,
                     source=source, detail=detail)
        if values:
            frame.results.setdefault(node.id, {}).update(values)
        if node.kind is NodeKind.PARALLEL and source and source in {b.id for b in node.branches}:
            frame.seen.add((source, event))
            final = event in FINAL or source in frame.ended
            if final and source not in frame.branch_done:
                frame.branch_done[source] = event
                self._stop_source(frame, source)
                outcome = self._parallel_outcome(node, frame.branch_done, source)
                if outcome is not None:
                    self._post(frame, "", outcome, f"branches: {dict(frame.branch_done)}")
            self._follow(frame, node, source, event, detail)
            return
        frame.seen.add((source, event))
        self._follow(frame, node, source, event, detail)

    @staticmethod
    def _parallel_outcome(node: Node, done: Mapping[str, Event], last: str) -> Event | None:
        if node.until is Until.ANY:
            return done[last]
        if len(done) < len(node.branches):
            return None
        for b in node.branches:
            if done[b.id] is not Event.SUCCESS:
                return done[b.id]
        return Event.SUCCESS

    def _follow(self, frame: _Frame, node: Node, source: str, event: Event, detail: str) -> None:
        edges = frame.graph.out_edges(node.id)
        for e in edges:
            if e.fires(frame.seen):
                self._take(frame, node, e.dest, event, edge=e.id, edge_label=e.label or e.id,
                           detail=detail)
                return
        own = source == "" or event in (Event.ERROR, Event.HARDWARE_FAILURE)
        if event in FAULTS and own and not any(e.handles(source, event) for e in edges):
            target = frame.graph.fault_terminal
            self._report(ProgressKind.EDGE, frame, node=node.id, label=node.name,
                         edge=f"{node.id}!{event}", edge_label=f"{node.name}!{event}",
                         event=event, detail=detail, implicit=True)
            self._close(frame)
            if target:
                self._enter(frame, target, cause=event)
            else:
                self._finish(frame, None, event, detail)

    def _take(self, frame: _Frame, node: Node, dest: str, event: Event, edge: str,
              edge_label: str, detail: str) -> None:
        self._report(ProgressKind.EDGE, frame, node=node.id, label=node.name, edge=edge,
                     edge_label=edge_label, event=event, detail=detail)
        self._close(frame)
        self._enter(frame, dest, cause=event)

    def _finish(self, frame: _Frame, terminal: Node | None, cause: Event | None,
                detail: str = "") -> None:
        if terminal is None:
            event = cause or Event.FAILURE
        elif terminal.event is not None:
            event = terminal.event
        elif terminal.kind is NodeKind.FAILURE and cause in FAULTS - {Event.FAILURE}:
            event = cause  # a timeout or hardware fault stays visible to the parent
        else:
            event = terminal.result_event()
        frame.finished = True
        term_id = terminal.id if terminal else ""
        label = terminal.name if terminal else ""
        if frame.parent is None:
            self._finish_root(frame, event, term_id, detail, label)
            return
        self._frames.remove(frame)
        parent, source = frame.parent, frame.parent_source
        parent.children.pop(source, None)
        parent.ended.add(source)
        exported: dict[str, Any] = {}
        for vals in frame.results.values():
            exported.update(vals)
        self._post(parent, source, event, f"task {frame.graph.name!r} ended in "
                   f"{label or event}" + (f": {detail}" if detail else ""), exported)

    def _finish_root(self, frame: _Frame, event: Event, terminal: str, detail: str,
                     label: str = "") -> None:
        frame.finished = True
        if frame in self._frames:
            self._frames.remove(frame)
        status = Status.SUCCESS if event is Event.SUCCESS else Status.FAILURE
        node = frame.graph.nodes.get(terminal)
        if node is not None and node.kind is NodeKind.SUCCESS:
            status = Status.SUCCESS
        res = RunResult(run=frame.run, status=status, event=event, terminal=terminal,
                        label=label or terminal, t=self.clock(), detail=detail)
        self._results[frame.run] = res
        self._report(ProgressKind.FINISHED, frame, node=terminal, label=res.label, event=event,
                     detail=detail)
