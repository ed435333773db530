"""Push (§6.3.6): move the hand along a direction for a distance, compliantly, stopping at a force limit."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from contactflow.embodiments.primitives.base import Capability, Primitive, pose6
from contactflow.nodes.status import Event


class Push(Primitive):
    """Push along ``direction`` (world) by ``distance``; over ``force_limit`` N it stops with FAILURE."""

    requires = Capability(ft=True)
    events = (Event.SUCCESS, Event.FAILURE, Event.ERROR, Event.CONTACT)
    sign: ClassVar[float] = 1.0

    @dataclass(frozen=True)
    class Params(Primitive.Params):
        direction: tuple[float, ...] = (1.0, 0.0, 0.0)  # world
        distance: float = 0.05  # m
        velocity: float = 0.02  # m/s
        force_limit: float = 15.0  # N
        contact_threshold: float = 1.0  # N, reported as the first contact with the object

    def begin(self) -> None:
        d = np.asarray(self.params.direction, dtype=np.float64)
        if d.shape != (3,) or np.linalg.norm(d) < 1e-9:
            raise ValueError(f"{self.name}: params.direction must be a non-zero 3-vector, got {self.params.direction}")
        self.d = self.sign * d / np.linalg.norm(d)
        self.r.tare_ft(self.arm_name)
        self.p0 = self.r.frame_pose(self.ee_frame)[:3, 3].copy()
        self.touched = False
        self.peak = 0.0

    def update(self) -> None:
        p = self.params
        T = self.r.frame_pose(self.ee_frame)
        moved = float((T[:3, 3] - self.p0) @ self.d)
        f = self.wrench_in("world")[:3]
        along = float(-f @ self.d)  # the object resists the motion: the reaction points backwards
        self.peak = max(self.peak, along)
        if not self.touched and np.linalg.norm(f) > p.contact_threshold:
            self.touched = True
            self.emit_once(Event.CONTACT, "object contacted")
        if np.linalg.norm(f) >= p.force_limit:
            self.fail(f"force limit {p.force_limit} N reached", moved=moved, force=float(np.linalg.norm(f)))
            return
        if moved >= p.distance:
            self.succeed(moved=moved, peak_force=self.peak, **pose6(T))
            return
        self.twist(np.concatenate([self.d * p.velocity, np.zeros(3)]))
