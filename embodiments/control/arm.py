"""One arm's controllers (thesis §6.3.2): joint paths with their force watchdog, the Cartesian controller and IK, guarded moves.

:class:`ArmController` turns an arm command into a joint position and velocity target at each
control tick, from the measured joints and wrist wrench it is given. It touches no robot: the
node that runs a robot's primitives runs it and streams the targets to the robot's interface
(:class:`~contactflow.embodiments.remote.RemoteRobot`), and an in-process simulated robot runs
it in its control hook (:class:`~contactflow.embodiments.sim_robot.SimRobot`).
"""

from __future__ import annotations

from collections.abc import Callable
from enum import StrEnum
from typing import Any

import numpy as np

from contactflow.embodiments.control.cartesian import CartesianController, CartesianParams, Mode
from contactflow.embodiments.control.ik import IKParams, VelocityIK
from contactflow.embodiments.control.kinematics import Kinematics
from contactflow.embodiments.control.trajectory import (
    ForceWatch,
    TrajectoryFollower,
    TrajectoryParams,
)
from contactflow.nodes.status import Status


class ArmMode(StrEnum):
    IDLE = "idle"  # sends nothing: the robot holds the last target, other sources may drive the joints
    JOINT = "joint"  # a joint path
    CARTESIAN = "cartesian"  # a pose, twist or wrench of the controlled frame
    GUARDED = "guarded"  # a twist until the wrist force changes


