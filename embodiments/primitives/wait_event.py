"""Wait event (§6.3.6 auxiliary): wait for a sensed condition (grasp lost/stable, contact, motion) or a delay."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from contactflow.embodiments.primitives.base import Primitive, low_pass
from contactflow.embodiments.primitives.fused import FusedParams, SensesFusedContacts
from contactflow.nodes.status import Event

SENSORS = ("hand", "tactile", "gripper_effort", "wrist_ft", "fused")
"""How a grasp is told (thesis Tables 7.3-7.4, one per robot): the hand's contact information or joint
configuration (§3.3.1), tactile pad pressure, the gripper's motor effort, the load on the wrist; or the
robot's fused contacts (thesis ch. 4: every cue of the robot fused into contacts on its links)."""


class WaitEvent(SensesFusedContacts, Primitive):
    """Emits ``event`` when its condition holds: grasp_lost / grasp_stable (by ``sensor``), contact (F/T), or after ``delay``.

    Used as a helper next to another primitive (e.g. watch for GRASP_LOST while transporting)
    or alone as a delay (``event: success``). ``finish`` ends the primitive with SUCCESS when the
    event fired; otherwise it keeps running and emits once.
    """

    events = (Event.SUCCESS, Event.FAILURE, Event.ERROR, Event.GRASP_LOST, Event.GRASP_STABLE, Event.CONTACT)
    commands_arm = False

    @dataclass(frozen=True)
    class Params(FusedParams, Primitive.Params):
        event: str = "success"  # grasp_lost | grasp_stable | contact | success (= plain delay)
        delay: float = 0.0  # s before the condition is checked (the whole wait for "success")
        force_threshold: float = 5.0  # N, for "contact"
        finish: bool = True  # end with SUCCESS after the event
        grace: float = 0.2  # s a tactile condition must hold
        sensor: str = "hand"  # grasp sensing: hand (pads touching or fingers held open) | tactile | gripper_effort | wrist_ft | fused
        threshold: float = 0.0  # N, a grasp holds at this total pad pressure, grip force or wrist load (not "hand")
        min_contacts: int = 1  # pads in contact for a hand or tactile grasp
        filter_hz: float = 0.0  # Hz, low-pass cut-off of the wrist load (0: none; for noisy estimated wrenches)

        def validate(self) -> None:
            if self.sensor not in SENSORS:
                raise ValueError(f"sensor: {self.sensor!r} is not one of {list(SENSORS)}")
            self.check_fused(self.sensor)

    def begin(self) -> None:
        try:
            self.event = Event(self.params.event)
        except ValueError:
            raise ValueError(f"{self.name}: params.event {self.params.event!r} is not an event") from None
        if self.event not in (Event.GRASP_LOST, Event.GRASP_STABLE, Event.CONTACT, Event.SUCCESS):
            raise ValueError(f"{self.name}: cannot wait for {self.event} (grasp_lost, grasp_stable, contact, success)")
        fused = self.params.sensor == "fused"
        self.f0 = self.wrench_in("world")[:3] if self.event is Event.CONTACT and not fused else np.zeros(3)
        self.since: float | None = None
        self.fired = False
        self.load: float | None = None  # N, the low-passed wrist load
        if self.params.sensor == "wrist_ft" and not self.r.spec.arm(self.arm_name).ft:
            raise ValueError(f"{self.name}: params.sensor wrist_ft: arm {self.arm_name!r} has no wrist F/T")
        if fused:
            self.start_fused()

    def grasped(self) -> bool:
        """The grasp holds, as this robot senses it (``sensor``)."""
        p = self.params
        if p.sensor == "tactile":
            return sum(self.pad_forces().values()) >= p.threshold and len(self.pads_in_contact()) >= p.min_contacts
        if p.sensor == "gripper_effort":
            return self.grip_force() >= max(p.threshold, 1e-9)
        if p.sensor == "wrist_ft":
            self.load = low_pass(self.load, float(np.linalg.norm(self.wrench_in("world")[:3])), p.filter_hz,
                                 1.0 / p.rate_hz)
            return self.load >= p.threshold
        return self.holding(min_pads=p.min_contacts)

    def holds(self) -> bool:
        if self.event is Event.SUCCESS:
            return True
        if self.params.sensor == "fused":
            found = self.fused_on_hand()
            if found is None:  # no fused contacts: neither a grasp nor its loss is sensed
                return False
            n = len(found)
            if self.event is Event.CONTACT:
                return n > 0
            held = n >= self.params.min_contacts
            return not held if self.event is Event.GRASP_LOST else held
        if self.event is Event.CONTACT:
            return bool(np.linalg.norm(self.wrench_in("world")[:3] - self.f0) > self.params.force_threshold)
        held = self.grasped()
        return not held if self.event is Event.GRASP_LOST else held

    def update(self) -> None:
        p = self.params
        if self.elapsed < p.delay or self.fired:
            return
        if self.holds():
            self.since = self.r.time if self.since is None else self.since
            if self.r.time - self.since >= (0.0 if self.event in (Event.SUCCESS, Event.CONTACT) else p.grace):
                self.fired = True
                if self.event is not Event.SUCCESS:
                    self.emit_once(self.event, f"{self.event} observed{self.told_by()}")
                if p.finish:
                    self.succeed(waited=self.elapsed)
        else:
            self.since = None
        self.fusion_silent()
