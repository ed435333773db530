"""Range sensor hypotheses generator (thesis §4.4.4): occupancy grid, virtual contact sensor, ICP.

1. Before manipulation the occupancy grid map (OGM) is initialised from the object's depth
   points: voxels holding points are occupied (P = 1), voxels on the camera ray behind a point
   down to the table are occluded (P = 0.5), the rest was seen free (P = 0).
2. Every frame the virtual contact sensor (eq. 4.10) evaluates the posed spherical robot model:
   P(z|c) = 0 inside the model, 0.9 on its surface (within ``surface_band``), 0.5 outside.
   The object is tracked with open3d (point-to-plane) ICP between consecutive object clouds.
3. Without object motion the voxels inside the model become free (P = 0). With motion
   (the object centroid moved >= ``motion_translation`` or rotated >= ``motion_angle``) the OGM
   is carried along with the ICP motion, the surface voxels get the binary Bayes update of eq. 4.11 and the surface voxels with P >= ``hypothesis_p`` become
   hypotheses with likelihood 1/n. When motion stops the OGM is rebuilt from the new cloud.
   With ``require_motion=False`` (objects that cannot move) every frame gets the update of
   eq. 4.11: the model surface lying in space not seen free becomes hypotheses.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import open3d as o3d

from contactflow.embodiments.messages import DepthImage, PointCloud, RobotModel
from contactflow.fusion.generators.base import GeneratorModule, capsules_of
from contactflow.fusion.geometry import DistanceFn, distance_fn
from contactflow.fusion.hypotheses import VOXEL_SIZE, Hypotheses, HypothesisType
from contactflow.nodes.module import Port
from contactflow.nodes.status import Status
from contactflow.nodes.wire import NDArray
from contactflow.recognition.messages import RoiMsg

P_OCCLUDED = 0.5


@dataclass(frozen=True)
class RangeParams:
    rate_hz: float = 15.0  # Hz
    robot: str = "robot"
    ogm_voxel: float = VOXEL_SIZE  # m, OGM resolution (the thesis used 1 mm; 5 mm matches the space)
    margin: float = 0.03  # m, OGM extent around the object and its shadow
    table_z: float = 0.75  # m, height of the support plane
    surface_band: float = 0.005  # m, |d| within which a voxel is on the model surface
    sensor_surface: float = 0.9  # P(z|c) on the model surface (eq. 4.10)
    hypothesis_p: float = 0.6  # OGM probability of a surface voxel to become a hypothesis
    motion_translation: float = 0.004  # m, ICP translation that counts as object motion
    motion_angle: float = 0.035  # rad, ICP rotation that counts as object motion
    icp_distance: float = 0.02  # m, ICP max correspondence distance
    icp_voxel: float = 0.004  # m, down-sampling of the clouds before ICP
    min_fitness: float = 0.3  # ICP fitness below this is no motion evidence
    icp_iterations: int = 100  # ICP iterations (sliding faces converge slowly)
    require_motion: bool = True  # thesis: hypotheses only once the object moved; False: whenever
    # the model's surface lies in likely occupied voxels (objects fixed to the table)
    robot_margin: float = 0.01  # m, depth points this close to the robot model are the robot
    table_margin: float = 0.005  # m, depth points this close above the table are the table
    roi: tuple[float, ...] = ()  # m, [xlo, ylo, zlo, xhi, yhi, zhi] box around the object, world; the roi input
    # (a vision chain's region above its support plane) overrides it; (): the whole view
    stride: int = 2  # px, decimation of a depth input's image before back-projection

    def validate(self) -> None:
        if self.roi and (len(self.roi) != 6 or not all(lo < hi for lo, hi in zip(self.roi[:3], self.roi[3:], strict=True))):
            raise ValueError(f"roi: {list(self.roi)} is not [xlo, ylo, zlo, xhi, yhi, zhi] with lo < hi")
        if self.stride < 1:
            raise ValueError(f"stride: {self.stride} must be at least 1")


def segment_object(points: np.ndarray, distance: DistanceFn | None, params: RangeParams,
                   lo: np.ndarray | None = None, hi: np.ndarray | None = None) -> np.ndarray:
    """Object points of a world-frame depth cloud: drop the robot, the table and all outside [lo, hi]."""
    pts = np.asarray(points, dtype=float).reshape(-1, 3)
    keep = pts[:, 2] > params.table_z + params.table_margin
    if lo is not None and hi is not None:
        keep &= np.all((pts >= lo) & (pts <= hi), axis=1)
    pts = pts[keep]
    if distance is not None and pts.shape[0]:
        pts = pts[distance(pts) > params.robot_margin]
    return pts


def icp_motion(prev: np.ndarray, curr: np.ndarray, params: RangeParams) -> tuple[float, float, float, np.ndarray]:
    """Object motion between two clouds by open3d ICP: (displacement of the centroid m,
    rotation rad, fitness, 4x4 transform prev -> curr)."""
    if prev.shape[0] < 10 or curr.shape[0] < 10:
        return 0.0, 0.0, 0.0, np.eye(4)
    src = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(prev)).voxel_down_sample(params.icp_voxel)
    dst = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(curr)).voxel_down_sample(params.icp_voxel)
    # Point-to-plane: faces sliding along themselves (a box top) do not hold the motion back.
    dst.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=3 * params.icp_voxel, max_nn=20))
    res = o3d.pipelines.registration.registration_icp(
        src, dst, params.icp_distance, np.eye(4),
        o3d.pipelines.registration.TransformationEstimationPointToPlane(),
        o3d.pipelines.registration.ICPConvergenceCriteria(1e-9, 1e-9, params.icp_iterations))
    T = np.asarray(res.transformation).copy()
    angle = float(np.arccos(np.clip((np.trace(T[:3, :3]) - 1.0) / 2.0, -1.0, 1.0)))
    c = prev.mean(axis=0)
    shift = float(np.linalg.norm(T[:3, :3] @ c + T[:3, 3] - c))
    return shift, angle, float(res.fitness), T


class OccupancyGrid:
    """Dense OGM over a box: P(c_i) per voxel, float32."""

    def __init__(self, lo: np.ndarray, hi: np.ndarray, voxel: float) -> None:
        self.voxel = voxel
        self.lo = np.asarray(lo, dtype=float)
        self.shape = tuple(np.maximum(np.ceil((np.asarray(hi) - self.lo) / voxel).astype(int), 1))
        self.p = np.zeros(self.shape, dtype=np.float32)
        ijk = np.stack(np.meshgrid(*[np.arange(s) for s in self.shape], indexing="ij"), axis=-1).reshape(-1, 3)
        self.centers = self.lo + (ijk + 0.5) * voxel

    def index(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Flat indices of the points inside the grid, and which points those are."""
        ijk = np.floor((points - self.lo) / self.voxel).astype(np.int64)
        ok = np.all((ijk >= 0) & (ijk < np.array(self.shape)), axis=1)
        return np.ravel_multi_index(ijk[ok].T, self.shape), ok

    @classmethod
    def from_depth(cls, object_points: np.ndarray, camera: np.ndarray, params: RangeParams) -> OccupancyGrid:
        """Occupied voxels at the points, occluded voxels along each ray behind them to the table."""
        pts = np.asarray(object_points, dtype=float).reshape(-1, 3)
        if pts.shape[0] == 0:
            raise ValueError("range: cannot initialise the occupancy grid from an empty object cloud")
        cam = np.asarray(camera, dtype=float).reshape(3)
        u = pts - cam
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        down = u[:, 2] < -1e-6
        t_end = np.where(down, (params.table_z - pts[:, 2]) / np.where(down, u[:, 2], -1.0), 0.0)
        t_end = np.clip(t_end, 0.0, 1.0)  # a shadow never extends more than 1 m
        ends = pts + t_end[:, None] * u
        lo = np.minimum(pts.min(axis=0), ends.min(axis=0)) - params.margin
        hi = np.maximum(pts.max(axis=0), ends.max(axis=0)) + params.margin
        lo[2] = max(lo[2], params.table_z)
        grid = cls(lo, hi, params.ogm_voxel)
        step = params.ogm_voxel / 2
        counts = np.ceil(t_end / step).astype(np.int64) + 1
        owner = np.repeat(np.arange(pts.shape[0]), counts)
        first = np.cumsum(counts) - counts
        k = np.arange(owner.size) - np.repeat(first, counts)
        samples = pts[owner] + (k * step)[:, None] * u[owner]
        idx, _ = grid.index(samples)
        flat = grid.p.reshape(-1)
        flat[idx] = P_OCCLUDED
        idx, _ = grid.index(pts)
        flat[idx] = 1.0
        return grid

    def transform(self, T: np.ndarray) -> None:
        """Carry the occupancy along with the object's motion T (nearest-voxel resampling)."""
        Tinv = np.linalg.inv(T)
        src = self.centers @ Tinv[:3, :3].T + Tinv[:3, 3]
        idx, ok = self.index(src)
        old = self.p.reshape(-1).copy()
        flat = self.p.reshape(-1)
        flat[:] = 0.0
        flat[np.flatnonzero(ok)] = old[idx]

    def sensor_model(self, d: np.ndarray, params: RangeParams) -> np.ndarray:
        """Virtual contact sensor P(z|c) of eq. 4.10 from signed distances to the model."""
        pz = np.full(d.shape, 0.5, dtype=np.float32)
        pz[d < -params.surface_band] = 0.0
        pz[np.abs(d) <= params.surface_band] = params.sensor_surface
        return pz

    def update(self, distance: DistanceFn, moved: bool, params: RangeParams) -> np.ndarray:
        """One OGM update; returns the flat indices of the model's surface voxels."""
        flat = self.p.reshape(-1)
        d = distance(self.centers)
        surface = np.flatnonzero(np.abs(d) <= params.surface_band)
        inside = np.flatnonzero(d < -params.surface_band)
        if not moved:
            # The thesis also clears the surface voxels here; a touch that has not moved the
            # object yet would then erase the very layer the contact is in, so they are kept.
            flat[inside] = 0.0
            return surface
        # Eq. 4.11 normalised over the two states of the voxel (occupied / free).
        pz = self.sensor_model(d[surface], params)
        prior = flat[surface]
        num = prior * pz
        den = num + (1.0 - prior) * (1.0 - pz)
        flat[surface] = np.divide(num, den, out=np.zeros_like(num), where=den > 0)
        flat[inside] = 0.0
        return surface


