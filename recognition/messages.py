"""Wire messages of the recognition area: clouds, plane/ROI, objects, grasps, labels.

The pipeline's input is the camera's ``DepthImage`` of the embodiments area (depth in
metres along the optical axis, 0 = no return, intrinsics ``K`` and ``T_world_cam``).

Every message derived from a depth frame names that frame in ``depth_frame`` and lists it
in its header provenance (``hdr.inputs``), so a segmented object can be traced back to the
image it was cut from (thesis §6.6). Clouds and objects also carry the frame's stamp
(``depth_t``): the services run on their node's clock, the camera on the world's, and a
reader asks when the scene looked like this, not when a service got to it.
"""

from __future__ import annotations

import msgspec
import numpy as np

from contactflow.embodiments.messages import DepthImage
from contactflow.nodes.wire import Message, MsgId, NDArray
from contactflow.recognition.geometry import Box
from contactflow.recognition.pipeline import Cluster, Plane

NO_FRAME = MsgId(source="", seq=0)


def nd(array: np.ndarray) -> NDArray:
    """``NDArray.of`` that also takes empty arrays (an empty cloud is a valid result)."""
    a = np.ascontiguousarray(array)
    if a.size == 0:
        return NDArray(dtype=a.dtype.name, shape=list(a.shape), data=memoryview(b""))
    return NDArray.of(a)


def depth_image(depth: np.ndarray, K: np.ndarray, world_T_cam: np.ndarray, camera: str = "camera") -> DepthImage:
    """The camera's wire message (``embodiments.messages.DepthImage``) from plain arrays."""
    return DepthImage.of(depth, K, world_T_cam, camera)


def depth_arrays(msg: DepthImage) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(depth, K, world_T_cam) of a depth image; raises ValueError naming the bad field."""
    if len(msg.K) != 9:
        raise ValueError(f"DepthImage.K: expected 9 numbers, got {len(msg.K)}")
    if len(msg.T_world_cam) != 16:
        raise ValueError(f"DepthImage.T_world_cam: expected 16 numbers, got {len(msg.T_world_cam)}")
    depth = msg.depth.numpy()
    if depth.ndim != 2:
        raise ValueError(f"DepthImage.depth: expected an (H, W) image, got shape {depth.shape}")
    return depth, np.reshape(msg.K, (3, 3)), np.reshape(msg.T_world_cam, (4, 4))


class PointCloud(Message, tag="vision_cloud"):
    """An (N, 3) float32 cloud in the world frame."""

    max_bytes = 32 << 20
    points: NDArray  # (N, 3) float32, m, world
    depth_frame: MsgId = NO_FRAME  # the depth frame it came from
    depth_t: float | None = None  # s, the depth frame's stamp on its camera's clock (None: unknown)
    frame: str = "world"  # always world

    def xyz(self) -> np.ndarray:
        p = self.points.numpy()
        if p.size == 0:
            return np.zeros((0, 3))
        if p.ndim != 2 or p.shape[1] != 3:
            raise ValueError(f"PointCloud.points: expected shape (N, 3), got {p.shape}")
        return p.astype(np.float64)

    @classmethod
    def of(cls, points: np.ndarray, depth_frame: MsgId = NO_FRAME, depth_t: float | None = None) -> PointCloud:
        return cls(points=nd(np.asarray(points, np.float32).reshape(-1, 3)), depth_frame=depth_frame, depth_t=depth_t)


class PlaneMsg(Message, tag="vision_plane"):
    """The principal plane ``normal · p + offset = 0`` and its frame (z = normal)."""

    normal: list[float]  # unit, world
    offset: float  # m
    origin: list[float]  # m, world: a point of the plane
    frame: list[float]  # row-major 3x3, columns are the plane axes
    inliers: int  # points of the cloud on the plane
    depth_frame: MsgId = NO_FRAME  # the depth frame it came from

    def plane(self) -> Plane:
        return Plane(np.array(self.normal), self.offset, np.array(self.origin), np.reshape(self.frame, (3, 3)),
                     self.inliers)

    @classmethod
    def of(cls, plane: Plane, depth_frame: MsgId = NO_FRAME) -> PlaneMsg:
        return cls(normal=plane.normal.tolist(), offset=float(plane.offset), origin=plane.origin.tolist(),
                   frame=plane.frame.ravel().tolist(), inliers=int(plane.inliers), depth_frame=depth_frame)


class BoxMsg(msgspec.Struct, kw_only=True):
    """An oriented box: centre, row-major rotation (columns = axes) and full extents (m)."""

    center: list[float]  # m, world
    rotation: list[float]  # row-major 3x3, columns are the box axes
    extent: list[float]  # m, full extents along the axes

    def box(self) -> Box:
        if len(self.center) != 3 or len(self.rotation) != 9 or len(self.extent) != 3:
            raise ValueError("BoxMsg: center needs 3, rotation 9 and extent 3 numbers")
        return Box(np.array(self.center), np.reshape(self.rotation, (3, 3)), np.array(self.extent))

    @classmethod
    def of(cls, box: Box) -> BoxMsg:
        return cls(center=box.center.tolist(), rotation=box.rotation.ravel().tolist(), extent=box.extent.tolist())


class RoiMsg(Message, tag="vision_roi"):
    """Region of interest: the 8 vertices of the box extruded from the plane, and the box."""

    vertices: list[float]  # 8 x 3, row-major
    box: BoxMsg  # the region as an oriented box
    depth_frame: MsgId = NO_FRAME  # the depth frame it came from

    @classmethod
    def of(cls, box: Box, depth_frame: MsgId = NO_FRAME) -> RoiMsg:
        return cls(vertices=box.vertices().ravel().tolist(), box=BoxMsg.of(box), depth_frame=depth_frame)


class RobotSpheres(Message, tag="vision_robot_spheres"):
    """The robot's spherical model at its current joint positions, in the world frame."""

    centers: NDArray  # (M, 3) m
    radii: NDArray  # (M,) m


