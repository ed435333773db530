"""Detect objects (§6.3.3, §3.4.1): object clusters in a region, of the vision chain or of its own camera frame, and a filtered approach vector (§6.3.5)."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from contactflow.embodiments.primitives.base import (
    Capability,
    Primitive,
    hand_pose_for,
    pose6,
    top_grasp_pose,
    wall_yaws,
)
from contactflow.nodes.module import Port
from contactflow.nodes.status import Event
from contactflow.recognition.messages import PlaneMsg, SegmentedObjects

if TYPE_CHECKING:
    from contactflow.recognition.pipeline import Cluster, Plane

VERTICAL_TOL_DEG = 1.0
"""deg: an approach this close to straight down is the top grasp (hand z exactly down)."""
MIN_HEIGHT = 0.01
"""m: points this close to the support are the support's."""
CLUSTER_EPS = 0.015
"""m: DBSCAN neighbourhood of the objects' points."""
TOP_BAND = 0.01
"""m: the points this close to an object's top are its top face, seen whole from above (its centre across)."""


def support_plane(region: np.ndarray, z: float) -> Plane:
    """The horizontal plane at height ``z`` (m) under the middle of ``region``: a known support, e.g. a box bottom."""
    from contactflow.recognition.pipeline import Plane

    origin = np.array([(region[0] + region[3]) / 2, (region[1] + region[4]) / 2, z])
    return Plane(np.array([0.0, 0.0, 1.0]), -float(z), origin, np.eye(3), 0)


def segment_scene(points: np.ndarray, region: np.ndarray, support_z: float | None = None,
                  min_height: float = MIN_HEIGHT, eps: float = CLUSTER_EPS, min_size: int = 30):
    """(support plane, object clusters largest first) of a world-frame cloud inside ``region``.

    The support is the RANSAC plane of the region (or the horizontal plane at ``support_z``
    when given, e.g. a known box bottom); points ``min_height`` above it are clustered with
    DBSCAN, each cluster with an upright box standing on the support.
    """
    from contactflow.recognition.pipeline import detect_plane, extract_clusters

    lo, hi = region[:3], region[3:]
    pts = points[np.all((points >= lo) & (points <= hi), axis=1)]
    if len(pts) < min_size:
        return None, []
    if support_z is None:
        plane, inliers = detect_plane(pts, distance=0.005, min_inliers=min_size)
        if plane is None:
            return None, []
        above = pts[(plane.height(pts) > min_height) & ~inliers]
    else:
        plane = support_plane(region, support_z)
        above = pts[pts[:, 2] > support_z + min_height]
    return plane, extract_clusters(above, eps=eps, min_size=min_size, plane=plane)


def observed_fraction(points: np.ndarray, region: np.ndarray, cell: float = 0.01) -> float:
    """Fraction of the ``region``'s ground cells (``cell`` m squares) that hold a point of ``points`` (world, in the region).

    A cell without a point was not seen: behind a wall, an arm or out of the image. An
    empty-looking region that was barely seen is not known to be empty.
    """
    lo, hi = np.asarray(region[:2], dtype=np.float64), np.asarray(region[3:5], dtype=np.float64)
    shape = np.maximum(np.ceil((hi - lo) / cell).astype(int), 1)
    if len(points) == 0:
        return 0.0
    ij = np.clip(np.floor((np.asarray(points)[:, :2] - lo) / cell).astype(int), 0, shape - 1)
    return len(np.unique(ij[:, 0] * shape[1] + ij[:, 1])) / float(shape[0] * shape[1])


def is_top_grasp(direction: np.ndarray) -> bool:
    """An approach within ``VERTICAL_TOL_DEG`` of straight down: a fitted normal's noise is no reason to tilt the hand."""
    return bool(direction[2] <= -np.cos(np.radians(VERTICAL_TOL_DEG)))


def top_centred(av, points: np.ndarray, band: float):
    """A top grasp ``av`` moved (in xy) over the centroid of the object ``points`` within ``band`` m of its top; other approaches unchanged.

    A camera sees an object's top and its near side: the centroid of all the points lies
    toward the camera, by a centimetre on a 5 cm can. Its top is seen whole.
    """
    if not is_top_grasp(av.direction):
        return av
    top = points[points[:, 2] >= points[:, 2].max() - band]
    return replace(av, position=np.array([*top[:, :2].mean(axis=0), av.position[2]]))


