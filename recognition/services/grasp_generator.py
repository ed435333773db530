"""Grasp generator service (§6.3.5): PCA approach vectors of a segmented object, filtered."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from contactflow.nodes.module import Layer, Module, Port
from contactflow.nodes.status import Status
from contactflow.recognition.grasp_synthesis import GraspFilters, IkFn, synthesize_grasps
from contactflow.recognition.messages import (
    ApproachVectors,
    PlaneMsg,
    SegmentedObjects,
    nd,
    provenance,
)


class GraspGenerator(Module):
    """Simple grasp generator followed by the AV filter services of §6.3.5.

    Approach vectors start where the object's box axes meet its box (the upright box of
    the cluster extractor, so side grasps are horizontal), ``standoff`` outside it. The
    collision filter keeps the hand clear of the plane and of the other objects; the
    orientation filter keeps directions within ``max_angle_deg`` of ``direction`` (a zero
    vector disables it); the distance filter keeps starts within ``max_distance`` of
    ``origin``. The reachability filter runs the pinocchio IK of arm ``arm`` of robot
    ``robot`` (placed at ``base``, xyz rpy, default the registry's) on the hand pose of
    each approach (z along it, at its start), or an IK callable given in code.
    """

    layer = Layer.SERVICE
    inputs = (Port("objects", SegmentedObjects, "segmented objects"),
              Port("plane", PlaneMsg, "principal plane (collision filter)"))
    outputs = (Port("approach_vectors", ApproachVectors, "filtered approach vectors, best first"),)

    @dataclass(frozen=True)
    class Params:
        rate_hz: float = 5.0  # Hz
        index: int = 0  # which object (largest first)
        standoff: float = 0.05  # m outside the box
        hand_radius: float = 0.04  # m, hand approximated by spheres along the approach
        hand_length: float = 0.15  # m
        direction: tuple[float, ...] = (0.0, 0.0, 0.0)  # preferred approach direction (zero: any)
        max_angle_deg: float = 45.0  # deg around ``direction``
        origin: tuple[float, ...] = (0.0, 0.0, 0.0)  # m, frame of the distance filter
        max_distance: float = 10.0  # m
        robot: str = ""  # registry name of the robot of the reachability filter ("" = no filter)
        arm: str = ""  # its arm ("" = the robot's first arm)
        base: tuple[float, ...] = ()  # xyz rpy of the robot base in the world (default: registry's)

    def __init__(self, name: str, params: Params | None = None, ik: IkFn | None = None) -> None:
        super().__init__(name, params)
        self.ik = ik

    def setup(self, io) -> None:
        super().setup(io)
        p = self.params
        if p.base and len(p.base) != 6:
            raise ValueError(f"{self.name}.params.base: expected xyz rpy (6 numbers), got {len(p.base)}")
        if self.ik is None and p.robot:
            self.ik = self._arm_ik()

    def _arm_ik(self) -> IkFn:
        from contactflow.embodiments import registry
        from contactflow.embodiments.transforms import xyz_rpy_to_matrix
        from contactflow.recognition.reachability import ArmReach

        p = self.params
        try:
            arm = p.arm or registry.get(p.robot).arms[0].name
        except KeyError as exc:
            raise ValueError(f"{self.name}.params.robot: {exc}") from None
        base = xyz_rpy_to_matrix(p.base[:3], p.base[3:]) if p.base else None
        return ArmReach(p.robot, arm, base, where=f"{self.name}.params.robot/arm").load()

    def step(self) -> Status:
        msgs = self.io.take("objects")
        if not msgs:
            return Status.RUNNING
        objs = msgs[-1]
        p = self.params
        plane_msg = self.io.latest("plane")
        avs = []
        if len(objs.objects) > p.index:
            clusters = objs.clusters()
            target = clusters[p.index]
            others = [c.points for i, c in enumerate(clusters) if i != p.index]
            filters = GraspFilters(p.standoff, p.hand_radius, p.hand_length, tuple(p.direction), p.max_angle_deg,
                                   tuple(p.origin), p.max_distance)
            avs = synthesize_grasps(target.points, target.box, filters, np.vstack(others) if others else None,
                                    plane_msg.plane() if plane_msg is not None else None, ik=self.ik)
        pos = np.array([a.position for a in avs]).reshape(-1, 3)
        dirs = np.array([a.direction for a in avs]).reshape(-1, 3)
        self.io.publish("approach_vectors",
                        ApproachVectors(positions=nd(pos), directions=nd(dirs),
                                        scores=[a.score for a in avs], depth_frame=objs.depth_frame),
                        inputs=provenance(objs.depth_frame, objs, plane_msg))
        return Status.RUNNING
