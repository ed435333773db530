"""The translation factory (thesis §7.2.2, Tables 7.3-7.4): abstract -> concrete primitives.

A factory sees one abstract state (or one abstract event of a transition) at a time, with
the ATD's object and environment information, and returns the concrete primitive type with
its typed ``Params`` (the primitive's own dataclass, the robot's overrides applied), where
it goes (a :class:`~contactflow.abstraction.concrete.Goal`, bound when the node starts) and
the event detectors that the robot's sensors allow. A parameter the primitive does not
declare, or a value of the wrong type, is an error naming the ATD state. It refuses with a
reason (:class:`MappingRefused`) when the robot lacks the primitive, the sensors, the reach
or the payload. Factories are pure: their input is a :class:`RobotProfile`. This module is
the base every robot shares; each robot's own factory (its table and detectors) lives in
its home, ``embodiments/robots/<name>/factory.py``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, ClassVar

from contactflow.abstraction.atd import DETECT, Atd, AtdEvent, AtdObject, AtdState
from contactflow.abstraction.concrete import LINE_SPEED, LINE_TURN, Goal
from contactflow.abstraction.events import AbstractEvent
from contactflow.abstraction.primitives import AbstractPrimitive, Movement
from contactflow.abstraction.profiles import RobotProfile, Sensor
from contactflow.embodiments.registry import HandKind
from contactflow.nodes.params import ParamError, params_dict, replace_params
from contactflow.nodes.registry import UnknownModuleType, resolve
from contactflow.nodes.status import Event
from contactflow.nodes.taskgraph import ANY_SOURCE, REQUIRED, Helper, Trigger

GRAVITY = 9.81  # m/s^2
FRICTION = 0.5  # assumed finger-object friction coefficient for grasp force
DEFAULT_OBJECT = "object"
DEFAULT_APPROACH = [0.0, 0.0, -1.0]  # from above
CARRY_FORCE = 10.0  # N, least unexpected-contact threshold of a guarded path that does not end on contact


class MappingRefused(Exception):
    """The factory cannot map an abstract state or event on this robot; ``reason`` says why."""

    def __init__(self, reason: str) -> None:
        self.reason = reason
        super().__init__(reason)


def params_class(type_: str) -> type:
    """The ``Params`` dataclass of concrete primitive ``type_``."""
    try:
        return resolve(type_).Params
    except UnknownModuleType as exc:
        raise MappingRefused(str(exc)) from None


def stated(params: Any, keys: Sequence[str]) -> dict[str, Any]:
    """The fields ``keys`` of ``params`` as plain values (what an ESTD node states; the rest are the class defaults)."""
    values = params_dict(params)
    return {k: values[k] for k in keys}


@dataclass(frozen=True, slots=True)
class PrimitiveChoice:
    """The concrete node for one abstract state: its type, typed ``Params`` and goal."""

    type: str
    params: Any  # the primitive's own Params dataclass
    goal: Goal | None = None
    explicit: tuple[str, ...] = ()  # the fields set: the robot's overrides and the factory's changes
    helpers: tuple[Helper, ...] = ()
    timeout: float | None = None
    notes: tuple[str, ...] = ()

    def node_params(self) -> dict[str, Any]:
        """The ESTD node's parameters: the ``Params`` fields set and the goal."""
        out = stated(self.params, self.explicit)
        if self.goal is not None:
            out["goal"] = self.goal.to_params()
        return out


@dataclass(frozen=True, slots=True)
class EventChoice:
    """The concrete condition for one abstract event: a conjunction of any-of groups."""

    groups: tuple[frozenset[Trigger], ...]
    helpers: tuple[Helper, ...] = ()
    timeout: float | None = None  # s, node timeout implied by a timeout event
    notes: tuple[str, ...] = ()


def _param_name(obj: str, what: str) -> str:
    return f"{obj}_{what}"


def _ref(obj: str, what: str) -> str:
    return f"${{params.{_param_name(obj, what)}}}"


def _flat(points: Sequence[Sequence[float]]) -> list[float]:
    return [float(c) for p in points for c in p]


