"""Wrist force-torque sensor from the joint constraint force at the hand mount (or estimated from joint efforts).

The measured wrench is the one the environment and the load exert on the hand, in world
axes, minus a tare taken in world axes. A PhysX incoming-joint force is the constraint
wrench from parent to child expressed in the joint frame; it includes the weight of the
hand, which the tare removes. Beside the tared wrench a reading carries the *external*
wrench (thesis §4.4.3: "the external forces and torques applied to the end effector"): the
raw one minus what the hand's own weight and motion press on the sensor, from the robot's
model (`HandLoad`), so it reads the load of a held object, stays still while the arm jerks,
and drops to zero when the object is lost, whatever a primitive tared meanwhile. For
``estimated`` sensors (Baxter, App. A.4.2) the wrench is solved from the arm drive efforts
through the transposed Jacobian, as the real robot does, and is noisier.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

from contactflow.embodiments.hand_geometry import link_subtree
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
    external: np.ndarray = field(default_factory=lambda: np.zeros(6))  # N, N m: untared, minus the hand's own weight and motion

    @property
    def vector(self) -> np.ndarray:
        return np.concatenate([self.force, self.torque])

    def external_in_sensor_frame(self) -> tuple[np.ndarray, np.ndarray]:
        """The external wrench (what the environment and a held load exert) in the sensor frame."""
        R = self.R_world_sensor
        return R.T @ self.external[:3], R.T @ self.external[3:]


def _rotate(R: np.ndarray, wrench: np.ndarray) -> np.ndarray:
    """A wrench's force and torque rotated by ``R`` (same origin)."""
    return (wrench.reshape(2, 3) @ R.T).ravel()


class WristFT:
    """Sample-and-hold F/T at ``spec.rate_hz`` with Gaussian noise and a constant bias."""

    def __init__(self, art, spec: FTSpec, seed: int = 0, kin=None, arm_joints: tuple[str, ...] = (),
                 dynamics: RobotDynamics | None = None) -> None:
        """``dynamics``: the robot's, shared by its sensors (one Newton-Euler pass a physics step); one of its own
        when not given."""
        self.art, self.spec = art, spec
        self.link = art.links[spec.link]
        self._joint = self.link.get_joint()  # the hand mount's joint (its binding looked up once, not per sample)
        self.rng = np.random.default_rng(seed)
        self._noise = np.repeat([spec.force_noise, spec.torque_noise], 3)  # N, N m: standard deviations
        self._bias = np.asarray(spec.bias, dtype=np.float64)
        self.tare_value = np.zeros(6)
        self._last: WrenchReading | None = None
        self.kin, self.arm_joints = kin, arm_joints
        self.lost = False
        if spec.estimated:
            if kin is None or not arm_joints:
                raise ValueError(f"F/T {spec.name}: estimated sensors need the kinematics and the arm joints")
            self._sidx = art.indices(arm_joints)
            self._kidx = kin.q_index(arm_joints)
        self._hand_model = None if spec.estimated or kin is None else \
            HandLoad(dynamics or RobotDynamics(art, kin), spec.link)

    def _raw(self) -> np.ndarray:
        if self.spec.estimated:
            tau = self.art.drive_efforts()[self._sidx]
            J = self.kin.jacobian(self.spec.link)[:, self._kidx]
            # drives balance the external wrench: tau = -J^T w
            return -np.linalg.lstsq(J.T, tau, rcond=None)[0]
        fw = self.art.incoming_joint_forces()[self.link.get_index()]
        # the constraint acts on the hand; the load on the sensor is its opposite
        return -_rotate(pose_to_matrix(self._joint.get_global_pose())[:3, :3], fw)

    def _load(self, R_world_sensor: np.ndarray) -> np.ndarray:
        """What the hand's own weight and motion press on the sensor (world axes, about its origin);
        an estimated wrench never sees them (the arm's drives are gravity-compensated)."""
        if self._hand_model is None:
            return np.zeros(6)
        return _rotate(R_world_sensor, self._hand_model.wrench())

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
        raw = self._raw()
        s = self.spec
        # the same draws as normal(0, sd) per axis, force then torque, without its broadcasting (4x dearer)
        noise = self.rng.standard_normal(6) * self._noise + self._bias
        w = raw - self.tare_value + noise
        R = self._pose()[:3, :3]
        self._last = WrenchReading(t, w[:3], w[3:], s.link, R, s.estimated, raw - self._load(R) + noise)
        return self._last


class RobotDynamics:
    """Recursive Newton-Euler on the robot's model at the simulator's joint positions, velocities and
    accelerations, run at most once a physics step: every F/T sensor of the robot reads the same pass."""

    def __init__(self, art, kin) -> None:
        self.art = art
        self.model = pin.Model(kin.model)
        R_base = kin.base[:3, :3]
        self.model.gravity.linear = R_base.T @ np.asarray(art.world.params.gravity, dtype=np.float64)
        self.data = self.model.createData()
        self._q, self._v, self._acc = (np.zeros(self.model.nq) for _ in range(3))  # filled at each pass
        self._kidx = kin.q_index(art.joint_names)
        self._step = -1

    def solved(self) -> pin.Data:
        """The data of this physics step's pass (``f``, ``v``, ``a_gf``, ``liMi`` of every joint)."""
        steps = self.art.world.steps
        if steps != self._step:
            a = self.art.articulation
            q, v, acc = self._q, self._v, self._acc
            q[self._kidx], v[self._kidx], acc[self._kidx] = a.get_qpos(), a.get_qvel(), a.get_qacc()
            pin.rnea(self.model, self.data, q, v, acc)
            self._step = steps
        return self.data


class HandLoad:
    """The wrench the hand's links (every link past the sensor) press on the sensor, from the
    robot's model: their weight and the force that accelerates them (recursive Newton-Euler on the
    simulator's joint positions, velocities and accelerations). What a robot's F/T compensation
    computes from its encoders and its hand's identified inertia; the rest of the reading is
    external: the environment's and a held load's."""

    def __init__(self, dynamics: RobotDynamics, sensor_link: str) -> None:
        self.dynamics = dynamics
        model = dynamics.model
        hand_joints = {lk.get_joint().get_name() for lk in link_subtree(dynamics.art.links[sensor_link])}
        fid = model.getFrameId(sensor_link)
        if fid >= len(model.frames):
            raise ValueError(f"F/T on {sensor_link!r}: the robot's model has no such link")
        self.joint = model.frames[fid].parentJoint
        # the hand's links fixed to the sensor's body (their inertia sits on the fixed joint
        # frames that hang them), and the hand's moving joints whose subtrees are fingers
        self.fixed = pin.Inertia.Zero()
        for f in model.frames:
            if f.parentJoint == self.joint and f.type == pin.FrameType.FIXED_JOINT and f.name in hand_joints:
                self.fixed += f.placement.act(f.inertia)
        self.roots = [i for i in range(1, model.njoints)
                      if model.parents[i] == self.joint and model.names[i] in hand_joints]
        self.origin = model.frames[fid].placement  # the sensor's origin on its body

    def wrench(self) -> np.ndarray:
        """The load on the sensor, in its link's frame."""
        d = self.dynamics.solved()
        j = self.joint
        # the support the sensor's body gives the hand: fixed links plus each finger subtree
        support = self.fixed * d.a_gf[j] + d.v[j].cross(self.fixed * d.v[j])
        for i in self.roots:
            support += d.liMi[i].act(d.f[i])
        # the load on the sensor is the opposite of that support
        return -self.origin.actInv(support).vector
