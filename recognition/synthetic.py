"""Depth rendering of open3d meshes by ray casting: the physics-free camera model of the simulator."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import open3d as o3d

from contactflow.recognition.geometry import check_intrinsics, check_pose, look_at


def box_mesh(size: tuple[float, float, float], center=(0.0, 0.0, 0.0), yaw: float = 0.0) -> o3d.geometry.TriangleMesh:
    """A box of full ``size`` (m) centred at ``center``, rotated by ``yaw`` about z."""
    m = o3d.geometry.TriangleMesh.create_box(*size)
    m.translate(-np.asarray(size) / 2)
    m.rotate(_rz(yaw), center=(0, 0, 0))
    m.translate(center)
    return m


def cylinder_mesh(radius: float, height: float, center=(0.0, 0.0, 0.0), axis=(0.0, 0.0, 1.0),
                  resolution: int = 64) -> o3d.geometry.TriangleMesh:
    """A closed cylinder whose axis is ``axis`` through ``center``."""
    m = o3d.geometry.TriangleMesh.create_cylinder(radius, height, resolution=resolution, split=1)
    m.rotate(_align_z(np.asarray(axis, float)), center=(0, 0, 0))
    m.translate(center)
    return m


def sphere_mesh(radius: float, center=(0.0, 0.0, 0.0), scale=(1.0, 1.0, 1.0)) -> o3d.geometry.TriangleMesh:
    """A sphere, or an ellipsoid when ``scale`` is not uniform."""
    m = o3d.geometry.TriangleMesh.create_sphere(radius, resolution=40)
    v = np.asarray(m.vertices) * np.asarray(scale)
    m.vertices = o3d.utility.Vector3dVector(v)
    m.translate(center)
    return m


def cone_mesh(radius: float, height: float, center=(0.0, 0.0, 0.0)) -> o3d.geometry.TriangleMesh:
    m = o3d.geometry.TriangleMesh.create_cone(radius, height, resolution=64, split=1)
    m.translate(center)
    return m


def _rz(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def _align_z(axis: np.ndarray) -> np.ndarray:
    z = axis / np.linalg.norm(axis)
    v = np.cross([0.0, 0.0, 1.0], z)
    c = float(np.dot([0.0, 0.0, 1.0], z))
    if np.linalg.norm(v) < 1e-9:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + vx + vx @ vx / (1 + c)


@dataclass
class Scene:
    """A set of meshes rendered by an ideal pinhole depth camera, with optional noise.

    ``noise`` is the axial standard deviation at 1 m (it grows with z², as for structured
    light sensors); ``labels`` renders which mesh each pixel sees (-1 for nothing).
    """

    meshes: list[o3d.geometry.TriangleMesh] = field(default_factory=list)

    def __post_init__(self) -> None:
        self._scene: o3d.t.geometry.RaycastingScene | None = None
        self._ids: list[int] = []

    def add(self, mesh: o3d.geometry.TriangleMesh) -> int:
        self.meshes.append(mesh)
        self._scene = None
        return len(self.meshes) - 1

    def _build(self) -> o3d.t.geometry.RaycastingScene:
        if self._scene is None:
            self._scene = o3d.t.geometry.RaycastingScene()
            self._ids = [self._scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(m)) for m in self.meshes]
        return self._scene

    def render(self, K: np.ndarray, world_T_cam: np.ndarray, width: int, height: int, noise: float = 0.0,
               rng: np.random.Generator | None = None, labels: bool = False):
        """Depth image (float32, m, inf where nothing is hit); with ``labels`` also the mesh ids."""
        K = check_intrinsics(K)
        T = check_pose(world_T_cam)
        scene = self._build()
        rays = o3d.t.geometry.RaycastingScene.create_rays_pinhole(
            o3d.core.Tensor(K), o3d.core.Tensor(np.linalg.inv(T)), int(width), int(height))
        ans = scene.cast_rays(rays)
        # rays from create_rays_pinhole have unit z in the camera frame: t_hit is the depth
        depth = ans["t_hit"].numpy().astype(np.float32)
        if noise > 0:
            rng = rng if rng is not None else np.random.default_rng()
            finite = np.isfinite(depth)
            depth[finite] += (noise * depth[finite] ** 2 * rng.standard_normal(int(finite.sum()))).astype(np.float32)
        if not labels:
            return depth
        gid = ans["geometry_ids"].numpy().astype(np.int64)
        lut = {g: i for i, g in enumerate(self._ids)}
        out = np.full(gid.shape, -1, np.int64)
        for g, i in lut.items():
            out[gid == g] = i
        return depth, out


def orbit_pose(target: np.ndarray, distance: float, elevation_deg: float, azimuth_deg: float) -> np.ndarray:
    """World-from-camera pose on a sphere around ``target``, looking at it (z is up)."""
    el, az = np.radians(elevation_deg), np.radians(azimuth_deg)
    eye = np.asarray(target, float) + distance * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    up = np.array([0.0, 0.0, 1.0]) if elevation_deg < 89.0 else np.array([-np.cos(az), -np.sin(az), 0.0])
    return look_at(eye, np.asarray(target, float), up)
