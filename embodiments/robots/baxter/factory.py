"""Baxter's translation factory: parallel grippers with a noisy wrist wrench, filtered thresholds, two grasp monitors."""

from __future__ import annotations

from typing import ClassVar

from contactflow.abstraction.atd import Atd, AtdState
from contactflow.abstraction.events import AbstractEvent
from contactflow.abstraction.factory import GRAVITY, EventChoice, Factory
from contactflow.abstraction.primitives import AbstractPrimitive
from contactflow.abstraction.profiles import Sensor


class BaxterFactory(Factory):
    """The gripper's motor effort tells the grip; the estimated wrist wrench tells the load when it is above noise."""

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
        grip, grip_t = self.watcher(e, f"{e.value}_grip", state, sensor="gripper_effort",
                                    threshold=round(0.5 * self.grasp_force(obj), 3))
        weight = obj.mass * GRAVITY if obj is not None and obj.mass is not None else 0.0
        if not self.robot.has(Sensor.WRIST_FT) or weight < 2.0 * self.robot.wrench_noise:
            return EventChoice((frozenset({grip_t}),), (grip,),
                               notes=(f"{e} from the gripper only: the object's weight is "
                                      "below the wrist wrench noise",))
        load, load_t = self.watcher(e, f"{e.value}_load", state, sensor="wrist_ft",
                                    threshold=round(0.5 * weight, 3), filter_hz=self.filter_hz())
        if e is AbstractEvent.GRASP_STABLE:
            # stable only when the jaws hold and the wrist carries the weight
            return EventChoice((frozenset({grip_t}), frozenset({load_t})), (grip, load))
        return EventChoice((frozenset({grip_t, load_t}),), (grip, load))


FACTORY = BaxterFactory
