"""Per-embodiment factories (thesis §7.2.2, Tables 7.3-7.4): abstract -> concrete primitives.

A factory sees one abstract state (or one abstract event of a transition) at a time, with
the ATD's object and environment information, and returns the concrete primitive type, its
parameters and the event detectors that the robot's sensors allow. It refuses with a
reason (:class:`MappingRefused`) when the robot lacks the primitive, the sensors, the reach
or the payload. Factories are pure: their input is a :class:`RobotProfile`.

Concrete parameters passed to primitives (units in brackets):
  arm motions  target [m, xyz], approach [unit xyz], standoff [m], waypoints [m, flat xyz],
               motion (free|line|constrained), keep_orientation, obstacles [m, flat 6 per box:
               centre xyz, size xyz], hand_shape, stop_force [N], stop_sensor, filter_hz [Hz]
  grasps       target, approach, preshape, pregrasp_size [m], corrections (robust_grasp),
               grasp_force [N], max_width [m] (close_until_force)
  place        target, contact_threshold [N], filter_hz [Hz]
  slide        target, slide_force [N], filter_hz [Hz]
  release      hand_position [m]
  hold         force [N]
  wait_event   event, sensor, threshold, filter_hz [Hz], min_contacts
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar

from contactflow.abstraction.atd import Atd, AtdEvent, AtdObject, AtdState
from contactflow.abstraction.events import AbstractEvent
from contactflow.abstraction.primitives import AbstractPrimitive, Movement
from contactflow.abstraction.profiles import HandKind, RobotProfile, Sensor
from contactflow.nodes.status import Event
from contactflow.nodes.taskgraph import ANY_SOURCE, REQUIRED, Helper, Trigger

GRAVITY = 9.81  # m/s^2
FRICTION = 0.5  # assumed finger-object friction coefficient for grasp force
DEFAULT_OBJECT = "object"
DEFAULT_APPROACH = [0.0, 0.0, -1.0]  # from above


class MappingRefused(Exception):
    """The factory cannot map an abstract state or event on this robot; ``reason`` says why."""

    def __init__(self, reason: str) -> None:
        self.reason = reason
        super().__init__(reason)


@dataclass(frozen=True, slots=True)
class PrimitiveChoice:
    """The concrete node for one abstract state."""

    type: str
    params: Mapping[str, Any]
    helpers: tuple[Helper, ...] = ()
    timeout: float | None = None
    notes: tuple[str, ...] = ()


@dataclass(frozen=True, slots=True)
class EventChoice:
    """The concrete condition for one abstract event: a conjunction of any-of groups."""

    groups: tuple[frozenset[Trigger], ...]
    helpers: tuple[Helper, ...] = ()
    timeout: float | None = None  # s, node timeout implied by a timeout event
    notes: tuple[str, ...] = ()


def _param_name(obj: str, what: str) -> str:
    return f"{obj}_{what}"


def _flat(points: Sequence[Sequence[float]]) -> list[float]:
    return [float(c) for p in points for c in p]


@dataclass
class Factory:
    """Base factory: the mappings every embodiment shares; subclasses fill the tables.

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
        if obj is not None and obj.location is not None:
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
        if self.robot.hand is HandKind.PARALLEL_GRIPPER:
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

    def _motion(self, state: AtdState, notes: list[str]) -> dict[str, Any]:
        movement = self.movement(state)
        p: dict[str, Any] = {
            "motion": {"free": "free", "guarded": "line", "constrained": "constrained"}[movement],
            "keep_orientation": movement is Movement.CONSTRAINED,
        }
        if movement is Movement.GUARDED:
            if self.robot.has(Sensor.WRIST_FT):
                p.update(stop_force=self.stop_force(), stop_sensor="wrist_ft",
                         filter_hz=self.filter_hz())
            elif self.robot.has(Sensor.TACTILE):
                p.update(stop_force=1.0, stop_sensor="tactile")
                notes.append("guarded motion stops on tactile contact (no wrist F/T sensor)")
            else:
                raise MappingRefused("a guarded motion needs a wrist F/T or tactile sensor to "
                                     "stop on contact")
        shape = self.hand_shape(state.hand_shape, notes)
        if shape:
            p["hand_shape"] = shape
        return p

    def _goal(self, atd: Atd, state: AtdState, p: dict[str, Any], standoff: float) -> None:
        """Fill target/approach/waypoints: an explicit goal, or the state's object."""
        if state.target_object:
            oname, obj = self._object_ref(atd, state, state.target_object)
            p["target"] = f"${{params.{_param_name(oname, 'location')}}}"
            if obj is not None and obj.location is not None:
                self._reach(obj.location, f"state {state.name!r}: target object {oname!r} at")
        elif state.goal is not None:
            p["target"] = list(state.goal)
            for i, w in enumerate(state.path or (state.goal,)):
                self._reach(w, f"state {state.name!r}: position {i + 1}")
        else:
            oname, obj = self._object_ref(atd, state)
            p["target"] = f"${{params.{_param_name(oname, 'location')}}}"
            p["approach"] = f"${{params.{_param_name(oname, 'approach')}}}"
            p["standoff"] = standoff
            if obj is not None and obj.location is not None:
                self._reach(obj.location, f"state {state.name!r}: object {oname!r} at")
        if len(state.path) > 1:
            p["waypoints"] = _flat(state.path)
        obj = atd.objects.get(state.target_object) if state.target_object else atd.object_of(state)
        size = state.object_size or (obj.size if obj is not None else None)
        if size is not None:
            p["size"] = list(size)  # m, world extents: how close the hand may come

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
        params, helpers = handler(kind, concrete, state, atd, notes)
        return PrimitiveChoice(concrete, params, tuple(helpers), state.timeout, tuple(notes))

    def arm_motion(self, kind: AbstractPrimitive, concrete: str, state: AtdState, atd: Atd,
                   notes: list[str]) -> tuple[dict[str, Any], list[Helper]]:
        p = self._motion(state, notes)
        free = self.movement(state) is Movement.FREE
        self._goal(atd, state, p, standoff=0.10 if free else 0.0)
        if free and atd.obstacles:
            p["obstacles"] = self._obstacles(atd)
        if kind is AbstractPrimitive.PUSH and concrete != "push":
            p["pushes"] = True  # an arm motion that moves the object to the target ahead of the hand
        if concrete == "place":
            p["contact_threshold"] = self.stop_force()
            p["filter_hz"] = self.filter_hz()
        if concrete == "slide":
            p["slide_force"] = round(max(5.0, 3.0 * self.stop_force()), 3)
            p["filter_hz"] = self.filter_hz()
        return p, []

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
              notes: list[str]) -> tuple[dict[str, Any], list[Helper]]:
        oname, obj = self.grasp_object(state, atd)
        p: dict[str, Any] = {
            "target": f"${{params.{_param_name(oname, 'location')}}}",
            "approach": f"${{params.{_param_name(oname, 'approach')}}}",
        }
        width = self.object_width(state, obj)
        if concrete in ("robust_grasp", "naive_grasp"):
            shape = self.hand_shape(state.hand_shape, notes)
            if shape:
                p["preshape"] = shape
            p["pregrasp_size"] = round(min(self.robot.max_opening,
                                           (width if width is not None else 0.06) + 0.04), 4)
            if concrete == "robust_grasp":
                p["corrections"] = list(self.corrections())
        else:
            if state.hand_shape:
                notes.append(f"hand shape {state.hand_shape!r} ignored: the gripper closes its jaws")
            p["grasp_force"] = self.grasp_force(obj)
            p["max_width"] = self.robot.max_opening
        return p, []

    def corrections(self) -> tuple[str, ...]:
        """Robust-grasp corrections the hand allows (§3.4: eq. 3.1, 3.2, finger lost, force): its capabilities."""
        return self.robot.grasp_corrections

    def release(self, kind: AbstractPrimitive, concrete: str, state: AtdState, atd: Atd,
                notes: list[str]) -> tuple[dict[str, Any], list[Helper]]:
        opening = state.hand_opening
        if opening is None:
            obj = atd.object_of(state)
            width = self.object_width(state, obj)
            opening = width + 0.03 if width is not None else self.robot.max_opening
        if opening > self.robot.max_opening:
            notes.append(f"hand opening {opening:.3f} m clipped to {self.robot.max_opening:.3f} m")
            opening = self.robot.max_opening
        return {"hand_position": round(opening, 4)}, []

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
        return self.grasp_event(e, state, atd)

    def grasp_event(self, e: AbstractEvent, state: AtdState, atd: Atd) -> EventChoice:
        raise MappingRefused(f"{self.robot.name} cannot detect {e}: no grasp sensing")

    @staticmethod
    def watcher(e: AbstractEvent, name: str, **params: Any) -> tuple[Helper, Trigger]:
        concrete = Event(e.value)
        return (Helper(name, "wait_event", {"event": concrete.value, **params}),
                Trigger(concrete, name))


