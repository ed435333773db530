"""Spherical robot model (thesis App. B): bi-spheres (or spheres) per link, fitted to its collision geometry.

A bi-sphere is the convex hull of two spheres ``(c1, r1)``, ``(c2, r2)``; a single sphere has
``c1 == c2``. Each s-tope is attached to the joint frame of its link and posed from the
joint state through pinocchio. The distance of a point to the robot is the minimum over
the s-topes of eq. B.3 (closest sphere on the segment) followed by eq. B.2 (distance to a
sphere), computed for N points at once. A link is one bi-sphere, or a few side by side where its
boxes are flat (the robot is "a combination of s-topes"; one around the allegro palm was a 7 cm
ball about a 4 cm thick plate).
"""

from __future__ import annotations

from dataclasses import dataclass

import coal
import numpy as np
import pinocchio as pin

from contactflow.embodiments.control.kinematics import Kinematics

MAX_EXCESS = 0.015  # m, a box link whose one bi-sphere stands further off its thinnest side is cut in slabs
MAX_SLABS = 3  # bi-spheres per such link at most


@dataclass(frozen=True)
class Stope:
    """One bi-sphere in the frame of pinocchio joint ``joint``."""

    link: str
    joint: int
    c1: np.ndarray
    c2: np.ndarray
    r1: float
    r2: float


def geometry_points(geo) -> np.ndarray | None:
    """Points of a coal collision geometry in its own frame (surface samples or vertices)."""
    if isinstance(geo, coal.Box):
        h = np.asarray(geo.halfSide)
        return np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * h
    if isinstance(geo, coal.Sphere):
        r = geo.radius
        return np.vstack([np.eye(3) * r, -np.eye(3) * r])
    if isinstance(geo, (coal.Cylinder, coal.Capsule)):
        r, h = geo.radius, geo.halfLength
        a = np.linspace(0, 2 * np.pi, 12, endpoint=False)
        ring = np.stack([r * np.cos(a), r * np.sin(a), np.zeros_like(a)], 1)
        pts = np.vstack([ring + [0, 0, -h], ring + [0, 0, h]])
        if isinstance(geo, coal.Capsule):
            pts = np.vstack([pts, [[0, 0, -h - r], [0, 0, h + r]]])
        return pts
    if hasattr(geo, "vertices"):
        v = np.asarray(geo.vertices(), dtype=np.float64)
        return v if v.size else None
    if hasattr(geo, "points"):
        return np.asarray(geo.points(), dtype=np.float64)
    return None


def fit_bisphere(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, float]:
    """A bi-sphere containing ``points`` (K, 3): principal axis, end radii from each half."""
    mean = points.mean(0)
    X = points - mean
    if len(points) < 3 or np.allclose(X, 0):
        r = float(np.linalg.norm(X, axis=1).max(initial=0.0))
        return mean, mean.copy(), r, r
    axis = np.linalg.svd(X, full_matrices=False)[2][0]
    a = X @ axis
    perp = np.linalg.norm(X - a[:, None] * axis, axis=1)
    lo, hi = a.min(), a.max()
    half = a < (lo + hi) / 2
    r1 = float(perp[half].max(initial=0.0))
    r2 = float(perp[~half].max(initial=0.0))
    s1 = min(r1, (hi - lo) / 2)
    s2 = min(r2, (hi - lo) / 2)
    c1, c2 = mean + (lo + s1) * axis, mean + (hi - s2) * axis
    # grow both radii until every point is inside (eq. B.3 applied to the points themselves)
    d, rr = _segment_distance(points, c1[None], c2[None], np.array([r1]), np.array([r2]))
    excess = float((d[:, 0]).max())
    if excess > 0:
        r1, r2 = r1 + excess, r2 + excess
    return c1, c2, r1, r2


def slab_bispheres(points: np.ndarray, max_slabs: int = MAX_SLABS) -> list[tuple[np.ndarray, np.ndarray, float, float]]:
    """Bi-spheres containing the oriented box of ``points`` (K, 3; their principal axes): the box cut
    across its middle side into slabs about as thick as its thinnest side, one bi-sphere along each
    slab's length (end centres on its end faces, radius its cross-section's half diagonal).

    A flat box (a palm, a gripper finger) in one bi-sphere is a ball or a fat capsule around it
    whose surface stands several cm off its broad faces; the slabs' stand off at most 0.41 of the
    thinnest half side (at most ``max_slabs`` of them).
    """
    mean = points.mean(0)
    axes = np.linalg.svd(points - mean, full_matrices=False)[2]
    local = (points - mean) @ axes.T
    lo, hi = local.min(0), local.max(0)
    centre, half = (lo + hi) / 2, (hi - lo) / 2
    thin, middle, long = np.argsort(half)
    n = int(min(max_slabs, max(1, np.ceil(half[middle] / max(half[thin], 1e-9) - 1e-9))))
    r = float(np.hypot(half[thin], half[middle] / n))
    out = []
    for k in range(n):
        c = centre.copy()
        c[middle] = lo[middle] + (2 * k + 1) * half[middle] / n
        c1, c2 = c.copy(), c.copy()
        c1[long], c2[long] = lo[long], hi[long]
        out.append((mean + c1 @ axes, mean + c2 @ axes, r, r))
    return out


