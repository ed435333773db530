"""Joint-space planning with OMPL (KPIECE1 as in the thesis, RRTConnect), collision-checked robot vs. scene.

Two checkers: ``CoalChecker`` (pinocchio geometry model of the URDF collision meshes
against the scene primitives and an octree of a sensed point cloud, via coal) and
``SphericalChecker`` (the App. B spherical model against points sampled on the obstacle
surfaces and the sensed cloud). Self-collision follows the simulated robot: links of different
parts (``RobotSpec.collision_groups``, e.g. a torso's two arms) collide, links of one part do
not (the world's collision groups, same rule). Nothing here imports SAPIEN, and the planner never sees the
simulated objects' true poses: the scene is what the caller sensed or was told
(:class:`Obstacle` records, a point cloud) plus the cell's known fixtures (the table).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import coal
import numpy as np
import pinocchio as pin
from ompl import base as ob
from ompl import geometric as og
from ompl import util as ou

from contactflow.embodiments.control.kinematics import Kinematics
from contactflow.embodiments.registry import collision_part
from contactflow.embodiments.spherical import SphericalModel, stope_distance
from contactflow.embodiments.transforms import inv, rotvec_error

ou.setLogLevel(ou.LogLevel.LOG_WARN)

PLANNERS = {"KPIECE1": og.KPIECE1, "RRTConnect": og.RRTConnect}
_seeded = False


def seed_ompl(seed: int) -> None:
    """Seed OMPL's RNG; OMPL accepts this only before its first sample, so later calls are ignored."""
    global _seeded
    if not _seeded:
        ou.RNG.setSeed(seed)
        _seeded = True


@dataclass(frozen=True)
class Obstacle:
    """A scene primitive in the world frame; cylinders/capsules along local z."""

    name: str
    kind: str  # box | cylinder | sphere | capsule
    size: tuple[float, ...]  # as ShapeSpec: box full sizes; cylinder radius, length; sphere radius
    pose: np.ndarray  # 4x4 world


@dataclass
class PlanProfile:
    """Where one plan's time went (s) and the collision checks it made."""

    ends: float = 0.0  # checking the start and goal states
    search: float = 0.0  # OMPL's solve, over every search
    simplify: float = 0.0  # shortcutting the found path, over every search
    validate: float = 0.0  # the found paths checked waypoint by waypoint at the fine step
    searches: int = 0  # over 1: the coarse search's path failed the fine check and was searched again at the fine step
    search_checks: int = 0  # states checked while searching and shortcutting
    path_checks: int = 0  # states checked at the ends and along found paths

    @property
    def checks_per_second(self) -> float:
        """Collision checks per second of search and shortcutting."""
        busy = self.search + self.simplify
        return self.search_checks / busy if busy > 0 else 0.0


@dataclass
class Plan:
    """A joint-space path of one arm."""

    joints: tuple[str, ...]
    waypoints: np.ndarray  # (K, n)
    planner: str
    planning_time: float  # s
    success: bool
    why_not: str = ""  # a failed plan's reason: which end state is invalid, or the time-out
    timed_out: bool = False  # the search ran out of time (a fresh try may find a path; invalid ends never)
    profile: PlanProfile = field(default_factory=PlanProfile)

    @property
    def length(self) -> float:
        return float(np.linalg.norm(np.diff(self.waypoints, axis=0), axis=1).sum())


def _coal_shape(o: Obstacle, padding: float):
    if o.kind == "box":
        return coal.Box(*[s + 2 * padding for s in o.size])
    if o.kind == "sphere":
        return coal.Sphere(o.size[0] + padding)
    if o.kind == "cylinder":
        return coal.Cylinder(o.size[0] + padding, o.size[1] + 2 * padding)
    if o.kind == "capsule":
        return coal.Capsule(o.size[0] + padding, o.size[1])
    raise ValueError(f"obstacle {o.name!r}: kind {o.kind!r} is not box|cylinder|sphere|capsule")


