"""Self filter service: removes the points of a cloud that belong to the robot (spherical model)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from contactflow.embodiments.messages import JointState
from contactflow.nodes.module import Layer, Port
from contactflow.nodes.status import Status
from contactflow.recognition.backlog import StreamStage
from contactflow.recognition.messages import PointCloud, RobotSpheres, provenance
from contactflow.recognition.pipeline import (
    DistanceFn,
    culled_distance,
    self_filter,
    sphere_distance,
)


class SelfFilter(StreamStage):
    """Drops points within ``margin`` of the robot (thesis §6.3.3, Appendix B).

    The robot comes, in order of preference, as
    * a distance function given to the constructor by a node that holds the robot in
      process, e.g. with the simulator
      ``SelfFilter("self", distance_fn=lambda p: robot.spherical.distance(p))``;
    * the spherical model of robot ``params.robot`` (from the embodiment registry, fitted
      to its URDF collision geometry) posed by the ``joints`` input;
    * a :class:`RobotSpheres` message (spheres already posed in the world).
    Without any of them nothing is removed.
    """

    layer = Layer.SERVICE
    inputs = (Port("cloud", PointCloud, "points inside the ROI"),
              Port("joints", JointState, "robot joint positions (with params.robot)"),
              Port("spheres", RobotSpheres, "robot spheres at the current joint positions"))
    outputs = (Port("cloud", PointCloud, "points not on the robot"),)

    @dataclass(frozen=True)
    class Params(StreamStage.Params):
        margin: float = 0.02  # m, clearance around the robot model
        robot: str = ""  # registry name of the robot whose spherical model is posed by `joints`
        base: tuple[float, ...] = ()  # xyz rpy of the robot base in the world (default: registry's)

    def __init__(self, name: str, params: Params | None = None, distance_fn: DistanceFn | None = None) -> None:
        super().__init__(name, params)
        self.distance_fn = distance_fn
        self.model = None
        self.kin = None

    def setup(self, io) -> None:
        super().setup(io)
        if self.params.robot and self.distance_fn is None:
            self._build_model()

    def _build_model(self) -> None:
        from contactflow.embodiments import registry
        from contactflow.embodiments.control.kinematics import Kinematics
        from contactflow.embodiments.spherical import SphericalModel
        from contactflow.embodiments.transforms import xyz_rpy_to_matrix

        p = self.params
        try:
            spec = registry.get(p.robot)
        except KeyError as exc:
            raise ValueError(f"{self.name}.params.robot: {exc}") from None
        if p.base and len(p.base) != 6:
            raise ValueError(f"{self.name}.params.base: expected xyz rpy (6 numbers), got {len(p.base)}")
        base = (xyz_rpy_to_matrix(p.base[:3], p.base[3:]) if p.base
                else xyz_rpy_to_matrix(spec.base_xyz, spec.base_rpy))
        self.kin = Kinematics(spec.urdf(), base)
        self.model = SphericalModel.from_urdf(self.kin, str(spec.urdf()))

    def _pose_model(self, joints: JointState) -> None:
        known = set(self.kin.joint_names)
        q = {n: float(v) for n, v in zip(joints.names, np.asarray(joints.position.numpy()), strict=False) if n in known}
        self.kin.update(q)
        self.model.update(self.kin)

    def step(self) -> Status:
        cloud = self.pending.next(self.io.take("cloud"))
        if cloud is None:
            return Status.RUNNING
        used = None
        fn = self.distance_fn
        if fn is None and self.model is not None:
            joints = self.io.latest("joints")
            if joints is not None:
                self._pose_model(joints)
                m = self.model
                fn = culled_distance(m.C1, m.C2, m.r1, m.r2, self.params.margin)
                used = joints
        if fn is None:
            spheres = self.io.latest("spheres")
            if spheres is not None:
                fn = sphere_distance(spheres.centers.numpy(), spheres.radii.numpy(), cutoff=self.params.margin)
                used = spheres
        kept = self_filter(cloud.xyz(), fn, self.params.margin)
        self.io.publish("cloud", PointCloud.of(kept, cloud.depth_frame, cloud.depth_t),
                        inputs=provenance(cloud.depth_frame, cloud, used))
        return Status.RUNNING
