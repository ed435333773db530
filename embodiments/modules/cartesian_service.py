"""Cartesian controller service (thesis §6.3.2): Cartesian targets of one arm to joint commands through pinocchio velocity IK.

The service keeps its own pinocchio model of the robot at the measured joint state and runs
:class:`~contactflow.embodiments.control.cartesian.CartesianController` (straight-line pose
moves, twists, admittance wrench control) on it. Its ``joint_command`` output commands the
shared resource ``arm_<arm>``, so one class exists per arm name (a resource is part of a
module type's declaration); the interface layer mixes it with other commanders by weight.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, ClassVar, TypeVar

import numpy as np

from contactflow.embodiments.control.cartesian import CartesianController, CartesianParams, Mode
from contactflow.embodiments.control.ik import IKParams, VelocityIK
from contactflow.embodiments.control.kinematics import Kinematics, KinematicsError
from contactflow.embodiments.messages import CartesianTarget, JointCommand, JointState, Wrench
from contactflow.embodiments.modules.sim_interface import COMMAND_PORT
from contactflow.nodes.module import Layer, Module, ModuleIO, Port
from contactflow.nodes.status import Status
from contactflow.nodes.wire import NDArray

if TYPE_CHECKING:
    from contactflow.embodiments.registry import ArmSpec, RobotSpec

_SIZES = {"pose": 16, "twist": 6, "wrench": 6, "stop": 0}


class TargetError(ValueError):
    """A CartesianTarget that cannot be executed."""


def measured_q(kin: Kinematics, msg: JointState, where: str) -> np.ndarray:
    """The full model joint vector of ``kin`` at the joint state ``msg`` (other joints as in ``kin``)."""
    q_in = msg.position.numpy().astype(np.float64).ravel()
    if q_in.shape[0] != len(msg.names) or not np.isfinite(q_in).all():
        raise ValueError(f"{where}: input 'joint_state' has {q_in.shape[0]} positions for "
                         f"{len(msg.names)} names or non-finite values")
    try:
        idx = kin.q_index(msg.names)
    except KinematicsError as exc:
        raise ValueError(f"{where}: input 'joint_state': {exc}") from None
    q = kin.q.copy()
    q[idx] = q_in
    return q


class CartesianControllerService(Module):
    """Follows the newest Cartesian target of its arm and publishes the arm's joint command at the control rate."""

    abstract = True
    layer = Layer.SERVICE
    arm: ClassVar[str] = ""
    inputs = (
        Port("joint_state", JointState, "measured joints of the robot"),
        Port("target", CartesianTarget, "pose, twist, wrench or stop of the controlled frame"),
        Port("wrench", Wrench, "wrist F/T of the arm, for wrench targets"),
    )

    @dataclass(frozen=True)
    class Params:
        rate_hz: float = 200.0  # Hz, the joint control rate (§6.3.1)
        robot: str = "melfa"  # embodiment registry name (URDF, arm chain, controlled frame, home posture)
        gain: float = 10.0  # 1/s, proportional correction toward the reference
        max_speed: float = 0.25  # m/s, bound on any commanded linear speed
        damping: float = 0.02  # damping of the IK pseudo-inverse (m, rad)

    def __init__(self, name: str, params: Params | None = None) -> None:
        super().__init__(name, params)
        self.kin: Kinematics | None = None
        self.ctl: CartesianController | None = None
        self.rejected = 0

    def setup(self, io: ModuleIO) -> None:
        super().setup(io)
        from contactflow.embodiments.transforms import xyz_rpy_to_matrix

        p = self.params
        spec, a = arm_of(self)
        self.joints = list(a.joints)
        self.kin = Kinematics(spec.urdf(), xyz_rpy_to_matrix(spec.base_xyz, spec.base_rpy))
        self.ik = VelocityIK(self.kin, a.joints, a.ee_frame, posture=np.asarray(a.home), params=IKParams(damping=p.damping))
        self.ctl = CartesianController(self.kin, self.ik, CartesianParams(gain=p.gain, max_speed=p.max_speed))
        self._last_t: float | None = None

    def start(self) -> None:
        self.ctl.stop()
        self._last_t = None

    def reset(self) -> None:
        self.ctl.stop()
        self.ctl.q_cmd = None

    @property
    def status(self) -> Status:
        """Outcome of the newest target (IDLE, RUNNING, SUCCESS, FAILURE)."""
        return self.ctl.status if self.ctl is not None else Status.IDLE

    def _apply(self, t: CartesianTarget, q: np.ndarray) -> None:
        where = f"{self.name}: input 'target' ({t.hdr.source or 'unknown source'})"
        if t.mode not in _SIZES:
            raise TargetError(f"{where}: mode {t.mode!r} is not one of {sorted(_SIZES)}")
        v = np.asarray(t.values, dtype=np.float64)
        if v.shape != (_SIZES[t.mode],) or not np.isfinite(v).all():
            raise TargetError(f"{where}: a {t.mode} target needs {_SIZES[t.mode]} finite values, got {v.shape[0]}")
        if t.frame != "world":
            try:
                self.kin.frame_id(t.frame)
            except KinematicsError as exc:
                raise TargetError(f"{where}: field 'frame': {exc}") from None
        if t.mode == "stop":
            self.ctl.stop()
            return
        if self.ctl.mode == Mode.IDLE or self.ctl.q_cmd is None:
            self.ctl.reset(q[self.ik.idx])  # start from where the arm is (other commanders may have moved it)
        q = q.copy()
        q[self.ik.idx] = self.ctl.q_cmd
        self.kin.update(q)
        if t.mode == "pose":
            T = v.reshape(4, 4)
            if not np.allclose(T[3], (0, 0, 0, 1)) or not np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-4):
                raise TargetError(f"{where}: field 'values' is not a homogeneous rigid transform (row-major 4x4)")
            if t.speed <= 0:
                raise TargetError(f"{where}: field 'speed' {t.speed} is not positive")
            self.ctl.set_pose(T, t.frame, t.speed)
        elif t.mode == "twist":
            self.ctl.set_twist(v, t.frame)
        else:
            self.ctl.set_wrench(v, t.frame)

    def step(self) -> Status:
        js = self.io.latest("joint_state")
        if js is None:
            return Status.RUNNING
        q = measured_q(self.kin, js, self.name)
        for t in self.io.take("target"):
            if t.arm != self.arm:
                continue
            try:
                self._apply(t, q)
            except TargetError as exc:
                self.rejected += 1
                self.io.log(str(exc))
        now = self.io.now
        period = 1.0 / self.params.rate_hz
        dt = period if self._last_t is None else min(max(now - self._last_t, 0.0), 5 * period)
        self._last_t = now
        if self.ctl.mode == Mode.IDLE or dt <= 0:
            return Status.RUNNING  # an idle arm sends nothing: the interface holds its last target
        w = self.io.latest("wrench")
        wrench = np.asarray([*w.force, *w.torque]) if w is not None and w.arm == self.arm else None
        q_cmd, qd = self.ctl.update(q, dt, wrench)
        self.io.publish(COMMAND_PORT, JointCommand(names=self.joints, position=NDArray.of(q_cmd),
                                                   velocity=NDArray.of(np.ascontiguousarray(qd)), source=self.name))
        return Status.RUNNING


