"""Self filter service: removes the points of a cloud that belong to the robot (spherical model)."""

from __future__ import annotations

from dataclasses import dataclass

from contactflow.nodes.module import Layer, Module, Port
from contactflow.nodes.status import Status
from contactflow.recognition.messages import PointCloud, RobotSpheres, provenance
from contactflow.recognition.pipeline import DistanceFn, self_filter, sphere_distance


class SelfFilter(Module):
    """Drops points within ``margin`` of the robot.

    The robot comes either as a :class:`RobotSpheres` message (the spherical model at the
    current joint positions, Appendix B) or as a distance function given to the constructor
    by a node that holds the robot model in process.
    """

    layer = Layer.SERVICE
    inputs = (Port("cloud", PointCloud, "points inside the ROI"),
              Port("spheres", RobotSpheres, "robot spheres at the current joint positions"))
    outputs = (Port("cloud", PointCloud, "points not on the robot"),)

    @dataclass(frozen=True)
    class Params:
        rate_hz: float = 30.0  # Hz
        margin: float = 0.02  # m, clearance around the robot spheres

    def __init__(self, name: str, params: Params | None = None, distance_fn: DistanceFn | None = None) -> None:
        super().__init__(name, params)
        self.distance_fn = distance_fn

    def step(self) -> Status:
        clouds = self.io.take("cloud")
        if not clouds:
            return Status.RUNNING
        cloud = clouds[-1]
        spheres = self.io.latest("spheres")
        fn = self.distance_fn
        if spheres is not None:
            fn = sphere_distance(spheres.centers.numpy(), spheres.radii.numpy())
        kept = self_filter(cloud.xyz(), fn, self.params.margin)
        self.io.publish("cloud", PointCloud.of(kept, cloud.depth_frame),
                        inputs=provenance(cloud.depth_frame, cloud, spheres))
        return Status.RUNNING
