"""Cluster extractor service: euclidean clustering into one segmented cloud per object."""

from __future__ import annotations

from dataclasses import dataclass

from contactflow.nodes.module import Layer, Port
from contactflow.nodes.status import Status
from contactflow.recognition import open3d_backend
from contactflow.recognition.backlog import StreamStage
from contactflow.recognition.messages import PlaneMsg, PointCloud, SegmentedObjects, provenance
from contactflow.recognition.pipeline import extract_clusters


class ClusterExtractor(StreamStage):
    """Clusters each new filtered cloud (open3d DBSCAN); boxes stand on the plane when known."""

    layer = Layer.SERVICE
    inputs = (Port("cloud", PointCloud, "object points"),
              Port("plane", PlaneMsg, "principal plane (optional, for upright boxes)"))
    outputs = (Port("objects", SegmentedObjects, "segmented objects, largest first"),)

    @dataclass(frozen=True)
    class Params(StreamStage.Params):
        eps: float = 0.018  # m, DBSCAN neighbourhood
        min_points: int = 4  # DBSCAN core density
        min_size: int = 25  # points per object
        max_size: int = 50_000  # points per object

    def setup(self, io) -> None:  # type: ignore[no-untyped-def]
        super().setup(io)
        open3d_backend.load()  # open3d loads now, not in the first step (the stream would queue behind its import)

    def step(self) -> Status:
        cloud = self.pending.next(self.io.take("cloud"))
        if cloud is None:
            return Status.RUNNING
        plane_msg = self.io.latest("plane")
        p = self.params
        clusters = extract_clusters(cloud.xyz(), p.eps, p.min_points, p.min_size, p.max_size,
                                    plane_msg.plane() if plane_msg is not None else None)
        self.io.publish("objects", SegmentedObjects.of(clusters, cloud.depth_frame, cloud.depth_t),
                        inputs=provenance(cloud.depth_frame, cloud, plane_msg))
        return Status.RUNNING
