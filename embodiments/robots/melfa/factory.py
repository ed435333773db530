"""Melfa's translation factory (Table 7.4): close-until-force grasp, a held grip while carrying, no slide."""

from __future__ import annotations

from typing import Any, ClassVar

from contactflow.abstraction.atd import Atd, AtdState
from contactflow.abstraction.concrete import LINE_SPEED, LINE_TURN, Goal
from contactflow.abstraction.events import AbstractEvent
from contactflow.abstraction.factory import EventChoice, Factory
from contactflow.abstraction.primitives import AbstractPrimitive
from contactflow.abstraction.profiles import Sensor
from contactflow.nodes.taskgraph import Helper


class MelfaFactory(Factory):
    """Table 7.4: move/transport, the gripper's pads tell a stable or lost grasp."""

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
                   notes: list[str]) -> tuple[dict[str, Any], Goal, list[Helper]]:
        p, goal, helpers = super().arm_motion(kind, concrete, state, atd, notes)
        where = f"state {state.name!r}"
        if kind in (AbstractPrimitive.TRANSPORT, AbstractPrimitive.PLACE):
            # §7.3: transport keeps squeezing, else the gripper loosens the item
            obj = atd.object_of(state)
            helpers.append(self.helper("grip", "hold", f"{where}: companion 'grip'", force=self.grasp_force(obj)))
        if kind is AbstractPrimitive.PLACE:
            p["velocity_limits"] = [LINE_SPEED] * 3 + [LINE_TURN] * 3
            p.update(self.guard(concrete, until_contact=True, notes=notes, tactile=True))
            notes.append("place runs as a guarded transport stopping on contact (Table 7.4)")
        return p, goal, helpers

    def grasp_event(self, e: AbstractEvent, state: AtdState, atd: Atd) -> EventChoice:
        if not self.robot.has(Sensor.TACTILE):
            return super().grasp_event(e, state, atd)
        obj = atd.object_of(state)
        helper, trig = self.watcher(e, e.value, state, sensor="tactile",
                                    threshold=round(0.5 * self.grasp_force(obj), 3))
        return EventChoice((frozenset({trig}),), (helper,))


FACTORY = MelfaFactory
