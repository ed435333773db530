"""Tombatossals' translation factory (Table 7.3): robust grasp with corrections, Cartesian transport for arm motions."""

from __future__ import annotations

from typing import ClassVar

from contactflow.abstraction.atd import Atd, AtdState
from contactflow.abstraction.events import AbstractEvent
from contactflow.abstraction.factory import EventChoice, Factory
from contactflow.abstraction.primitives import AbstractPrimitive
from contactflow.abstraction.profiles import Sensor


class TombatossalsFactory(Factory):
    """Table 7.3: the grasp is watched as the robust grasp judges it: two pads touching, or fingers held open (§3.3.1)."""

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
        helper, trig = self.watcher(e, e.value, state, sensor="hand", min_contacts=2)
        return EventChoice((frozenset({trig}),), (helper,))


FACTORY = TombatossalsFactory