def self_pairs(links: list[str], moving: list[bool], parts: tuple[str, ...]) -> list[tuple[int, int]]:
    """Index pairs of robot bodies that can collide: different parts, at least one moved by a joint."""
    part = [collision_part(n, parts) for n in links]
    return [(i, j) for i in range(len(links)) for j in range(i + 1, len(links))
            if part[i] != part[j] and (moving[i] or moving[j])] if parts else []


class CoalChecker:
    """Robot collision meshes vs. obstacles and, across ``parts``, vs. each other, with pinocchio/coal."""

    def __init__(self, kin: Kinematics, urdf: str, obstacles: list[Obstacle], padding: float = 0.005,
                 cloud: np.ndarray | None = None, resolution: float = 0.02, parts: tuple[str, ...] = ()) -> None:
        self.kin = kin
        self.model = kin.model
        self.geom = pin.buildGeomFromUrdf(self.model, str(urdf), pin.GeometryType.COLLISION)
        robot_geoms = list(range(len(self.geom.geometryObjects)))
        gos = self.geom.geometryObjects
        inner = self_pairs([self.model.frames[g.parentFrame].name for g in gos], [g.parentJoint != 0 for g in gos], parts)
        for i, j in inner:
            self.geom.addCollisionPair(pin.CollisionPair(i, j))
        base_inv = inv(kin.base)
        obs_ids = []
        for o in obstacles:
            M = base_inv @ np.asarray(o.pose)
            go = pin.GeometryObject(f"obstacle/{o.name}", 0, 0, pin.SE3(M[:3, :3], M[:3, 3]), _coal_shape(o, padding))
            obs_ids.append(self.geom.addGeometryObject(go))
        cloud = _cloud(cloud, "CoalChecker cloud")
        if len(cloud):
            # a sensed cloud becomes an occupancy octree (cells of ``resolution`` m around each point)
            local = cloud @ base_inv[:3, :3].T + base_inv[:3, 3]
            tree = coal.makeOctree(np.ascontiguousarray(local), float(resolution))
            obs_ids.append(self.geom.addGeometryObject(pin.GeometryObject("obstacle/cloud", 0, 0, pin.SE3.Identity(), tree)))
        for g in robot_geoms:
            for o in obs_ids:
                self.geom.addCollisionPair(pin.CollisionPair(g, o))
        self.data = self.model.createData()
        self.gdata = pin.GeometryData(self.geom)
        # A broad phase tests only the pairs whose boxes overlap: of the ~1,200 pairs of a two-armed
        # robot nearly all are far apart (bench sim: 355 -> 30 us a check). Coal's SSaP (sort and
        # prune on the boxes' widest axis) over its dynamic AABB tree: a check of tombatossals' 64
        # bodies in the bench's table scene 57 -> 39 us, the same verdicts on 4,000 states
        self._manager = pin.BroadPhaseManager_SSaPCollisionManager(self.model, self.geom, self.gdata)
        self.checks = 0

    def valid(self, q: np.ndarray) -> bool:
        """Free of the scene and of the robot's other parts."""
        self.checks += 1
        if not self.geom.collisionPairs:
            return True
        return not pin.computeCollisions(self.model, self.data, self._manager, q, True)


def _cloud(cloud: np.ndarray | None, where: str) -> np.ndarray:
    if cloud is None:
        return np.zeros((0, 3))
    c = np.asarray(cloud, dtype=np.float64)
    if c.ndim != 2 or c.shape[1] != 3:
        raise ValueError(f"{where}: expected an (N, 3) point cloud, got shape {c.shape}")
    if not np.all(np.isfinite(c)):
        raise ValueError(f"{where}: the point cloud has non-finite values")
    return c


