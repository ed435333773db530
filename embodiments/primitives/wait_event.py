"""Wait event (§6.3.6 auxiliary): wait for a sensed condition (grasp lost/stable, contact, motion) or a delay."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from contactflow.embodiments.primitives.base import Primitive, low_pass
from contactflow.fusion.messages import ContactList
from contactflow.fusion.regions import Region
from contactflow.nodes.keys import KeySpace
from contactflow.nodes.module import Port
from contactflow.nodes.status import Event

SENSORS = ("hand", "tactile", "gripper_effort", "wrist_ft", "fused")
"""How a grasp is told (thesis Tables 7.3-7.4, one per robot): the hand's contact information or joint
configuration (§3.3.1), tactile pad pressure, the gripper's motor effort, the load on the wrist; or the
robot's fused contacts (thesis ch. 4: every cue of the robot fused into contacts on its links)."""


class WaitEvent(Primitive):
    """Emits ``event`` when its condition holds: grasp_lost / grasp_stable (by ``sensor``), contact (F/T), or after ``delay``.

    Used as a helper next to another primitive (e.g. watch for GRASP_LOST while transporting)
    or alone as a delay (``event: success``). ``finish`` ends the primitive with SUCCESS when the
    event fired; otherwise it keeps running and emits once.
    """

    events = (Event.SUCCESS, Event.FAILURE, Event.ERROR, Event.GRASP_LOST, Event.GRASP_STABLE, Event.CONTACT)
    commands_arm = False
    inputs = (Port("contacts", ContactList, "the robot's fused contacts (sensor: fused)"),)

    @dataclass(frozen=True)
    class Params(Primitive.Params):
        event: str = "success"  # grasp_lost | grasp_stable | contact | success (= plain delay)
        delay: float = 0.0  # s before the condition is checked (the whole wait for "success")
        force_threshold: float = 5.0  # N, for "contact"
        finish: bool = True  # end with SUCCESS after the event
        grace: float = 0.2  # s a tactile condition must hold
        sensor: str = "hand"  # grasp sensing: hand (pads touching or fingers held open) | tactile | gripper_effort | wrist_ft | fused
        threshold: float = 0.0  # N, a grasp holds at this total pad pressure, grip force or wrist load (not "hand")
        min_contacts: int = 1  # pads in contact for a hand or tactile grasp
        filter_hz: float = 0.0  # Hz, low-pass cut-off of the wrist load (0: none; for noisy estimated wrenches)
        fused_timeout: float = 1.0  # s; sensor fused: a contact list this old says nothing, and none this long fails the wait
        region: str = ""  # sensor fused: count only the contacts on this region of the hand (finger | palm | held_object); "": all

        def validate(self) -> None:
            if self.sensor not in SENSORS:
                raise ValueError(f"sensor: {self.sensor!r} is not one of {list(SENSORS)}")
            if self.region and self.region not in set(Region):
                raise ValueError(f"region: {self.region!r} is not one of {[str(r) for r in Region]}")
            if self.region and self.sensor != "fused":
                raise ValueError(f"region: {self.region!r} needs sensor fused (the fused contacts tell the region), "
                                 f"not {self.sensor!r}")

    @classmethod
    def default_input_keys(cls, ks: KeySpace, robot: str, name: str, params: Params) -> dict[str, str]:
        """The fused contacts of the robot the module is hosted for (a ``contact_fusion`` module with ``robot`` set)."""
        return {"contacts": ks.fused(robot, "contacts")}

    def begin(self) -> None:
        try:
            self.event = Event(self.params.event)
        except ValueError:
            raise ValueError(f"{self.name}: params.event {self.params.event!r} is not an event") from None
        if self.event not in (Event.GRASP_LOST, Event.GRASP_STABLE, Event.CONTACT, Event.SUCCESS):
            raise ValueError(f"{self.name}: cannot wait for {self.event} (grasp_lost, grasp_stable, contact, success)")
        fused = self.params.sensor == "fused"
        self.f0 = self.wrench_in("world")[:3] if self.event is Event.CONTACT and not fused else np.zeros(3)
        self.heard = self.r.time  # sensor fused: when a fresh contact list was last read
        self.evidence = ""  # ... and which one (source#seq), named in the event it fires
        self.since: float | None = None
        self.fired = False
        self.load: float | None = None  # N, the low-passed wrist load
        if self.params.sensor == "wrist_ft" and not self.r.spec.arm(self.arm_name).ft:
            raise ValueError(f"{self.name}: params.sensor wrist_ft: arm {self.arm_name!r} has no wrist F/T")
        if fused and not self.hand_name:
            raise ValueError(f"{self.name}: params.sensor fused: arm {self.arm_name!r} has no hand to hold contacts")

    def fused_contacts(self) -> int | None:
        """Contacts the robot's fusion places on this arm's hand now; None without a fresh contact list."""
        msg = self.io.latest("contacts") if self.io is not None else None
        if not isinstance(msg, ContactList) or msg.stamp < self.r.time - self.params.fused_timeout:
            return None
        self.heard = self.r.time
        self.evidence = f"{msg.hdr.source}#{msg.hdr.seq}"
        region = self.params.region
        return sum(1 for c in msg.contacts
                   if c.robot == self.r.name and c.link == self.hand_name and (not region or c.region == region))

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
            n = self.fused_contacts()
            if n is None:  # no fused contacts: neither a grasp nor its loss is sensed
                return False
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
                    by = f" (fused contacts {self.evidence})" if p.sensor == "fused" else ""
                    self.emit_once(self.event, f"{self.event} observed{by}")
                if p.finish:
                    self.succeed(waited=self.elapsed)
        else:
            self.since = None
        if p.sensor == "fused" and self.r.time - self.heard > p.fused_timeout:
            self.fail(f"no fused contacts of {self.r.name} for {p.fused_timeout:g} s: is a contact_fusion module "
                      f"running for the robot?")
