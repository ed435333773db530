"""Abstract Task Descriptions (thesis §7.2.1): parsing the XML of Fig. 7.2 and a YAML form.

An ATD is a cyclic, directed, connected, labelled multigraph of abstract primitives
(:class:`AbstractPrimitive`) joined by transitions labelled with abstract events
(:class:`AbstractEvent`), plus the target objects (location, mass, approach direction,
size) and environment obstacles. XML layout::

    <statemachine name="grasp_and_lift" start="approach">
      <object name="cup"><location>0.2 0.6 0.1</location><mass>0.3</mass>
        <approach>0 0 -1</approach><size>0.06 0.06 0.12</size></object>
      <object name="ball"><location>detect</location></object>   <!-- the robot finds it -->
      <environment><obstacle name="box"><position>..</position><size>..</size></obstacle>
      </environment>
      <state name="approach" type="move"><movement>free</movement>
        <hand_shape>open</hand_shape></state>
      <state name="lift" type="transport"><path><position>0.2 0.6 0.25</position></path></state>
      <state name="done" type="success"/>
      <transition origin="approach" destination="lift"><success/></transition>
    </statemachine>

XML is parsed with ``defusedxml`` and DTDs are refused outright, so entity expansion
("billion laughs") and external entities never reach the parser. Every error names the
file, line and element.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from xml.etree.ElementTree import Element, ParseError

import defusedxml
import defusedxml.ElementTree as DET

from contactflow.abstraction.events import AbstractEvent
from contactflow.abstraction.primitives import (
    COMMON_PROPERTIES,
    STATE_PROPERTIES,
    AbstractPrimitive,
    Movement,
    Terminal,
)
from contactflow.nodes.taskfile import LocatedYaml
from contactflow.nodes.taskgraph import TaskError, Where

MAX_ATD_BYTES = 1 << 20
"""An ATD larger than this is refused before parsing."""

Vec3 = tuple[float, float, float]


class AtdError(ValueError):
    """An ATD is refused; ``issues`` lists each problem as ``file:line: <element>: message``."""

    def __init__(self, issues: Iterable[str]) -> None:
        self.issues = list(issues)
        super().__init__("\n".join(self.issues))


@dataclass(frozen=True, slots=True)
class AtdObject:
    """A target object: location (m), mass (kg), approach direction (unit) and size (m).

    A location is given, left to the dispatch (``None``), or found by the robot's vision when
    the task starts (``detect``, written ``<location>detect</location>``).
    """

    name: str
    location: Vec3 | None = None
    mass: float | None = None
    approach: Vec3 | None = None
    size: Vec3 | None = None
    where: Where = field(default_factory=Where)
    detect: bool = False  # the robot detects the object's location when the task starts


DETECT = "detect"
"""The location of an object the robot detects: the ATD's word, and the ESTD parameter's value until bound."""


@dataclass(frozen=True, slots=True)
class Obstacle:
    """An axis-aligned box obstacle: centre position and full size (m)."""

    name: str
    position: Vec3
    size: Vec3
    where: Where = field(default_factory=Where)


@dataclass(frozen=True, slots=True)
class AtdState:
    """A node of the ATD: an abstract primitive with its properties, or a terminal."""

    name: str
    type: AbstractPrimitive | Terminal
    movement: Movement | None = None
    hand_shape: str = ""
    target: Vec3 | None = None
    target_object: str = ""  # the target is this object's location
    path: tuple[Vec3, ...] = ()
    object: str = ""  # the object the primitive acts on
    hand_opening: float | None = None  # m
    object_size: Vec3 | None = None  # m
    timeout: float | None = None  # s
    where: Where = field(default_factory=Where)

    @property
    def terminal(self) -> bool:
        return isinstance(self.type, Terminal)

    @property
    def goal(self) -> Vec3 | None:
        """Explicit end-effector goal: the target, else the last path position."""
        return self.target if self.target is not None else (self.path[-1] if self.path else None)


@dataclass(frozen=True, slots=True)
class AtdEvent:
    event: AbstractEvent
    after: float | None = None  # s, for timeout
    where: Where = field(default_factory=Where)


@dataclass(frozen=True, slots=True)
class AtdTransition:
    """An edge of the ATD; its events all have to hold for it to fire (§7.2.1)."""

    name: str
    origin: str
    destination: str
    events: tuple[AtdEvent, ...]
    where: Where = field(default_factory=Where)


@dataclass(frozen=True, slots=True)
class Atd:
    name: str
    states: tuple[AtdState, ...]
    transitions: tuple[AtdTransition, ...]
    objects: Mapping[str, AtdObject]
    obstacles: tuple[Obstacle, ...]
    start: str
    source: str = "<memory>"
    where: Where = field(default_factory=Where)

    def state(self, name: str) -> AtdState:
        for s in self.states:
            if s.name == name:
                return s
        raise KeyError(name)

    def object_of(self, state: AtdState) -> AtdObject | None:
        """The object a state acts on: its ``object`` property, else the only object."""
        if state.object:
            return self.objects.get(state.object)
        if len(self.objects) == 1:
            return next(iter(self.objects.values()))
        return None


# -- property values ----------------------------------------------------------------------------
def _numbers(text: Any, n: int | None, what: str) -> tuple[float, ...]:
    if isinstance(text, list | tuple):
        parts = list(text)
    else:
        parts = str(text if text is not None else "").replace(",", " ").split()
    try:
        vals = tuple(float(p) for p in parts if not isinstance(p, bool))
    except (TypeError, ValueError):
        raise ValueError(f"{what} must be numbers, got {text!r}") from None
    if len(vals) != len(parts) or (n is not None and len(vals) != n) or not vals:
        raise ValueError(f"{what} must be {n or 'some'} numbers, got {text!r}")
    if not all(math.isfinite(v) for v in vals):
        raise ValueError(f"{what} must be finite, got {text!r}")
    return vals


def _vec3(text: Any, what: str) -> Vec3:
    x, y, z = _numbers(text, 3, what)
    return (x, y, z)


def _positive(text: Any, what: str) -> float:
    (v,) = _numbers(text, 1, what)
    if v <= 0:
        raise ValueError(f"{what} must be > 0, got {v}")
    return v


def _unit(text: Any, what: str) -> Vec3:
    v = _vec3(text, what)
    norm = math.sqrt(sum(c * c for c in v))
    if norm < 1e-9:
        raise ValueError(f"{what} must be a non-zero direction")
    return (v[0] / norm, v[1] / norm, v[2] / norm)


def _state_type(text: str) -> AbstractPrimitive | Terminal:
    for enum in (AbstractPrimitive, Terminal):
        try:
            return enum(text)
        except ValueError:
            continue
    known = [p.value for p in AbstractPrimitive] + [t.value for t in Terminal]
    raise ValueError(f"unknown abstract primitive {text!r} (known: {', '.join(known)})")


def _event(text: str) -> AbstractEvent:
    try:
        return AbstractEvent(text)
    except ValueError:
        raise ValueError(f"unknown abstract event {text!r} (known: "
                         f"{', '.join(e.value for e in AbstractEvent)})") from None


def _allowed_properties(kind: AbstractPrimitive | Terminal) -> frozenset[str]:
    if isinstance(kind, Terminal):
        return frozenset()
    req, opt = STATE_PROPERTIES[kind]
    return req | opt | COMMON_PROPERTIES


def _state(name: str, kind: AbstractPrimitive | Terminal, props: Mapping[str, Any],
           where: Where) -> AtdState:
    """Build a state from its raw properties; ValueError names the offending property."""
    allowed = _allowed_properties(kind)
    for key in props:
        if key not in allowed:
            raise ValueError(f"property <{key}> is not accepted by a {kind} state (accepted: "
                             f"{', '.join(sorted(allowed)) or 'none'})")
    kw: dict[str, Any] = {}
    if "movement" in props:
        try:
            kw["movement"] = Movement(str(props["movement"]).strip())
        except ValueError:
            raise ValueError(f"movement {props['movement']!r} is not one of "
                             f"{', '.join(m.value for m in Movement)}") from None
    if "hand_shape" in props:
        kw["hand_shape"] = str(props["hand_shape"]).strip()
    if "object" in props:
        kw["object"] = str(props["object"]).strip()
    if "target" in props:
        t = props["target"]
        if isinstance(t, Mapping):
            kw["target_object"] = str(t.get("object", "")).strip()
            if not kw["target_object"]:
                raise ValueError("target needs three numbers or an object name")
        else:
            kw["target"] = _vec3(t, "target")
    if "path" in props:
        path = props["path"]
        if not isinstance(path, list | tuple) or not path:
            raise ValueError("path needs at least one position")
        kw["path"] = tuple(_vec3(p, f"path position {i + 1}") for i, p in enumerate(path))
    if "hand_opening" in props:
        kw["hand_opening"] = _positive(props["hand_opening"], "hand_opening")
    if "object_size" in props:
        kw["object_size"] = _vec3(props["object_size"], "object_size")
    if "timeout" in props:
        kw["timeout"] = _positive(props["timeout"], "timeout")
    return AtdState(name=name, type=kind, where=where, **kw)


def _object(name: str, props: Mapping[str, Any], where: Where) -> AtdObject:
    allowed = {"location", "mass", "approach", "size"}
    for key in props:
        if key not in allowed:
            raise ValueError(f"object property <{key}> is unknown (accepted: {', '.join(sorted(allowed))})")
    detect = isinstance(props.get("location"), str) and props["location"].strip() == DETECT
    return AtdObject(
        name=name, where=where, detect=detect,
        location=_vec3(props["location"], "location") if "location" in props and not detect else None,
        mass=_positive(props["mass"], "mass") if "mass" in props else None,
        approach=_unit(props["approach"], "approach") if "approach" in props else None,
        size=_vec3(props["size"], "size") if "size" in props else None,
    )


def _obstacle(name: str, props: Mapping[str, Any], where: Where) -> Obstacle:
    for key in ("position", "size"):
        if key not in props:
            raise ValueError(f"obstacle needs <{key}>")
    extra = set(props) - {"position", "size"}
    if extra:
        raise ValueError(f"obstacle property <{sorted(extra)[0]}> is unknown (accepted: position, size)")
    size = _vec3(props["size"], "size")
    if min(size) <= 0:
        raise ValueError(f"size must be > 0, got {size}")
    return Obstacle(name, _vec3(props["position"], "position"), size, where)


# -- XML -----------------------------------------------------------------------------------------
class _LineParser(DET.DefusedXMLParser):
    """defusedxml's parser, refusing any DTD, and remembering each element's line."""

    def __init__(self) -> None:
        super().__init__(forbid_dtd=True, forbid_entities=True, forbid_external=True)
        self.lines: dict[Element, int] = {}

    def _start(self, tag: str, attr_list: Any) -> Element:  # type: ignore[override]
        elem = super()._start(tag, attr_list)
        self.lines[elem] = self.parser.CurrentLineNumber
        return elem


class _Xml:
    def __init__(self, file: str, lines: Mapping[Element, int]) -> None:
        self.file, self.lines = file, lines
        self.issues: list[str] = []

    def where(self, e: Element) -> Where:
        return Where(self.file, self.lines.get(e, 0))

    def tag(self, e: Element) -> str:
        name = e.get("name")
        return f"<{e.tag} name={name!r}>" if name else f"<{e.tag}>"

    def err(self, e: Element, msg: str) -> None:
        self.issues.append(f"{self.where(e)}: {self.tag(e)}: {msg}")

    def attrs(self, e: Element, required: Iterable[str], optional: Iterable[str] = ()) -> bool:
        ok = True
        for a in required:
            if not (e.get(a) or "").strip():
                self.err(e, f"needs attribute {a!r}")
                ok = False
        extra = set(e.attrib) - set(required) - set(optional)
        if extra:
            self.err(e, f"unknown attribute {sorted(extra)[0]!r}")
            ok = False
        return ok

    def props(self, e: Element) -> dict[str, Any] | None:
        """Child elements as a property mapping (``path`` -> positions, ``target`` -> attrs)."""
        out: dict[str, Any] = {}
        for c in e:
            if c.tag in out:
                self.err(c, f"duplicate property in {self.tag(e)}")
                return None
            if c.tag == "path":
                positions = []
                for p in c:
                    if p.tag != "position":
                        self.err(p, "a <path> holds only <position> elements")
                        return None
                    positions.append(p.text or "")
                out["path"] = positions
            elif c.tag == "target" and c.get("object"):
                out["target"] = {"object": c.get("object")}
            else:
                if len(c):
                    self.err(c, "a property holds text, not elements")
                    return None
                out[c.tag] = (c.text or "").strip()
        return out


def _parse_xml(data: bytes, file: str) -> Atd:
    parser = _LineParser()
    try:
        parser.feed(data)
        root = parser.close()
    except defusedxml.DTDForbidden:
        raise AtdError([f"{file}: refused: the ATD declares a DTD; DTDs (and with them entity "
                        "expansion and external entities) are not allowed"]) from None
    except defusedxml.DefusedXmlException as exc:
        raise AtdError([f"{file}: refused unsafe XML: {exc}"]) from None
    except ParseError as exc:
        line, col = exc.position
        reason = str(exc).split(":")[0]
        raise AtdError([f"{file}:{line}: not well-formed XML (column {col}): {reason}"]) from None
    x = _Xml(file, parser.lines)
    if root.tag != "statemachine":
        raise AtdError([f"{x.where(root)}: <{root.tag}>: the root element must be <statemachine>"])
    x.attrs(root, (), ("name", "start"))
    states: list[AtdState] = []
    transitions: list[AtdTransition] = []
    objects: dict[str, AtdObject] = {}
    obstacles: list[Obstacle] = []

    def add_object(e: Element) -> None:
        if not x.attrs(e, ("name",)):
            return
        props = x.props(e)
        if props is None:
            return
        try:
            obj = _object(e.get("name", ""), props, x.where(e))
        except ValueError as exc:
            x.err(e, str(exc))
            return
        if obj.name in objects:
            x.err(e, f"object {obj.name!r} is defined twice")
        objects[obj.name] = obj

    for e in root:
        if e.tag == "state":
            if not x.attrs(e, ("name", "type")):
                continue
            props = x.props(e)
            if props is None:
                continue
            try:
                kind = _state_type(e.get("type", "").strip())
                allowed = _allowed_properties(kind)
                bad = [c for c in e if c.tag not in allowed]
                if bad:
                    x.err(bad[0], f"property of {x.tag(e)} is not accepted by a {kind} state "
                                  f"(accepted: {', '.join(sorted(allowed)) or 'none'})")
                    continue
                states.append(_state(e.get("name", "").strip(), kind, props, x.where(e)))
            except ValueError as exc:
                x.err(e, str(exc))
        elif e.tag == "transition":
            if not x.attrs(e, ("origin", "destination"), ("name",)):
                continue
            events: list[AtdEvent] = []
            for c in e:
                try:
                    ev = _event(c.tag)
                    extra = set(c.attrib) - ({"after"} if ev is AbstractEvent.TIMEOUT else set())
                    if extra:
                        raise ValueError(f"<{c.tag}> has unknown attribute {sorted(extra)[0]!r}")
                    after = _positive(c.get("after"), "timeout after") if c.get("after") else None
                    events.append(AtdEvent(ev, after, x.where(c)))
                except ValueError as exc:
                    x.err(c, f"in {x.tag(e)} at line {x.where(e).line}: {exc}")
            origin, dest = e.get("origin", "").strip(), e.get("destination", "").strip()
            name = (e.get("name") or "").strip() or f"{origin}->{dest}"
            transitions.append(AtdTransition(name, origin, dest, tuple(events), x.where(e)))
        elif e.tag == "object":
            add_object(e)
        elif e.tag == "environment":
            for c in e:
                if c.tag == "object":
                    add_object(c)
                elif c.tag == "obstacle":
                    if not x.attrs(c, ("name",)):
                        continue
                    props = x.props(c)
                    if props is None:
                        continue
                    try:
                        obstacles.append(_obstacle(c.get("name", ""), props, x.where(c)))
                    except ValueError as exc:
                        x.err(c, str(exc))
                else:
                    x.err(c, "unknown element in <environment> (accepted: object, obstacle)")
        else:
            x.err(e, "unknown element in <statemachine> (accepted: state, transition, object, "
                     "environment)")
    if x.issues:
        raise AtdError(x.issues)
    name = (root.get("name") or "").strip() or (Path(file).stem if file != "<memory>" else "atd")
    start = (root.get("start") or "").strip() or (states[0].name if states else "")
    atd = Atd(name, tuple(states), tuple(transitions), objects, tuple(obstacles), start, file,
              x.where(root))
    validate_atd(atd)
    return atd


# -- YAML ----------------------------------------------------------------------------------------
def _yaml_props(doc: LocatedYaml, what: str) -> dict[str, Any]:
    return {k: d.value for k, d in doc.items(what)}


def _parse_yaml(text: str, file: str) -> Atd:
    try:
        doc = LocatedYaml.compose(text, file, "ATD")
    except TaskError as exc:
        raise AtdError(exc.issues) from None
    issues: list[str] = []
    try:
        top = doc.mapping("ATD", {"statemachine"})
        if "statemachine" not in top:
            raise AtdError([f"{file}:1: the ATD needs a top-level 'statemachine'"])
        sm = top["statemachine"].mapping(
            "statemachine", {"name", "start", "objects", "environment", "states", "transitions"})
        objects: dict[str, AtdObject] = {}
        for name, d in (sm["objects"].items("objects") if "objects" in sm else []):
            try:
                objects[name] = _object(name, _yaml_props(d, f"objects.{name}"), d.where)
            except ValueError as exc:
                issues.append(f"{d.where}: objects.{name}: {exc}")
        obstacles: list[Obstacle] = []
        if "environment" in sm:
            env = sm["environment"].mapping("environment", {"obstacles"})
            for name, d in (env["obstacles"].items("obstacles") if "obstacles" in env else []):
                try:
                    obstacles.append(_obstacle(name, _yaml_props(d, f"obstacles.{name}"), d.where))
                except ValueError as exc:
                    issues.append(f"{d.where}: obstacles.{name}: {exc}")
        states: list[AtdState] = []
        for i, d in enumerate(sm["states"].seq("states") if "states" in sm else []):
            props = _yaml_props(d, f"states[{i}]")
            name, kind = str(props.pop("name", "")).strip(), str(props.pop("type", "")).strip()
            if not name or not kind:
                issues.append(f"{d.where}: states[{i}]: needs 'name' and 'type'")
                continue
            try:
                states.append(_state(name, _state_type(kind), props, d.where))
            except ValueError as exc:
                issues.append(f"{d.where}: state {name!r}: {exc}")
        transitions: list[AtdTransition] = []
        for i, d in enumerate(sm["transitions"].seq("transitions") if "transitions" in sm else []):
            t = d.mapping(f"transitions[{i}]", {"name", "origin", "destination", "events", "timeout"})
            if "origin" not in t or "destination" not in t:
                issues.append(f"{d.where}: transitions[{i}]: needs 'origin' and 'destination'")
                continue
            origin = t["origin"].text(f"transitions[{i}].origin")
            dest = t["destination"].text(f"transitions[{i}].destination")
            evs: list[AtdEvent] = []
            raw = t["events"].value if "events" in t else []
            for ev in raw if isinstance(raw, list) else [raw]:
                try:
                    evs.append(AtdEvent(_event(str(ev)), None, t["events"].where))
                except ValueError as exc:
                    issues.append(f"{t['events'].where}: transitions[{i}]: {exc}")
            if "timeout" in t:
                evs.append(AtdEvent(AbstractEvent.TIMEOUT, t["timeout"].number("timeout"),
                                    t["timeout"].where))
            name = t["name"].text("name") if "name" in t else f"{origin}->{dest}"
            transitions.append(AtdTransition(name, origin, dest, tuple(evs), d.where))
        atd_name = sm["name"].text("name") if "name" in sm else Path(file).stem
        start = sm["start"].text("start") if "start" in sm else (states[0].name if states else "")
    except TaskError as exc:
        raise AtdError(exc.issues) from None
    if issues:
        raise AtdError(issues)
    atd = Atd(atd_name, tuple(states), tuple(transitions), objects, tuple(obstacles), start,
              file, top["statemachine"].where)
    validate_atd(atd)
    return atd


# -- validation ----------------------------------------------------------------------------------
def validate_atd(atd: Atd) -> None:
    """Refuse dangling transitions, unreachable states, dead ends and missing terminals."""
    issues: list[str] = []
    names: dict[str, AtdState] = {}
    for s in atd.states:
        if s.name in names:
            issues.append(f"{s.where}: <state name={s.name!r}>: duplicate state name (first at "
                          f"line {names[s.name].where.line})")
        names[s.name] = s
        if isinstance(s.type, AbstractPrimitive) and s.type.needs_target and s.goal is None \
                and not s.target_object:
            issues.append(f"{s.where}: <state name={s.name!r}>: a {s.type} state needs a "
                          "<target> or a <path>")
        for obj in filter(None, (s.object, s.target_object)):
            if atd.objects and obj not in atd.objects:
                issues.append(f"{s.where}: <state name={s.name!r}>: unknown object {obj!r} "
                              f"(defined: {', '.join(sorted(atd.objects))})")
        if s.target_object and not atd.objects:
            issues.append(f"{s.where}: <state name={s.name!r}>: target object "
                          f"{s.target_object!r} is not defined")
    if not atd.states:
        raise AtdError([f"{atd.where}: <statemachine>: no states"])
    if atd.start not in names:
        issues.append(f"{atd.where}: <statemachine>: start state {atd.start!r} does not exist")
    terminals = [s for s in atd.states if s.terminal]
    if not terminals:
        issues.append(f"{atd.where}: <statemachine>: no terminal state (a state of type "
                      "success or failure)")
    for t in atd.transitions:
        tag = f"<transition origin={t.origin!r} destination={t.destination!r}>"
        for end, what in ((t.origin, "origin"), (t.destination, "destination")):
            if end not in names:
                issues.append(f"{t.where}: {tag}: dangling {what}: no state named {end!r}")
        if t.origin in names and names[t.origin].terminal:
            issues.append(f"{t.where}: {tag}: leaves the terminal state {t.origin!r}")
        if not t.events:
            issues.append(f"{t.where}: {tag}: no event (give at least one of "
                          f"{', '.join(e.value for e in AbstractEvent)})")
        kinds = [e.event for e in t.events]
        if len(set(kinds)) != len(kinds):
            issues.append(f"{t.where}: {tag}: the same event is listed twice")
    for s in atd.states:
        if not s.terminal and not any(t.origin == s.name for t in atd.transitions):
            issues.append(f"{s.where}: <state name={s.name!r}>: not terminal and no transition "
                          "leaves it (dead end)")
    if atd.start in names:
        reach, todo = {atd.start}, [atd.start]
        while todo:
            cur = todo.pop()
            for t in atd.transitions:
                if t.origin == cur and t.destination in names and t.destination not in reach:
                    reach.add(t.destination)
                    todo.append(t.destination)
        for s in atd.states:
            if s.name not in reach:
                issues.append(f"{s.where}: <state name={s.name!r}>: unreachable from the start "
                              f"state {atd.start!r}")
        if terminals and not any(s.name in reach for s in terminals):
            issues.append(f"{atd.where}: <statemachine>: no terminal state is reachable")
    if issues:
        raise AtdError(issues)


# -- entry points --------------------------------------------------------------------------------
def parse_atd(data: str | bytes, file: str = "<memory>") -> Atd:
    """Parse and validate an ATD given as XML or YAML text (chosen by its first character)."""
    raw = data.encode("utf-8") if isinstance(data, str) else bytes(data)
    if len(raw) > MAX_ATD_BYTES:
        raise AtdError([f"{file}: refused: {len(raw)} bytes exceeds the {MAX_ATD_BYTES}-byte limit"])
    if raw.lstrip().startswith(b"<"):
        return _parse_xml(raw, file)
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise AtdError([f"{file}: not UTF-8 text: {exc}"]) from None
    return _parse_yaml(text, file)


def load_atd(path: str | Path) -> Atd:
    """Read and parse an ATD file (.xml or .yaml/.yml)."""
    return parse_atd(read_atd(path), str(path))


def read_atd(path: str | Path) -> bytes:
    """The bytes of an ATD file, refused past :data:`MAX_ATD_BYTES`."""
    p = Path(path)
    try:
        # read at most one byte past the limit: a device or pipe reports size 0 and may never end
        with p.open("rb") as f:
            data = f.read(MAX_ATD_BYTES + 1)
    except OSError as exc:
        raise AtdError([f"{p}: cannot read ATD: {exc.strerror}"]) from None
    if len(data) > MAX_ATD_BYTES:
        raise AtdError([f"{p}: refused: file exceeds the {MAX_ATD_BYTES}-byte limit"])
    return data
