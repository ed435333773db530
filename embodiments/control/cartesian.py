"""Cartesian controller: a target pose, twist or wrench in any known frame → joint position/velocity commands.

It integrates its own commanded joint vector through the velocity IK (as the thesis'
Cartesian controller + ik solver pipeline, §6.3.2) and returns position and velocity drive
targets. Pose targets follow a straight line at a bounded speed with a proportional
correction, so a commanded line is tracked, not just its end point.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

import numpy as np

from contactflow.embodiments.control.ik import VelocityIK
from contactflow.embodiments.control.kinematics import Kinematics
from contactflow.embodiments.transforms import rotvec_error, so3_exp
from contactflow.nodes.status import Status


class Mode(StrEnum):
    IDLE = "idle"
    POSE = "pose"
    TWIST = "twist"
    WRENCH = "wrench"


@dataclass(frozen=True)
class CartesianParams:
    gain: float = 10.0  # 1/s, proportional correction toward the reference
    speed: float = 0.1  # m/s, default linear speed of pose moves
    angular_speed: float = 0.8  # rad/s
    pos_tol: float = 0.001  # m, pose move done
    rot_tol: float = 0.01  # rad
    settle_tol: float = 0.003  # m, measured position error at which a pose move succeeds
    settle_timeout: float = 2.0  # s after the reference ends before a pose move fails
    admittance: float = 0.002  # m/s per N in wrench mode
    admittance_rot: float = 0.02  # rad/s per N m
    wrench_filter: float = 0.03  # s, time constant of the measured-wrench low-pass in wrench mode
    max_speed: float = 0.25  # m/s, bound on any commanded linear speed


class CartesianController:
    """One arm; call :meth:`update` at the control rate with the full model joint vector."""

    def __init__(self, kin: Kinematics, ik: VelocityIK, params: CartesianParams | None = None) -> None:
        self.kin, self.ik = kin, ik
        self.params = params or CartesianParams()
        self.mode = Mode.IDLE
        self.status = Status.IDLE
        self.q_cmd: np.ndarray | None = None
        self._t = 0.0
        self._ramp_t = 0.0
        self._duration: float | None = None

    @property
    def frame(self) -> str:
        return self.ik.frame

    def reset(self, q_arm: np.ndarray) -> None:
        self.q_cmd = np.asarray(q_arm, dtype=np.float64).copy()

    def _axes(self, frame: str) -> np.ndarray:
        return self.kin.frame_pose(frame)[:3, :3]

    def set_pose(self, T: np.ndarray, frame: str = "world", speed: float | None = None) -> None:
        """Move the controlled frame in a straight line to ``T`` (given in ``frame``)."""
        goal = self.kin.frame_pose(frame) @ np.asarray(T, dtype=np.float64) if frame != "world" else np.asarray(T, dtype=np.float64)
        start = self.kin.frame_pose(self.frame)
        speed = speed or self.params.speed
        dist = float(np.linalg.norm(goal[:3, 3] - start[:3, 3]))
        ang = float(np.linalg.norm(rotvec_error(goal[:3, :3], start[:3, :3])))
        self._duration = 1.5 * max(dist / speed, ang / self.params.angular_speed, 1e-3)  # smoothstep peak is 1.5x mean
        self._start, self._goal = start, goal
        self._rot = rotvec_error(goal[:3, :3], start[:3, :3])  # world-frame rotation start -> goal
        self._t = 0.0
        self.mode, self.status = Mode.POSE, Status.RUNNING

    def set_twist(self, twist: np.ndarray, frame: str = "world", duration: float | None = None) -> None:
        """Constant twist ``[v, w]`` of the controlled frame, in ``frame`` axes."""
        R = self._axes(frame) if frame != "world" else np.eye(3)
        tw = np.asarray(twist, dtype=np.float64)
        self._twist = np.concatenate([R @ tw[:3], R @ tw[3:]])
        if self.mode != Mode.TWIST:
            self._ramp_t = 0.0  # re-issuing a twist every tick (primitives do) must not restart the ramp
        self._duration, self._t = duration, 0.0
        self.mode, self.status = Mode.TWIST, Status.RUNNING

    def set_wrench(self, wrench: np.ndarray, frame: str = "world") -> None:
        """Admittance control toward the applied wrench ``wrench`` (``frame`` axes)."""
        self._wrench_frame = frame
        self._wrench = np.asarray(wrench, dtype=np.float64)
        self._t, self._duration = 0.0, None
        self._wf: np.ndarray | None = None
        self.mode, self.status = Mode.WRENCH, Status.RUNNING

    def stop(self) -> None:
        self.mode = Mode.IDLE
        if self.status == Status.RUNNING:
            self.status = Status.IDLE

    def _reference(self) -> tuple[np.ndarray, np.ndarray]:
        # smoothstep timing: zero velocity at both ends, so the hand does not jerk the F/T
        tau = min(self._t / self._duration, 1.0)
        s = tau * tau * (3.0 - 2.0 * tau)
        ds = 6.0 * tau * (1.0 - tau) / self._duration
        ref = np.eye(4)
        ref[:3, 3] = (1 - s) * self._start[:3, 3] + s * self._goal[:3, 3]
        ref[:3, :3] = so3_exp(s * self._rot) @ self._start[:3, :3]
        v = np.zeros(6)
        v[:3] = (self._goal[:3, 3] - self._start[:3, 3]) * ds
        v[3:] = self._rot * ds
        return ref, v

    def update(self, q_full: np.ndarray, dt: float, wrench: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Commanded (q, qd) of the arm joints for this tick. ``wrench``: measured F/T in world axes."""
        if self.q_cmd is None:
            self.reset(q_full[self.ik.idx])
        q = np.asarray(q_full, dtype=np.float64).copy()
        q[self.ik.idx] = self.q_cmd
        self.kin.update(q)
        if self.mode == Mode.IDLE:
            return self.q_cmd.copy(), np.zeros(len(self.q_cmd))
        self._t += dt
        p = self.params
        cur = self.kin.frame_pose(self.frame)
        if self.mode == Mode.POSE:
            ref, v_ff = self._reference()
            err = np.concatenate([ref[:3, 3] - cur[:3, 3], rotvec_error(ref[:3, :3], cur[:3, :3])])
            twist = v_ff + p.gain * err
            if self._t >= self._duration:
                gerr = np.concatenate([self._goal[:3, 3] - cur[:3, 3], rotvec_error(self._goal[:3, :3], cur[:3, :3])])
                reached = False
                if np.linalg.norm(gerr[:3]) < p.pos_tol and np.linalg.norm(gerr[3:]) < p.rot_tol:
                    # done when the measured arm, not only the command, is there
                    self.kin.update(np.asarray(q_full, dtype=np.float64))
                    real = self.kin.frame_pose(self.frame)
                    self.kin.update(q)
                    reached = np.linalg.norm(self._goal[:3, 3] - real[:3, 3]) < p.settle_tol
                if reached:
                    self.status, self.mode = Status.SUCCESS, Mode.IDLE
                elif self._t > self._duration + p.settle_timeout:
                    # unreachable (joint limits) or blocked: give up instead of pushing forever
                    self.status, self.mode = Status.FAILURE, Mode.IDLE
        elif self.mode == Mode.TWIST:
            # ramp up over 0.1 s: a velocity step would jerk the arm (and the F/T)
            self._ramp_t += dt
            twist = self._twist * min(1.0, self._ramp_t / 0.1)
            if self._duration is not None and self._t >= self._duration:
                self.status, self.mode = Status.SUCCESS, Mode.IDLE
                return self.q_cmd.copy(), np.zeros(len(self.q_cmd))
        else:
            R = self._axes(self._wrench_frame) if self._wrench_frame != "world" else np.eye(3)
            target = np.concatenate([R @ self._wrench[:3], R @ self._wrench[3:]])
            measured = np.zeros(6) if wrench is None else np.asarray(wrench, dtype=np.float64)
            a = min(1.0, dt / p.wrench_filter)
            self._wf = measured if self._wf is None else (1 - a) * self._wf + a * measured
            measured = self._wf
            # the F/T reads the reaction of the environment on the hand: applied = -measured
            err = target - (-measured)
            twist = np.concatenate([p.admittance * err[:3], p.admittance_rot * err[3:]])
        lin = np.linalg.norm(twist[:3])
        if lin > p.max_speed:
            twist[:3] *= p.max_speed / lin
        qd = self.ik.solve(twist, dt)
        self.q_cmd = self.q_cmd + qd * dt
        return self.q_cmd.copy(), qd
