"""RGBD camera: depth image and world point cloud, rendered by SAPIEN or ray cast on the collision geometry.

:class:`DepthCamera` renders with SAPIEN (``render_camera.RenderDepth``) when the world has a
render system (a Vulkan device exists) and ray casts otherwise, with the same intrinsics and
mounting. The ray-casting backend (:class:`Raycaster`): the scene's collision shapes
(objects, table, floor, robot links, at their current poses) are meshed once per shape and
moved per frame into an open3d ``RaycastingScene``; rays follow the pinhole model of the
camera's intrinsics, so the image has the same geometry a rendered one would (robot pixels
differ where link collision meshes are convex hulls). Depth is the optical-axis distance; 0 means no return.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import sapien

from contactflow.embodiments.registry import CameraSpec
from contactflow.embodiments.sensors import unit_meshes
from contactflow.embodiments.sensors.render_camera import RenderDepth
from contactflow.embodiments.transforms import pose_to_matrix
from contactflow.recognition import open3d_backend


@dataclass(frozen=True)
class DepthFrame:
    """One camera frame. ``labels``/``label_names`` say which body each pixel hit (evaluation only)."""

    t: float
    depth: np.ndarray  # (H, W) float32, m along the optical axis, 0 = no return
    points: np.ndarray  # (N, 3) float64, world frame, valid pixels only
    pixels: np.ndarray  # (N, 2) int32, (row, col) of each point
    K: np.ndarray  # 3x3 intrinsics
    T_world_cam: np.ndarray  # 4x4 optical frame (x right, y down, z forward)
    labels: np.ndarray  # (H, W) int32, index into label_names, -1 = none
    label_names: tuple[str, ...]


def intrinsics(spec: CameraSpec) -> np.ndarray:
    return np.array([[spec.fx, 0.0, spec.cx], [0.0, spec.fy, spec.cy], [0.0, 0.0, 1.0]])


def _box(half: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    v, t = unit_meshes.box(2 * half)
    return v - half, t


def _along_x(mesh: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    v, t = mesh
    return v[:, [2, 1, 0]] * np.array([1.0, 1.0, -1.0]), t[:, [0, 2, 1]]


def shape_mesh(shape) -> tuple[np.ndarray, np.ndarray] | None:
    """Vertices and triangles of one PhysX collision shape in its own local frame."""
    P = sapien.physx
    if isinstance(shape, P.PhysxCollisionShapeBox):
        return _box(np.asarray(shape.get_half_size(), dtype=np.float64))
    if isinstance(shape, P.PhysxCollisionShapeSphere):
        return unit_meshes.sphere(shape.get_radius(), 12)
    if isinstance(shape, P.PhysxCollisionShapeCylinder):
        return _along_x(unit_meshes.cylinder(shape.get_radius(), 2 * shape.get_half_length(), 24))
    if isinstance(shape, P.PhysxCollisionShapeCapsule):
        r, h = shape.get_radius(), shape.get_half_length()
        ends = []
        for z in (-h, h):
            v, t = unit_meshes.sphere(r, 8)
            ends.append((v + (0.0, 0.0, z), t))
        return _along_x(unit_meshes.merged(unit_meshes.cylinder(r, 2 * h, 16), *ends))
    if isinstance(shape, (P.PhysxCollisionShapeConvexMesh, P.PhysxCollisionShapeTriangleMesh)):
        v = np.asarray(shape.get_vertices(), dtype=np.float64) * np.asarray(shape.get_scale(), dtype=np.float64)
        return v, np.asarray(shape.get_triangles(), dtype=np.int64)
    if isinstance(shape, P.PhysxCollisionShapePlane):
        # PhysX planes face +x in their local frame
        s = 20.0
        v = np.array([[0.0, -s, -s], [0.0, s, -s], [0.0, s, s], [0.0, -s, s]])
        return v, np.array([[0, 1, 2], [0, 2, 3]])
    return None


class Raycaster:
    """Depth and hit-body labels by ray casting on the collision shapes of ``world``."""

    def __init__(self, world, spec: CameraSpec) -> None:
        self.world, self.spec = world, spec
        self.K = intrinsics(spec)
        self._cache: dict[int, tuple] = {}

    def _bodies(self) -> list:
        system = self.world.scene.get_physx_system()
        return (list(system.get_rigid_static_components()) + list(system.get_rigid_dynamic_components())
                + list(system.get_articulation_link_components()))

    def _geometry(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[str]]:
        verts, tris, tri_label, names = [], [], [], []
        n = 0
        for body in self._bodies():
            key = id(body)
            if key not in self._cache:
                local = []
                for shape in body.get_collision_shapes():
                    mesh = shape_mesh(shape)
                    if mesh is not None:
                        local.append((pose_to_matrix(shape.get_local_pose()), mesh[0], mesh[1]))
                self._cache[key] = (body, local, body.get_name() or body.entity.get_name())
            _, local, name = self._cache[key]
            if not local:
                continue
            T = pose_to_matrix(body.get_entity_pose())
            label = len(names)
            names.append(name)
            for L, v, t in local:
                M = T @ L
                verts.append(v @ M[:3, :3].T + M[:3, 3])
                tris.append(t + n)
                tri_label.append(np.full(len(t), label, dtype=np.int32))
                n += len(v)
        return (np.concatenate(verts).astype(np.float32), np.concatenate(tris).astype(np.uint32),
                np.concatenate(tri_label), names)

    def shoot(self, T_world_cam: np.ndarray, labels: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[str]]:
        """Depth (H, W) along the optical axis (0 = none), world points of the depth > 0 pixels in
        row-major order (N, 3), labels (H, W) and label names (ray casting finds the labels on the way,
        asked for or not)."""
        o3d = open3d_backend.load()
        s = self.spec
        V, F, tri_label, names = self._geometry()
        scene = o3d.t.geometry.RaycastingScene()
        scene.add_triangles(o3d.core.Tensor(V), o3d.core.Tensor(F))
        extrinsic = np.linalg.inv(T_world_cam)
        # open3d shoots through pixel corners + 0.5; our K uses pixel centres (cx = 319.5)
        K = self.K.copy()
        K[0, 2] += 0.5
        K[1, 2] += 0.5
        rays = o3d.t.geometry.RaycastingScene.create_rays_pinhole(
            o3d.core.Tensor(K), o3d.core.Tensor(extrinsic), s.width, s.height)
        ans = scene.cast_rays(rays)
        r = rays.numpy().reshape(s.height, s.width, 6)
        th = ans["t_hit"].numpy().reshape(s.height, s.width)
        prim = ans["primitive_ids"].numpy().reshape(s.height, s.width)
        pts = r[..., :3] + th[..., None] * r[..., 3:]
        z = (pts - T_world_cam[:3, 3]) @ T_world_cam[:3, 2]
        valid = np.isfinite(th) & (z >= s.near) & (z <= s.far)
        depth = np.where(valid, z, 0.0).astype(np.float32)
        labels = np.full((s.height, s.width), -1, dtype=np.int32)
        labels[valid] = tri_label[prim[valid].astype(np.int64)]
        return depth, pts[valid].astype(np.float64), labels, names

    def depth(self, T_world_cam: np.ndarray) -> np.ndarray:
        """Depth (H, W) only (ray casting finds the points and labels on the way: no cheaper)."""
        return self.shoot(T_world_cam)[0]


class DepthCamera:
    """A camera attached to a link (or fixed in the world when ``link`` is None).

    ``backend`` is ``"render"`` (SAPIEN, needs a world built with a render system) or
    ``"raycast"``; None takes rendering whenever the world has a render system.
    """

    def __init__(self, world, spec: CameraSpec, link=None, T_world_cam: np.ndarray | None = None,
                 backend: str | None = None) -> None:
        self.world, self.spec, self.link = world, spec, link
        self.K = intrinsics(spec)
        self.offset = spec.optical_in_link()
        self.fixed_pose = T_world_cam
        if link is None and T_world_cam is None:
            raise ValueError(f"camera {spec.name}: give a link or a fixed T_world_cam")
        rendering = world.rendering
        self.backend = backend or ("render" if rendering else "raycast")
        if self.backend == "render":
            if not rendering:
                raise ValueError(f"camera {spec.name}: backend 'render' needs a world with WorldParams.camera_backend "
                                 "'render' or 'auto' on a machine with a Vulkan device")
            self._shooter = RenderDepth(world.scene, spec)
        elif self.backend == "raycast":
            self._shooter = Raycaster(world, spec)
        else:
            raise ValueError(f"camera {spec.name}: backend {self.backend!r} is not render|raycast")
        self._last: DepthFrame | None = None
        self._labelled = False  # whether the last frame carries its labels
        self._depth_t = -np.inf  # time of the latest depth-only read
        self.lost = False

    def pose(self) -> np.ndarray:
        if self.link is None:
            return np.asarray(self.fixed_pose, dtype=np.float64)
        return pose_to_matrix(self.link.get_entity_pose()) @ self.offset

    def capture(self, t: float, labels: bool = True) -> DepthFrame:
        """A new frame of the current scene (ray casting 20-40 ms, rendering ~40 ms at 640x480, one core);
        without ``labels`` (evaluation only) a rendered frame skips the segmentation picture, ~15 ms."""
        s = self.spec
        Twc = self.pose()
        depth, points, hit, names = self._shooter.shoot(Twc, labels)
        rows, cols = np.nonzero(depth > 0)
        frame = DepthFrame(t, depth, points, np.stack([rows, cols], 1).astype(np.int32),
                           self.K, Twc, hit.reshape(s.height, s.width), tuple(names))
        self._last, self._labelled = frame, labels or bool(names)  # a cast frame has its labels, asked for or not
        return frame

    @property
    def stamp(self) -> float:
        """Time of the latest frame or depth read (-inf before the first): what a stream watchdog checks."""
        return max(self._last.t if self._last is not None else -np.inf, self._depth_t)

    def read_depth(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """(depth (H, W), camera pose) valid at ``t``, without a full frame's points and labels (what
        a depth stream publishes; rendering skips the segmentation picture). A lost stream repeats
        its last frame's."""
        last = self._last
        if self.lost:
            return (last.depth, last.T_world_cam) if last is not None else (self.empty_frame().depth, self.pose())
        if last is not None and t - last.t < 1.0 / self.spec.rate_hz - 1e-9:
            return last.depth, last.T_world_cam
        Twc = self.pose()
        depth = self._shooter.depth(Twc)
        self._depth_t = t
        return depth, Twc

    def empty_frame(self) -> DepthFrame:
        """A frame with no returns, stamped -inf (what a camera that never delivered gives)."""
        s = self.spec
        return DepthFrame(-np.inf, np.zeros((s.height, s.width), np.float32), np.zeros((0, 3)), np.zeros((0, 2), np.int32),
                          self.K, self.pose(), np.full((s.height, s.width), -1, np.int32), ())

    def read(self, t: float, labels: bool = True) -> DepthFrame:
        """Frame valid at ``t``: re-captured at most at ``rate_hz`` (and when ``labels`` are asked of a frame
        taken without them); a lost stream repeats its last frame."""
        if self.lost:
            return self._last if self._last is not None else self.empty_frame()
        if (self._last is not None and t - self._last.t < 1.0 / self.spec.rate_hz - 1e-9
                and (self._labelled or not labels)):
            return self._last
        return self.capture(t, labels)



def depth_to_points(depth: np.ndarray, K: np.ndarray, T_world_cam: np.ndarray) -> np.ndarray:
    """Back-project a depth image (optical z, 0 = invalid) to world points (N, 3)."""
    rows, cols = np.nonzero(depth > 0)
    z = depth[rows, cols].astype(np.float64)
    x = (cols - K[0, 2]) / K[0, 0] * z
    y = (rows - K[1, 2]) / K[1, 1] * z
    p = np.stack([x, y, z], 1)
    return p @ T_world_cam[:3, :3].T + T_world_cam[:3, 3]
