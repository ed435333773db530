"""Kinematics wrapper on pinocchio: forward kinematics, frame Jacobians, every link frame and named task frames."""

from __future__ import annotations

import pathlib

import numpy as np
import pinocchio as pin


class KinematicsError(ValueError):
    """Unknown frame or joint, or a joint type the wrapper does not handle."""


class Kinematics:
    """A fixed-base robot model placed at ``base`` (4x4, world frame).

    Joint vectors passed to :meth:`update` are either in :attr:`joint_names` order or a
    ``{name: value}`` mapping. Poses are world-frame 4x4 matrices; Jacobians are 6 x nv in
    LOCAL_WORLD_ALIGNED convention (linear velocity of the frame origin, then angular
    velocity, both in world axes).
    """

    def __init__(self, urdf: str | pathlib.Path, base: np.ndarray | None = None) -> None:
        self.model = pin.buildModelFromUrdf(str(urdf))
        self.data = self.model.createData()
        if self.model.nq != self.model.nv:
            raise KinematicsError(f"{urdf}: continuous joints (nq {self.model.nq} != nv {self.model.nv}) are not supported")
        self.base = np.eye(4) if base is None else np.asarray(base, dtype=np.float64)
        self._identity_base = bool(np.allclose(self.base, np.eye(4)))
        self._base_se3 = pin.SE3(self.base[:3, :3], self.base[:3, 3])
        self.joint_names = [self.model.names[i] for i in range(1, self.model.njoints)]
        self._jidx = {n: self.model.joints[self.model.getJointId(n)].idx_q for n in self.joint_names}
        self.lower = self.model.lowerPositionLimit.copy()
        self.upper = self.model.upperPositionLimit.copy()
        self.q = np.clip(pin.neutral(self.model), self.lower, self.upper)
        self.task_frames: dict[str, tuple[str, np.ndarray]] = {}
        self._frame_ids = {self.model.frames[i].name: i for i in range(len(self.model.frames))}
        self.update(self.q)

    @property
    def nq(self) -> int:
        return self.model.nq

    @property
    def frames(self) -> list[str]:
        """Every link / fixed frame of the model plus the named task frames."""
        return list(self._frame_ids) + list(self.task_frames)

    def q_index(self, names: list[str] | tuple[str, ...]) -> np.ndarray:
        """Indices of joints ``names`` in the q vector."""
        try:
            return np.array([self._jidx[n] for n in names], dtype=np.int64)
        except KeyError as exc:
            raise KinematicsError(f"joint {exc.args[0]!r} is not in the model (joints: {self.joint_names})") from None

    def frame_id(self, name: str) -> int:
        try:
            return self._frame_ids[name]
        except KeyError:
            raise KinematicsError(f"unknown frame {name!r}") from None

    def update(self, q: np.ndarray | dict[str, float]) -> None:
        """Set the joint state and recompute every frame placement."""
        if isinstance(q, dict):
            v = self.q.copy()
            for n, x in q.items():
                v[self.q_index([n])[0]] = x
            q = v
        q = np.array(q, dtype=np.float64)
        if q.shape != (self.model.nq,):
            raise KinematicsError(f"q has shape {q.shape}, model needs ({self.model.nq},)")
        self.q = q
        pin.forwardKinematics(self.model, self.data, self.q)
        pin.updateFramePlacements(self.model, self.data)

    def add_task_frame(self, name: str, parent: str, offset: np.ndarray) -> None:
        """A named frame at ``offset`` (4x4) relative to ``parent`` (a model frame or "world")."""
        if parent != "world":
            self.frame_id(parent)
        self.task_frames[name] = (parent, np.asarray(offset, dtype=np.float64))

    def frame_pose(self, name: str, relative_to: str = "world") -> np.ndarray:
        """World pose of a frame (or relative to another frame)."""
        T = self._world_pose(name)
        if relative_to == "world":
            return T
        R = self._world_pose(relative_to)
        return np.linalg.solve(R, T)

    def _world_pose(self, name: str) -> np.ndarray:
        if name == "world":
            return np.eye(4)
        if name in self.task_frames:
            parent, off = self.task_frames[name]
            return self._world_pose(parent) @ off
        M = self.data.oMf[self.frame_id(name)].homogeneous
        return M if self._identity_base else self.base @ M

    def jacobian(self, frame: str) -> np.ndarray:
        """6 x nv Jacobian of a model frame, LOCAL_WORLD_ALIGNED, in world axes."""
        J = pin.computeFrameJacobian(self.model, self.data, self.q, self.frame_id(frame), pin.LOCAL_WORLD_ALIGNED)
        if self._identity_base:
            return J
        R = self.base[:3, :3]
        out = np.empty_like(J)
        out[:3] = R @ J[:3]
        out[3:] = R @ J[3:]
        return out

    def link_poses(self) -> dict[str, np.ndarray]:
        """World pose of every body frame (one per URDF link)."""
        out = {}
        for f in self.model.frames:
            if f.type == pin.FrameType.BODY:
                out[f.name] = self.base @ self.data.oMf[self.frame_id(f.name)].homogeneous
        return out
