"""ROI filter service: keeps the points of a cloud inside the region of interest."""

from __future__ import annotations

from contactflow.nodes.module import Layer, Port
from contactflow.nodes.status import Status
from contactflow.recognition.backlog import StreamStage
from contactflow.recognition.messages import PointCloud, RoiMsg, provenance
from contactflow.recognition.pipeline import roi_filter


class RoiFilter(StreamStage):
    """Applies the newest ROI to every new cloud; before the first ROI the newest clouds wait for it.

    An empty cloud would tell the cluster extractor, and the primitives reading its objects,
    that the region is empty, when the plane detector (1 Hz) has only not fitted it yet.
    """

    layer = Layer.SERVICE
    inputs = (Port("cloud", PointCloud, "world-frame cloud"),
              Port("roi", RoiMsg, "region of interest (8 vertices)"))
    outputs = (Port("cloud", PointCloud, "points inside the ROI"),)

    def step(self) -> Status:
        cloud = self.pending.next(self.io.take("cloud"))
        if cloud is None:
            return Status.RUNNING
        roi = self.io.latest("roi")
        if roi is None:
            self.pending.push_back(cloud)
            return Status.RUNNING
        inside = roi_filter(cloud.xyz(), roi.box.box())
        self.io.publish("cloud", PointCloud.of(inside, cloud.depth_frame, cloud.depth_t),
                        inputs=provenance(cloud.depth_frame, cloud, roi))
        return Status.RUNNING