class RangeGenerator:
    """The stateful core: initialise from a first cloud, then observe frame by frame."""

    def __init__(self, params: RangeParams | None = None) -> None:
        self.params = params or RangeParams()
        self.grid: OccupancyGrid | None = None
        self.camera: np.ndarray | None = None
        self.prev: np.ndarray | None = None
        self.moving = False
        self.last_motion = (0.0, 0.0, 0.0)

    def initialize(self, object_points: np.ndarray, camera: np.ndarray) -> None:
        self.grid = OccupancyGrid.from_depth(object_points, camera, self.params)
        self.camera = np.asarray(camera, dtype=float).reshape(3)
        self.prev = np.asarray(object_points, dtype=float).reshape(-1, 3)
        self.moving = False

    def observe(self, object_points: np.ndarray, distance: DistanceFn, stamp: float,
                camera: np.ndarray | None = None) -> Hypotheses:
        """One frame of segmented object points; hypotheses when the object moved."""
        pts = np.asarray(object_points, dtype=float).reshape(-1, 3)
        if self.grid is None:
            if camera is None:
                raise ValueError("range: the first frame needs the camera position")
            if pts.shape[0] == 0:
                return Hypotheses.empty(stamp)
            self.initialize(pts, camera)
            return Hypotheses.empty(stamp)
        assert self.prev is not None
        p = self.params
        # Compare like with like: the points the robot now hides are dropped from both clouds.
        prev = self.prev[distance(self.prev) > p.robot_margin] if self.prev.shape[0] else self.prev
        trans, angle, fitness, T = icp_motion(prev, pts, p)
        self.last_motion = (trans, angle, fitness)
        moved = fitness >= p.min_fitness and (trans >= p.motion_translation or angle >= p.motion_angle)
        if moved:
            self.grid.transform(T)
        # A fixed object cannot move: every frame then carries the virtual sensor's evidence.
        surface = self.grid.update(distance, moved or not p.require_motion, p)
        if pts.shape[0]:
            self.prev = pts
        if not moved:
            if self.moving and pts.shape[0] and self.camera is not None:
                self.initialize(pts, self.camera if camera is None else camera)
                return Hypotheses.empty(stamp)
            if p.require_motion:
                return Hypotheses.empty(stamp)
        else:
            self.moving = True
        flat = self.grid.p.reshape(-1)
        hit = surface[flat[surface] >= p.hypothesis_p]
        if hit.size == 0:
            return Hypotheses.empty(stamp)
        return Hypotheses.make(self.grid.centers[hit], 1.0 / hit.size, HypothesisType.REGULAR, stamp=stamp,
                               where="range")


