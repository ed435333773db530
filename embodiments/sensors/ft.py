"""Wrist force-torque sensor from the joint constraint force at the hand mount (or estimated from joint efforts).

The measured wrench is the one the environment and the load exert on the hand, in world
axes, minus a tare taken in world axes. A PhysX incoming-joint force is the constraint
wrench from parent to child expressed in the joint frame; it includes the weight of the
hand, which the tare removes. For ``estimated`` sensors (Baxter, App. A.4.2) the wrench is
solved from the arm drive efforts through the transposed Jacobian, as the real robot does,
and is noisier.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from contactflow.embodiments.registry import FTSpec
from contactflow.embodiments.transforms import pose_to_matrix


@dataclass(frozen=True)
class WrenchReading:
    """One F/T sample: force/torque in world axes, at the sensor origin."""

    t: float
    force: np.ndarray
    torque: np.ndarray
    frame: str  # sensor link
    R_world_sensor: np.ndarray  # rotation of the sensor frame (for sensor-frame values)
    estimated: bool = False  # True when solved from joint efforts rather than measured

    @property
    def vector(self) -> np.ndarray:
        return np.concatenate([self.force, self.torque])

    def in_sensor_frame(self) -> tuple[np.ndarray, np.ndarray]:
        R = self.R_world_sensor
        return R.T @ self.force, R.T @ self.torque


class WristFT:
    """Sample-and-hold F/T at ``spec.rate_hz`` with Gaussian noise and a constant bias."""

    def __init__(self, art, spec: FTSpec, seed: int = 0, kin=None, arm_joints: tuple[str, ...] = ()) -> None:
        self.art, self.spec = art, spec
        self.link = art.links[spec.link]
        self.rng = np.random.default_rng(seed)
        self.tare_value = np.zeros(6)
        self._last: WrenchReading | None = None
        self.kin, self.arm_joints = kin, arm_joints
        self.lost = False
        if spec.estimated:
            if kin is None or not arm_joints:
                raise ValueError(f"F/T {spec.name}: estimated sensors need the kinematics and the arm joints")
            self._sidx = art.indices(arm_joints)
            self._kidx = kin.q_index(arm_joints)

    def _raw(self) -> np.ndarray:
        if self.spec.estimated:
            tau = self.art.drive_efforts()[self._sidx]
            J = self.kin.jacobian(self.spec.link)[:, self._kidx]
            # drives balance the external wrench: tau = -J^T w
            return -np.linalg.lstsq(J.T, tau, rcond=None)[0]
        fw = np.asarray(self.art.articulation.get_link_incoming_joint_forces()[self.link.get_index()], dtype=np.float64)
        R = pose_to_matrix(self.link.get_joint().get_global_pose())[:3, :3]
        # the constraint acts on the hand; the load on the sensor is its opposite
        return -np.concatenate([R @ fw[:3], R @ fw[3:]])

    def _pose(self) -> np.ndarray:
        return pose_to_matrix(self.link.get_entity_pose())

    @property
    def stamp(self) -> float:
        """Time of the latest sample (-inf before the first): what a stream watchdog checks."""
        return self._last.t if self._last is not None else -np.inf

    def tare(self) -> None:
        """Zero the sensor at the current (noise-free) reading; a silent sensor cannot be tared."""
        if self.lost:
            return
        self.tare_value = self._raw()
        self._last = None

    def read(self, t: float) -> WrenchReading:
        """The sample valid at time ``t`` (a new one every 1/rate_hz); a lost stream repeats its last sample."""
        if self.lost:
            if self._last is None:
                zero = np.zeros(3)
                return WrenchReading(-np.inf, zero, zero, self.spec.link, np.eye(3), self.spec.estimated)
            return self._last
        if self._last is not None and (t - self._last.t) < 1.0 / self.spec.rate_hz - 1e-9:
            return self._last
        w = self._raw() - self.tare_value
        s = self.spec
        noise = np.concatenate([self.rng.normal(0, s.force_noise, 3), self.rng.normal(0, s.torque_noise, 3)])
        w = w + noise + np.asarray(s.bias, dtype=np.float64)
        self._last = WrenchReading(t, w[:3], w[3:], s.link, self._pose()[:3, :3], s.estimated)
        return self._last
