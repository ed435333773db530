"""Pure cores of the 3D vision pipeline (thesis §6.3.3, Fig. 6.5) and their chaining.

Depth image → decimated, voxelised world cloud → principal plane (open3d RANSAC, cached
and refreshed at a low rate) → region of interest extruded from the plane → ROI filter →
self filter (a robot distance function) → euclidean clustering (open3d DBSCAN) → one
segmented cloud per object with centroid and box. Every stage takes and returns plain
numpy arrays, and an empty or degenerate input gives an empty output.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from contactflow.recognition import open3d_backend
from contactflow.recognition.geometry import (
    EMPTY,
    Box,
    as_points,
    depth_to_points,
    min_area_rectangle,
    orthonormal_frame,
    pca_box,
    upright_box,
    voxel_downsample,
)

DistanceFn = Callable[[np.ndarray], np.ndarray]
"""Signed distance (m) from each of (N, 3) world points to the robot surface, (N,)."""

if TYPE_CHECKING:
    import open3d as o3d


def _cloud(points: np.ndarray) -> o3d.geometry.PointCloud:
    o3d = open3d_backend.load()
    return o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.ascontiguousarray(points, dtype=np.float64)))


@dataclass(frozen=True, eq=False)
class Plane:
    """Plane ``normal · p + offset = 0``; ``frame`` has the normal as z, ``origin`` lies on it."""

    normal: np.ndarray
    offset: float
    origin: np.ndarray
    frame: np.ndarray
    inliers: int
    t: float = 0.0  # s, time of the cloud it was fitted on

    def height(self, points: np.ndarray) -> np.ndarray:
        return points @ self.normal + self.offset


def detect_plane(points: np.ndarray, distance: float = 0.01, iterations: int = 200,
                 up: np.ndarray | None = np.array([0.0, 0.0, 1.0]), max_tilt_deg: float = 30.0,
                 attempts: int = 4, min_inliers: int = 100, t: float = 0.0,
                 highest_fraction: float = 0.2) -> tuple[Plane | None, np.ndarray]:
    """Principal plane by open3d RANSAC: (plane, inlier mask), or (None, all-False).

    With ``up`` given, planes tilted more than ``max_tilt_deg`` from it (walls) are skipped
    and the normal is oriented along ``up``. Up to ``attempts`` planes are extracted in
    turn; the principal one is the highest horizontal plane holding at least
    ``highest_fraction`` of the largest one's inliers, so a table wins over a floor seen
    around it while the top face of a box on the table does not.
    """
    pts = as_points(points, "detect_plane.points")
    remaining = np.arange(len(pts))
    found: list[tuple[np.ndarray, float, np.ndarray]] = []
    cos_tilt = np.cos(np.radians(max_tilt_deg))
    for _ in range(max(attempts, 1)):
        if len(remaining) < max(min_inliers, 3):
            break
        model, idx = _cloud(pts[remaining]).segment_plane(distance, 3, iterations)
        idx = np.asarray(idx, dtype=np.int64)
        if len(idx) < min_inliers:
            break
        n = np.asarray(model[:3], float)
        norm = np.linalg.norm(n)
        if not np.isfinite(norm) or norm < 1e-9:
            break
        n, d = n / norm, float(model[3]) / norm
        inl = remaining[idx]
        remaining = np.delete(remaining, idx)
        if up is not None:
            if np.dot(n, up) < 0:
                n, d = -n, -d
            if np.dot(n, up) < cos_tilt:
                continue
        found.append((n, d, inl))
        if up is None:
            break
    mask = np.zeros(len(pts), bool)
    if not found:
        return None, mask
    largest = max(len(f[2]) for f in found)
    big = [f for f in found if len(f[2]) >= highest_fraction * largest]
    n, d, inl = max(big, key=lambda f: -f[1]) if up is not None else big[0]
    n, d, inl = _refit(pts, n, d, distance)
    mask[inl] = True
    centroid = pts[inl].mean(axis=0)
    origin = centroid - (centroid @ n + d) * n
    frame = orthonormal_frame(n, _principal_direction(pts[inl] - origin, n))
    return Plane(n, d, origin, frame, len(inl), t), mask


def _refit(pts: np.ndarray, n: np.ndarray, d: float, distance: float, rounds: int = 8) -> tuple[np.ndarray, float, np.ndarray]:
    """Least-squares refit of a RANSAC plane on its consensus set until the set stops changing.

    open3d's RANSAC draws its samples on several threads, so two runs on one cloud return
    slightly different planes; their consensus sets, refitted, settle on the same plane, which
    keeps a seeded run repeatable (the same points above the table, the same objects).
    """
    inl = np.flatnonzero(np.abs(pts @ n + d) < distance)
    for _ in range(rounds):
        if len(inl) < 3:
            break
        c = pts[inl].mean(axis=0)
        m = np.linalg.svd(pts[inl] - c, full_matrices=False)[2][-1]
        m = m if m @ n >= 0 else -m
        n, d = m, float(-(m @ c))
        again = np.flatnonzero(np.abs(pts @ n + d) < distance)
        if np.array_equal(again, inl):
            break
        inl = again
    return n, d, inl


def _principal_direction(points: np.ndarray, normal: np.ndarray) -> np.ndarray:
    flat = points - np.outer(points @ normal, normal)
    _, vecs = np.linalg.eigh(flat.T @ flat)
    return vecs[:, -1]


def roi_from_plane(plane: Plane, inliers: np.ndarray, min_height: float = 0.01, max_height: float = 0.4,
                   margin: float = 0.0) -> Box:
    """Region of interest: the footprint of the plane's inliers extruded along its normal.

    The box starts ``min_height`` above the plane so that the plane itself is left out.
    """
    loc = (inliers - plane.origin) @ plane.frame
    centre2, ang, size2 = min_area_rectangle(loc[:, :2])
    c, s = np.cos(ang), np.sin(ang)
    rotation = plane.frame @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
    centre = plane.origin + plane.frame @ np.array([centre2[0], centre2[1], (min_height + max_height) / 2])
    extent = np.array([size2[0] + 2 * margin, size2[1] + 2 * margin, max_height - min_height])
    return Box(centre, rotation, extent)


def roi_filter(points: np.ndarray, roi: Box | None) -> np.ndarray:
    """The points inside the region of interest (none without one)."""
    pts = as_points(points, "roi_filter.points")
    if roi is None or len(pts) == 0:
        return EMPTY.copy()
    return pts[roi.contains(pts)]


def sphere_distance(centers: np.ndarray, radii: np.ndarray, cutoff: float = np.inf) -> DistanceFn:
    """Distance function of a spherical robot model: min over spheres of ``|p - c| - r``.

    With a finite ``cutoff`` only spheres reaching within ``cutoff`` of the points'
    bounding box are evaluated: distances below ``cutoff`` stay exact, larger ones may
    come out larger (``inf`` when no sphere is near), which is all a self filter needs.
    """
    c = np.asarray(centers, float).reshape(-1, 3)
    r = np.asarray(radii, float).reshape(-1)
    if len(c) != len(r):
        raise ValueError(f"sphere_distance: {len(c)} centres but {len(r)} radii")

    def dist(points: np.ndarray) -> np.ndarray:
        cc, rr = c, r
        if np.isfinite(cutoff) and len(points):
            lo, hi = points.min(axis=0), points.max(axis=0)
            gap = np.linalg.norm(np.maximum(np.maximum(lo - cc, cc - hi), 0.0), axis=1) - rr
            cc, rr = cc[gap <= cutoff], rr[gap <= cutoff]
        if len(cc) == 0:
            return np.full(len(points), np.inf)
        # |p-c|^2 = |p|^2 - 2 p.c + |c|^2, as one matrix product
        d2 = (points * points).sum(axis=1)[:, None] - 2.0 * points @ cc.T + (cc * cc).sum(axis=1)[None]
        return (np.sqrt(np.maximum(d2, 0.0)) - rr[None]).min(axis=1)

    return dist


def culled_distance(c1: np.ndarray, c2: np.ndarray, r1: np.ndarray, r2: np.ndarray, cutoff: float) -> DistanceFn:
    """The distance to a robot model made of sphere-swept segments (s-topes, Appendix B),
    evaluated per point only on the s-topes whose bounding box grown by ``cutoff`` holds it
    (:mod:`~contactflow.recognition.kernels`): exact below ``cutoff``, at least ``cutoff``
    (or ``inf``) above it.

    ``c1``/``c2`` (M, 3) are the end centres and ``r1``/``r2`` (M,) the end radii, posed in
    the world (copied: the model may be posed again while the function is in use).
    """
    from contactflow.recognition.kernels import culled_stope_distance

    c1, c2 = (np.array(c, dtype=np.float64).reshape(-1, 3) for c in (c1, c2))
    r1, r2 = (np.array(r, dtype=np.float64).reshape(-1) for r in (r1, r2))
    rmax = np.maximum(r1, r2)[:, None] + cutoff
    lo = np.minimum(c1, c2) - rmax
    hi = np.maximum(c1, c2) + rmax

    def dist(points: np.ndarray) -> np.ndarray:
        pts = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
        out = np.empty(len(pts))
        culled_stope_distance(pts, c1, c2, r1, r2, lo, hi, out)
        return out

    return dist


def self_filter(points: np.ndarray, distance_fn: DistanceFn | None, margin: float = 0.02) -> np.ndarray:
    """Drop the points closer than ``margin`` to the robot surface."""
    pts = as_points(points, "self_filter.points")
    if distance_fn is None or len(pts) == 0:
        return pts
    d = np.asarray(distance_fn(pts), float).reshape(-1)
    if d.shape != (len(pts),):
        raise ValueError(f"self_filter: distance function returned {d.shape}, expected ({len(pts)},)")
    return pts[~(d < margin)]


@dataclass(frozen=True, eq=False)
class Cluster:
    """One segmented object: its points, centroid and oriented box."""

    points: np.ndarray
    centroid: np.ndarray
    box: Box


def extract_clusters(points: np.ndarray, eps: float = 0.015, min_points: int = 5, min_size: int = 30,
                     max_size: int = 100_000, plane: Plane | None = None) -> list[Cluster]:
    """Euclidean clustering by open3d DBSCAN, largest first; boxes stand on ``plane`` if given."""
    pts = as_points(points, "extract_clusters.points")
    if len(pts) < max(min_size, 1):
        return []
    labels = np.asarray(_cloud(pts).cluster_dbscan(eps, min_points, print_progress=False), dtype=np.int64)
    if labels.size == 0 or labels.max() < 0:
        return []
    counts = np.bincount(labels[labels >= 0])
    order = np.argsort(labels, kind="stable")
    starts = np.concatenate(([0], np.cumsum(np.bincount(labels + 1))))
    out = []
    for lab in np.argsort(-counts):
        if not (min_size <= counts[lab] <= max_size):
            continue
        members = pts[order[starts[lab + 1]:starts[lab + 2]]]
        box = upright_box(members, plane.frame, plane.origin) if plane is not None else pca_box(members)
        out.append(Cluster(members, members.mean(axis=0), box))
    return out


class PlaneCache:
    """The principal plane, refitted at most every ``period`` seconds (thesis: 1 Hz)."""

    def __init__(self, period: float = 1.0, **detect_kwargs) -> None:
        self.period = period
        self.kwargs = detect_kwargs
        self.plane: Plane | None = None
        self.roi_inliers: np.ndarray = EMPTY

    def due(self, t: float) -> bool:
        return self.plane is None or t - self.plane.t >= self.period or t < self.plane.t

    def update(self, points: np.ndarray, t: float) -> Plane | None:
        """Refit when due; a failed fit drops the cached plane rather than keep a stale one."""
        if not self.due(t):
            return self.plane
        plane, mask = detect_plane(points, t=t, **self.kwargs)
        self.plane, self.roi_inliers = plane, points[mask] if plane is not None else EMPTY
        return plane

    def reset(self) -> None:
        self.plane, self.roi_inliers = None, EMPTY


@dataclass(frozen=True)
class PipelineParams:
    stride: int = 2  # px, depth decimation before back-projection
    min_range: float = 0.2  # m
    max_range: float = 3.0  # m
    voxel: float = 0.006  # m, voxel grid edge
    plane_period: float = 1.0  # s, the plane detector runs at 1 Hz (§6.3.3)
    plane_distance: float = 0.012  # m, RANSAC inlier distance
    plane_iterations: int = 150
    plane_max_tilt_deg: float = 30.0  # deg from world up
    plane_min_inliers: int = 100
    roi_min_height: float = 0.012  # m above the plane
    roi_max_height: float = 0.40  # m above the plane
    roi_margin: float = 0.0  # m, grows the plane footprint
    self_margin: float = 0.02  # m, points closer to the robot are removed
    cluster_eps: float = 0.018  # m, DBSCAN neighbourhood (3 voxels)
    cluster_min_points: int = 4
    cluster_min_size: int = 25  # points
    cluster_max_size: int = 50_000  # points


@dataclass
class SegmentationResult:
    clusters: list[Cluster]
    plane: Plane | None
    roi: Box | None
    timings: dict[str, float] = field(default_factory=dict)  # s per stage
    counts: dict[str, int] = field(default_factory=dict)  # points after each stage


class SegmentationPipeline:
    """The whole chain in one process, with per-stage timings (used by primitives and benchmarks)."""

    def __init__(self, params: PipelineParams | None = None, clock: Callable[[], float] = time.perf_counter) -> None:
        """``clock`` times the stages (``time.process_time`` gives CPU time, immune to other load)."""
        self.params = params or PipelineParams()
        self.clock = clock
        p = self.params
        self.planes = PlaneCache(p.plane_period, distance=p.plane_distance, iterations=p.plane_iterations,
                                 max_tilt_deg=p.plane_max_tilt_deg, min_inliers=p.plane_min_inliers)
        self.roi: Box | None = None

    def reset(self) -> None:
        self.planes.reset()
        self.roi = None

    def cloud(self, depth: np.ndarray, K: np.ndarray, world_T_cam: np.ndarray) -> np.ndarray:
        p = self.params
        pts = depth_to_points(depth, K, world_T_cam, p.stride, p.min_range, p.max_range)
        return voxel_downsample(pts, p.voxel)

    def process_depth(self, depth: np.ndarray, K: np.ndarray, world_T_cam: np.ndarray, t: float = 0.0,
                      distance_fn: DistanceFn | None = None) -> SegmentationResult:
        t0 = self.clock()
        pts = self.cloud(depth, K, world_T_cam)
        t_cloud = self.clock() - t0
        res = self.process_points(pts, t, distance_fn, downsample=False)
        res.timings = {"cloud": t_cloud, **res.timings}
        res.timings["total"] = self.clock() - t0
        return res

    def process_points(self, points: np.ndarray, t: float = 0.0, distance_fn: DistanceFn | None = None,
                       downsample: bool = True) -> SegmentationResult:
        p = self.params
        timings: dict[str, float] = {}
        counts: dict[str, int] = {}
        t0 = self.clock()
        pts = as_points(points, "points")
        if downsample:
            pts = voxel_downsample(pts, p.voxel)
        counts["cloud"] = len(pts)
        t1 = self.clock()
        replan = self.planes.due(t)
        plane = self.planes.update(pts, t)
        if replan:
            self.roi = (roi_from_plane(plane, self.planes.roi_inliers, p.roi_min_height, p.roi_max_height,
                                       p.roi_margin) if plane is not None else None)
        t2 = self.clock()
        inside = roi_filter(pts, self.roi)
        counts["roi"] = len(inside)
        t3 = self.clock()
        free = self_filter(inside, distance_fn, p.self_margin)
        counts["self"] = len(free)
        t4 = self.clock()
        clusters = extract_clusters(free, p.cluster_eps, p.cluster_min_points, p.cluster_min_size,
                                    p.cluster_max_size, plane)
        t5 = self.clock()
        timings.update(prepare=t1 - t0, plane=t2 - t1, roi=t3 - t2, self=t4 - t3, cluster=t5 - t4, total=t5 - t0)
        counts["clusters"] = len(clusters)
        return SegmentationResult(clusters, plane, self.roi, timings, counts)
