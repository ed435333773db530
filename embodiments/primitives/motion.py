"""Shared arm motion helpers of the primitives: pose targets from parameters, planned or Cartesian moves."""

from __future__ import annotations

import numpy as np

from contactflow.embodiments.primitives.base import Primitive, matrix6


def target_pose(prim: Primitive, target: tuple[float, ...], field: str, relative: bool = False) -> np.ndarray:
    """``target`` ([x, y, z, roll, pitch, yaw]) as a world pose; ``relative`` adds it to the current pose."""
    T = matrix6(target, f"{prim.name}.params.{field}")
    if relative:
        cur = prim.r.frame_pose(prim.ee_frame)
        out = cur.copy()
        out[:3, 3] += T[:3, 3]
        out[:3, :3] = T[:3, :3] @ cur[:3, :3]
        return out
    return T


def pose_error(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """(position error m, rotation error rad) between two poses."""
    from contactflow.embodiments.transforms import rotvec_error

    return float(np.linalg.norm(a[:3, 3] - b[:3, 3])), float(np.linalg.norm(rotvec_error(a[:3, :3], b[:3, :3])))
