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
    w, x, y, z = pose.q.tolist()
    px, py, pz = pose.p.tolist()
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w), px],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w), py],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y), pz],
                     [0.0, 0.0, 0.0, 1.0]])


def inv(T: np.ndarray) -> np.ndarray:
    out = np.eye(4)
    R = T[:3, :3]
    out[:3, :3] = R.T
    out[:3, 3] = -R.T @ T[:3, 3]
    return out


def so3_log(R: np.ndarray) -> np.ndarray:
    """Rotation vector of a rotation matrix (numpy only; scipy's is ~50x slower per call)."""
    c = np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)
    angle = np.arccos(c)
    w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if angle < 1e-6:
        return 0.5 * w
    if angle > np.pi - 1e-4:
        return Rotation.from_matrix(R).as_rotvec()
    return angle / (2.0 * np.sin(angle)) * w


def so3_exp(v: np.ndarray) -> np.ndarray:
    """Rotation matrix of a rotation vector (Rodrigues)."""
    angle = float(np.linalg.norm(v))
    if angle < 1e-12:
        return np.eye(3)
    k = np.asarray(v) / angle
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + np.sin(angle) * K + (1.0 - np.cos(angle)) * (K @ K)


def rotvec_error(R_target: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Rotation vector (world frame) taking ``R`` to ``R_target``."""
    return so3_log(R_target @ R.T)


def matrix_to_xyz_quat(T: np.ndarray) -> np.ndarray:
    """[x, y, z, qx, qy, qz, qw]."""
    return np.concatenate([T[:3, 3], Rotation.from_matrix(T[:3, :3]).as_quat()])


def xyz_quat_to_matrix(v) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat(v[3:7]).as_matrix()
    T[:3, 3] = v[:3]
    return T