@dataclass
class Factory:
    """Base factory: the mappings every embodiment shares; each robot's subclass fills the tables.

    ``TABLE`` maps each abstract primitive to the concrete types the robot prefers, best
    first (empty: the robot cannot do it, with ``WHY_NOT`` as the reason).
    """

    robot: RobotProfile
    default_timeout: float = 60.0  # s
    TABLE: ClassVar[dict[AbstractPrimitive, tuple[str, ...]]] = {}
    WHY_NOT: ClassVar[dict[AbstractPrimitive, str]] = {}
    REQUIRES: ClassVar[dict[str, frozenset[Sensor]]] = {
        "robust_grasp": frozenset({Sensor.WRIST_FT, Sensor.TACTILE}),
        "place": frozenset({Sensor.WRIST_FT}),
        "slide": frozenset({Sensor.WRIST_FT}),
        "push": frozenset({Sensor.WRIST_FT}),
        "close_until_force": frozenset({Sensor.TACTILE}),  # the simulated primitive reads pad pressure
        "close_until_stall": frozenset({Sensor.GRIPPER_EFFORT}),
    }
    _params_used: dict[str, Any] = field(default_factory=dict, init=False, repr=False)

    def begin(self, atd: Atd) -> None:
        """Start translating ``atd`` (forgets the parameters of a previous translation)."""
        self._params_used = {}

    # -- typed parameters ------------------------------------------------------------------
    def params(self, type_: str, where: str, **changes: Any) -> Any:
        """``type_``'s typed ``Params``: the robot's overrides, then ``changes``; a bad field names ``where``."""
        cls = params_class(type_)
        try:
            base = replace_params(cls(), dict(self.robot.overrides.get(type_, {})),
                                  where=f"{self.robot.name}'s overrides of {type_}: ")
            return replace_params(base, changes, where=f"{where}: {type_}.params." if where else f"{type_}.params.")
        except ParamError as exc:
            raise MappingRefused(str(exc)) from None

    def explicit(self, type_: str, changes: Mapping[str, Any]) -> tuple[str, ...]:
        """The fields an ESTD states for ``type_``: what the robot overrides or the factory sets (even at a default)."""
        return tuple(sorted({*self.robot.overrides.get(type_, {}), *changes}))

    def helper(self, name: str, type_: str, where: str, **changes: Any) -> Helper:
        """A helper primitive with typed parameters (the fields set or overridden travel)."""
        return Helper(name, type_, stated(self.params(type_, where, **changes), self.explicit(type_, changes)))

    # -- task parameters (objects) -------------------------------------------------------
    def task_params(self, atd: Atd) -> dict[str, Any]:
        """ESTD task parameters: each referenced object's location and approach direction.

        Values the ATD gives are the defaults; a missing location must be bound by the plan
        (e.g. from perception), a missing approach defaults to from above.
        """
        return dict(self._params_used)

    def _object_ref(self, atd: Atd, state: AtdState, name: str = "") -> tuple[str, AtdObject | None]:
        obj = atd.objects.get(name) if name else atd.object_of(state)
        oname = obj.name if obj is not None else (name or state.object or DEFAULT_OBJECT)
        loc, app = _param_name(oname, "location"), _param_name(oname, "approach")
        if obj is not None and obj.detect:
            if not self.robot.has(Sensor.CAMERA) or "detect_objects" not in self.robot.capabilities:
                raise MappingRefused(f"object {oname!r} is to be detected and {self.robot.name} cannot find it "
                                     "(that needs a camera and the detect_objects primitive)")
            self._params_used[loc] = DETECT
        elif obj is not None and obj.location is not None:
            self._params_used[loc] = list(obj.location)
        else:
            self._params_used.setdefault(loc, REQUIRED)
        if obj is not None and obj.approach is not None:
            self._params_used[app] = list(obj.approach)
        else:
            self._params_used.setdefault(app, list(DEFAULT_APPROACH))
        return oname, obj

    # -- choice of concrete type -----------------------------------------------------------
    def choose(self, kind: AbstractPrimitive) -> str:
        prefs = self.TABLE.get(kind, ())
        if not prefs:
            raise MappingRefused(self.WHY_NOT.get(kind, f"{self.robot.name} has no primitive for "
                                                  f"abstract {kind}"))
        missing: list[str] = []
        for t in prefs:
            if t not in self.robot.capabilities:
                missing.append(f"{t} (not a capability of {self.robot.name})")
                continue
            lacking = self.REQUIRES.get(t, frozenset()) - self.robot.sensors
            if lacking:
                missing.append(f"{t} (needs sensors {', '.join(sorted(lacking))})")
                continue
            return t
        raise MappingRefused(f"no usable primitive for abstract {kind}: " + "; ".join(missing))

    # -- geometry checks -------------------------------------------------------------------
    def _reach(self, point: Sequence[float], what: str) -> None:
        if not self.robot.workspace.reaches(point):
            raise MappingRefused(f"{what} {tuple(round(c, 3) for c in point)} is out of "
                                 f"{self.robot.name}'s reach: {self.robot.workspace.describe(point)}")

    def _obstacles(self, atd: Atd) -> list[float]:
        return _flat([(*o.position, *o.size) for o in atd.obstacles])

    def stop_force(self) -> float:
        """N, contact threshold above the wrist wrench noise (4 sigma, at least 3 N)."""
        return round(max(3.0, 4.0 * self.robot.wrench_noise), 3)

    def filter_hz(self) -> float:
        """Hz, low-pass cut-off for the wrist wrench: lower when it is noisy."""
        return 5.0 if self.robot.wrench_noise > 1.0 else 30.0

    def hand_shape(self, shape: str, notes: list[str]) -> str:
        if not shape:
            return ""
        if shape in self.robot.hand_shapes:
            return self.robot.hand_shapes[shape]
        if self.robot.hand is HandKind.PARALLEL:
            mapped = "open" if (shape.endswith("preshape") or shape == "open") else "closed"
            notes.append(f"hand shape {shape!r} approximated by {mapped!r} on the gripper")
            return mapped
        notes.append(f"hand shape {shape!r} is unknown to {self.robot.name}; ignored (a hint)")
        return ""

    @staticmethod
    def movement(state: AtdState) -> Movement:
        """The state's motion type; contact primitives default to guarded, others to free."""
        if state.movement is not None:
            return state.movement
        contact = (AbstractPrimitive.PLACE, AbstractPrimitive.PUSH, AbstractPrimitive.SLIDE)
        return Movement.GUARDED if state.type in contact else Movement.FREE

    def guard(self, concrete: str, until_contact: bool, notes: list[str], tactile: bool = False) -> dict[str, Any]:
        """A guarded move/transport's contact stop: on the contact it goes to, or on an unexpected one.

        Going to an object or down onto a surface the contact is the goal (``guarded``); on a
        free path it is a fault, judged above the jolts a carried load gives.
        """
        if tactile or not self.robot.has(Sensor.WRIST_FT):
            if not self.robot.has(Sensor.TACTILE):
                raise MappingRefused("a guarded motion needs a wrist F/T or tactile sensor to stop on contact")
            force = 3.0
            notes.append("the guarded motion stops on a 3 N contact: the arm primitives sense contact at the wrist")
        else:
            force = self.stop_force()
        key = "force_threshold" if concrete == "transport" else "abort_force"
        return {"guarded": until_contact, key: force if until_contact else max(force, CARRY_FORCE)}

    def _goal(self, atd: Atd, state: AtdState, standoff: float, pushes: bool = False) -> Goal:
        """Where an arm motion goes: an explicit goal, or the state's object (approached from its side, ``standoff`` m back)."""
        approach: str | tuple[float, ...] = ()
        if state.target_object:
            oname, obj = self._object_ref(atd, state, state.target_object)
            target: str | tuple[float, ...] = _ref(oname, "location")
            if obj is not None and obj.location is not None:
                self._reach(obj.location, f"state {state.name!r}: target object {oname!r} at")
        elif state.goal is not None:
            target = tuple(state.goal)
            for i, w in enumerate(state.path or (state.goal,)):
                self._reach(w, f"state {state.name!r}: position {i + 1}")
        else:
            oname, obj = self._object_ref(atd, state)
            target, approach = _ref(oname, "location"), _ref(oname, "approach")
            if obj is not None and obj.location is not None:
                self._reach(obj.location, f"state {state.name!r}: object {oname!r} at")
        obj = atd.objects.get(state.target_object) if state.target_object else atd.object_of(state)
        size = state.object_size or (obj.size if obj is not None else None)
        return Goal(target=target, approach=approach, standoff=standoff if approach else 0.0,
                    size=tuple(size) if size is not None else (),
                    waypoints=tuple(_flat(state.path)) if len(state.path) > 1 else (), pushes=pushes)

    # -- the abstract primitives -----------------------------------------------------------
    def node(self, state: AtdState, atd: Atd) -> PrimitiveChoice:
        """Map one abstract state (not a terminal) to a concrete primitive."""
        assert isinstance(state.type, AbstractPrimitive)
        kind = state.type
        concrete = self.choose(kind)
        notes: list[str] = []
        handler = {
            AbstractPrimitive.GRASP: self.grasp,
            AbstractPrimitive.RELEASE: self.release,
        }.get(kind, self.arm_motion)
        changes, goal, helpers = handler(kind, concrete, state, atd, notes)
        return PrimitiveChoice(concrete, self.params(concrete, "", **changes), goal,
                               self.explicit(concrete, changes), tuple(helpers), state.timeout, tuple(notes))

    def arm_motion(self, kind: AbstractPrimitive, concrete: str, state: AtdState, atd: Atd,
                   notes: list[str]) -> tuple[dict[str, Any], Goal, list[Helper]]:
        movement = self.movement(state)
        free = movement is Movement.FREE
        pushes = kind is AbstractPrimitive.PUSH and concrete != "push"  # an arm motion moving the object ahead of the hand
        goal = self._goal(atd, state, standoff=0.10 if free else 0.0, pushes=pushes)
        if free and atd.obstacles:
            goal = replace(goal, obstacles=tuple(self._obstacles(atd)))
        if concrete == "place" and state.goal is None:
            goal = replace(goal, target=(), approach=())  # onto another object: its location is not the rest pose
        p: dict[str, Any] = {}
        shape = self.hand_shape(state.hand_shape, notes)
        if concrete in ("move_to", "transport"):
            if shape:
                p["preshape"] = shape
            if concrete == "move_to":
                p["planning"] = free
            else:
                p["filter_hz"] = self.filter_hz()  # the contact check of a transport reads the filtered wrench
                if movement is Movement.GUARDED:
                    p["velocity_limits"] = [LINE_SPEED] * 3 + [LINE_TURN] * 3  # straight and slow: no planner
            if movement is Movement.GUARDED and not pushes:
                p.update(self.guard(concrete, until_contact=bool(goal.approach), notes=notes))
        elif shape:
            notes.append(f"hand shape {state.hand_shape!r} ignored: {concrete} keeps its own hand posture")
        if movement is Movement.CONSTRAINED:
            notes.append("constrained motion: the hand keeps its orientation along the path")
        if concrete == "place":
            p.update(force_threshold=self.stop_force(), filter_hz=self.filter_hz())
        elif concrete == "slide":
            slide = round(max(5.0, 3.0 * self.stop_force()), 3)
            # the thesis's 9 N / 5 N band (§3.3.3), scaled to the wrist's noise
            p.update(upper_force_threshold=slide, lower_force_threshold=round(slide * 5.0 / 9.0, 3))
        elif concrete == "push":
            p["contact_threshold"] = self.stop_force()
        return p, goal, []

    def grasp_object(self, state: AtdState, atd: Atd) -> tuple[str, AtdObject | None]:
        oname, obj = self._object_ref(atd, state)
        if obj is not None and obj.mass is not None and obj.mass > self.robot.max_payload:
            raise MappingRefused(f"object {oname!r} of {obj.mass} kg exceeds {self.robot.name}'s "
                                 f"payload of {self.robot.max_payload} kg")
        width = self.object_width(state, obj)
        if width is not None and width > self.robot.max_opening:
            raise MappingRefused(f"object {oname!r} is {width:.3f} m wide; {self.robot.name}'s "
                                 f"hand opens to {self.robot.max_opening:.3f} m")
        if obj is not None and obj.location is not None:
            self._reach(obj.location, f"state {state.name!r}: object {oname!r} at")
        return oname, obj

    @staticmethod
    def object_width(state: AtdState, obj: AtdObject | None) -> float | None:
        size = state.object_size or (obj.size if obj is not None else None)
        return min(size[0], size[1]) if size is not None else None

    def grasp_force(self, obj: AtdObject | None) -> float:
        """N, squeezing force to hold the object's weight by friction (safety factor 2)."""
        if obj is None or obj.mass is None:
            return 10.0
        return round(min(40.0, max(5.0, 2.0 * obj.mass * GRAVITY / (2.0 * FRICTION))), 3)

    def grasp(self, kind: AbstractPrimitive, concrete: str, state: AtdState, atd: Atd,
              notes: list[str]) -> tuple[dict[str, Any], Goal, list[Helper]]:
        oname, obj = self.grasp_object(state, atd)
        goal = Goal(target=_ref(oname, "location"), approach=_ref(oname, "approach"))
        width = self.object_width(state, obj)
        p: dict[str, Any] = {}
        if state.hand_shape:
            notes.append(f"hand shape {state.hand_shape!r}: {concrete} closes every finger on what it touches")
        if concrete in ("robust_grasp", "naive_grasp"):
            p["pregrasp_type"] = "open"
        if concrete == "robust_grasp":
            size = (width if width is not None else 0.06) + 0.04  # m, the object and a margin
            corrections = self.corrections()
            p.update(pregrasp_size=round(min(1.0, size / self.robot.max_opening), 4),
                     alignment="alignment" in corrections, sliding="sliding" in corrections,
                     finger_lost="finger_lost" in corrections)
        elif concrete == "close_until_force":
            p["grip_force"] = round(self.grasp_force(obj) / 2.0, 3)  # per pad: two pads share the squeeze
        return p, goal, []

    def corrections(self) -> tuple[str, ...]:
        """Robust-grasp corrections the hand allows (§3.4: eq. 3.1, 3.2, finger lost, force): its capabilities."""
        return self.robot.grasp_corrections

    def release(self, kind: AbstractPrimitive, concrete: str, state: AtdState, atd: Atd,
                notes: list[str]) -> tuple[dict[str, Any], None, list[Helper]]:
        opening = state.hand_opening
        if opening is None:
            return {}, None, []  # let go completely
        if self.robot.hand is not HandKind.PARALLEL:
            # a multi-finger hand's joints between closed and open give no aperture in metres, and a
            # hand stopped part-way can stay caught on what it held
            notes.append(f"hand opening {opening:.3f} m approximated by the open hand")
            return {}, None, []
        if opening > self.robot.max_opening:
            notes.append(f"hand opening {opening:.3f} m clipped to {self.robot.max_opening:.3f} m")
            opening = self.robot.max_opening
        return {"hand_target": round(opening / self.robot.max_opening, 4)}, None, []

    # -- abstract events -------------------------------------------------------------------
    def event(self, ev: AtdEvent, state: AtdState, node: PrimitiveChoice, atd: Atd) -> EventChoice:
        """Map one abstract event of a transition leaving ``state`` (mapped to ``node``)."""
        e = ev.event
        if e is AbstractEvent.SUCCESS:
            return EventChoice((frozenset({Trigger(Event.SUCCESS)}),))
        if e is AbstractEvent.ERROR:
            return EventChoice((frozenset({Trigger(Event.ERROR, ANY_SOURCE), Trigger(Event.FAILURE)}),))
        if e is AbstractEvent.HARDWARE_FAILURE:
            return EventChoice((frozenset({Trigger(Event.HARDWARE_FAILURE, ANY_SOURCE)}),))
        if e is AbstractEvent.TIMEOUT:
            # measured by the engine on the robot's clock: the same on every platform
            return EventChoice((frozenset({Trigger(Event.TIMEOUT)}),),
                               timeout=ev.after if ev.after is not None else self.default_timeout)
        if e is AbstractEvent.PREDICTION_MISMATCH:
            # the same on every robot: its predictor (a ``predictor`` module beside it) tells it; a robot run
            # without one never takes the transition
            helper = self.helper(e.value, "watch_prediction", f"state {state.name!r}: detector {e.value!r}")
            return EventChoice((frozenset({Trigger(Event.PREDICTION_MISMATCH, e.value)}),), (helper,))
        return self.grasp_event(e, state, atd)

    def grasp_event(self, e: AbstractEvent, state: AtdState, atd: Atd) -> EventChoice:
        raise MappingRefused(f"{self.robot.name} cannot detect {e}: no grasp sensing")

    def watcher(self, e: AbstractEvent, name: str, state: AtdState, **params: Any) -> tuple[Helper, Trigger]:
        """A ``wait_event`` helper that keeps watching for ``e`` (its sensor and thresholds in ``params``)."""
        concrete = Event(e.value)
        return (self.helper(name, "wait_event", f"state {state.name!r}: detector {name!r}", event=concrete.value,
                            finish=False, **params),
                Trigger(concrete, name))


def factory_for(robot: RobotProfile) -> Factory:
    """The factory of a robot (``robot.factory`` or its name): the one its home registers."""
    from contactflow.embodiments import registry

    key = robot.factory or robot.name
    if key not in registry.names():
        raise MappingRefused(f"no translation factory for robot {robot.name!r} (factories: "
                             f"{', '.join(registry.names())})")
    return registry.home(key).factory(robot)