def sample_surface(o: Obstacle, spacing: float = 0.01) -> np.ndarray:
    """Points on the surface of an obstacle (world frame), about ``spacing`` apart."""
    if o.kind == "box":
        hx, hy, hz = (s / 2 for s in o.size)
        pts = []
        for axis, h, (a, b) in ((0, hx, (hy, hz)), (1, hy, (hx, hz)), (2, hz, (hx, hy))):
            ua = np.linspace(-a, a, max(2, int(2 * a / spacing) + 1))
            ub = np.linspace(-b, b, max(2, int(2 * b / spacing) + 1))
            A, B = np.meshgrid(ua, ub)
            for sgn in (-1, 1):
                P = np.zeros((A.size, 3))
                others = [i for i in range(3) if i != axis]
                P[:, axis] = sgn * h
                P[:, others[0]], P[:, others[1]] = A.ravel(), B.ravel()
                pts.append(P)
        local = np.vstack(pts)
    elif o.kind == "sphere":
        n = max(20, int(4 * np.pi * o.size[0] ** 2 / spacing**2))
        v = np.random.default_rng(0).normal(size=(n, 3))
        local = o.size[0] * v / np.linalg.norm(v, axis=1, keepdims=True)
    else:
        r, h = o.size[0], o.size[1] / 2
        na = max(8, int(2 * np.pi * r / spacing))
        nz = max(2, int(2 * h / spacing) + 1)
        a, z = np.meshgrid(np.linspace(0, 2 * np.pi, na, endpoint=False), np.linspace(-h, h, nz))
        side = np.stack([r * np.cos(a).ravel(), r * np.sin(a).ravel(), z.ravel()], 1)
        rr, aa = np.meshgrid(np.linspace(0, r, max(2, int(r / spacing) + 1)), np.linspace(0, 2 * np.pi, na, endpoint=False))
        cap = np.stack([(rr * np.cos(aa)).ravel(), (rr * np.sin(aa)).ravel(), np.zeros(rr.size)], 1)
        local = np.vstack([side, cap + [0, 0, -h], cap + [0, 0, h]])
    T = np.asarray(o.pose)
    return local @ T[:3, :3].T + T[:3, 3]


class SphericalChecker:
    """The spherical model (App. B) vs. points sampled on the obstacles (KD-tree pre-selection per s-tope) and,
    across ``parts``, s-tope vs. s-tope (points along one's axis against the other)."""

    AXIS_SAMPLES = 7  # points along an s-tope's axis for the s-tope vs. s-tope distance

    def __init__(self, kin: Kinematics, model, obstacles: list[Obstacle], margin: float = 0.005, spacing: float = 0.015,
                 cloud: np.ndarray | None = None, parts: tuple[str, ...] = ()) -> None:
        from scipy.spatial import cKDTree

        self.kin, self.model, self.margin = kin, model, margin
        self.points = np.vstack([np.zeros((0, 3)), _cloud(cloud, "SphericalChecker cloud")]
                                + [sample_surface(o, spacing) for o in obstacles])
        self.tree = cKDTree(self.points) if len(self.points) else None
        self._reach = np.linalg.norm(model._c2 - model._c1, axis=1) / 2 + np.maximum(model.r1, model.r2) + margin
        pairs = np.array(self_pairs(list(model.links), [int(j) != 0 for j in model._joint], parts), dtype=np.int64)
        self._pairs = pairs.reshape(-1, 2)
        self._lam = np.linspace(0.0, 1.0, self.AXIS_SAMPLES)
        self.checks = 0

    def _self_collides(self) -> bool:
        if not len(self._pairs):
            return False
        m = self.model
        a, b = self._pairs[:, 0], self._pairs[:, 1]
        # points along s-tope a's axis with its radius there, against s-tope b
        P = m.C1[a][:, None] + self._lam[None, :, None] * (m.C2[a] - m.C1[a])[:, None]
        ra = m.r1[a][:, None] + self._lam[None] * (m.r2[a] - m.r1[a])[:, None]
        d, _ = stope_distance(P, m.C1[b][:, None], m.C2[b][:, None], m.r1[b][:, None], m.r2[b][:, None])
        return bool((d - ra <= self.margin).any())

    def valid(self, q: np.ndarray) -> bool:
        """Free of the scene and of the robot's other parts."""
        self.checks += 1
        with_parts = len(self._pairs) > 0
        if self.tree is None and not with_parts:
            return True
        self.kin.update(q)
        self.model.update(self.kin)
        if with_parts and self._self_collides():
            return False
        if self.tree is None:
            return True
        mid = (self.model.C1 + self.model.C2) / 2
        # most s-topes have no obstacle point within reach: one vectorised nearest query skips them
        d_near, _ = self.tree.query(mid, k=1, distance_upper_bound=float(self._reach.max()))
        cand = np.nonzero(d_near <= self._reach)[0]
        if len(cand) == 0:
            return True
        for m, near in zip(cand, self.tree.query_ball_point(mid[cand], self._reach[cand]), strict=True):
            if not near:
                continue
            P = self.points[near]
            D = self.model.C2[m] - self.model.C1[m]
            lam = np.clip(((P - self.model.C1[m]) @ D) / max(D @ D, 1e-12), 0.0, 1.0)
            d = np.linalg.norm(P - (self.model.C1[m] + lam[:, None] * D), axis=1) - (
                self.model.r1[m] + lam * (self.model.r2[m] - self.model.r1[m]))
            if d.min() <= self.margin:
                return False
        return True


