"""Approach-vector synthesis and filtering (thesis §6.3.5).

Two generators: the simple one runs PCA on a segmented cloud and starts an approach
where each principal axis meets the object's bounding box, pointing inward along that
axis; the model-based one (OpenRAVE-like) samples the surface of the bounding box of a
known model, casts each sample inward onto the model (open3d ray casting) and approaches
against the surface normal there. ``register_model`` places a model on a cloud by ICP.
Filters keep approach vectors that are reachable (an IK callable), collision free,
pointing along a direction ± a threshold, and near a frame.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import open3d as o3d
from scipy.spatial import cKDTree

from contactflow.recognition.geometry import Box, as_points, orthonormal_frame, pca_box
from contactflow.recognition.pipeline import DistanceFn, Plane

IkFn = Callable[[np.ndarray], object | None]
"""Inverse kinematics: a 4x4 hand pose → a joint solution, or None when unreachable."""

PoseFn = Callable[["ApproachVector"], np.ndarray]
"""The 4x4 hand pose a robot would command for an approach vector."""


@dataclass(frozen=True, eq=False)
class ApproachVector:
    """Where the hand starts (``position``) and the unit direction it then moves in.

    ``score`` ranks approach vectors: for PCA ones the sum of the box extents across the
    approach (a larger face is easier to reach and to centre the hand on).
    """

    position: np.ndarray
    direction: np.ndarray
    source: str = "pca"
    score: float = 0.0

    def pose(self, standoff: float = 0.0) -> np.ndarray:
        """Hand pose: z along the approach direction, origin ``standoff`` behind the start."""
        T = np.eye(4)
        T[:3, :3] = orthonormal_frame(self.direction)
        T[:3, 3] = self.position - standoff * self.direction
        return T


def pca_approach_vectors(points: np.ndarray, box: Box | None = None, standoff: float = 0.0,
                         min_points: int = 10) -> list[ApproachVector]:
    """Six approach vectors along ± each principal axis of the cloud (simple grasp generator).

    Each starts where the principal axis through the centroid leaves the bounding box (the
    PCA box unless ``box`` is given, whose axes are then used), plus ``standoff`` outward.
    """
    pts = as_points(points, "pca_approach_vectors.points")
    if len(pts) < min_points:
        return []
    box = box if box is not None else pca_box(pts)
    centroid = pts.mean(axis=0)
    c_local = box.local(centroid[None])[0]
    out = []
    for i in range(3):
        axis = box.rotation[:, i]
        half = box.extent[i] / 2
        for sign in (1.0, -1.0):
            t = sign * half - c_local[i]
            start = centroid + axis * (t + sign * standoff)
            out.append(ApproachVector(start, -sign * axis, "pca", float(box.extent[(i + 1) % 3] + box.extent[(i + 2) % 3])))
    return out


def model_approach_vectors(mesh: o3d.geometry.TriangleMesh, world_T_obj: np.ndarray | None = None,
                           spacing: float = 0.02, standoff: float = 0.0) -> list[ApproachVector]:
    """Approach vectors from a model (OpenRAVE grasp generator, Fig. 6.6).

    The surface of the model's axis-aligned bounding box is sampled every ``spacing``
    metres; from each sample a ray goes inward (against the face normal); where it hits
    the model the hand approaches against the surface normal.
    """
    T = np.eye(4) if world_T_obj is None else np.asarray(world_T_obj, float)
    verts = np.asarray(mesh.vertices)
    if len(verts) == 0 or len(mesh.triangles) == 0:
        return []
    lo, hi = verts.min(axis=0), verts.max(axis=0)
    origins, dirs = [], []
    for ax in range(3):
        others = [a for a in range(3) if a != ax]
        g = [np.arange(lo[a] + spacing / 2, hi[a], spacing) if hi[a] - lo[a] > spacing else np.array([(lo[a] + hi[a]) / 2])
             for a in others]
        uu, vv = np.meshgrid(*g, indexing="ij")
        for face, sign in ((lo[ax], 1.0), (hi[ax], -1.0)):
            o = np.zeros((uu.size, 3))
            o[:, others[0]], o[:, others[1]], o[:, ax] = uu.ravel(), vv.ravel(), face - sign * 1e-3
            d = np.zeros((uu.size, 3))
            d[:, ax] = sign
            origins.append(o)
            dirs.append(d)
    o, d = np.vstack(origins), np.vstack(dirs)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
    ans = scene.cast_rays(o3d.core.Tensor(np.hstack((o, d)).astype(np.float32)))
    t = ans["t_hit"].numpy()
    n = ans["primitive_normals"].numpy().astype(float)
    hit = np.isfinite(t)
    if not hit.any():
        return []
    p = o[hit] + d[hit] * t[hit, None]
    n = n[hit]
    # normals must face the ray's origin, whatever the triangle winding
    flip = (n * d[hit]).sum(axis=1) > 0
    n[flip] *= -1
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    R, tr = T[:3, :3], T[:3, 3]
    pw, nw = p @ R.T + tr, n @ R.T
    return [ApproachVector(pw[k] + standoff * nw[k], -nw[k], "model") for k in range(len(pw))]


def register_model(model_points: np.ndarray, cloud: np.ndarray, init: np.ndarray | None = None,
                   max_distance: float = 0.02, iterations: int = 50) -> tuple[np.ndarray, float, float]:
    """Place a model on a segmented cloud by open3d ICP: (world_T_obj, fitness, rmse).

    Without ``init`` the model's centroid is moved onto the cloud's centroid.
    """
    m, c = as_points(model_points, "register_model.model_points"), as_points(cloud, "register_model.cloud")
    if len(m) < 3 or len(c) < 3:
        return np.eye(4), 0.0, float("inf")
    if init is None:
        init = np.eye(4)
        init[:3, 3] = c.mean(axis=0) - m.mean(axis=0)
    src = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(m))
    dst = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(c))
    reg = o3d.pipelines.registration.registration_icp(
        src, dst, max_distance, np.asarray(init, float),
        o3d.pipelines.registration.TransformationEstimationPointToPoint(),
        o3d.pipelines.registration.ICPConvergenceCriteria(max_iteration=iterations))
    return np.asarray(reg.transformation), float(reg.fitness), float(reg.inlier_rmse)


def reachability_filter(avs: Sequence[ApproachVector], ik: IkFn, standoff: float = 0.0,
                        pose: PoseFn | None = None, first: bool = False) -> list[ApproachVector]:
    """Keep the approach vectors whose hand pose has an IK solution.

    ``pose`` maps an approach vector to the hand pose actually commanded (default: its
    :meth:`ApproachVector.pose`); with ``first`` only the first reachable one is kept,
    which spares the IK of the rest when the list is already ranked.
    """
    out = []
    for a in avs:
        if ik(pose(a) if pose is not None else a.pose(standoff)) is not None:
            out.append(a)
            if first:
                break
    return out


def collision_filter(avs: Sequence[ApproachVector], obstacles: np.ndarray | None = None, plane: Plane | None = None,
                     robot: DistanceFn | None = None, hand_radius: float = 0.04, hand_length: float = 0.15,
                     samples: int = 4) -> list[ApproachVector]:
    """Keep approach vectors whose hand (spheres along the approach line, behind the start)
    is clear of the obstacle points, above the plane and away from the robot."""
    if not avs:
        return []
    offsets = hand_radius + np.linspace(0.0, hand_length, samples)
    pos = np.array([a.position for a in avs])
    dirs = np.array([a.direction for a in avs])
    centres = pos[:, None, :] - dirs[:, None, :] * offsets[None, :, None]
    flat = centres.reshape(-1, 3)
    free = np.ones(len(flat), bool)
    obs = as_points(obstacles, "collision_filter.obstacles") if obstacles is not None else np.zeros((0, 3))
    if len(obs):
        d, _ = cKDTree(obs).query(flat, k=1)
        free &= d >= hand_radius
    if plane is not None:
        free &= plane.height(flat) >= hand_radius
    if robot is not None:
        free &= np.asarray(robot(flat)).reshape(-1) >= hand_radius
    ok = free.reshape(len(avs), samples).all(axis=1)
    return [a for a, k in zip(avs, ok, strict=True) if k]


def orientation_filter(avs: Sequence[ApproachVector], direction: np.ndarray, max_angle_deg: float) -> list[ApproachVector]:
    """Keep approach vectors pointing along ``direction`` within ± ``max_angle_deg``."""
    d = np.asarray(direction, float)
    d = d / np.linalg.norm(d)
    cos = np.cos(np.radians(max_angle_deg))
    return [a for a in avs if float(np.dot(a.direction, d)) >= cos - 1e-12]


def distance_filter(avs: Sequence[ApproachVector], origin: np.ndarray, max_distance: float) -> list[ApproachVector]:
    """Keep approach vectors starting within ``max_distance`` of a frame's origin."""
    o = np.asarray(origin, float)
    return [a for a in avs if float(np.linalg.norm(a.position - o)) <= max_distance]


