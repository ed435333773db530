"""Builders of interface-layer messages from plain arrays, for tests of the generator shells."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from contactflow.embodiments.messages import PointCloud, RobotModel, TactileArray, TaxelPoses
from contactflow.nodes.wire import NDArray


def robot_model(caps: np.ndarray, frames: Mapping[str, np.ndarray] | None = None, robot: str = "robot",
                t: float = 0.0) -> RobotModel:
    """A ``RobotModel`` of bi-spheres ``caps`` (m, 8) ``[c1, r1, c2, r2]`` and world frame poses."""
    caps = np.asarray(caps, dtype=np.float64).reshape(-1, 8)
    frames = dict(frames or {})
    poses = np.stack([np.asarray(T, dtype=np.float64) for T in frames.values()]) if frames else None
    return RobotModel(robot=robot, t=t, links=[f"link{i}" for i in range(len(caps))],
                      c1=NDArray.of(np.ascontiguousarray(caps[:, 0:3])), r1=NDArray.of(np.ascontiguousarray(caps[:, 3])),
                      c2=NDArray.of(np.ascontiguousarray(caps[:, 4:7])), r2=NDArray.of(np.ascontiguousarray(caps[:, 7])),
                      frames=list(frames), poses=NDArray.of(poses) if poses is not None else None)


def one_pad_hand(positions: np.ndarray, pressure: np.ndarray, normal=(0.0, 0.0, 1.0), hand: str = "hand",
                 robot: str = "robot") -> tuple[TactileArray, TaxelPoses]:
    """A hand with one pad of 1 x n taxels at world ``positions`` (n, 3) reading ``pressure`` (n,)."""
    pos = np.asarray(positions, dtype=np.float64).reshape(1, 1, -1, 3)
    nrm = np.broadcast_to(np.asarray(normal, dtype=np.float64), pos.shape).copy()
    p = np.asarray(pressure, dtype=np.float32).reshape(1, 1, -1)
    return (TactileArray(hand=hand, pads=["pad"], pressure=NDArray.of(p)),
            TaxelPoses(robot=robot, hand=hand, t=0.0, pads=["pad"], positions=NDArray.of(pos), normals=NDArray.of(nrm)))


def point_cloud(points: np.ndarray, origin=(0.0, 0.0, 1.4)) -> PointCloud:
    """A world ``PointCloud`` seen from ``origin``."""
    return PointCloud(points=NDArray.of(np.asarray(points, dtype=np.float32).reshape(-1, 3)),
                      origin=[float(v) for v in origin], sensor="camera")