@dataclass(frozen=True)
class PlannerParams:
    check_step: float = 0.02  # rad, joint-space distance between the checks of a returned path (its waypoint spacing)
    search_step: float = 0.05  # rad, distance between checks along motions while searching and shortcutting
    simplify: bool = True  # shortcut the found path (OMPL's vertex reduction, then rope shortcutting)
    range_: float = 0.0  # planner range (0 = OMPL default)
    fine_searches: int = 3  # searches at check_step before giving up: a motion checked at points check_step apart
    # can still clip an obstacle's corner between them, which the waypoint check then catches


class ArmPlanner:
    """Plans the joints ``joints`` of ``kin``; the other joints stay at ``q_fixed``.

    ``valid`` is the whole collision check. The search and the shortcutting check motions every
    ``search_step``; the path found is then checked at every ``check_step`` (lazy validation),
    and only a path that fails is searched again at ``check_step``, up to ``fine_searches`` times
    (each search has the whole ``timeout``). Every returned path is free under ``valid`` at ``check_step``.
    """

    def __init__(self, kin: Kinematics, joints: tuple[str, ...], valid: Callable[[np.ndarray], bool], q_fixed: np.ndarray,
                 params: PlannerParams | None = None) -> None:
        self.kin, self.joints, self._valid = kin, tuple(joints), valid
        self.idx = kin.q_index(self.joints)
        self.q_fixed = np.asarray(q_fixed, dtype=np.float64).copy()
        self.params = params or PlannerParams()
        self.lower = np.maximum(kin.lower[self.idx], -np.pi * 2)
        self.upper = np.minimum(kin.upper[self.idx], np.pi * 2)
        self._profile = PlanProfile()  # the plan under way

    def full(self, q_arm: np.ndarray) -> np.ndarray:
        q = self.q_fixed.copy()
        q[self.idx] = q_arm
        return q

    def valid(self, q_arm: np.ndarray) -> bool:
        q = np.asarray(q_arm)
        if (q < self.lower).any() or (q > self.upper).any():  # the methods: np.any's dispatch was a tenth of a check
            return False
        return bool(self._valid(self.full(q)))

    def _path_free(self, waypoints) -> bool:
        self._profile.path_checks += len(waypoints)
        return all(self.valid(w) for w in waypoints)

    def plan(self, start: np.ndarray, goal: np.ndarray, planner: str = "KPIECE1", timeout: float = 2.0,
             seed: int | None = None, checks: int = 0) -> Plan:
        """A path from ``start`` to ``goal``; each search ends at ``timeout`` s, or with ``checks`` > 0 after that
        many state checks whatever the time: the same search, so the same path, on any machine and load."""
        if planner not in PLANNERS:
            raise ValueError(f"planner {planner!r} is not one of {sorted(PLANNERS)}")
        start, goal = np.asarray(start, dtype=np.float64), np.asarray(goal, dtype=np.float64)
        t0 = time.perf_counter()
        prof = self._profile = PlanProfile()
        fail = Plan(self.joints, np.stack([start]), planner, 0.0, False, profile=prof)
        for label, q in (("start", start), ("goal", goal)):
            if not self._path_free([q]):
                limits = np.any(q < self.lower) or np.any(q > self.upper)
                fail.why_not = f"the {label} state is {'outside the joint limits' if limits else 'in collision'}"
                fail.planning_time = prof.ends = time.perf_counter() - t0
                return fail
        prof.ends = time.perf_counter() - t0
        if seed is not None:
            seed_ompl(seed)
        step, fine = self.params.search_step, 0
        while True:
            dense = self._search(start, goal, planner, timeout, step, checks)
            if dense is None:
                fail.why_not = f"{planner} found no path in {f'{checks} state checks' if checks > 0 else f'{timeout} s'}"
                fail.timed_out = True
                break
            t = time.perf_counter()
            free = self._path_free(dense)
            prof.validate += time.perf_counter() - t
            if free:
                return Plan(self.joints, dense, planner, time.perf_counter() - t0, True, profile=prof)
            if step <= self.params.check_step:
                fine += 1
            if fine >= self.params.fine_searches:
                fail.why_not = (f"{planner}'s {prof.searches} paths each failed the check every "
                                f"{self.params.check_step} rad")
                break
            step = self.params.check_step
        fail.planning_time = time.perf_counter() - t0
        return fail

    def _search(self, start: np.ndarray, goal: np.ndarray, planner: str, timeout: float, step: float,
                checks: int = 0) -> np.ndarray | None:
        """OMPL search checking motions every ``step`` rad: the shortcut path, densified to ``check_step``, or None."""
        n = len(self.idx)
        space = ob.RealVectorStateSpace(n)
        bounds = ob.RealVectorBounds(n)
        for i in range(n):
            bounds.setLow(i, float(self.lower[i]))
            bounds.setHigh(i, float(self.upper[i]))
        space.setBounds(bounds)
        ss = og.SimpleSetup(space)
        buf = np.empty(n)
        prof = self._profile

        def state_valid(s) -> bool:
            for i in range(n):
                buf[i] = s[i]
            prof.search_checks += 1
            # OMPL's states keep to the space's bounds, the joint limits: only the collision check is left
            return bool(self._valid(self.full(buf)))

        ss.setStateValidityChecker(state_valid)
        si = ss.getSpaceInformation()
        si.setStateValidityCheckingResolution(min(0.5, step / space.getMaximumExtent()))
        s0, s1 = space.allocState(), space.allocState()
        for i in range(n):
            s0[i], s1[i] = float(start[i]), float(goal[i])
        ss.setStartAndGoalStates(s0, s1)
        p = PLANNERS[planner](si)
        if self.params.range_ > 0:
            p.setRange(self.params.range_)
        ss.setPlanner(p)
        prof.searches += 1
        t = time.perf_counter()
        if checks > 0:
            first = prof.search_checks
            solved = bool(ss.solve(ob.PlannerTerminationCondition(lambda: prof.search_checks - first >= checks)))
        else:
            solved = bool(ss.solve(timeout))
        solved = solved and ss.haveExactSolutionPath()
        prof.search += time.perf_counter() - t
        if not solved:
            return None
        path = ss.getSolutionPath()
        if self.params.simplify:
            # OMPL's full simplification (simplifyMax: several rounds of shortcuts and B-spline
            # smoothing) took 3/4 of a plan; these two passes give paths as short (bench sim)
            t = time.perf_counter()
            shortcut = ss.getPathSimplifier()
            shortcut.reduceVertices(path)
            shortcut.ropeShortcutPath(path)
            prof.simplify += time.perf_counter() - t
        W = np.array([[path.getState(k)[i] for i in range(n)] for k in range(path.getStateCount())])
        # waypoints at most check_step apart in every joint
        dense = [W[0]]
        for a, b in zip(W[:-1], W[1:], strict=True):
            m = max(1, int(np.ceil(np.abs(b - a).max() / self.params.check_step)))
            dense += [a + (b - a) * (j / m) for j in range(1, m + 1)]
        return np.array(dense)


