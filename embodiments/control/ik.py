"""Velocity IK: damped pseudo-inverse of the frame Jacobian, joint limits, posture and limit avoidance in the null space."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from contactflow.embodiments.control.kinematics import Kinematics


@dataclass(frozen=True)
class IKParams:
    damping: float = 0.02  # damping of the pseudo-inverse (m, rad)
    posture_gain: float = 0.5  # 1/s, pull toward the posture in the null space
    limit_margin: float = 0.02  # rad, keep this far from joint limits
    limit_return_gain: float = 2.0  # 1/s, rate at which a joint found inside the margin is brought back out of it
    limit_zone: float = 0.3  # rad inside the margin where the null space starts pushing a joint away from its limit
    limit_zone_gain: float = 2.0  # 1/s, that push per rad of depth into the zone
    max_joint_velocity: float = 1.5  # rad/s


class VelocityIK:
    """Joint velocities of ``joints`` that realise a twist of ``frame`` (world axes)."""

    def __init__(self, kin: Kinematics, joints: tuple[str, ...], frame: str, posture: np.ndarray | None = None,
                 params: IKParams | None = None) -> None:
        self.kin, self.frame = kin, frame
        self.joints = tuple(joints)
        self.idx = kin.q_index(self.joints)
        self.params = params or IKParams()
        self.posture = np.asarray(posture, dtype=np.float64) if posture is not None else None
        self.lower = kin.lower[self.idx] + self.params.limit_margin
        self.upper = kin.upper[self.idx] - self.params.limit_margin
        kin.frame_id(frame)

    def bounds(self, q: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """Joint velocity bounds: never past the margin in one tick; a joint already inside the margin
        (a joint-space planner ends on the hard limit) leaves it at ``limit_return_gain``, not in one tick,
        which would be a velocity step that jerks the arm and its F/T."""
        p = self.params
        lo = np.where(q < self.lower, p.limit_return_gain * (self.lower - q), (self.lower - q) / dt)
        hi = np.where(q > self.upper, p.limit_return_gain * (self.upper - q), (self.upper - q) / dt)
        return lo, hi

    def limit_push(self, q: np.ndarray) -> np.ndarray:
        """Null-space velocity away from the limits for the joints within ``limit_zone`` of their margin, so
        the redundancy is spent before a joint stops on its limit and the arm loses that degree of freedom."""
        p = self.params
        into_lo = np.clip(p.limit_zone - (q - self.lower), 0.0, p.limit_zone)
        into_hi = np.clip(p.limit_zone - (self.upper - q), 0.0, p.limit_zone)
        return p.limit_zone_gain * (into_lo - into_hi)

    def solve(self, twist: np.ndarray, dt: float) -> np.ndarray:
        """qd for the arm joints at the model's current state (call ``kin.update`` first)."""
        p = self.params
        J = self.kin.jacobian(self.frame)[:, self.idx]
        q = self.kin.q[self.idx]
        active = np.ones(len(self.idx), dtype=bool)
        qd = np.zeros(len(self.idx))
        lo, hi = self.bounds(q, dt)
        secondary = self.limit_push(q)
        if self.posture is not None and p.posture_gain > 0:
            secondary = secondary + p.posture_gain * (self.posture - q)
        for _ in range(3):
            Ja = J[:, active]
            Jp = Ja.T @ np.linalg.inv(Ja @ Ja.T + p.damping**2 * np.eye(6))
            sol = Jp @ (np.asarray(twist, dtype=np.float64) - J[:, ~active] @ qd[~active])
            N = np.eye(Ja.shape[1]) - Jp @ Ja
            sol += N @ secondary[active]
            qd[active] = sol
            over = active & ((qd < lo) | (qd > hi))
            if not over.any():
                break
            qd[over] = np.clip(qd[over], lo[over], hi[over])
            active &= ~over
            if not active.any():
                break
        qd = np.clip(qd, lo, hi)
        peak = np.abs(qd).max(initial=0.0)
        if peak > p.max_joint_velocity:
            qd *= p.max_joint_velocity / peak
        return qd