def stope_distance(P: np.ndarray, C1: np.ndarray, C2: np.ndarray, R1: np.ndarray, R2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eq. B.2-B.3, broadcast: signed distance of points ``P (..., 3)`` to s-topes ``C1, C2 (..., 3)``, ``R1, R2 (...)``,
    and the s-tope's radius at the closest axis point."""
    D = C2 - C1
    L2 = np.maximum((D * D).sum(-1), 1e-12)
    lam = np.clip(((P - C1) * D).sum(-1) / L2, 0.0, 1.0)
    cmin = C1 + lam[..., None] * D
    rmin = R1 + lam * (R2 - R1)
    return np.linalg.norm(P - cmin, axis=-1) - rmin, rmin


def _segment_distance(P: np.ndarray, C1: np.ndarray, C2: np.ndarray, R1: np.ndarray, R2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eq. B.2-B.3 for every point/s-tope pair: (N, M) signed distances and radii."""
    return stope_distance(P[:, None, :], C1[None], C2[None], R1[None], R2[None])


class SphericalModel:
    """All s-topes of a robot, posed by :meth:`update`; :meth:`distance` for N points."""

    def __init__(self, stopes: list[Stope], base: np.ndarray) -> None:
        if not stopes:
            raise ValueError("spherical model needs at least one s-tope")
        self.stopes = stopes
        self.base = base
        self.links = [s.link for s in stopes]
        self._joint = np.array([s.joint for s in stopes])
        self._c1 = np.stack([s.c1 for s in stopes])
        self._c2 = np.stack([s.c2 for s in stopes])
        self.r1 = np.array([s.r1 for s in stopes])
        self.r2 = np.array([s.r2 for s in stopes])
        self.C1 = self._c1.copy()
        self.C2 = self._c2.copy()

    @classmethod
    def from_urdf(cls, kin: Kinematics, urdf: str, skip_links: tuple[str, ...] = ()) -> SphericalModel:
        """Fit a bi-sphere per link (slabs of them for a flat box link) to the collision geometry of ``urdf``."""
        geom = pin.buildGeomFromUrdf(kin.model, str(urdf), pin.GeometryType.COLLISION)
        by_link: dict[str, tuple[int, list[np.ndarray], list[float]]] = {}
        for go in geom.geometryObjects:
            link = kin.model.frames[go.parentFrame].name
            if link in skip_links:
                continue
            pts = geometry_points(go.geometry)
            if pts is None:
                continue
            M = go.placement.homogeneous
            entry = by_link.setdefault(link, (go.parentJoint, [], []))
            entry[1].append(pts @ M[:3, :3].T + M[:3, 3])
            # only boxes are known flat; a mesh or a cylinder keeps its one bi-sphere
            entry[2].append(float(np.min(go.geometry.halfSide)) if isinstance(go.geometry, coal.Box) else np.inf)
        stopes = []
        for link, (joint, parts, thin) in by_link.items():
            pts = np.vstack(parts)
            fits = [fit_bisphere(pts)]
            if max(fits[0][2:]) - max(thin) > MAX_EXCESS:
                fits = slab_bispheres(pts)
            stopes += [Stope(link, int(joint), c1, c2, r1, r2) for c1, c2, r1, r2 in fits]
        model = cls(stopes, kin.base)
        model.update(kin)
        return model

    @classmethod
    def from_robot(cls, kin: Kinematics, art) -> SphericalModel:
        return cls.from_urdf(kin, str(art.spec.urdf()))

    def update(self, kin: Kinematics) -> None:
        """Pose the s-topes from the joint placements of ``kin`` (call ``kin.update`` first)."""
        T = np.stack([self.base @ kin.data.oMi[int(j)].homogeneous for j in self._joint])
        R, t = T[:, :3, :3], T[:, :3, 3]
        self.C1 = np.einsum("mij,mj->mi", R, self._c1) + t
        self.C2 = np.einsum("mij,mj->mi", R, self._c2) + t

    def distance(self, points: np.ndarray, return_link: bool = False, chunk: int = 8192):
        """Signed distance of each point (N, 3) to the robot (negative inside); optionally the closest link index."""
        P = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        out = np.empty(len(P))
        arg = np.empty(len(P), dtype=np.int64)
        for s in range(0, len(P), chunk):
            d, _ = _segment_distance(P[s:s + chunk], self.C1, self.C2, self.r1, self.r2)
            arg[s:s + chunk] = d.argmin(1)
            out[s:s + chunk] = d[np.arange(len(d)), arg[s:s + chunk]]
        return (out, arg) if return_link else out

    def clear_of(self, points: np.ndarray, margin: float) -> np.ndarray:
        """Mask of the points (N, 3) farther than ``margin`` from the robot (self-filtering of point clouds):
        ``distance(points) > margin``, each point evaluated only on the s-topes whose box grown by ``margin`` holds
        it (a camera frame's points are mostly far from every link: the full distance of each to every s-tope
        was most of a tracked frame's cost)."""
        from contactflow.recognition.pipeline import culled_distance

        return culled_distance(self.C1, self.C2, self.r1, self.r2, margin)(points) > margin
