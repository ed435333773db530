"""Spherical robot model (thesis App. B): one bi-sphere (or sphere) per link, fitted to its collision geometry.

A bi-sphere is the convex hull of two spheres ``(c1, r1)``, ``(c2, r2)``; a single sphere has
``c1 == c2``. Each s-tope is attached to the joint frame of its link and posed from the
joint state through pinocchio. The distance of a point to the robot is the minimum over
the s-topes of eq. B.3 (closest sphere on the segment) followed by eq. B.2 (distance to a
sphere), computed for N points at once.
"""

from __future__ import annotations

from dataclasses import dataclass

import coal
import numpy as np
import pinocchio as pin

from contactflow.embodiments.control.kinematics import Kinematics


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
        """Fit one bi-sphere per link to the collision geometry of ``urdf`` (same model as ``kin``)."""
        geom = pin.buildGeomFromUrdf(kin.model, str(urdf), pin.GeometryType.COLLISION)
        by_link: dict[str, tuple[int, list[np.ndarray]]] = {}
        for go in geom.geometryObjects:
            link = kin.model.frames[go.parentFrame].name
            if link in skip_links:
                continue
            pts = geometry_points(go.geometry)
            if pts is None:
                continue
            M = go.placement.homogeneous
            by_link.setdefault(link, (go.parentJoint, []))[1].append(pts @ M[:3, :3].T + M[:3, 3])
        stopes = []
        for link, (joint, parts) in by_link.items():
            c1, c2, r1, r2 = fit_bisphere(np.vstack(parts))
            stopes.append(Stope(link, int(joint), c1, c2, r1, r2))
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

    def inside(self, points: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """Mask of points within ``margin`` of the robot (self-filtering of point clouds)."""
        return self.distance(points) <= margin
