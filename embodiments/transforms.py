"""Small rigid-transform helpers (4x4 homogeneous matrices, numpy only)."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation


def xyz_rpy_to_matrix(xyz, rpy=(0.0, 0.0, 0.0)) -> np.ndarray:
    """URDF convention: fixed-axis roll, pitch, yaw."""
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("xyz", rpy).as_matrix()
    T[:3, 3] = xyz
    return T


def pose_to_matrix(pose) -> np.ndarray:
    """A SAPIEN pose (p, q=wxyz) as a 4x4 matrix."""
    T = np.eye(4)
    w, x, y, z = pose.q
    T[:3, :3] = Rotation.from_quat([x, y, z, w]).as_matrix()
    T[:3, 3] = pose.p
    return T


def inv(T: np.ndarray) -> np.ndarray:
    out = np.eye(4)
    R = T[:3, :3]
    out[:3, :3] = R.T
    out[:3, 3] = -R.T @ T[:3, 3]
    return out


def rotvec_error(R_target: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Rotation vector (world frame) taking ``R`` to ``R_target``."""
    return Rotation.from_matrix(R_target @ R.T).as_rotvec()


def matrix_to_xyz_quat(T: np.ndarray) -> np.ndarray:
    """[x, y, z, qx, qy, qz, qw]."""
    return np.concatenate([T[:3, 3], Rotation.from_matrix(T[:3, :3]).as_quat()])


def xyz_quat_to_matrix(v) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat(v[3:7]).as_matrix()
    T[:3, 3] = v[:3]
    return T
