"""Unscrew (thesis §3.3.6, Fig. 3.11): pinch the cap, twist, pull; regrasp on resistance; re-centre on the cap from the tactile contacts."""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

import numpy as np

from contactflow.embodiments.primitives.base import Capability, Primitive
from contactflow.embodiments.primitives.hands import ClosingRamp, finger_groups
from contactflow.nodes.status import Event


class Phase(StrEnum):
    PINCH = "pinch"
    TWIST = "twist"
    PULL = "pull"
    REOPEN = "reopen"
    RETURN = "return"


class Unscrew(Primitive):
    """Pinch-twist-pull cycles until the cap is ``cap_removed_distance`` away; needs a multi-finger hand with pads."""

    requires = Capability(ft=True, hand=True, tactile=True)
    hand_kinds = ("multi_finger",)
    events = (Event.SUCCESS, Event.FAILURE, Event.ERROR, Event.GRASP_STABLE)

    @dataclass(frozen=True)
    class Params(Primitive.Params):
        unscrew_torque_limit: float = 10.0  # N m, twist stops above it
        pull_force_limit: float = 7.0  # N, pulling stops above it (cap still screwed)
        grasping_fingers: int = 2  # fingers used to pinch (thumb + index for 2)
        finger_grasping_force: float = 5.0  # N per fingertip
        twist_angle: float = 30.0  # deg per twist
        finger_min_distance: float = 0.012  # m, closer fingertips = empty hand
        cap_removed_distance: float = 0.04  # m
        pull_velocity: float = 0.01  # m/s
        twist_velocity: float = 0.5  # rad/s
        closing_velocity: float = 0.6  # rad/s
        recenter: bool = True  # tactile cap re-centring (reactive adaptation)
        max_cycles: int = 8

    def begin(self) -> None:
        spec = self.r.spec.hand(self.hand_name)
        groups = finger_groups(spec)
        pads = [pd.name for pd in spec.pads]
        n = max(2, min(self.params.grasping_fingers, len(pads)))
        self.fingers = [pads[-1]] + pads[: n - 1]  # thumb + first fingers
        self.tips = dict(zip(pads, spec.fingertips, strict=False))
        closed = np.asarray(spec.preshapes.get("pinch", spec.preshapes["closed"]), dtype=np.float64)
        self.goal = self.hand.positions().copy()
        for f in self.fingers:
            self.goal[groups[f]] = np.asarray(spec.preshapes["closed"], dtype=np.float64)[groups[f]]
        self.pinch_shape = closed
        self.groups = groups
        self.home = self.r.frame_pose(self.ee_frame).copy()
        self.cycles = 0
        self.corrections = 0
        self.contacts: list[np.ndarray] = []
        self.nominal: np.ndarray | None = None
        self._pinch()

    def _pinch(self) -> None:
        self.ramp = ClosingRamp(self.hand.positions(), self.goal, self.params.closing_velocity)
        self.phase, self.t_phase = Phase.PINCH, self.r.time

    def _tip_gap(self) -> float:
        a = self.r.frame_pose(self.tips[self.fingers[0]])[:3, 3]
        b = self.r.frame_pose(self.tips[self.fingers[1]])[:3, 3]
        return float(np.linalg.norm(a - b))

    def _record_contacts(self) -> None:
        """Fingertip midpoint while both pinching fingers touch, in the frame of the start pose."""
        forces = self.pad_forces()
        pts = [self.r.frame_pose(self.tips[f])[:3, 3] for f in self.fingers if forces.get(f, 0.0) > 0.05]
        if len(pts) == len(self.fingers):
            T = self.r.frame_pose(self.ee_frame)
            local = T[:3, :3].T @ (np.mean(pts, axis=0) - T[:3, 3])
            self.contacts.append(self.home[:3, 3] + self.home[:3, :3] @ local)

    def _regrasp(self, why: str) -> None:
        if self.io is not None:
            self.io.log(f"regrasp: {why}")
        self.hand.open()
        self.phase, self.t_phase = Phase.REOPEN, self.r.time

    def update(self) -> None:
        p = self.params
        dt = 1.0 / p.rate_hz
        forces = self.pad_forces()
        if self.phase is Phase.PINCH:
            for f in self.fingers:
                if forces.get(f, 0.0) >= p.finger_grasping_force:
                    self.ramp.freeze(self.groups[f], self.ramp.target)
            self.hand.set_fingers(self.ramp.advance(dt))
            self._record_contacts()
            if all(forces.get(f, 0.0) >= p.finger_grasping_force for f in self.fingers):
                self.emit_once(Event.GRASP_STABLE, "cap pinched")
                if self.nominal is None:
                    # the grasping fingers' centre in the hand frame: where the cap should sit
                    mid = np.mean([self.r.frame_pose(self.tips[f])[:3, 3] for f in self.fingers], axis=0)
                    T = self.r.frame_pose(self.ee_frame)
                    self.nominal = T[:3, :3].T @ (mid - T[:3, 3])
                self.contacts = []
                self.r.tare_ft(self.arm_name)
                self.twisted = 0.0
                # rotate about the axis through the fingers' centre, not the hand frame origin
                r = self.nominal if self.nominal is not None else np.zeros(3)
                w = np.array([0.0, 0.0, p.twist_velocity])
                self.twist(np.concatenate([-np.cross(w, r), w]), frame=self.ee_frame)
                self.phase, self.t_phase = Phase.TWIST, self.r.time
            elif self._tip_gap() < p.finger_min_distance or self.r.time - self.t_phase > 3.0:
                self.fail("fingers closed without pinching the cap", cycles=self.cycles)
            return
        if self.phase is Phase.TWIST:
            self._record_contacts()
            self.twisted += p.twist_velocity * dt
            torque = float(np.linalg.norm(self.wrench_in(self.ee_frame)[3:]))
            if torque > p.unscrew_torque_limit or self._tip_gap() < p.finger_min_distance:
                self.halt()
                self._regrasp(f"twist stopped (torque {torque:.1f} N m)")
                return
            if self.twisted >= np.deg2rad(p.twist_angle):
                self.halt()
                self.start_pull = self.r.frame_pose(self.ee_frame)[:3, 3].copy()
                self.r.tare_ft(self.arm_name)
                self.twist(np.array([0.0, 0.0, -p.pull_velocity, 0.0, 0.0, 0.0]), frame=self.ee_frame)
                self.phase, self.t_phase = Phase.PULL, self.r.time
            return
        if self.phase is Phase.PULL:
            self._record_contacts()
            pulled = float(np.linalg.norm(self.r.frame_pose(self.ee_frame)[:3, 3] - self.start_pull))
            f = float(np.linalg.norm(self.wrench_in(self.ee_frame)[:3]))
            if not any(forces.get(x, 0.0) > 0.05 for x in self.fingers):
                self.hand.set_fingers(self.goal)
            if pulled >= p.cap_removed_distance:
                self.succeed(cycles=self.cycles + 1, corrections=self.corrections, pulled=pulled)
            elif f > p.pull_force_limit or self._tip_gap() < p.finger_min_distance:
                self.halt()
                self._regrasp(f"pull resisted ({f:.1f} N, finger gap {self._tip_gap() * 1000:.0f} mm)")
            return
        if self.phase is Phase.REOPEN:
            if self.hand.done() or self.r.time - self.t_phase > 1.0:
                self.cycles += 1
                if self.cycles >= p.max_cycles:
                    self.fail(f"cap not removed after {p.max_cycles} cycles", cycles=self.cycles)
                    return
                goal = self.home.copy()
                if p.recenter and self.contacts and self.nominal is not None:
                    # the averaged contacts are the cap centre: move the fingers' centre onto it
                    c = np.mean(self.contacts, axis=0)
                    off = c - (self.home[:3, 3] + self.home[:3, :3] @ self.nominal)
                    off -= (off @ self.home[:3, 2]) * self.home[:3, 2]
                    if np.linalg.norm(off) > 0.002:
                        goal[:3, 3] += off
                        self.corrections += 1
                self.contacts = []
                self.home = goal
                self.arm.move_pose(goal, speed=0.05)
                self.phase, self.t_phase = Phase.RETURN, self.r.time
            return
        if self.phase is Phase.RETURN and (self.arm.done() or self.r.time - self.t_phase > 3.0):
            self._pinch()