def grasp_height(points: np.ndarray, depth: float) -> float:
    """World z a grasp of the object ``points`` aims at: ``depth`` below its top, at most half its height down."""
    top, bottom = float(points[:, 2].max()), float(points[:, 2].min())
    return top - min(depth, max(0.5 * (top - bottom), 0.01))


def raised(avs: list, up_to: float, step: float) -> list:
    """Each approach, a side approach followed by itself ``step`` m higher at a time while its start stays at or
    below ``up_to`` (world z); top grasps unchanged.

    A side approach starts level with the object's centroid. Beside a short object there the
    arm's wrist and the hand's lowest finger are in the support (tombatossals' left side grasp
    needs its grasp centre 11 cm over the table), so no collision-free arm posture reaches it;
    higher up the object one may.
    """
    if step <= 0.0:
        return list(avs)
    out = []
    for av in avs:
        out.append(av)
        if is_top_grasp(av.direction):
            continue
        lift = step
        while av.position[2] + lift <= up_to + 1e-9:
            out.append(replace(av, position=av.position + np.array([0.0, 0.0, lift])))
            lift += step
    return out


def segment_objects(points: np.ndarray, region: np.ndarray, support_z: float | None = None,
                    min_height: float = MIN_HEIGHT, eps: float = CLUSTER_EPS, min_size: int = 30) -> list[np.ndarray]:
    """Object clusters (largest first) of a world-frame cloud inside ``region`` [xmin, ymin, zmin, xmax, ymax, zmax]."""
    return [c.points for c in segment_scene(points, region, support_z, min_height, eps, min_size)[1]]


@dataclass(frozen=True)
class View:
    """One look at the region: the support plane, the object clusters (largest first) and where they came from."""

    plane: Plane | None
    clusters: list[Cluster]  # world frame
    points: np.ndarray | None  # the region's points (a camera frame's); None: only the objects are known
    source: str


