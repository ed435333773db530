"""Vectorised point-cloud geometry: depth back-projection, voxel grid, oriented boxes, planes."""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy.spatial import ConvexHull, QhullError

from contactflow.recognition import kernels

EMPTY = np.zeros((0, 3))


def check_intrinsics(K: np.ndarray, where: str = "intrinsics") -> np.ndarray:
    """Validate a 3x3 pinhole matrix; raise ValueError naming ``where`` otherwise."""
    K = np.asarray(K, dtype=float)
    if K.shape != (3, 3) or not np.all(np.isfinite(K)):
        raise ValueError(f"{where}: expected a finite 3x3 matrix, got shape {K.shape}")
    if K[0, 0] <= 0 or K[1, 1] <= 0:
        raise ValueError(f"{where}: focal lengths must be > 0, got fx={K[0, 0]} fy={K[1, 1]}")
    return K


def check_pose(T: np.ndarray, where: str = "camera pose") -> np.ndarray:
    """Validate a 4x4 rigid transform; raise ValueError naming ``where`` otherwise."""
    T = np.asarray(T, dtype=float)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise ValueError(f"{where}: expected a finite 4x4 matrix, got shape {T.shape}")
    R = T[:3, :3]
    if not np.allclose(R.T @ R, np.eye(3), atol=1e-4):
        raise ValueError(f"{where}: rotation block is not orthonormal")
    return T


def as_points(points: np.ndarray, where: str = "points") -> np.ndarray:
    """An (N, 3) float array with non-finite rows dropped; any other shape is an error."""
    p = np.asarray(points, dtype=float)
    if p.size == 0:
        return EMPTY.copy()
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"{where}: expected an (N, 3) array, got shape {p.shape}")
    return p[np.isfinite(p).all(axis=1)]


@lru_cache(maxsize=8)
def _pixel_grid(h: int, w: int, stride: int, fx: float, fy: float, cx: float, cy: float):
    v, u = np.mgrid[0:h:stride, 0:w:stride]
    return ((u - cx) / fx).astype(np.float32), ((v - cy) / fy).astype(np.float32)


def depth_to_points(depth: np.ndarray, K: np.ndarray, world_T_cam: np.ndarray, stride: int = 1,
                    min_range: float = 0.1, max_range: float = 4.0) -> np.ndarray:
    """Back-project a depth image (metres along the optical axis) to world points.

    ``stride`` decimates the image before back-projection (the cheapest downsampling there
    is); pixels that are NaN, infinite or outside [min_range, max_range] are dropped.
    """
    d = np.asarray(depth)
    if d.ndim != 2:
        raise ValueError(f"depth: expected an (H, W) image, got shape {d.shape}")
    if d.size == 0:
        return EMPTY.copy()
    K = check_intrinsics(K)
    T = check_pose(world_T_cam)
    gx, gy = _pixel_grid(d.shape[0], d.shape[1], int(stride), K[0, 0], K[1, 1], K[0, 2], K[1, 2])
    z = d[::stride, ::stride].astype(np.float32, copy=False)
    with np.errstate(invalid="ignore"):
        ok = np.isfinite(z) & (z >= min_range) & (z <= max_range)
    z, rx, ry = z[ok], gx[ok], gy[ok]
    R = T[:3, :3].astype(np.float32)
    out = np.empty((len(z), 3))
    # p = z * R [x/z, y/z, 1] + t, one row of R at a time to stay in float32 temporaries
    for k in range(3):
        out[:, k] = z * (R[k, 0] * rx + R[k, 1] * ry + R[k, 2])
        out[:, k] += T[k, 3]
    return out


def voxel_downsample(points: np.ndarray, voxel: float) -> np.ndarray:
    """Centroid of the points in each occupied voxel of edge ``voxel`` (metres), in the order of the voxels (x, then
    y, then z); each voxel's points summed in cloud order (compiled: :mod:`~contactflow.recognition.kernels`)."""
    if len(points) == 0 or voxel <= 0:
        return points
    pts = np.ascontiguousarray(points, dtype=np.float64)
    n = len(pts)
    key = np.empty(n, dtype=np.int64)
    kernels.voxel_numbers(pts, float(voxel), key)
    if int(key.max()) < np.iinfo(np.int64).max // n:
        # one sort of (voxel, point) numbers: the points by voxel, in cloud order within one (a stable argsort of the
        # voxels, at less than half its cost)
        order = np.sort(key * n + np.arange(n)) % n
    else:
        order = np.argsort(key, kind="stable")
    return kernels.run_means(pts, key, order)


def orthonormal_frame(z: np.ndarray, hint: np.ndarray | None = None) -> np.ndarray:
    """A rotation whose third column is ``z`` (normalised); the first follows ``hint``."""
    z = z / np.linalg.norm(z)
    if hint is None or abs(np.dot(hint, z)) > 0.99 * np.linalg.norm(hint):
        hint = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = hint - np.dot(hint, z) * z
    x /= np.linalg.norm(x)
    return np.column_stack((x, np.cross(z, x), z))


