"""YAML task files: load (keeping file:line of every element), validate and dump task graphs.

Layout (``tasks`` holds one or more tasks; ``main`` names the one to run)::

    main: pick
    tasks:
      pick:
        params: {object: null, approach: [0, 0, -1]}   # null: the plan must bind it
        timeout: 30                                     # s, default node timeout
        start: detect                                   # default: the first node
        nodes:
          detect: {primitive: detect_objects, params: {region: table}}
          grasp:
            primitive: robust_grasp
            params: {approach: "${detect.approach_vector}"}
            helpers: {watch: {primitive: wait_event, params: {event: grasp_lost}}}
          place_it: {task: place, params: {target: "${params.target}"}}
          look_and_pick: {parallel: [{name: track, task: track}, {name: pick, task: pick}],
                          until: any}
          done: {terminal: success}
          failed: {terminal: failure, event: object_not_found}
        edges:
          - {from: detect, to: grasp, on: success}
          - {from: grasp, to: done, on: [success, watch.grasp_stable]}   # all of
          - {from: grasp, to: failed, on: [[failure, error]]}            # any of

A file may also hold a single task at its top level (``name`` defaults to the file stem).
"""

from __future__ import annotations

from collections.abc import Collection, Mapping
from pathlib import Path
from typing import Any

import yaml

from contactflow.nodes.status import Event
from contactflow.nodes.taskgraph import (
    REGISTERED,
    REQUIRED,
    Edge,
    Helper,
    Node,
    NodeKind,
    TaskError,
    TaskGraph,
    Trigger,
    Until,
    Where,
    validate_library,
)

_NODE_KINDS = ("primitive", "task", "parallel", "terminal")
_NODE_KEYS = frozenset({*_NODE_KINDS, "params", "helpers", "timeout", "event", "until", "label"})
_TASK_KEYS = frozenset({"name", "label", "params", "timeout", "start", "fault", "nodes", "edges"})
_EDGE_KEYS = frozenset({"from", "to", "on", "name", "label"})
MAX_YAML_NODES = 100_000
"""A task file or ATD that expands (through its aliases) to more YAML nodes than this is refused."""


def _bounded(root: yaml.Node, file: str, what: str) -> None:
    """Refuse a document whose aliases expand it past :data:`MAX_YAML_NODES` (a kilobyte of nested aliases
    can stand for billions of nodes); the walk stops at the limit, so it costs no more than that."""
    stack, seen = [root], 0
    while stack:
        node = stack.pop()
        seen += 1
        if seen > MAX_YAML_NODES:
            raise TaskError([f"{file}: refused: the {what} expands to more than {MAX_YAML_NODES} YAML nodes "
                             f"(nested aliases)"])
        if isinstance(node, yaml.MappingNode):
            stack.extend(n for pair in node.value for n in pair)
        elif isinstance(node, yaml.SequenceNode):
            stack.extend(node.value)


