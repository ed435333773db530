"""ROI filter service: keeps the points of a cloud inside the region of interest."""

from __future__ import annotations

from dataclasses import dataclass

from contactflow.nodes.module import Layer, Module, Port
from contactflow.nodes.status import Status
from contactflow.recognition.messages import PointCloud, RoiMsg, provenance
from contactflow.recognition.pipeline import roi_filter


class RoiFilter(Module):
    """Applies the newest ROI to every new cloud; before the first ROI the newest cloud waits for it.

    An empty cloud would tell the cluster extractor, and the primitives reading its objects,
    that the region is empty, when the plane detector (1 Hz) has only not fitted it yet.
    """

    layer = Layer.SERVICE
    inputs = (Port("cloud", PointCloud, "world-frame cloud"),
              Port("roi", RoiMsg, "region of interest (8 vertices)"))
    outputs = (Port("cloud", PointCloud, "points inside the ROI"),)

    @dataclass(frozen=True)
    class Params:
        rate_hz: float = 200.0  # Hz, how often it looks for a new cloud (each is filtered once)

    def __init__(self, name: str, params: Params | None = None) -> None:
        super().__init__(name, params)
        self.waiting: PointCloud | None = None  # the newest cloud not filtered yet

    def reset(self) -> None:
        self.waiting = None

    def step(self) -> Status:
        clouds = self.io.take("cloud")
        if clouds:
            self.waiting = clouds[-1]
        roi = self.io.latest("roi")
        if self.waiting is None or roi is None:
            return Status.RUNNING
        cloud, self.waiting = self.waiting, None
        inside = roi_filter(cloud.xyz(), roi.box.box())
        self.io.publish("cloud", PointCloud.of(inside, cloud.depth_frame, cloud.depth_t),
                        inputs=provenance(cloud.depth_frame, cloud, roi))
        return Status.RUNNING
