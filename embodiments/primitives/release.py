"""Release (thesis §3.3.4, eq. 3.5): open the hand; back the arm off along the surface normal while the fingers push on it."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from contactflow.embodiments.primitives.base import Capability, Primitive
from contactflow.nodes.status import Event


def release_velocity(force: np.ndarray, normal: np.ndarray, speed: float, threshold: float) -> np.ndarray:
    """Eq. 3.5: move away (+n v) while the reaction along the surface normal exceeds the threshold, else 0."""
    if float(force @ normal) > threshold:
        return normal * speed
    return np.zeros(3)


class Release(Primitive):
    """Open the hand to ``hand_target`` (0 closed .. 1 open), compliant to finger contacts with the surface."""

    requires = Capability(ft=True, hand=True)
    events = (Event.SUCCESS, Event.FAILURE, Event.ERROR, Event.CONTACT)

    @dataclass(frozen=True)
    class Params(Primitive.Params):
        hand_target: float = 1.0  # 0 = fully closed, 1 = fully open
        force_threshold: float = 5.0  # N, fingers pushing on the supporting plane
        surface_normal: tuple[float, ...] = (0.0, 0.0, 1.0)  # world
        velocity: float = 0.001  # m/s, back-off speed
        opening_velocity: float = 0.5  # rad/s (m/s for a gripper), smooth opening
        tolerance: float = 0.05  # rad (m), hand target reached
        timeout: float = 10.0  # s

    def begin(self) -> None:
        p = self.params
        n = np.asarray(p.surface_normal, dtype=np.float64)
        if n.shape != (3,) or np.linalg.norm(n) < 1e-9:
            raise ValueError(f"{self.name}: params.surface_normal must be a non-zero 3-vector, got {p.surface_normal}")
        self.n = n / np.linalg.norm(n)
        spec = self.r.spec.hand(self.hand_name)
        opened = np.asarray(spec.preshapes["open"], dtype=np.float64)
        closed = np.asarray(spec.preshapes["closed"], dtype=np.float64)
        s = float(np.clip(p.hand_target, 0.0, 1.0))
        self.goal = closed + s * (opened - closed)
        self.travel = float(np.abs(opened - closed).max())
        self.target = self.hand.positions().copy()
        self.r.tare_ft(self.arm_name)
        self.z0 = self.r.frame_pose(self.ee_frame)[:3, 3].copy()
        self.backoffs = 0

    def update(self) -> None:
        p = self.params
        dt = 1.0 / p.rate_hz
        step = p.opening_velocity * dt
        self.target = self.target + np.clip(self.goal - self.target, -step, step)
        self.hand.set_fingers(self.target)
        f = self.wrench_in("world")[:3]
        v = release_velocity(f, self.n, p.velocity, p.force_threshold)
        if v.any():
            if self.backoffs == 0:
                self.emit_once(Event.CONTACT, f"fingers push on the surface ({float(f @ self.n):.1f} N): backing off")
            self.backoffs += 1
        self.twist(np.concatenate([v, np.zeros(3)]))
        backed = float((self.r.frame_pose(self.ee_frame)[:3, 3] - self.z0) @ self.n)
        q = self.hand.positions()
        # a gripper's jaws travel a few centimetres: the tolerance shrinks with the travel
        if np.abs(q - self.goal).max() <= min(p.tolerance, 0.1 * self.travel):
            self.succeed(backoff=backed, backoff_steps=self.backoffs)
        elif self.elapsed > p.timeout:
            self.fail(f"hand not open after {p.timeout} s (max error {np.abs(q - self.goal).max():.3f})",
                      backoff=backed, backoff_steps=self.backoffs)