class RangeHypothesesGenerator(GeneratorModule):
    """Depth camera + occupancy grid + ICP object tracking to contact hypotheses (§4.4.4)."""

    Params = RangeParams
    inputs = (
        Port("points", PointCloud, "depth points, world frame, with the camera position as origin"),
        Port("depth", DepthImage, "or a camera's depth frames (a world's depth stream), back-projected here"),
        Port("robot_model", RobotModel, "posed bi-spheres of the observed robot, world"),
        Port("roi", RoiMsg, "the region the objects are read in (a vision chain's region above its support plane: "
                            "its box's axis-aligned bounds, world; optional, else params.roi)"),
    )

    def setup(self, io) -> None:  # type: ignore[no-untyped-def]
        super().setup(io)
        self.core = RangeGenerator(self.params)

    def reset(self) -> None:
        self.core = RangeGenerator(self.params)

    def step(self) -> Status:
        assert self.io is not None
        model = capsules_of(self.io.latest("robot_model"), "robot_model", self.name)
        frames = self.io.take("points") + self.io.take("depth")
        if model is None or not frames:
            return Status.RUNNING
        roi = self.io.latest("roi")
        lo = hi = None
        if roi is not None:
            corners = np.asarray(roi.vertices, dtype=float)  # type: ignore[attr-defined]
            if corners.shape != (24,) or not np.isfinite(corners).all():
                raise ValueError(f"{self.name}: input 'roi' has {corners.size} vertex values, expected 8 finite x, y, z")
            lo, hi = corners.reshape(8, 3).min(axis=0), corners.reshape(8, 3).max(axis=0)
        elif self.params.roi:
            lo, hi = np.asarray(self.params.roi[:3]), np.asarray(self.params.roi[3:])
        # a point or a voxel farther from the robot than its margins is neither the robot nor on its surface
        dist = distance_fn(self.near(model, lo, hi), cutoff=max(self.params.surface_band, self.params.robot_margin))
        msg = max(frames, key=lambda m: m.hdr.t_sim)
        if isinstance(msg, DepthImage):
            msg = self.back_project(msg)
        assert isinstance(msg, PointCloud)
        if msg.frame != "world":
            raise ValueError(f"{self.name}: input 'points' is in frame {msg.frame!r}, expected 'world'")
        camera = np.asarray(msg.origin, dtype=float)
        if camera.shape != (3,) or not np.isfinite(camera).all():
            raise ValueError(f"{self.name}: input 'points' ({msg.sensor}) has origin {msg.origin}, "
                             "expected the camera position [x, y, z]")
        pts = msg.points.numpy().astype(np.float64)
        if pts.ndim != 2 or pts.shape[1] != 3 or not np.isfinite(pts).all():
            raise ValueError(f"{self.name}: input 'points' has shape {pts.shape} or non-finite values, "
                             "expected finite (n, 3)")
        obj = segment_object(pts, dist, self.params, lo, hi)
        self.publish_cloud(self.core.observe(obj, dist, self.stamp_of(msg), camera))
        return Status.RUNNING

    def near(self, caps: np.ndarray, lo: np.ndarray | None, hi: np.ndarray | None) -> np.ndarray:
        """The robot's bi-spheres that reach the space the generator reads (the roi and the grid): the others
        change no voxel's class (inside, surface) nor any point's (robot or not), and every link of the robot
        evaluated over every voxel of the grid was most of a frame's cost (profiled on the contacts bench)."""
        if lo is None or hi is None:  # no roi: every point of the view is read
            return caps
        boxes = [(lo, hi)]
        grid = self.core.grid
        if grid is not None:
            boxes.append((grid.lo, grid.lo + np.asarray(grid.shape) * grid.voxel))
        p = self.params
        pad = max(p.surface_band, p.robot_margin) + p.ogm_voxel
        b_lo = np.min([b[0] for b in boxes], axis=0) - pad
        b_hi = np.max([b[1] for b in boxes], axis=0) + pad
        r1, r2 = caps[:, 3:4], caps[:, 7:8]
        c_lo = np.minimum(caps[:, 0:3] - r1, caps[:, 4:7] - r2)
        c_hi = np.maximum(caps[:, 0:3] + r1, caps[:, 4:7] + r2)
        return caps[np.all((c_lo <= b_hi) & (c_hi >= b_lo), axis=1)]

    def back_project(self, msg: DepthImage) -> PointCloud:
        """The world points of a depth frame, with its camera position as origin and its stamp."""
        from contactflow.recognition.geometry import depth_to_points
        from contactflow.recognition.messages import depth_arrays

        try:
            depth, K, T = depth_arrays(msg)
        except ValueError as exc:
            raise ValueError(f"{self.name}: input 'depth': {exc}") from None
        pts = depth_to_points(depth, K, T, self.params.stride)
        return PointCloud(points=NDArray.of(pts.astype(np.float32)), origin=[float(v) for v in T[:3, 3]],
                          sensor=msg.camera, hdr=msg.hdr)
