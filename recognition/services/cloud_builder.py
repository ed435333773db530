"""Cloud builder service: depth frame → decimated, voxelised point cloud in the world frame."""

from __future__ import annotations

from dataclasses import dataclass

from contactflow.embodiments.messages import DepthImage
from contactflow.nodes.module import Layer, Port
from contactflow.nodes.status import Status
from contactflow.recognition.backlog import StreamStage
from contactflow.recognition.geometry import depth_to_points, voxel_downsample
from contactflow.recognition.messages import PointCloud, depth_arrays, provenance


class CloudBuilder(StreamStage):
    """Back-projects each new depth frame and downsamples it early (the pipeline's cost driver)."""

    layer = Layer.SERVICE
    inputs = (Port("depth", DepthImage, "depth image with intrinsics and camera pose"),)
    outputs = (Port("cloud", PointCloud, "world-frame cloud"),)

    @dataclass(frozen=True)
    class Params(StreamStage.Params):
        stride: int = 2  # px, depth decimation
        min_range: float = 0.2  # m
        max_range: float = 3.0  # m
        voxel: float = 0.006  # m, voxel grid edge

    def step(self) -> Status:
        frame = self.pending.next(self.io.take("depth"))
        if frame is None:
            return Status.RUNNING
        depth, K, T = depth_arrays(frame)
        p = self.params
        pts = voxel_downsample(depth_to_points(depth, K, T, p.stride, p.min_range, p.max_range), p.voxel)
        self.io.publish("cloud", PointCloud.of(pts, frame.hdr.id, frame.hdr.t_sim), inputs=provenance(frame.hdr.id, frame))
        return Status.RUNNING
