"""Detect objects (§6.3.3, §3.4.1): segment the camera point cloud in a region into object clusters and give an approach vector."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from contactflow.embodiments.primitives.base import Capability, Primitive, pose6, top_grasp_pose
from contactflow.embodiments.primitives.profiles import hand_pose_for
from contactflow.nodes.status import Event


def segment_objects(points: np.ndarray, region: np.ndarray, support_z: float | None = None,
                    min_height: float = 0.01, eps: float = 0.015, min_size: int = 30) -> list[np.ndarray]:
    """Object clusters (largest first) of a world-frame cloud inside ``region`` [xmin, ymin, zmin, xmax, ymax, zmax].

    The support is the RANSAC plane of the region (or ``support_z`` when given, e.g. a known
    box bottom); points ``min_height`` above it are clustered with DBSCAN.
    """
    from contactflow.recognition.pipeline import detect_plane, extract_clusters

    lo, hi = region[:3], region[3:]
    pts = points[np.all((points >= lo) & (points <= hi), axis=1)]
    if len(pts) < min_size:
        return []
    if support_z is None:
        plane, inliers = detect_plane(pts, distance=0.005, min_inliers=min_size)
        if plane is None:
            return []
        above = pts[(plane.height(pts) > min_height) & ~inliers]
    else:
        above = pts[pts[:, 2] > support_z + min_height]
    return [c.points for c in extract_clusters(above, eps=eps, min_size=min_size)]


class DetectObjects(Primitive):
    """Perceptual primitive: OBJECT_DETECTED with the chosen object's centroid, top and top-grasp approach pose.

    With no object in the region it ends with OBJECT_NOT_FOUND (the "no objects left" edge).
    """

    requires = Capability(camera=True)
    commands_arm = False
    events = (Event.SUCCESS, Event.FAILURE, Event.ERROR, Event.OBJECT_DETECTED, Event.OBJECT_NOT_FOUND)

    @dataclass(frozen=True)
    class Params(Primitive.Params):
        region: tuple[float, ...] = (0.3, -0.6, 0.74, 1.0, 0.6, 1.2)  # m, world box [xmin, ymin, zmin, xmax, ymax, zmax]
        support_z: float = -1.0  # m, known support height (< 0: fit the table plane)
        select: str = "largest"  # largest | leftmost | nearest | random
        standoff: float = 0.05  # m, approach pose this far above the object top
        grasp_depth: float = 0.06  # m, grasp frame below the object top (clipped to half the height)
        yaw: float = 1.5707963267948966  # rad, hand yaw of the top grasp
        camera: str = "kinect"
        min_size: int = 30  # points per object
        seed: int = 0  # for select=random
        settle: float = 0.1  # s waited before the snapshot
        self_margin: float = 0.02  # m, points this close to the robot model are removed

    def begin(self) -> None:
        if self.params.select not in ("largest", "leftmost", "nearest", "random"):
            raise ValueError(f"{self.name}: params.select must be largest|leftmost|nearest|random, got {self.params.select!r}")
        region = np.asarray(self.params.region, dtype=np.float64)
        if region.shape != (6,) or np.any(region[:3] >= region[3:]):
            raise ValueError(f"{self.name}: params.region must be [xmin, ymin, zmin, xmax, ymax, zmax], got {self.params.region}")
        self.region = region

    def update(self) -> None:
        p = self.params
        if self.elapsed < p.settle:
            return
        frame = self.r.camera(p.camera)
        support = p.support_z if p.support_z >= 0 else None
        pts = np.asarray(frame.points)
        lo, hi = self.region[:3], self.region[3:]
        pts = pts[np.all((pts >= lo) & (pts <= hi), axis=1)]
        model = getattr(self.r, "spherical", None)
        if model is not None and len(pts):
            pts = pts[model.distance(pts) > p.self_margin]  # the robot's own arms are not objects
        clusters = segment_objects(pts, self.region, support, min_size=p.min_size)
        if not clusters:
            self.fail("no object in the region", event=Event.OBJECT_NOT_FOUND, count=0)
            return
        if p.select == "leftmost":
            pick = max(clusters, key=lambda c: c[:, 1].mean())
        elif p.select == "nearest":
            pick = min(clusters, key=lambda c: np.linalg.norm(c.mean(axis=0)[:2]))
        elif p.select == "random":
            pick = clusters[int(np.random.default_rng(p.seed + int(self.r.time * 1000)).integers(len(clusters)))]
        else:
            pick = clusters[0]
        c = pick.mean(axis=0)
        top = float(pick[:, 2].max())
        bottom = float(pick[:, 2].min())
        size = pick.max(axis=0) - pick.min(axis=0)
        grasp_z = top - min(p.grasp_depth, max(0.5 * (top - bottom), 0.01))
        # the approach puts the hand's grasp centre (per embodiment) over the object centroid
        approach = hand_pose_for(self.r.spec.name, top_grasp_pose((c[0], c[1], top + p.standoff), p.yaw))
        vals = dict(count=len(clusters), cx=float(c[0]), cy=float(c[1]), cz=float(c[2]), top=top,
                    size_x=float(size[0]), size_y=float(size[1]), size_z=float(top - bottom),
                    grasp_z=float(grasp_z), **pose6(approach))
        self.emit_once(Event.OBJECT_DETECTED, f"{len(clusters)} objects", vals)
        self.succeed(**vals)