M = TypeVar("M", bound=Module)


def arm_of(module: Module) -> tuple[RobotSpec, ArmSpec]:
    """The robot spec of ``module.params.robot`` and its arm ``module.arm``; errors name the module."""
    from contactflow.embodiments import registry

    spec = registry.configured(module.params.robot, f"{module.name}.params.robot")
    arms = {a.name: a for a in spec.arms}
    if module.arm not in arms:
        raise ValueError(f"{module.name}: robot {spec.name!r} has no arm {module.arm!r} (arms: {sorted(arms)}); "
                         f"use the module type of one of those arms")
    return spec, arms[module.arm]


def command_port(arm: str) -> tuple[Port, ...]:
    """The output of a commander of arm ``arm``: joint commands on the resource ``arm_<arm>``."""
    return (Port(COMMAND_PORT, JointCommand, f"joint command of arm {arm!r}", resource=f"arm_{arm}"),)


def for_arm(name: str, base: type[M], arm: str) -> type[M]:
    """``base`` bound to the arm ``arm`` as class ``name``: a module type per arm, each claiming its own resource."""
    return type(name, (base,), {
        "__doc__": f"{base.__doc__.splitlines()[0]} Arm {arm!r}; commands resource ``arm_{arm}``.",
        "__module__": base.__module__, "arm": arm, "resources": (f"arm_{arm}",), "outputs": command_port(arm)})


LeftArmCartesianController = for_arm("LeftArmCartesianController", CartesianControllerService, "left")  # tombatossals, baxter
RightArmCartesianController = for_arm("RightArmCartesianController", CartesianControllerService, "right")
SingleArmCartesianController = for_arm("SingleArmCartesianController", CartesianControllerService, "arm")  # melfa
