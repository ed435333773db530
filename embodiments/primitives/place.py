"""Place (thesis §3.3.3, eq. 3.4): move the grasped object along -n until the wrist force reaches the threshold."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from contactflow.embodiments.primitives.base import Capability, Primitive, low_pass, pose6
from contactflow.nodes.status import Event


def place_velocity(force: np.ndarray, normal: np.ndarray, speed: float, threshold: float) -> np.ndarray:
    """Eq. 3.4: -v_place (= -n v) while ||F|| < F_threshold, else 0."""
    if np.linalg.norm(force) >= threshold:
        return np.zeros(3)
    return -normal * speed


class Place(Primitive):
    """Lower the object onto a supporting surface; success once the contact force is sensed."""

    requires = Capability(ft=True)
    events = (Event.SUCCESS, Event.FAILURE, Event.ERROR, Event.CONTACT)

    @dataclass(frozen=True)
    class Params(Primitive.Params):
        force_threshold: float = 5.0  # N, supporting plane contacted
        surface_normal: tuple[float, ...] = (0.0, 0.0, 1.0)  # world, normal of the supporting surface
        velocity: float = 0.005  # m/s, toward the surface
        max_distance: float = 0.3  # m, travel before giving up
        filter_hz: float = 0.0  # Hz, low-pass cut-off on the wrist force (0 = none; for noisy estimated wrenches)

    def begin(self) -> None:
        p = self.params
        n = np.asarray(p.surface_normal, dtype=np.float64)
        if n.shape != (3,) or np.linalg.norm(n) < 1e-9:
            raise ValueError(f"{self.name}: params.surface_normal must be a non-zero 3-vector, got {p.surface_normal}")
        self.n = n / np.linalg.norm(n)
        self.r.tare_ft(self.arm_name)
        self.p0 = self.r.frame_pose(self.ee_frame)[:3, 3].copy()
        self.f = np.zeros(3)

    def update(self) -> None:
        p = self.params
        self.f = f = low_pass(self.f, self.wrench_in("world")[:3], p.filter_hz, 1.0 / p.rate_hz)
        v = place_velocity(f, self.n, p.velocity, p.force_threshold)
        T = self.r.frame_pose(self.ee_frame)
        travelled = float((self.p0 - T[:3, 3]) @ self.n)
        if not v.any():
            self.emit_once(Event.CONTACT, f"surface reached, |F| = {np.linalg.norm(f):.1f} N")
            self.succeed(force=float(np.linalg.norm(f)), travelled=travelled, **pose6(T))
            return
        if travelled >= p.max_distance:
            self.fail(f"no surface within {p.max_distance} m", travelled=travelled)
            return
        self.twist(np.concatenate([v, np.zeros(3)]))