@dataclass(frozen=True, eq=False)
class Box:
    """An oriented box: centre, rotation (columns are the box axes) and full extents (m)."""

    center: np.ndarray
    rotation: np.ndarray
    extent: np.ndarray

    def vertices(self) -> np.ndarray:
        """The 8 corners, (8, 3)."""
        signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float)
        return self.center + (signs * self.extent / 2) @ self.rotation.T

    def local(self, points: np.ndarray) -> np.ndarray:
        return (points - self.center) @ self.rotation

    def contains(self, points: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """Boolean mask of the points inside the box grown by ``margin`` on every side."""
        if len(points) == 0:
            return np.zeros(0, bool)
        return np.all(np.abs(self.local(points)) <= self.extent / 2 + margin, axis=1)

    def sorted_dims(self) -> np.ndarray:
        """Extents ordered from larger to smaller (D1 >= D2 >= D3)."""
        return np.sort(self.extent)[::-1]


def min_area_rectangle(xy: np.ndarray) -> tuple[np.ndarray, float, np.ndarray]:
    """Minimum-area enclosing rectangle of 2-D points: (centre, angle of first side, sizes)."""
    if len(xy) < 3:
        lo, hi = xy.min(axis=0), xy.max(axis=0)
        return (lo + hi) / 2, 0.0, hi - lo
    if len(xy) > 2000:
        # the extreme points along 64 directions span the hull to within 0.12 %
        a = np.linspace(0.0, 2 * np.pi, 64, endpoint=False)
        xy = xy[np.unique(np.argmax(np.stack((np.cos(a), np.sin(a)), axis=1) @ xy.T, axis=1))]
    try:
        hull = xy[ConvexHull(xy).vertices]
    except QhullError:
        hull = xy
    edges = np.diff(np.vstack((hull, hull[:1])), axis=0)
    angles = np.unique(np.mod(np.arctan2(edges[:, 1], edges[:, 0]), np.pi / 2))
    c, s = np.cos(angles), np.sin(angles)
    # rotate the hull by -angle for every candidate at once: (A, H)
    u = hull[:, 0][None] * c[:, None] + hull[:, 1][None] * s[:, None]
    v = -hull[:, 0][None] * s[:, None] + hull[:, 1][None] * c[:, None]
    areas = (u.max(1) - u.min(1)) * (v.max(1) - v.min(1))
    k = int(np.argmin(areas))
    a = angles[k]
    umid, vmid = (u[k].max() + u[k].min()) / 2, (v[k].max() + v[k].min()) / 2
    centre = np.array([umid * np.cos(a) - vmid * np.sin(a), umid * np.sin(a) + vmid * np.cos(a)])
    return centre, float(a), np.array([u[k].max() - u[k].min(), v[k].max() - v[k].min()])


def upright_box(points: np.ndarray, frame: np.ndarray, origin: np.ndarray, to_plane: bool = True) -> Box:
    """Box with one axis along ``frame[:, 2]`` (the plane normal) and minimal footprint.

    With ``to_plane`` the box reaches down to the plane, since objects rest on it and the
    camera only sees their upper faces.
    """
    loc = (points - origin) @ frame
    centre2, ang, size2 = min_area_rectangle(loc[:, :2])
    zlo = 0.0 if to_plane else loc[:, 2].min()
    zhi = loc[:, 2].max()
    c, s = np.cos(ang), np.sin(ang)
    rot_local = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
    rotation = frame @ rot_local
    centre = origin + frame @ np.array([centre2[0], centre2[1], (zlo + zhi) / 2])
    return Box(centre, rotation, np.array([size2[0], size2[1], max(zhi - zlo, 0.0)]))


def pca_box(points: np.ndarray) -> Box:
    """Box along the principal axes of the points (axes sorted by decreasing variance)."""
    c = points.mean(axis=0)
    if len(points) < 3:
        return Box(c, np.eye(3), np.ptp(points, axis=0) if len(points) else np.zeros(3))
    _, vecs = np.linalg.eigh(np.cov((points - c).T))
    R = vecs[:, ::-1].copy()
    if np.linalg.det(R) < 0:
        R[:, 2] *= -1
    loc = (points - c) @ R
    lo, hi = loc.min(axis=0), loc.max(axis=0)
    return Box(c + R @ ((lo + hi) / 2), R, hi - lo)


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray = np.array([0.0, 0.0, 1.0])) -> np.ndarray:
    """World-from-camera pose of an optical frame (x right, y down, z forward) at ``eye``."""
    f = np.asarray(target, float) - np.asarray(eye, float)
    f /= np.linalg.norm(f)
    r = np.cross(f, up)
    if np.linalg.norm(r) < 1e-9:
        r = np.cross(f, np.array([0.0, 1.0, 0.0]))
    r /= np.linalg.norm(r)
    T = np.eye(4)
    T[:3, :3] = np.column_stack((r, np.cross(f, r), f))
    T[:3, 3] = eye
    return T


def intrinsics(width: int = 640, height: int = 480, fov_x_deg: float = 62.0) -> np.ndarray:
    """Pinhole matrix with the principal point at the image centre (Kinect-like defaults)."""
    f = width / 2 / np.tan(np.radians(fov_x_deg) / 2)
    return np.array([[f, 0, (width - 1) / 2], [0, f, (height - 1) / 2], [0, 0, 1.0]])
