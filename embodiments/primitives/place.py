"""Place (thesis §3.3.3, eq. 3.4): move the grasped object along -n until the wrist force reaches the threshold.

Where the task says where the object goes (``target``: the grasp frame's pose with the object resting there), the
hand goes down faster until ``slow_distance`` above it, then at the thesis's ``velocity``: a place that starts from a
carry height 15 cm up takes 5 s rather than 30 s. The force guard holds in both phases.
"""

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


def place_speed(height: float | None, velocity: float, approach_velocity: float, slow_distance: float) -> float:
    """m/s toward the surface: ``approach_velocity`` while more than ``slow_distance`` above the expected rest
    (``height``, m along the normal; None: unknown), the thesis's ``velocity`` from there on."""
    if height is None or height <= slow_distance:
        return velocity
    return max(velocity, approach_velocity)


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
        target: tuple[float, ...] = ()  # [x, y, z, roll, pitch, yaw] m/rad, grasp frame with the object at rest; (): unknown
        approach_velocity: float = 0.05  # m/s, toward the surface while more than slow_distance above the target
        slow_distance: float = 0.04  # m above the target (along the normal) where the descent slows to velocity

    def begin(self) -> None:
        p = self.params
        n = np.asarray(p.surface_normal, dtype=np.float64)
        if n.shape != (3,) or np.linalg.norm(n) < 1e-9:
            raise ValueError(f"{self.name}: params.surface_normal must be a non-zero 3-vector, got {p.surface_normal}")
        self.n = n / np.linalg.norm(n)
        if p.target and len(p.target) != 6:
            raise ValueError(f"{self.name}: params.target must be [x, y, z, roll, pitch, yaw] or empty, got {p.target}")
        self.rest = np.asarray(p.target[:3], dtype=np.float64) if p.target else None
        self.r.tare_ft(self.arm_name)
        self.p0 = self.r.frame_pose(self.ee_frame)[:3, 3].copy()
        self.f = np.zeros(3)

    def update(self) -> None:
        p = self.params
        self.f = f = low_pass(self.f, self.wrench_in("world")[:3], p.filter_hz, 1.0 / p.rate_hz)
        T = self.r.frame_pose(self.ee_frame)
        height = float((T[:3, 3] - self.rest) @ self.n) if self.rest is not None else None
        v = place_velocity(f, self.n, place_speed(height, p.velocity, p.approach_velocity, p.slow_distance),
                           p.force_threshold)
        travelled = float((self.p0 - T[:3, 3]) @ self.n)
        if not v.any():
            self.emit_once(Event.CONTACT, f"surface reached, |F| = {np.linalg.norm(f):.1f} N")
            self.succeed(force=float(np.linalg.norm(f)), travelled=travelled, **pose6(T))
            return
        if travelled >= p.max_distance:
            self.fail(f"no surface within {p.max_distance} m", travelled=travelled)
            return
        self.twist(np.concatenate([v, np.zeros(3)]))