class ArmController:
    """The controllers of one arm; :meth:`update` once per control tick while :attr:`mode` is not idle.

    ``kin`` is the controllers' own model: the Cartesian controller puts it at the measured joints
    with the arm at its commanded joints. ``measured()`` is the model's joint vector as measured,
    ``target()`` the arm's joint target now (a new command starts from it: another source may have
    moved it), ``on_contact(detail)`` reports a path or guarded move stopped by a contact.
    """

    def __init__(self, kin: Kinematics, spec: Any, measured: Callable[[], np.ndarray],
                 target: Callable[[], np.ndarray], on_contact: Callable[[str], None]) -> None:
        self.kin, self.spec, self.name = kin, spec, spec.name
        self._measured, self._target, self._on_contact = measured, target, on_contact
        self._kidx = kin.q_index(spec.joints)
        self.ik = VelocityIK(kin, spec.joints, spec.ee_frame, posture=np.asarray(spec.home), params=IKParams())
        self.cart = CartesianController(kin, self.ik, CartesianParams())
        self.traj: TrajectoryFollower | None = None
        self.q_cmd = np.asarray(target(), dtype=np.float64).copy()
        self.mode = ArmMode.IDLE
        self.status = Status.IDLE
        self.abort_reason = ""
        self._guard: ForceWatch | None = None

    # -- commands --------------------------------------------------------------------------
    def _start(self, mode: ArmMode, failed: bool) -> None:
        if failed:  # a command to a failed robot fails at once
            self.stop()
            self.status, self.abort_reason = Status.FAILURE, "hardware_failure"
            return
        self.mode, self.status, self.abort_reason = mode, Status.RUNNING, ""

    def fail(self) -> None:
        """The robot failed: nothing runs any more, a running command fails."""
        running = self.status == Status.RUNNING
        self.stop()
        if running:
            self.status, self.abort_reason = Status.FAILURE, "hardware_failure"

    def stop(self) -> None:
        """Hold the current commanded position."""
        self.cart.stop()
        self.traj = None
        self.mode = ArmMode.IDLE
        if self.status == Status.RUNNING:
            self.status = Status.IDLE

    def _resync(self) -> None:
        """Start a new command from the joints' current target (other sources may have moved it)."""
        if self.mode == ArmMode.IDLE:
            self.q_cmd = np.asarray(self._target(), dtype=np.float64).copy()

    def execute_waypoints(self, waypoints: np.ndarray, speed: float | None, abort_force: float, failed: bool) -> None:
        """Follow joint waypoints; abort when the F/T force changes by more than ``abort_force`` N.

        Each segment is timed alone (``TrajectoryParams.min_segment``), so a densely planned path runs
        at 0.4 rad/s at most, and comes to rest where the path turns back. The empty-box benchmark was
        measured with this timing: timed along the path with an acceleration bound, its moves that
        started with the hand pressed against an object aborted more, and more boxes were left
        unemptied (the planner module uses that timing).
        """
        self._resync()
        w = np.asarray(waypoints, dtype=np.float64)
        if np.linalg.norm(w[0] - self.q_cmd) > 1e-6:
            w = np.vstack([self.q_cmd, w])
        self.traj = TrajectoryFollower(w, TrajectoryParams(max_velocity=speed or self.spec.max_velocity, abort_force=abort_force))
        self._start(ArmMode.JOINT, failed)

    def _cart_start(self) -> None:
        self._resync()
        self.traj = None
        self.cart.reset(self.q_cmd)
        q = self._measured()
        q[self._kidx] = self.q_cmd
        self.kin.update(q)

    def move_pose(self, T: np.ndarray, frame: str, speed: float, failed: bool) -> None:
        self._cart_start()
        self.cart.set_pose(T, frame, speed)
        self._start(ArmMode.CARTESIAN, failed)

    def set_twist(self, twist: np.ndarray, frame: str, duration: float | None, failed: bool) -> None:
        self._cart_start()
        self.cart.set_twist(twist, frame, duration)
        self._start(ArmMode.CARTESIAN, failed)

    def set_wrench(self, wrench: np.ndarray, frame: str, failed: bool) -> None:
        if not self.spec.ft:
            raise ValueError(f"arm {self.name} has no F/T sensor for wrench control")
        self._cart_start()
        self.cart.set_wrench(wrench, frame)
        self._start(ArmMode.CARTESIAN, failed)

    def guarded_move(self, twist: np.ndarray, frame: str, max_force: float, duration: float | None, failed: bool) -> None:
        """Move at ``twist`` until the wrist force changes by ``max_force`` N (SUCCESS + CONTACT)."""
        if not self.spec.ft:
            raise ValueError(f"arm {self.name} has no F/T sensor for a guarded move")
        self._cart_start()
        self.cart.set_twist(twist, frame, duration)
        self._guard = ForceWatch(max_force)
        self._start(ArmMode.GUARDED, failed)

    # -- control tick ----------------------------------------------------------------------
    def update(self, q_arm: np.ndarray, dt: float, force: np.ndarray | None,
               wrench: np.ndarray | None) -> tuple[np.ndarray, np.ndarray] | None:
        """This tick's (position, velocity) target of the arm's joints, or None when idle.

        ``q_arm``: the arm's measured joints; ``force`` and ``wrench``: the wrist F/T (world
        axes), None without a sensor.
        """
        if self.mode == ArmMode.IDLE:
            return None
        if self.mode == ArmMode.JOINT and self.traj is not None:
            q, qd = self.traj.step(dt, force)
            self.q_cmd = q
            if self.traj.status == Status.FAILURE:
                self.abort_reason = self.traj.abort_reason
                self._on_contact(f"arm {self.name}: trajectory aborted on contact")
                self.q_cmd = np.asarray(q_arm, dtype=np.float64).copy()
                qd = np.zeros_like(qd)
            if self.traj.status != Status.RUNNING:
                self.status = self.traj.status
                self.mode = ArmMode.IDLE
            return self.q_cmd.copy(), qd
        # measured joints: the controller substitutes its own commanded arm joints
        q, qd = self.cart.update(self._measured(), dt, wrench)
        self.q_cmd = q
        if self.mode == ArmMode.GUARDED and force is not None and self._guard is not None:
            if self._guard.update(force, dt):
                self.cart.stop()
                self.q_cmd = np.asarray(q_arm, dtype=np.float64).copy()
                qd = np.zeros_like(qd)
                self.status, self.mode = Status.SUCCESS, ArmMode.IDLE
                self._on_contact(f"arm {self.name}: guarded move stopped on contact")
            elif self.cart.status == Status.SUCCESS:
                self.status, self.mode = Status.FAILURE, ArmMode.IDLE
                self.abort_reason = "no contact"
        elif self.cart.mode == Mode.IDLE:
            self.status = self.cart.status
            self.mode = ArmMode.IDLE
            if self.status == Status.FAILURE:
                self.abort_reason = "not reached"
        return self.q_cmd.copy(), qd
