"""Plane detector service: principal plane by RANSAC and the ROI extruded from it (1 Hz)."""

from __future__ import annotations

from dataclasses import dataclass

from contactflow.nodes.module import Layer, Module, Port
from contactflow.nodes.status import Status
from contactflow.recognition import open3d_backend
from contactflow.recognition.messages import PlaneMsg, PointCloud, RoiMsg, provenance
from contactflow.recognition.pipeline import detect_plane, roi_from_plane


class PlaneDetector(Module):
    """Fits the principal plane of the newest cloud at a low rate: the table rarely moves."""

    layer = Layer.SERVICE
    inputs = (Port("cloud", PointCloud, "world-frame cloud"),)
    outputs = (Port("plane", PlaneMsg, "principal plane"),
               Port("roi", RoiMsg, "region of interest above the plane"))

    @dataclass(frozen=True)
    class Params:
        rate_hz: float = 1.0  # Hz (§6.3.3)
        distance: float = 0.012  # m, RANSAC inlier distance
        iterations: int = 150
        max_tilt_deg: float = 30.0  # deg, planes steeper than this from world up are walls
        min_inliers: int = 100
        min_height: float = 0.012  # m, ROI starts this far above the plane
        max_height: float = 0.40  # m, ROI height
        margin: float = 0.0  # m, grows the ROI footprint

    def setup(self, io) -> None:  # type: ignore[no-untyped-def]
        super().setup(io)
        open3d_backend.load()  # open3d loads now, not in the first step (the stream would queue behind its import)

    def step(self) -> Status:
        cloud = self.io.latest("cloud")
        if cloud is None:
            return Status.RUNNING
        p = self.params
        pts = cloud.xyz()
        plane, mask = detect_plane(pts, p.distance, p.iterations, max_tilt_deg=p.max_tilt_deg,
                                   min_inliers=p.min_inliers, t=self.io.now)
        if plane is None:
            return Status.RUNNING
        inputs = provenance(cloud.depth_frame, cloud)
        roi = roi_from_plane(plane, pts[mask], p.min_height, p.max_height, p.margin)
        self.io.publish("plane", PlaneMsg.of(plane, cloud.depth_frame), inputs=inputs)
        self.io.publish("roi", RoiMsg.of(roi, cloud.depth_frame), inputs=inputs)
        return Status.RUNNING