class LocatedYaml:
    """A composed YAML node with its constructed value and its place in the file."""

    def __init__(self, node: yaml.Node, loader: yaml.SafeLoader, file: str,
                 key: yaml.Node | None = None) -> None:
        self.node, self._loader, self.file, self.key = node, loader, file, key

    @classmethod
    def compose(cls, text: str, file: str, what: str) -> LocatedYaml:
        """The document's root node; :class:`TaskError` naming the line when it is no YAML or empty."""
        loader: yaml.SafeLoader | None = None
        try:
            loader = yaml.SafeLoader(text)  # its reader already refuses control characters
            root = loader.get_single_node()
        except yaml.YAMLError as exc:
            mark = getattr(exc, "problem_mark", None)
            line = f":{mark.line + 1}" if mark is not None else ""
            raise TaskError([f"{file}{line}: not valid YAML: {getattr(exc, 'problem', None) or exc}"]) from None
        finally:
            if loader is not None:
                loader.dispose()
        if root is None:
            raise TaskError([f"{file}: empty {what}"])
        _bounded(root, file, what)
        return cls(root, loader, file)

    @property
    def where(self) -> Where:
        """The line of the element's key when it has one (a block value starts below it)."""
        mark = (self.key or self.node).start_mark
        return Where(self.file, mark.line + 1)

    def fail(self, msg: str) -> TaskError:
        return TaskError([f"{self.where}: {msg}"])

    @property
    def value(self) -> Any:
        return self._loader.construct_object(self.node, deep=True)

    def items(self, what: str) -> list[tuple[str, LocatedYaml]]:
        if not isinstance(self.node, yaml.MappingNode):
            raise self.fail(f"{what} must be a mapping")
        out: list[tuple[str, LocatedYaml]] = []
        seen: set[str] = set()
        for k, v in self.node.value:
            # raw key text: YAML 1.1 would read the edge key ``on`` as a boolean
            key = k.value if isinstance(k, yaml.ScalarNode) else None
            if not isinstance(key, str):
                raise TaskError([f"{Where(self.file, k.start_mark.line + 1)}: {what}: keys must "
                                 f"be plain strings"])
            if key in seen:
                raise TaskError([f"{Where(self.file, k.start_mark.line + 1)}: {what}: duplicate "
                                 f"key {key!r}"])
            seen.add(key)
            out.append((key, LocatedYaml(v, self._loader, self.file, k)))
        return out

    def mapping(self, what: str, allowed: Collection[str]) -> dict[str, LocatedYaml]:
        out = dict(self.items(what))
        for k, d in out.items():
            if k not in allowed:
                raise TaskError([f"{d.where}: {what}: unknown key {k!r} (allowed: "
                                 f"{', '.join(sorted(allowed))})"])
        return out

    def seq(self, what: str) -> list[LocatedYaml]:
        if not isinstance(self.node, yaml.SequenceNode):
            raise self.fail(f"{what} must be a list")
        return [LocatedYaml(v, self._loader, self.file) for v in self.node.value]

    def text(self, what: str) -> str:
        v = self.value
        if not isinstance(v, str) or not v:
            raise self.fail(f"{what} must be a non-empty string, got {v!r}")
        return v

    def number(self, what: str) -> float:
        v = self.value
        if isinstance(v, bool) or not isinstance(v, int | float):
            raise self.fail(f"{what} must be a number, got {v!r}")
        return float(v)


def _event(doc: LocatedYaml, text: str, what: str) -> Event:
    try:
        return Event(text)
    except ValueError:
        raise doc.fail(f"{what}: unknown event {text!r} (known: "
                       f"{', '.join(e.value for e in Event)})") from None


def _trigger(doc: LocatedYaml, what: str) -> Trigger:
    text = doc.text(what)
    source, _, name = text.rpartition(".")
    return Trigger(_event(doc, name, what), source)


def _when(doc: LocatedYaml, what: str) -> tuple[frozenset[Trigger], ...]:
    if isinstance(doc.node, yaml.ScalarNode):
        return (frozenset({_trigger(doc, what)}),)
    groups: list[frozenset[Trigger]] = []
    for item in doc.seq(what):
        if isinstance(item.node, yaml.SequenceNode):
            groups.append(frozenset(_trigger(t, what) for t in item.seq(what)))
        else:
            groups.append(frozenset({_trigger(item, what)}))
    if not groups:
        raise doc.fail(f"{what}: no event label")
    return tuple(groups)


def _params(doc: LocatedYaml | None, what: str) -> dict[str, Any]:
    if doc is None:
        return {}
    return {k: d.value for k, d in doc.items(what)}


def _helpers(doc: LocatedYaml | None, what: str) -> tuple[Helper, ...]:
    if doc is None:
        return ()
    out = []
    for name, d in doc.items(what):
        spec = d.mapping(f"{what}.{name}", {"primitive", "params"})
        if "primitive" not in spec:
            raise d.fail(f"{what}.{name}: needs 'primitive'")
        out.append(Helper(name, spec["primitive"].text(f"{what}.{name}.primitive"),
                          _params(spec.get("params"), f"{what}.{name}.params"), d.where))
    return tuple(out)