GOAL_RESTARTS = 16
"""Random restarts of the goal IK, for the planner's pose goals and the grasp filters that pass them (detect_objects):
one search from the same joints, so a pose the filter reaches the planner reaches too. With 8 here and the
filter's 16, the planner missed goals the filter had passed: in one empty-box run (vision, seed 105) all 6
approaches to a brick at the box's +x wall ("motion aborted (not reached)" on the Cartesian fallback; the 8
restarts find no posture, 16 do). Only a pose that is never reached pays for all of them (0.1-0.2 s)."""


def solve_ik(kin: Kinematics, joints: tuple[str, ...], frame: str, target: np.ndarray, q_full: np.ndarray,
             valid: Callable[[np.ndarray], bool] | None = None, iters: int = 300, restarts: int = GOAL_RESTARTS,
             seed: int = 0, tol: float = 1e-3) -> np.ndarray | None:
    """Arm joints placing ``frame`` at ``target`` (4x4 world), damped least squares from ``q_full`` with random
    restarts (drawn from ``seed``: the same search gives the same posture)."""
    idx = kin.q_index(joints)
    lo, hi = np.maximum(kin.lower[idx], -2 * np.pi), np.minimum(kin.upper[idx], 2 * np.pi)
    rng = np.random.default_rng(seed)
    q0 = np.asarray(q_full, dtype=np.float64).copy()
    for attempt in range(restarts):
        q = q0.copy()
        if attempt:
            q[idx] = rng.uniform(lo, hi)
        for _ in range(iters):
            kin.update(q)
            T = kin.frame_pose(frame)
            err = np.concatenate([target[:3, 3] - T[:3, 3], rotvec_error(target[:3, :3], T[:3, :3])])
            if np.linalg.norm(err[:3]) < tol and np.linalg.norm(err[3:]) < 10 * tol:
                if valid is None or valid(q):
                    return q[idx].copy()
                break
            J = kin.jacobian(frame)[:, idx]
            dq = J.T @ np.linalg.solve(J @ J.T + 1e-4 * np.eye(6), err)
            q[idx] = np.clip(q[idx] + dq, lo, hi)
    return None