class TombatossalsFactory(Factory):
    """Table 7.3: robust grasp with corrections, Cartesian transport for all arm motions."""

    TABLE: ClassVar[dict[AbstractPrimitive, tuple[str, ...]]] = {
        AbstractPrimitive.GRASP: ("robust_grasp", "naive_grasp"),
        AbstractPrimitive.MOVE: ("transport",),
        AbstractPrimitive.PUSH: ("transport",),
        AbstractPrimitive.TRANSPORT: ("transport",),
        AbstractPrimitive.PLACE: ("place",),
        AbstractPrimitive.SLIDE: ("slide",),
        AbstractPrimitive.RELEASE: ("release",),
    }

    def grasp_event(self, e: AbstractEvent, state: AtdState, atd: Atd) -> EventChoice:
        if not self.robot.has(Sensor.TACTILE):
            return super().grasp_event(e, state, atd)
        helper, trig = self.watcher(e, e.value, sensor="tactile", min_contacts=2, threshold=0.5)
        return EventChoice((frozenset({trig}),), (helper,))


class MelfaFactory(Factory):
    """Table 7.4: close-until-force grasp, move/transport without F/T, no slide."""

    TABLE: ClassVar[dict[AbstractPrimitive, tuple[str, ...]]] = {
        AbstractPrimitive.GRASP: ("close_until_force",),
        AbstractPrimitive.MOVE: ("move_to",),
        AbstractPrimitive.PUSH: ("move_to",),
        AbstractPrimitive.TRANSPORT: ("transport",),
        AbstractPrimitive.PLACE: ("transport",),
        AbstractPrimitive.SLIDE: (),
        AbstractPrimitive.RELEASE: ("release",),
    }
    WHY_NOT: ClassVar[dict[AbstractPrimitive, str]] = {
        AbstractPrimitive.SLIDE: "melfa cannot slide: keeping a sliding force needs a wrist "
                                 "force-torque sensor it does not have (Table 7.4)",
    }

    def arm_motion(self, kind: AbstractPrimitive, concrete: str, state: AtdState, atd: Atd,
                   notes: list[str]) -> tuple[dict[str, Any], list[Helper]]:
        p, helpers = super().arm_motion(kind, concrete, state, atd, notes)
        if kind in (AbstractPrimitive.TRANSPORT, AbstractPrimitive.PLACE):
            # §7.3: transport keeps squeezing, else the gripper loosens the item
            obj = atd.object_of(state)
            helpers.append(Helper("grip", "hold", {"force": self.grasp_force(obj)}))
        if kind is AbstractPrimitive.PLACE:
            p.update(motion="line", stop_sensor="tactile", stop_force=1.0, until_contact=True)
            notes.append("place runs as a guarded transport stopping on tactile change (Table 7.4)")
        return p, helpers

    def grasp_event(self, e: AbstractEvent, state: AtdState, atd: Atd) -> EventChoice:
        if not self.robot.has(Sensor.TACTILE):
            return super().grasp_event(e, state, atd)
        obj = atd.object_of(state)
        helper, trig = self.watcher(e, e.value, sensor="tactile",
                                    threshold=round(0.5 * self.grasp_force(obj), 3))
        return EventChoice((frozenset({trig}),), (helper,))