@dataclass(frozen=True)
class GraspFilters:
    """Settings of the AV filter services of §6.3.5 (a zero ``direction`` disables the orientation filter)."""

    standoff: float = 0.05  # m, approach starts this far outside the box
    hand_radius: float = 0.04  # m, hand approximated by spheres along the approach
    hand_length: float = 0.15  # m
    direction: tuple[float, ...] = (0.0, 0.0, 0.0)  # preferred approach direction (zero: any)
    max_angle_deg: float = 45.0  # deg around ``direction``
    origin: tuple[float, ...] = (0.0, 0.0, 0.0)  # m, frame of the distance filter
    max_distance: float = 10.0  # m


def synthesize_grasps(points: np.ndarray, box: Box | None, filters: GraspFilters,
                      obstacles: np.ndarray | None = None, plane: Plane | None = None,
                      robot: DistanceFn | None = None, ik: IkFn | None = None,
                      pose: PoseFn | None = None, first_reachable: bool = False) -> list[ApproachVector]:
    """PCA approach vectors of one segmented object through every filter, best score first.

    The cheap geometric filters run first; the IK of the reachability filter (when ``ik``
    is given) only sees the survivors, in rank order.
    """
    f = filters
    avs = pca_approach_vectors(points, box, f.standoff)
    avs = collision_filter(avs, obstacles, plane, robot, hand_radius=f.hand_radius, hand_length=f.hand_length)
    if np.linalg.norm(f.direction) > 0:
        avs = orientation_filter(avs, np.asarray(f.direction, float), f.max_angle_deg)
    avs = distance_filter(avs, np.asarray(f.origin, float), f.max_distance)
    avs = sorted(avs, key=lambda a: -a.score)
    if ik is not None:
        avs = reachability_filter(avs, ik, pose=pose, first=first_reachable)
    return avs