FIXTURE_CATEGORIES = ("table",)
"""Object categories that are part of the cell's known layout (declared, not sensed)."""


def fixtures_from_world(world) -> list[Obstacle]:
    """The cell's fixtures (floor, table) at their declared pose: known layout, not a simulation readout."""
    from contactflow.embodiments.transforms import xyz_rpy_to_matrix

    floor = np.eye(4)
    floor[2, 3] = world.params.floor_z - 0.05
    out = [Obstacle("floor", "box", (10.0, 10.0, 0.1), floor)]
    for name, obj in world.objects.items():
        spec = obj.spec
        if spec.category not in FIXTURE_CATEGORIES or not spec.static:
            continue
        T = xyz_rpy_to_matrix(spec.xyz, spec.rpy)
        for k, s in enumerate(spec.shapes):
            out.append(Obstacle(f"{name}/{k}", s.kind, tuple(s.size), T @ xyz_rpy_to_matrix(s.xyz, s.rpy)))
    return out


def inside_obstacles(points: np.ndarray, obstacles: list[Obstacle], margin: float) -> np.ndarray:
    """Mask of the points within ``margin`` of a box obstacle (other kinds: of its bounding box)."""
    inside = np.zeros(len(points), bool)
    for o in obstacles:
        if o.kind == "box":
            half = np.asarray(o.size) / 2
        elif o.kind == "sphere":
            half = np.full(3, o.size[0])
        else:
            half = np.array([o.size[0], o.size[0], o.size[1] / 2 + (o.size[0] if o.kind == "capsule" else 0.0)])
        T = np.asarray(o.pose)
        local = (points - T[:3, 3]) @ T[:3, :3]
        inside |= np.all(np.abs(local) <= half + margin, axis=1)
    return inside


