"""Grasp generator service (§6.3.5): PCA approach vectors of a segmented object, filtered."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from contactflow.nodes.module import Layer, Module, Port
from contactflow.nodes.status import Status
from contactflow.recognition.grasp_synthesis import (
    IkFn,
    collision_filter,
    distance_filter,
    orientation_filter,
    pca_approach_vectors,
    reachability_filter,
)
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
    ``origin``; the reachability filter runs when an IK callable is given.
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

    def __init__(self, name: str, params: Params | None = None, ik: IkFn | None = None) -> None:
        super().__init__(name, params)
        self.ik = ik

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
            avs = pca_approach_vectors(target.points, target.box, p.standoff)
            avs = collision_filter(avs, np.vstack(others) if others else None,
                                   plane_msg.plane() if plane_msg is not None else None,
                                   hand_radius=p.hand_radius, hand_length=p.hand_length)
            if np.linalg.norm(p.direction) > 0:
                avs = orientation_filter(avs, np.asarray(p.direction), p.max_angle_deg)
            avs = distance_filter(avs, np.asarray(p.origin), p.max_distance)
            if self.ik is not None:
                avs = reachability_filter(avs, self.ik)
            avs = sorted(avs, key=lambda a: -a.score)
        pos = np.array([a.position for a in avs]).reshape(-1, 3)
        dirs = np.array([a.direction for a in avs]).reshape(-1, 3)
        self.io.publish("approach_vectors",
                        ApproachVectors(positions=nd(pos), directions=nd(dirs),
                                        scores=[a.score for a in avs], depth_frame=objs.depth_frame),
                        inputs=provenance(objs.depth_frame, objs, plane_msg))
        return Status.RUNNING