class DetectObjects(Primitive):
    """Perceptual primitive: OBJECT_DETECTED with the chosen object's centroid, top and approach pose.

    The approach comes from grasp synthesis (§6.3.5) on the object's segmented cloud: PCA
    approach vectors where its box axes meet the box, ``standoff`` outside, kept when the
    hand is clear of the support and the other objects, within ``max_angle_deg`` of
    ``direction`` (default straight down, the top grasp), within ``max_distance`` of the arm
    base and, with ``reachable``, when the arm's IK (pinocchio) reaches the hand pose clear of
    the cell's fixtures (a side approach it does not reach is tried ``raise_step`` higher at a
    time, up to the grasp height); the best ranked one wins. Without ``arm`` the nearest arm base counts and any arm of the
    robot may reach it. Beside a container wall (``walls``) the hand turns its ``wall_side`` to it. The hand's
    x axis follows ``yaw`` (about world z) as far as the approach allows (within
    ``VERTICAL_TOL_DEG`` of straight down it is the top grasp of that yaw), and the hand's
    grasp centre (per embodiment) is put on the approach start. If the selected object has
    no approach passing the filters the next one is tried; none ends with FAILURE. With
    no object in the region it ends with OBJECT_NOT_FOUND (the "no objects left" edge),
    unless less than ``min_observed`` of the region's ground was seen (an arm in the view):
    then FAILURE, as the region is not known to be empty.

    Where the objects come from: on a node whose configuration wires the ``objects`` port
    (the vision3d chain's clusters, thesis §6.3.3), from the newest message of a depth frame
    taken ``settle`` s or more after the start, each cluster cut to the region and off the
    robot (a cut cluster is clustered again: what joined it may have been cut away), on the
    support of ``support_z`` or else of the ``plane`` port; no such message within
    ``timeout`` is FAILURE. The clusters do not show how much of an empty-looking region was
    in view, so with ``min_observed`` that case is judged on a camera frame. Unwired
    (in-process runs, benches) the primitive segments a camera frame of its own. The
    OBJECT_DETECTED and outcome details name the source.
    """

    requires = Capability(camera=True)
    commands_arm = False
    inputs = (Port("objects", SegmentedObjects, "the vision chain's object clusters, world frame (unwired: the camera)"),
              Port("plane", PlaneMsg, "the vision chain's support plane (collision filter)"))
    events = (Event.SUCCESS, Event.FAILURE, Event.ERROR, Event.OBJECT_DETECTED, Event.OBJECT_NOT_FOUND)

    @dataclass(frozen=True)
    class Params(Primitive.Params):
        region: tuple[float, ...] = (0.3, -0.6, 0.74, 1.0, 0.6, 1.2)  # m, world box [xmin, ymin, zmin, xmax, ymax, zmax]
        support_z: float = -1.0  # m, known support height (< 0: fit the table plane)
        select: str = "largest"  # largest | leftmost | nearest | random (random also turns the hand yaw by 90, 180 or 270 deg in half the draws, so a retry is not the same failed grasp)
        standoff: float = 0.05  # m, approach starts this far outside the object's box
        grasp_depth: float = 0.06  # m, grasp frame below the object top (clipped to half the height)
        yaw: float = 1.5707963267948966  # rad, hand yaw of the top grasp
        preshape: str = ""  # the hand preshape the grasp closes from: the approach puts where it catches an object (the robot's grasp centre for it) on the object ("": open)
        direction: tuple[float, ...] = (0.0, 0.0, -1.0)  # preferred approach direction, world (zeros: any)
        max_angle_deg: float = 30.0  # deg, orientation filter around ``direction``
        max_distance: float = 1.0  # m, distance filter: approach start from the arm base
        reachable: bool = True  # reachability filter by the arm's IK, clear of the cell's fixtures (the planner's goal test)
        raise_step: float = 0.01  # m, a side approach the arm cannot reach is tried this much higher at a time, up to the grasp height (grasp_depth below the top; 0: not raised)
        hand_radius: float = 0.04  # m, collision filter: hand spheres along the approach
        hand_length: float = 0.15  # m
        camera: str = "kinect"
        min_size: int = 30  # points per object
        seed: int = 0  # for select=random
        settle: float = 0.1  # s waited before the snapshot (wired: the depth frame is taken this long after the start, or later)
        timeout: float = 5.0  # s after settle a wired objects port has to deliver, else FAILURE
        self_margin: float = 0.02  # m, points this close to the robot model are removed
        walls: tuple[float, ...] = ()  # m, [xmin, ymin, xmax, ymax] inner sides of a container the objects are in (none: no walls)
        wall_margin: float = 0.055  # m, an object centre this close to a wall is grasped with ``wall_side`` toward it
        wall_side: tuple[float, ...] = (1.0, 0.0)  # hand-frame (x, y) direction put toward a nearby wall (per hand, measured)
        min_observed: float = 0.0  # fraction of the region's ground (1 cm cells) seen before "no object" is believed
        top_band: float = 0.0  # m, a top grasp is centred on the object's points this close to its top (0: on all its points; the camera sees one side of an object, which pulls their centroid toward it)

    def setup(self, io) -> None:  # type: ignore[no-untyped-def]
        super().setup(io)
        from contactflow.recognition import open3d_backend

        open3d_backend.load()  # the clustering and the grasp synthesis: at setup, not in the control loop's first detect

    def begin(self) -> None:
        p = self.params
        if p.select not in ("largest", "leftmost", "nearest", "random"):
            raise ValueError(f"{self.name}: params.select must be largest|leftmost|nearest|random, got {p.select!r}")
        region = np.asarray(p.region, dtype=np.float64)
        if region.shape != (6,) or np.any(region[:3] >= region[3:]):
            raise ValueError(f"{self.name}: params.region must be [xmin, ymin, zmin, xmax, ymax, zmax], got {p.region}")
        if len(p.direction) != 3 or not np.all(np.isfinite(p.direction)):
            raise ValueError(f"{self.name}: params.direction must be 3 finite numbers, got {p.direction}")
        if not p.raise_step >= 0.0:
            raise ValueError(f"{self.name}: params.raise_step must be >= 0 m, got {p.raise_step}")
        if not 0.0 <= p.min_observed <= 1.0:
            raise ValueError(f"{self.name}: params.min_observed must be a fraction in [0, 1], got {p.min_observed}")
        self.region = region
        self.from_vision = self.io.wired("objects")  # unwired (an in-process runner wires none): the camera

    def _order(self, clusters: list, rng: np.random.Generator) -> list:
        p = self.params
        if p.select == "leftmost":
            return sorted(clusters, key=lambda c: -c.centroid[1])
        if p.select == "nearest":
            return sorted(clusters, key=lambda c: float(np.linalg.norm(c.centroid[:2])))
        if p.select == "random":
            k = int(rng.integers(len(clusters)))
            return [clusters[k]] + clusters[:k] + clusters[k + 1:]
        return clusters

    def hand_pose(self, av, yaw: float | None = None) -> np.ndarray:
        """Controlled-frame pose putting the hand's grasp centre on the approach start, z along the approach.

        The hand's x axis follows ``yaw`` (default: ``params.yaw``) as far as the approach allows.
        """
        yaw = self.params.yaw if yaw is None else yaw
        from contactflow.recognition.geometry import orthonormal_frame

        d = np.asarray(av.direction, float)
        if is_top_grasp(d):
            return hand_pose_for(self.r.spec.name, top_grasp_pose(av.position, yaw), self.params.preshape)
        T = np.eye(4)
        T[:3, :3] = orthonormal_frame(d, np.array([np.cos(yaw), np.sin(yaw), 0.0]))
        T[:3, 3] = av.position
        return hand_pose_for(self.r.spec.name, T, self.params.preshape)

    def _reach(self):
        """IK of the arm (any arm without ``params.arm``), seeded where the planner's goal IK starts (the robot's
        joints, each arm at its commanded ones) and searching as long (``GOAL_RESTARTS``): an approach the filter
        passes is one the planner reaches; None: no filter."""
        from contactflow.embodiments.control.planning import GOAL_RESTARTS
        from contactflow.recognition.reachability import ArmReach

        if not self.params.reachable:
            return None
        kin = getattr(self.r, "kin", None)
        arms = [self.params.arm] if self.params.arm else list(self.r.arms)
        solvers = []
        fixtures = self.r.fixtures()
        for arm in arms:
            # 16 restarts: clear of the table, a side grasp's postures are few (beside the open_bottle cell's
            # bottle 1 cm above the lowest reachable height, 4 restarts of 200 steps found none, 8 of 300 one
            # seed in two); only a pose that is never reached pays for all of them (0.2 s)
            reach = ArmReach(self.r.spec.name, arm, None if kin is None else kin.base, restarts=GOAL_RESTARTS,
                             iters=300, where=f"{self.name}: arm {arm!r}", obstacles=fixtures)
            if kin is not None:
                reach.set_seed(self.r.kin_q_cmd())
            solvers.append(reach)

        def ik(T: np.ndarray):
            for s in solvers:
                q = s(T)
                if q is not None:
                    return q
            return None

        return ik

    def update(self) -> None:
        from contactflow.recognition.grasp_synthesis import (
            GraspFilters,
            reachability_filter,
            synthesize_grasps,
        )

        p = self.params
        if self.elapsed < p.settle:
            return
        view = self._vision_view() if self.from_vision else None
        if self.from_vision and view is None:
            if self.elapsed >= p.settle + p.timeout:
                self.fail(f"the vision chain sent no objects of a depth frame taken {p.settle:g} s or more after "
                          f"the start within {p.timeout:g} s", count=0)
            return
        if view is None or (not view.clusters and p.min_observed > 0.0):
            # the clusters do not show how much of an empty-looking region was in view: a camera frame does
            view = self._camera_view()
        plane, clusters = view.plane, view.clusters
        if not clusters:
            seen = None if view.points is None else observed_fraction(view.points, self.region)
            if seen is not None and seen < p.min_observed:
                self.fail(f"no object seen, but only {100 * seen:.0f} % of the region was in view "
                          f"(min_observed {100 * p.min_observed:.0f} %)", count=0, observed=seen)
                return
            self.fail(f"no object in the region ({view.source})", event=Event.OBJECT_NOT_FOUND, count=0,
                      **({} if seen is None else {"observed": seen}))
            return
        # a fresh draw per detection (the seed alone would repeat it): the run's seed and the time
        rng = np.random.default_rng([p.seed, int(self.r.time * 1000)])
        yaws = [p.yaw]
        if p.select == "random" and rng.random() < 0.5:
            # half the draws keep the configured yaw (the hand's best), the others start a quarter or half turn off it
            yaws = [p.yaw + k * np.pi / 2 for k in (*rng.permutation([1, 2, 3]), 0)]
        arms = [p.arm] if p.arm else list(self.r.arms)
        bases = np.array([self.r.frame_pose(self.r.spec.arm(a).base_link)[:3, 3] for a in arms])
        ik = self._reach()
        for pick in self._order(clusters, rng):
            pick_yaws = wall_yaws(yaws, pick.centroid, p.walls, p.wall_margin, p.wall_side)
            base = bases[int(np.argmin(np.linalg.norm(bases - pick.centroid, axis=1)))]  # the nearest arm's
            filters = GraspFilters(p.standoff, p.hand_radius, p.hand_length, tuple(p.direction), p.max_angle_deg,
                                   tuple(base), p.max_distance)
            others = [c.points for c in clusters if c is not pick]
            # the geometric filters do not depend on the yaw: only the reachability is checked per yaw
            avs = synthesize_grasps(pick.points, pick.box, filters, np.vstack(others) if others else None, plane)
            if p.top_band > 0.0:
                avs = [top_centred(av, pick.points, p.top_band) for av in avs]
            if ik is not None:
                avs = raised(avs, grasp_height(pick.points, p.grasp_depth), p.raise_step)
            for yaw in pick_yaws:
                reached = avs if ik is None else reachability_filter(
                    avs, ik, pose=lambda av, yaw=yaw: self.hand_pose(av, yaw), first=True)
                if reached:
                    self._detected(pick, reached[0], len(clusters), yaw, view.source)
                    return
        self.fail(f"no approach vector of the {len(clusters)} objects passes the filters ({view.source})",
                  count=len(clusters))

    def _camera_view(self) -> View:
        """The objects of a camera frame of the region, off the robot."""
        p = self.params
        frame = self.r.camera(p.camera)
        pts = np.asarray(frame.points)
        lo, hi = self.region[:3], self.region[3:]
        pts = pts[np.all((pts >= lo) & (pts <= hi), axis=1)]
        model = getattr(self.r, "spherical", None)
        if model is not None and len(pts):
            pts = pts[model.clear_of(pts, p.self_margin)]  # the robot's own arms are not objects
        plane, clusters = segment_scene(pts, self.region, p.support_z if p.support_z >= 0 else None,
                                        min_size=p.min_size)
        return View(plane, clusters, pts, f"camera {p.camera} at {frame.t:.2f} s")

    def _vision_view(self) -> View | None:
        """The objects of the wired vision chain's newest message, if its depth frame was taken after the settle."""
        from contactflow.recognition.pipeline import extract_clusters

        p = self.params
        msg = self.io.latest("objects")
        if msg is None or msg.depth_t is None or msg.depth_t < self.t0 + p.settle:
            return None
        if p.support_z >= 0:
            plane = support_plane(self.region, p.support_z)
        else:
            plane_msg = self.io.latest("plane")
            plane = plane_msg.plane() if plane_msg is not None else None
        lo, hi = self.region[:3], self.region[3:]
        model = getattr(self.r, "spherical", None)
        clusters = []
        for c in msg.clusters():
            keep = np.all((c.points >= lo) & (c.points <= hi), axis=1)
            if p.support_z >= 0:
                keep &= c.points[:, 2] > p.support_z + MIN_HEIGHT
            if model is not None and keep.any():
                keep[keep] = model.clear_of(c.points[keep], p.self_margin)  # the robot's own arms are not objects
            if keep.all():
                clusters.append(c)
            else:  # the parts of a cut cluster: the chain may have joined objects through what was cut away
                clusters += extract_clusters(c.points[keep], eps=CLUSTER_EPS, min_size=p.min_size, plane=plane)
        clusters = sorted((c for c in clusters if len(c.points) >= p.min_size), key=lambda c: -len(c.points))
        f = msg.depth_frame
        return View(plane, clusters, None, f"vision chain, depth frame {f.source}#{f.seq} at {msg.depth_t:.2f} s")

    def _detected(self, pick, av, count: int, yaw: float, source: str) -> None:
        p = self.params
        pts = pick.points
        c = pick.centroid
        top, bottom = float(pts[:, 2].max()), float(pts[:, 2].min())
        size = pts.max(axis=0) - pts.min(axis=0)
        grasp_z = grasp_height(pts, p.grasp_depth)
        approach = self.hand_pose(av, yaw)
        d = av.direction
        dims = np.sort(pick.box.extent)[::-1]
        tx, ty = pts[pts[:, 2] >= top - TOP_BAND][:, :2].mean(axis=0)
        vals = dict(count=count, cx=float(c[0]), cy=float(c[1]), cz=float(c[2]), top=top, tx=float(tx), ty=float(ty),
                    size_x=float(size[0]), size_y=float(size[1]), size_z=float(top - bottom),
                    grasp_z=float(grasp_z), dx=float(d[0]), dy=float(d[1]), dz=float(d[2]),
                    d1=float(dims[0]), d2=float(dims[1]), d3=float(dims[2]), **pose6(approach))
        self.emit_once(Event.OBJECT_DETECTED, f"{count} objects ({source})", vals)
        self.succeed(f"{count} objects ({source})", **vals)
