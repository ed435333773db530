"""Contacts told by the robot's contact fusion (thesis ch. 4), for primitives that take them instead of a sensor of their own."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from contactflow.fusion.messages import ContactInfo, ContactList
from contactflow.fusion.regions import Region
from contactflow.nodes.keys import KeySpace
from contactflow.nodes.module import Port


@dataclass(frozen=True)
class FusedParams:
    """The fields every primitive that can sense through the fusion shares (its ``sensor`` names the choice)."""

    fused_timeout: float = 1.0  # s; sensor fused: a contact list this old says nothing, and none this long fails
    region: str = ""  # sensor fused: count only the contacts on this region of the hand (finger | palm | held_object); "": all

    def check_fused(self, sensor: str) -> None:
        """Refuse a region that is not one, a region without the fused sensor, a timeout that is not positive."""
        if self.region and self.region not in set(Region):
            raise ValueError(f"region: {self.region!r} is not one of {[str(r) for r in Region]}")
        if self.region and sensor != "fused":
            raise ValueError(f"region: {self.region!r} needs sensor fused (the fused contacts tell the region), "
                             f"not {sensor!r}")
        if self.fused_timeout <= 0:
            raise ValueError(f"fused_timeout: {self.fused_timeout} must be > 0 s")


CONTACT_SENSORS = ("own", "fused")
LIKELY = 0.9  # of the most likely new contact's likelihood: as likely, for telling the leading one


@dataclass(frozen=True)
class ContactSensorParams(FusedParams):
    """A guarded motion's choice: stop on its own reading of the wrist and pads, or on the fused contacts."""

    sensor: str = "own"  # how the contact is told: own (wrist F/T over force_threshold, or a pad) | fused

    def validate(self) -> None:
        if self.sensor not in CONTACT_SENSORS:
            raise ValueError(f"sensor: {self.sensor!r} is not one of {list(CONTACT_SENSORS)}")
        self.check_fused(self.sensor)


class SensesFusedContacts:
    """Mixed into a primitive (before :class:`Primitive`): its ``contacts`` input is the robot's fused
    contacts (a ``contact_fusion`` module of the robot publishes them), read by :meth:`fused_on_hand`."""

    inputs = (Port("contacts", ContactList, "the robot's fused contacts (sensor: fused)"),)

    @classmethod
    def default_input_keys(cls, ks: KeySpace, robot: str, name: str, params: Any) -> dict[str, str]:
        """The fused contacts of the robot the module is hosted for (a ``contact_fusion`` module with ``robot`` set)."""
        return {"contacts": ks.fused(robot, "contacts")}

    def fused_on_hand(self) -> list[ContactInfo] | None:
        """The contacts the robot's fusion places on this arm's hand now (of ``params.region``, if set), and
        ``self.evidence`` the list they came in (``source#seq``); None without a list fresher than
        ``params.fused_timeout`` (:meth:`fusion_silent` tells when that lasted too long)."""
        p = self.params
        msg = self.io.latest("contacts") if self.io is not None else None
        if not isinstance(msg, ContactList) or msg.stamp < self.r.time - p.fused_timeout:
            return None
        self.heard = self.r.time
        self.evidence = f"{msg.hdr.source}#{msg.hdr.seq}"
        return [c for c in msg.contacts
                if c.robot == self.r.name and c.link == self.hand_name and (not p.region or c.region == p.region)]

    def start_fused(self) -> None:
        """Call at ``begin``: nothing heard yet, as of now."""
        if not self.hand_name:
            raise ValueError(f"{self.name}: params.sensor fused: arm {self.arm_name!r} has no hand to hold contacts")
        self.heard = self.r.time
        self.evidence = ""
        self._before: int | None = None  # the contacts on the hand in the first list heard

    def new_fused_contact(self, moving: np.ndarray) -> ContactInfo | None:
        """A contact the fusion places on the hand that was not there when the primitive began (more contacts
        than in the first list heard). Of the most likely ones, the one furthest along ``moving`` (world): a
        wrist wrench alone is told at every surface its line of action crosses, and a hand moving into
        something meets it with its leading surface (a thumb tip on the table, not the palm above it)."""
        found = self.fused_on_hand()
        if found is None:
            return None
        if self._before is None:
            self._before = len(found)
        if len(found) <= self._before:
            return None
        best = max(c.likelihood for c in found)
        return max((c for c in found if c.likelihood >= LIKELY * best), key=lambda c: float(np.dot(c.location, moving)))

    def sensed_contact(self, prefix: str, moving: np.ndarray) -> dict[str, float] | None:
        """A contact sensed now, moving along ``moving`` (world), by ``params.sensor``: own (the wrist's force
        over ``params.force_threshold``, or a pad), no values; fused (:meth:`new_fused_contact`), where the fusion
        places it (``<prefix>_x``...)."""
        p = self.params
        if p.sensor == "own":
            f = self.wrench_in("world")[:3]
            return {} if np.linalg.norm(f) > p.force_threshold or self.pads_in_contact() else None
        c = self.new_fused_contact(moving)
        return None if c is None else {f"{prefix}_{k}": v for k, v in zip("xyz", c.location, strict=True)}

    def told_by(self) -> str:
        """What told a contact, for an event's detail: the fused contact list it came in, or nothing (own)."""
        return f" (fused contacts {self.evidence})" if self.params.sensor == "fused" else ""

    def fusion_silent(self) -> bool:
        """With ``sensor: fused``, no fresh contact list for ``params.fused_timeout`` (no fusion runs for the
        robot): the primitive fails saying so, and this is True."""
        p = self.params
        if p.sensor != "fused" or self.r.time - self.heard <= p.fused_timeout:
            return False
        self.fail(f"no fused contacts of {self.r.name} for {p.fused_timeout:g} s: is a contact_fusion "
                  f"module running for the robot?")
        return True
