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


def planning_cloud(prim: Primitive, flat: tuple[float, ...], field: str, sense: bool) -> np.ndarray:
    """The obstacle cloud a primitive plans against: its ``field`` points plus, if ``sense``, the camera's cloud
    with the robot removed by the spherical model (never the simulator's object poses)."""
    pts = np.asarray(flat, dtype=np.float64)
    if pts.size % 3:
        raise ValueError(f"{prim.name}.params.{field}: expected a multiple of 3 values, got {pts.size}")
    pts = pts.reshape(-1, 3)
    if sense:
        from contactflow.embodiments.control.planning import sensed_cloud

        pts = np.vstack([pts, sensed_cloud(prim.r)])
    return pts