def _node(node_id: str, doc: LocatedYaml, what: str) -> Node:
    spec = doc.mapping(what, _NODE_KEYS)
    kinds = [k for k in _NODE_KINDS if k in spec]
    if len(kinds) != 1:
        raise doc.fail(f"{what}: give exactly one of {', '.join(_NODE_KINDS)} (got {kinds or 'none'})")
    kind_key = kinds[0]
    timeout = spec["timeout"].number(f"{what}.timeout") if "timeout" in spec else None
    common: dict[str, Any] = {
        "id": node_id, "where": doc.where, "timeout": timeout,
        "params": _params(spec.get("params"), f"{what}.params"),
        "helpers": _helpers(spec.get("helpers"), f"{what}.helpers"),
        "label": spec["label"].text(f"{what}.label") if "label" in spec else "",
    }
    if "event" in spec and kind_key != "terminal":
        raise spec["event"].fail(f"{what}: only terminals carry an 'event'")
    if "until" in spec and kind_key != "parallel":
        raise spec["until"].fail(f"{what}: only parallel nodes carry 'until'")
    if kind_key == "primitive":
        return Node(kind=NodeKind.PRIMITIVE, type=spec["primitive"].text(f"{what}.primitive"), **common)
    if kind_key == "task":
        return Node(kind=NodeKind.TASK, type=spec["task"].text(f"{what}.task"), **common)
    if kind_key == "terminal":
        term = spec["terminal"].text(f"{what}.terminal")
        if term not in ("success", "failure"):
            raise spec["terminal"].fail(f"{what}.terminal must be success or failure, got {term!r}")
        ev = _event(spec["event"], spec["event"].text(f"{what}.event"), f"{what}.event") \
            if "event" in spec else None
        return Node(kind=NodeKind(term), event=ev, **common)
    branches = []
    for i, b in enumerate(spec["parallel"].seq(f"{what}.parallel")):
        bspec = b.mapping(f"{what}.parallel[{i}]", {"name", "primitive", "task", "params", "timeout"})
        if "name" not in bspec:
            raise b.fail(f"{what}.parallel[{i}]: needs a 'name'")
        branches.append(_node(bspec["name"].text(f"{what}.parallel[{i}].name"), _strip_name(b),
                              f"{what}.parallel[{i}]"))
    until_txt = spec["until"].text(f"{what}.until") if "until" in spec else "any"
    if until_txt not in ("any", "all"):
        raise spec["until"].fail(f"{what}.until must be any or all, got {until_txt!r}")
    return Node(kind=NodeKind.PARALLEL, branches=tuple(branches), until=Until(until_txt), **common)


def _strip_name(doc: LocatedYaml) -> LocatedYaml:
    node = doc.node
    kept = [(k, v) for k, v in node.value if getattr(k, "value", None) != "name"]
    return LocatedYaml(yaml.MappingNode(node.tag, kept, node.start_mark, node.end_mark), doc._loader,
                doc.file, doc.key)


def _task(name: str, doc: LocatedYaml) -> TaskGraph:
    what = f"task {name!r}"
    spec = doc.mapping(what, _TASK_KEYS)
    if "nodes" not in spec:
        raise doc.fail(f"{what}: needs 'nodes'")
    nodes: dict[str, Node] = {}
    for node_id, nd in spec["nodes"].items(f"{what}.nodes"):
        nodes[node_id] = _node(node_id, nd, f"{what}.nodes.{node_id}")
    edges: list[Edge] = []
    for i, ed in enumerate(spec["edges"].seq(f"{what}.edges") if "edges" in spec else []):
        ew = f"{what}.edges[{i}]"
        es = ed.mapping(ew, _EDGE_KEYS)
        for key in ("from", "to", "on"):
            if key not in es:
                raise ed.fail(f"{ew}: needs '{key}'")
        origin, dest = es["from"].text(f"{ew}.from"), es["to"].text(f"{ew}.to")
        eid = es["name"].text(f"{ew}.name") if "name" in es else f"{origin}->{dest}#{i}"
        edges.append(Edge(eid, origin, dest, _when(es["on"], f"{ew}.on"),
                          label=es["label"].text(f"{ew}.label") if "label" in es else "",
                          where=ed.where))
    params: dict[str, Any] = {}
    if "params" in spec:
        for k, v in spec["params"].items(f"{what}.params"):
            val = v.value
            params[k] = REQUIRED if val is None else val
    first = next(iter(nodes), "")
    return TaskGraph(
        name=spec["name"].text(f"{what}.name") if "name" in spec else name,
        nodes=nodes, edges=tuple(edges),
        start=spec["start"].text(f"{what}.start") if "start" in spec else first,
        params=params,
        timeout=spec["timeout"].number(f"{what}.timeout") if "timeout" in spec else 120.0,
        fault=spec["fault"].text(f"{what}.fault") if "fault" in spec else "",
        label=spec["label"].text(f"{what}.label") if "label" in spec else "",
        where=doc.where,
    )


