"""Unscrew (thesis §3.3.6, Fig. 3.11): pinch the cap, twist, pull; grasp again on resistance or a pinch that missed; re-centre on the cap from the tactile contacts."""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

import numpy as np

from contactflow.embodiments.primitives.base import (
    TACTILE_CONTACT,
    Capability,
    Primitive,
    PrimitiveError,
)
from contactflow.embodiments.primitives.hands import ClosingRamp, finger_groups
from contactflow.embodiments.sensors.tactile import taxel_positions
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
        pinch_center: tuple[float, ...] = ()  # m, where a centred cap sits between the pinching fingertips, in the controlled frame; () = where the first pinch found it
        max_cycles: int = 8

    def begin(self) -> None:
        p = self.params
        if p.pinch_center and len(p.pinch_center) != 3:
            raise PrimitiveError(f"{self.name}: params.pinch_center must be [x, y, z] (m) or empty, got {list(p.pinch_center)}")
        spec = self.r.spec.hand(self.hand_name)
        groups = finger_groups(spec)
        pads = list(spec.pads)
        n = max(2, min(p.grasping_fingers, len(pads)))
        chosen = [pads[-1]] + pads[: n - 1]  # thumb + first fingers
        self.fingers = [pd.name for pd in chosen]
        self.pads = {pd.name: pd for pd in chosen}
        self.taxels = {pd.name: taxel_positions(pd) for pd in chosen}
        self.goal = self.hand.positions().copy()
        closed = np.asarray(spec.preshapes["closed"], dtype=np.float64)
        for f in self.fingers:
            self.goal[groups[f]] = closed[groups[f]]
        self.groups = groups
        self.home = self.r.frame_pose(self.ee_frame).copy()
        self.cycles = 0
        self.corrections = 0
        self.slips = 0  # pulls that ended without the cap in the fingers
        self.twists = 0
        self.contacts: list[np.ndarray] = []
        self.edges: list[np.ndarray] = []  # single pads' contacts of a pinch that has not closed on the cap
        self.misses = 0  # pinches that closed without the cap
        self.nominal: np.ndarray | None = np.asarray(p.pinch_center, dtype=np.float64) if p.pinch_center else None
        self._pinch()

    def _pinch(self) -> None:
        self.ramp = ClosingRamp(self.hand.positions(), self.goal, self.params.closing_velocity)
        self.phase, self.t_phase = Phase.PINCH, self.r.time

    def _tip_gap(self) -> float:
        a = self.r.frame_pose(self.pads[self.fingers[0]].link)[:3, 3]
        b = self.r.frame_pose(self.pads[self.fingers[1]].link)[:3, 3]
        return float(np.linalg.norm(a - b))

    def _touches(self) -> list[np.ndarray]:
        """The pressure centroids (world) of the pinching pads that touch."""
        images = self.r.tactile(self.hand_name)
        pts = []
        for f in self.fingers:
            img = images.get(f)
            if img is None or float(img.max(initial=0.0)) <= TACTILE_CONTACT:
                continue
            local = (img[..., None] * self.taxels[f]).sum(axis=(0, 1)) / float(img.sum())
            T = self.r.frame_pose(self.pads[f].link)
            pts.append(T[:3, :3] @ local + T[:3, 3])
        return pts

    def _contact_centre(self) -> np.ndarray | None:
        """Midpoint of the pinching pads' pressure centroids (world), or None unless every pinching pad touches."""
        pts = self._touches()
        return np.mean(pts, axis=0) if len(pts) == len(self.fingers) else None

    def _in_hand(self, point: np.ndarray) -> np.ndarray:
        T = self.r.frame_pose(self.ee_frame)
        return T[:3, :3].T @ (point - T[:3, 3])

    def _record_contacts(self) -> None:
        """The contact centre (world) while every pinching pad touches; averaged, it is where the cap is. A pad
        touching alone is kept apart: a pinch that closed beside the cap knows only the side it touched."""
        pts = self._touches()
        if len(pts) == len(self.fingers):
            self.contacts.append(np.mean(pts, axis=0))
        elif pts:
            self.edges.extend(pts)

    def _twist_about_centre(self) -> None:
        """Turn about the approach axis through the fingers' centre; re-sent every step as the centre's lever arm turns."""
        T = self.r.frame_pose(self.ee_frame)
        # a right-hand thread opens counter-clockwise seen from outside the cap: about -z of a frame approaching along +z
        w = -self.params.twist_velocity * T[:3, 2]
        centre = T[:3, :3] @ self.nominal + T[:3, 3]
        self.twist(np.concatenate([np.cross(w, T[:3, 3] - centre), w]), frame="world")

    def _twisted(self) -> float:
        R = self.twist_start[:3, :3].T @ self.r.frame_pose(self.ee_frame)[:3, :3]
        return float(abs(np.arctan2(R[1, 0], R[0, 0])))

    def _keep_closing(self, forces: dict[str, float]) -> None:
        """Contact with the cap lost while twisting or pulling: the fingers close until they feel it again."""
        if not any(forces.get(f, 0.0) > TACTILE_CONTACT for f in self.fingers):
            self.hand.set_fingers(self.goal)

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
                    # no calibrated centre: the cap is taken to sit where this first pinch found it
                    c = self._contact_centre()
                    self.nominal = self._in_hand(c) if c is not None else np.zeros(3)
                self.r.tare_ft(self.arm_name)
                self.twist_start = self.r.frame_pose(self.ee_frame).copy()
                self._twist_about_centre()
                self.phase, self.t_phase = Phase.TWIST, self.r.time
            elif self._tip_gap() < p.finger_min_distance or self.r.time - self.t_phase > 3.0:
                self.misses += 1
                self._regrasp("fingers closed without pinching the cap")
            return
        if self.phase is Phase.TWIST:
            self._record_contacts()
            self._keep_closing(forces)
            torque = float(np.linalg.norm(self.wrench_in(self.ee_frame)[3:]))
            if torque > p.unscrew_torque_limit or self._tip_gap() < p.finger_min_distance:
                self.halt()
                self._regrasp(f"twist stopped (torque {torque:.1f} N m)")
                return
            if self._twisted() >= np.deg2rad(p.twist_angle):
                self.halt()
                self.twists += 1
                self.start_pull = self.r.frame_pose(self.ee_frame)[:3, 3].copy()
                self.r.tare_ft(self.arm_name)
                self.twist(np.array([0.0, 0.0, -p.pull_velocity, 0.0, 0.0, 0.0]), frame=self.ee_frame)
                self.phase, self.t_phase = Phase.PULL, self.r.time
                return
            self._twist_about_centre()
            return
        if self.phase is Phase.PULL:
            self._record_contacts()
            pulled = float(np.linalg.norm(self.r.frame_pose(self.ee_frame)[:3, 3] - self.start_pull))
            f = float(np.linalg.norm(self.wrench_in(self.ee_frame)[:3]))
            self._keep_closing(forces)
            if pulled >= p.cap_removed_distance:
                # "pulls the cap further than": a hand that slipped off a cap still screwed on moves as freely
                if all(forces.get(finger, 0.0) > TACTILE_CONTACT for finger in self.fingers):
                    self.succeed(cycles=self.cycles + 1, twists=self.twists, corrections=self.corrections, pulled=pulled,
                                 misses=self.misses)
                else:
                    self.halt()
                    self.slips += 1
                    self._regrasp(f"pulled {pulled * 100:.0f} cm without the cap in the fingers")
            elif f > p.pull_force_limit or self._tip_gap() < p.finger_min_distance:
                self.halt()
                self._regrasp(f"pull resisted ({f:.1f} N, finger gap {self._tip_gap() * 1000:.0f} mm)")
            return
        if self.phase is Phase.REOPEN:
            if self.hand.done() or self.r.time - self.t_phase > 1.0:
                self.cycles += 1
                if self.cycles >= p.max_cycles:
                    self.fail(f"cap not removed after {p.max_cycles} cycles", cycles=self.cycles, twists=self.twists,
                              corrections=self.corrections, slips=self.slips, misses=self.misses)
                    return
                goal = self.home.copy()
                seen = self.contacts or self.edges  # a pinch that missed moves toward the side it touched
                if p.recenter and seen and self.nominal is not None:
                    # the averaged contacts are the cap centre: bring the fingers' centre of the start pose onto it
                    off = np.mean(seen, axis=0) - (self.home[:3, :3] @ self.nominal + self.home[:3, 3])
                    off -= (off @ self.home[:3, 2]) * self.home[:3, 2]
                    if np.linalg.norm(off) > 0.002:
                        goal[:3, 3] += off
                        self.corrections += 1
                self.contacts, self.edges = [], []
                self.home = goal
                self.arm.move_pose(goal, speed=0.05)
                self.phase, self.t_phase = Phase.RETURN, self.r.time
            return
        if self.phase is Phase.RETURN and (self.arm.done() or self.r.time - self.t_phase > 3.0):
            self._pinch()
