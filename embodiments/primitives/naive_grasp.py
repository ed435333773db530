"""Naive grasp, the thesis baseline of §3.4.1: move forward 10 cm or to a contact, close stopping each touching finger, tighten the distal phalanxes."""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

import numpy as np

from contactflow.embodiments.primitives.base import Capability, Primitive
from contactflow.embodiments.primitives.hands import ClosingRamp, finger_groups, held_fingers
from contactflow.nodes.status import Event


class Phase(StrEnum):
    PRESHAPE = "preshape"
    APPROACH = "approach"
    CLOSE = "close"
    TIGHTEN = "tighten"


class NaiveGrasp(Primitive):
    """Non-adaptive grasp: no corrective motion; sensors only stop the approach and each finger."""

    requires = Capability(ft=True, hand=True)
    events = (Event.SUCCESS, Event.FAILURE, Event.ERROR, Event.CONTACT, Event.GRASP_STABLE)

    @dataclass(frozen=True)
    class Params(Primitive.Params):
        pregrasp_type: str = ""  # hand preshape before the grasp ("" = current configuration)
        force_threshold: float = 2.0  # N, contact detection with the F/T (same default as the robust grasp)
        grasp_direction: tuple[float, ...] = (0.0, 0.0, 1.0)  # hand frame
        max_distance: float = 0.10  # m, "moves forward 10 cm or until a contact is detected"
        approach_velocity: float = 0.04  # m/s, same forward speed as the robust grasp
        closing_velocity: float = 0.8  # rad/s (m/s for a gripper), same as the robust grasp
        effort: float = 1.0  # 0..1 finger force limit
        distal_increment: float = 0.3  # rad (m for a gripper), extra closing of the distal joints at the end
        min_contacts: int = 2  # pads in contact to report SUCCESS

    def begin(self) -> None:
        p = self.params
        d = np.asarray(p.grasp_direction, dtype=np.float64)
        if d.shape != (3,) or np.linalg.norm(d) < 1e-9:
            raise ValueError(f"{self.name}: params.grasp_direction must be a non-zero 3-vector, got {p.grasp_direction}")
        self.dir = d / np.linalg.norm(d)
        self.spec = self.r.spec.hand(self.hand_name)
        self.groups = finger_groups(self.spec)
        self.closed = np.asarray(self.spec.preshapes["closed"], dtype=np.float64)
        self._t_phase = self.r.time
        if p.pregrasp_type:
            self.hand.preshape(p.pregrasp_type)
        self.phase = Phase.PRESHAPE

    def _to(self, phase: Phase) -> None:
        self.phase, self._t_phase = phase, self.r.time

    def update(self) -> None:
        p = self.params
        dt = 1.0 / p.rate_hz
        if self.phase is Phase.PRESHAPE:
            if self.hand.done() or self.r.time - self._t_phase > 1.0:
                self.r.tare_ft(self.arm_name)
                self.p0 = self.r.frame_pose(self.ee_frame)[:3, 3].copy()
                self._to(Phase.APPROACH)
            return
        if self.phase is Phase.APPROACH:
            T = self.r.frame_pose(self.ee_frame)
            travelled = float((T[:3, 3] - self.p0) @ (T[:3, :3] @ self.dir))
            contact = bool(np.linalg.norm(self.wrench_in(self.ee_frame)[:3]) > p.force_threshold) \
                or bool(self.pads_in_contact())
            if contact:
                self.emit_once(Event.CONTACT, "grasp approach touched")
            if self.blocked():
                self.relax()
                contact = True
            if contact or travelled >= p.max_distance:
                self.halt()
                self.ramp = ClosingRamp(self.hand.positions(), self.closed, p.closing_velocity)
                self._to(Phase.CLOSE)
                return
            self.twist(np.concatenate([self.dir * p.approach_velocity, np.zeros(3)]), frame=self.ee_frame)
            return
        if self.phase is Phase.CLOSE:
            q = self.hand.positions()
            for pad in self.pads_in_contact():
                idx = self.groups.get(pad)
                if idx is not None and not self.ramp.frozen[idx].all():
                    self.ramp.freeze(idx, q)
            self.hand.set_fingers(self.ramp.advance(dt), effort=p.effort)
            stalled = self.ramp.observe(self.r.time, q)
            if self.ramp.reached or (stalled and self.r.time - self._t_phase > 0.3) or self.r.time - self._t_phase > 6.0:
                target = self.ramp.target.copy()
                for distal in sorted({int(idx[-1]) for idx in self.groups.values()}):
                    target[distal] = min(target[distal] + p.distal_increment, self.closed[distal]) \
                        if self.closed[distal] >= target[distal] else target[distal] - p.distal_increment
                self.hand.set_fingers(target, effort=p.effort)
                self.tight = target
                self._to(Phase.TIGHTEN)
            return
        if self.phase is Phase.TIGHTEN and (self.hand.done() or self.r.time - self._t_phase > 1.0):
            pads = self.pads_in_contact()
            need = min(p.min_contacts, len(self.groups))
            vals = dict(contacts=len(pads))
            # held open against the command, not against the closed preshape: a finger frozen at a
            # touch stays open by its own target even after the object rolled away
            if len(held_fingers(self.hand.positions(), self.tight, self.groups, pads)) >= need:
                self.emit_once(Event.GRASP_STABLE, f"pads in contact: {pads}", vals)
                self.succeed(f"grasped with {pads}", **vals)
            else:
                self.fail(f"closed with pads in contact: {pads}", **vals)