def sensed_cloud(robot, camera: str = "kinect", self_margin: float = 0.03, fixture_margin: float = 0.015,
                 voxel: float = 0.01) -> np.ndarray:
    """Obstacle points seen by ``camera``: the robot removed by its spherical model (App. B), fixtures removed, voxelised."""
    pts = np.asarray(robot.camera(camera).points, dtype=np.float64)
    if len(pts):
        pts = pts[robot.spherical.clear_of(pts, self_margin)]
    if len(pts):
        pts = pts[~inside_obstacles(pts, robot.fixtures(), fixture_margin)]
    if len(pts) and voxel > 0:
        _, first = np.unique(np.floor(pts / voxel).astype(np.int64), axis=0, return_index=True)
        pts = pts[np.sort(first)]
    return pts


def plan_arm(robot, arm, goal: np.ndarray, planner: str = "KPIECE1", timeout: float = 2.0, checker: str = "coal",
             obstacles: tuple[Obstacle, ...] | list[Obstacle] = (), cloud: np.ndarray | None = None,
             fixtures: bool = True, seed: int | None = None, rest: bool = False, checks: int = 0) -> Plan | None:
    """Plan ``arm`` of a robot (simulated or remote) from its commanded joints to a joint goal or a 4x4 pose
    (``timeout`` and ``checks``: :meth:`ArmPlanner.plan`).

    Collisions are checked against ``obstacles`` and the point ``cloud`` the caller sensed or
    was given, plus the cell's fixtures when ``fixtures``; never against the simulated objects.
    A pose goal's joints are the IK solution found from the current joints, or with ``rest``
    from the arm's home posture: the same pose then gives the same arm posture, however the
    arm got there (a 7-joint arm's elbow otherwise drifts from move to move).
    """
    kin = Kinematics(robot.spec.urdf(), robot.kin.base)
    q_full = robot.kin_q_cmd()
    scene = list(obstacles) + (robot.fixtures() if fixtures else [])
    parts = robot.spec.collision_groups
    if checker == "coal":
        check = CoalChecker(kin, str(robot.spec.urdf()), scene, cloud=cloud, parts=parts)
    elif checker == "spherical":
        check = SphericalChecker(kin, SphericalModel.from_urdf(kin, str(robot.spec.urdf())), scene, cloud=cloud,
                                 parts=parts)
    else:
        raise ValueError(f"checker {checker!r} is not coal|spherical")
    ap = ArmPlanner(kin, arm.joints, check.valid, q_full)
    goal = np.asarray(goal, dtype=np.float64)
    if goal.shape == (4, 4):
        q_seed = q_full
        if rest:
            q_seed = q_full.copy()
            q_seed[kin.q_index(arm.joints)] = arm.spec.home
        q_goal = solve_ik(kin, arm.joints, arm.spec.ee_frame, goal, q_seed, check.valid)
        if q_goal is None:
            return None
    else:
        q_goal = goal
    return ap.plan(q_full[ap.idx], q_goal, planner=planner, timeout=timeout, seed=seed, checks=checks)
