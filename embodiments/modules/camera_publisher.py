"""RGBD camera publisher: depth image and world point cloud."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from contactflow.embodiments.messages import DepthImage, PointCloud
from contactflow.embodiments.modules.backend import RobotBackend
from contactflow.nodes.module import Layer, Module, Port
from contactflow.nodes.status import Status
from contactflow.nodes.wire import NDArray


class CameraPublisher(Module):
    """Publishes depth and the world-frame point cloud of ``params.camera``, decimated by ``params.stride``."""

    layer = Layer.INTERFACE
    outputs = (Port("depth", DepthImage, "depth image"), Port("cloud", PointCloud, "world point cloud, origin at the camera"))

    @dataclass(frozen=True)
    class Params:
        rate_hz: float = 5.0  # Hz (ray casting costs ~40 ms per frame)
        camera: str = "kinect"
        stride: int = 2  # keep every stride-th point of the cloud

    def __init__(self, name: str, robot: RobotBackend, params: Params | None = None) -> None:
        super().__init__(name, params)
        self.robot = robot

    def step(self) -> Status:
        f = self.robot.camera(self.params.camera)
        self.io.publish("depth", DepthImage.of(f.depth, f.K, f.T_world_cam, self.params.camera))
        pts = np.ascontiguousarray(f.points[:: max(1, self.params.stride)], dtype=np.float32)
        self.io.publish("cloud", PointCloud(points=NDArray.of(pts), origin=[float(x) for x in f.T_world_cam[:3, 3]],
                                            sensor=self.params.camera))
        return Status.RUNNING