class BaxterFactory(Factory):
    """Parallel gripper with a noisy wrist wrench: filtered thresholds, two grasp monitors."""

    TABLE: ClassVar[dict[AbstractPrimitive, tuple[str, ...]]] = {
        AbstractPrimitive.GRASP: ("close_until_force", "close_until_stall", "naive_grasp"),
        AbstractPrimitive.MOVE: ("move_to",),
        AbstractPrimitive.PUSH: ("push", "move_to"),
        AbstractPrimitive.TRANSPORT: ("transport",),
        AbstractPrimitive.PLACE: ("place", "transport"),
        AbstractPrimitive.SLIDE: ("slide",),
        AbstractPrimitive.RELEASE: ("release",),
    }

    def grasp_event(self, e: AbstractEvent, state: AtdState, atd: Atd) -> EventChoice:
        if not self.robot.has(Sensor.GRIPPER_EFFORT):
            return super().grasp_event(e, state, atd)
        obj = atd.object_of(state)
        grip, grip_t = self.watcher(e, f"{e.value}_grip", sensor="gripper_effort",
                                    threshold=round(0.5 * self.grasp_force(obj), 3))
        weight = obj.mass * GRAVITY if obj is not None and obj.mass is not None else 0.0
        if not self.robot.has(Sensor.WRIST_FT) or weight < 2.0 * self.robot.wrench_noise:
            return EventChoice((frozenset({grip_t}),), (grip,),
                               notes=(f"{e} from the gripper only: the object's weight is "
                                      "below the wrist wrench noise",))
        load, load_t = self.watcher(e, f"{e.value}_load", sensor="wrist_ft",
                                    threshold=round(0.5 * weight, 3), filter_hz=self.filter_hz())
        if e is AbstractEvent.GRASP_STABLE:
            # stable only when the jaws hold and the wrist carries the weight
            return EventChoice((frozenset({grip_t}), frozenset({load_t})), (grip, load))
        return EventChoice((frozenset({grip_t, load_t}),), (grip, load))


FACTORIES: dict[str, type[Factory]] = {
    "tombatossals": TombatossalsFactory,
    "melfa": MelfaFactory,
    "baxter": BaxterFactory,
}


def factory_for(robot: RobotProfile) -> Factory:
    """The factory of a robot (by ``robot.factory`` or its name)."""
    key = robot.factory or robot.name
    if key not in FACTORIES:
        raise MappingRefused(f"no translation factory for robot {robot.name!r} (factories: "
                             f"{', '.join(sorted(FACTORIES))})")
    return FACTORIES[key](robot)
