"""Slide (thesis §3.3.5, eq. 3.6): press an object against its support with a force in [Fmin, Fmax] while moving it to the target."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from contactflow.embodiments.primitives.base import Capability, Primitive, pose6
from contactflow.nodes.status import Event


def slide_velocity(fn: float, to_target: np.ndarray, normal: np.ndarray, fmin: float, fmax: float,
                   v_target: float, v_contact: float) -> np.ndarray:
    """Eq. 3.6: toward the target inside the force band, press (-n) below it, loosen (+n) above it."""
    if fn <= fmin:
        return -normal * v_contact
    if fn >= fmax:
        return normal * v_contact
    dist = float(np.linalg.norm(to_target))
    if dist < 1e-9:
        return np.zeros(3)
    return to_target / dist * min(v_target, dist)


class Slide(Primitive):
    """Non-prehensile sliding with a hook-like preshape; success when the hand reaches ``target`` (x, y, z)."""

    requires = Capability(ft=True)
    events = (Event.SUCCESS, Event.FAILURE, Event.ERROR, Event.CONTACT)

    @dataclass(frozen=True)
    class Params(Primitive.Params):
        target: tuple[float, ...] = ()  # [x, y, z] m, world target of the hand (the height is kept)
        upper_force_threshold: float = 9.0  # N, Fmax
        lower_force_threshold: float = 5.0  # N, Fmin
        surface_normal: tuple[float, ...] = (0.0, 0.0, 1.0)  # world
        target_velocity: float = 0.005  # m/s, toward the target
        contact_velocity: float = 0.005  # m/s, pressing / loosening
        preshape: str = "closed"  # hand preshape used to slide ("" = keep)
        tolerance: float = 0.005  # m
        timeout: float = 60.0  # s
        dwell: float = 0.2  # s, minimum duration of one velocity command

    def begin(self) -> None:
        p = self.params
        t = np.asarray(p.target, dtype=np.float64)
        n = np.asarray(p.surface_normal, dtype=np.float64)
        if t.shape != (3,):
            raise ValueError(f"{self.name}: params.target must be [x, y, z], got {p.target}")
        if n.shape != (3,) or np.linalg.norm(n) < 1e-9:
            raise ValueError(f"{self.name}: params.surface_normal must be a non-zero 3-vector")
        self.target, self.n = t, n / np.linalg.norm(n)
        if p.preshape and self.hand_name:
            self.hand.preshape(p.preshape)
        self.r.tare_ft(self.arm_name)
        self.in_band = 0
        self.touched = False
        self._since = -np.inf

    def update(self) -> None:
        p = self.params
        T = self.r.frame_pose(self.ee_frame)
        f = self.wrench_in("world")[:3]
        fn = float(f @ self.n)  # the support pushes the hand back along +n
        to_target = self.target - T[:3, 3]
        to_target -= (to_target @ self.n) * self.n
        if not self.touched and fn > p.lower_force_threshold:
            self.touched = True
            self.emit_once(Event.CONTACT, "pressing the object")
        if self.touched and float(np.linalg.norm(to_target)) <= p.tolerance:
            self.succeed(force=fn, in_band_steps=self.in_band, **pose6(T))
            return
        if self.elapsed > p.timeout:
            self.fail(f"target not reached after {p.timeout} s", event=Event.TIMEOUT)
            return
        v = slide_velocity(fn, to_target, self.n, p.lower_force_threshold, p.upper_force_threshold,
                           p.target_velocity, p.contact_velocity)
        if p.lower_force_threshold < fn < p.upper_force_threshold:
            self.in_band += 1
        # a new twist restarts the arm's Cartesian controller: keep each command at least dwell s
        if self.r.time - self._since >= p.dwell:
            self._since = self.r.time
            self.twist(np.concatenate([np.round(v, 4), np.zeros(3)]))
