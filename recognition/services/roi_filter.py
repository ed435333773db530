"""ROI filter service: keeps the points of a cloud inside the region of interest."""

from __future__ import annotations

from dataclasses import dataclass

from contactflow.nodes.module import Layer, Module, Port
from contactflow.nodes.status import Status
from contactflow.recognition.messages import PointCloud, RoiMsg, provenance
from contactflow.recognition.pipeline import roi_filter


class RoiFilter(Module):
    """Applies the newest ROI to every new cloud; without a ROI nothing passes."""

    layer = Layer.SERVICE
    inputs = (Port("cloud", PointCloud, "world-frame cloud"),
              Port("roi", RoiMsg, "region of interest (8 vertices)"))
    outputs = (Port("cloud", PointCloud, "points inside the ROI"),)

    @dataclass(frozen=True)
    class Params:
        rate_hz: float = 30.0  # Hz

    def step(self) -> Status:
        clouds = self.io.take("cloud")
        if not clouds:
            return Status.RUNNING
        cloud = clouds[-1]
        roi = self.io.latest("roi")
        inside = roi_filter(cloud.xyz(), roi.box.box() if roi is not None else None)
        self.io.publish("cloud", PointCloud.of(inside, cloud.depth_frame),
                        inputs=provenance(cloud.depth_frame, cloud, roi))
        return Status.RUNNING