def parse_tasks(text: str, file: str = "<memory>") -> tuple[dict[str, TaskGraph], str]:
    """Parse (without validating) a task file; returns the tasks and the main task's name."""
    doc = LocatedYaml.compose(text, file, "task file")
    top = dict(doc.items("task file"))
    if "tasks" in top:
        extra = sorted(set(top) - {"tasks", "main"})
        if extra:
            raise top[extra[0]].fail(f"task file: unknown key {extra[0]!r} (allowed: tasks, main)")
        tasks = {name: _task(name, d) for name, d in top["tasks"].items("tasks")}
        if not tasks:
            raise top["tasks"].fail("task file has no tasks")
        main = top["main"].text("main") if "main" in top else next(iter(tasks))
        if main not in tasks:
            raise top["main"].fail(f"main task {main!r} is not defined (tasks: {sorted(tasks)})")
        return tasks, main
    name = Path(file).stem if file != "<memory>" else "task"
    task = _task(name, doc)
    return {task.name: task}, task.name


def load_tasks(source: str | Path, text: str | None = None,
               primitives: Collection[str] | None = REGISTERED) -> tuple[dict[str, TaskGraph], str]:
    """Load and validate a task file (``text`` given: ``source`` only names it)."""
    file = str(source)
    if text is None:
        try:
            text = Path(source).read_text(encoding="utf-8")
        except OSError as exc:
            raise TaskError([f"{file}: cannot read task file: {exc.strerror}"]) from None
    tasks, main = parse_tasks(text, file)
    validate_library(tasks, primitives)
    return tasks, main


# -- dumping ---------------------------------------------------------------------------------
def _plain(v: Any) -> Any:
    if v is REQUIRED:
        return None
    if isinstance(v, Mapping):
        return {str(k): _plain(x) for k, x in v.items()}
    if isinstance(v, list | tuple):
        return [_plain(x) for x in v]
    if isinstance(v, str):
        return str(v)
    return v


def _node_dict(n: Node) -> dict[str, Any]:
    d: dict[str, Any] = {}
    if n.kind is NodeKind.PRIMITIVE:
        d["primitive"] = n.type
    elif n.kind is NodeKind.TASK:
        d["task"] = n.type
    elif n.kind is NodeKind.PARALLEL:
        d["parallel"] = [{"name": b.id, **_node_dict(b)} for b in n.branches]
        d["until"] = str(n.until)
    else:
        d["terminal"] = str(n.kind)
        if n.event is not None:
            d["event"] = str(n.event)
    if n.params:
        d["params"] = _plain(n.params)
    if n.helpers:
        d["helpers"] = {h.name: {"primitive": h.type, **({"params": _plain(h.params)} if h.params else {})}
                        for h in n.helpers}
    if n.timeout is not None:
        d["timeout"] = n.timeout
    if n.label:
        d["label"] = n.label
    return d


def _trigger_text(t: Trigger) -> str:
    return f"{t.source}.{t.event}" if t.source else str(t.event)


def task_dict(task: TaskGraph) -> dict[str, Any]:
    """A task as the plain mapping this module loads."""
    d: dict[str, Any] = {}
    if task.label:
        d["label"] = task.label
    if task.params:
        d["params"] = _plain(task.params)
    d["timeout"] = task.timeout
    d["start"] = task.start
    if task.fault:
        d["fault"] = task.fault
    d["nodes"] = {k: _node_dict(n) for k, n in task.nodes.items()}
    d["edges"] = []
    for e in task.edges:
        on = [sorted(_trigger_text(t) for t in g) if len(g) > 1 else _trigger_text(next(iter(g)))
              for g in e.when]
        ed: dict[str, Any] = {"name": e.id, "from": e.origin, "to": e.dest, "on": on}
        if e.label:
            ed["label"] = e.label
        d["edges"].append(ed)
    return d


def dump_tasks(tasks: Mapping[str, TaskGraph], main: str | None = None) -> str:
    """YAML text of a task library (loads back with :func:`load_tasks`)."""
    doc = {"main": main or next(iter(tasks)), "tasks": {k: task_dict(t) for k, t in tasks.items()}}
    return yaml.safe_dump(doc, sort_keys=False, allow_unicode=True)