class SegmentedObject(msgspec.Struct, kw_only=True):
    """One object's points, centroid and box, world frame."""

    points: NDArray  # (N, 3) float32
    centroid: list[float]  # m, world
    box: BoxMsg  # its oriented bounding box

    def cluster(self) -> Cluster:
        pts = self.points.numpy().astype(np.float64).reshape(-1, 3)
        return Cluster(pts, np.array(self.centroid), self.box.box())


class SegmentedObjects(Message, tag="vision_objects"):
    """One segmented cloud per object found in the region of interest (world frame), largest first."""

    max_bytes = 32 << 20
    objects: list[SegmentedObject]  # the objects
    depth_frame: MsgId = NO_FRAME  # the depth frame it came from
    depth_t: float | None = None  # s, the depth frame's stamp on its camera's clock (None: unknown)

    def clusters(self) -> list[Cluster]:
        return [o.cluster() for o in self.objects]

    @classmethod
    def of(cls, clusters: list[Cluster], depth_frame: MsgId = NO_FRAME, depth_t: float | None = None) -> SegmentedObjects:
        objs = [SegmentedObject(points=nd(c.points.astype(np.float32)), centroid=c.centroid.tolist(),
                                box=BoxMsg.of(c.box)) for c in clusters]
        return cls(objects=objs, depth_frame=depth_frame, depth_t=depth_t)


class ApproachVectors(Message, tag="vision_approach_vectors"):
    """Approach vectors: where the hand starts (position) and the direction it moves in."""

    positions: NDArray  # (K, 3) m
    directions: NDArray  # (K, 3) unit
    scores: list[float] = []  # a score per vector, higher is better
    depth_frame: MsgId = NO_FRAME  # the depth frame it came from


class ShapeClass(Message, tag="vision_shape"):
    """V4 shape class of an object (thesis §8.4.2); ``label`` is "unknown" below the 70 % rule."""

    label: str  # the class, or unknown
    classes: list[str]  # every class
    probabilities: list[float]  # a probability per class
    curvedness: float  # mean curvedness of the object's surface, 1/m
    depth_frame: MsgId = NO_FRAME  # the depth frame it came from


class ObjectIdentity(Message, tag="vision_identity"):
    """LOC object identity (thesis §8.4.3); ``label`` is "unknown" when not confident."""

    label: str  # the object, or unknown
    confidence: float  # in [0, 1]
    features: list[float]  # the feature vector
    feature_names: list[str]  # a name per feature
    depth_frame: MsgId = NO_FRAME  # the depth frame it came from


class MeasuredWeight(Message, tag="vision_weight"):
    """Weight of a lifted object from the wrist force/torque sensor."""

    weight: float  # N
    std: float = 0.0  # N


def provenance(depth_frame: MsgId, *inputs: Message | None) -> list[MsgId]:
    """Header inputs of a derived message: the depth frame first, then the direct inputs."""
    out = [depth_frame] if depth_frame.source else []
    for m in inputs:
        if m is not None and m.hdr.id not in out:
            out.append(m.hdr.id)
    return out
