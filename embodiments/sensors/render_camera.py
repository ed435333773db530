"""RGBD camera backend that renders depth with SAPIEN (Vulkan) in a scene that has a render system.

The camera is a ``RenderCameraComponent`` on its own entity, placed every frame at the
sensor's optical pose (the link pose times the spec's mounting offset, exactly as the
ray-casting backend computes it) and given the spec's intrinsics, so both backends produce
the same image geometry. It renders with one of two single-pass shader packs cut from
SAPIEN's ``trivial`` (``shaders/``: its uniforms, no lighting, <1 s to compile where the
default pack takes ~5 s): ``depth`` writes the Position picture only (a depth stream's
frame), ``labelled`` Position and Segmentation (a frame with the bodies its pixels hit);
``trivial`` also writes a textured Color picture nobody reads (640x480 on lavapipe, the same
pictures: a depth frame 29.4 -> 21.9 ms, a labelled one 30.6 -> 27.1 ms). The ``Position``
picture is in the OpenGL camera frame (x right, y up, z backwards); SAPIEN's principal point
counts from the pixel corner while the spec's counts from the pixel centre (cx = 319.5),
hence the half-pixel shift. Whether a Vulkan device is usable is probed once in a subprocess,
because a missing device can abort the process that creates a render system; the processes a
probed one starts inherit the answer (``CONTACTFLOW_RENDER``).
"""

from __future__ import annotations

import functools
import os
import pathlib
import subprocess
import sys

import numpy as np
import sapien

from contactflow.embodiments.registry import CameraSpec

_PACKS = pathlib.Path(__file__).parent / "shaders"
"""The shader packs: ``depth`` (the Position picture) and ``labelled`` (Position and Segmentation)."""
_PROBE = "import sapien; sapien.render.RenderSystem(); print('render-ok')"
RENDER_ENV = "CONTACTFLOW_RENDER"
"""``1``: a render device was found, ``0``: none (the ray-cast camera); set by the first probe, or by hand."""
_PROBE_TIMEOUT = 60.0  # s; a lavapipe device is created in ~1 s
_GL_FROM_OPTICAL = np.array([[0.0, -1.0, 0.0, 0.0], [0.0, 0.0, -1.0, 0.0], [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]])
"""SAPIEN's camera entity frame (x forward, y left, z up) expressed in the optical frame."""


@functools.cache
def render_available() -> bool:
    """True when a render system can be created here: checked in a subprocess once, and the answer left in the
    environment (:data:`RENDER_ENV`) for the node processes this one starts, which would each probe the same
    device again (a second or more of a node's start, every time)."""
    known = os.environ.get(RENDER_ENV)
    if known in ("0", "1"):
        return known == "1"
    try:
        out = subprocess.run([sys.executable, "-c", _PROBE], capture_output=True, text=True, timeout=_PROBE_TIMEOUT)
        ok = out.returncode == 0 and "render-ok" in out.stdout
    except (OSError, subprocess.TimeoutExpired):
        ok = False
    os.environ[RENDER_ENV] = "1" if ok else "0"
    return ok


class RenderDepth:
    """Depth and hit-body labels rendered by SAPIEN for one camera spec in ``scene``."""

    def __init__(self, scene: sapien.Scene, spec: CameraSpec) -> None:
        self.scene, self.spec = scene, spec
        self._cameras: dict[str, tuple[sapien.Entity, sapien.render.RenderCameraComponent]] = {}  # pack -> its camera

    def _camera(self, pack: str) -> tuple[sapien.Entity, sapien.render.RenderCameraComponent]:
        """The camera rendering with shader pack ``pack``, added to the scene at its first frame."""
        if pack not in self._cameras:
            s = self.spec
            camera = sapien.render.RenderCameraComponent(s.width, s.height, str(_PACKS / pack))
            camera.set_perspective_parameters(s.near, s.far, s.fx, s.fy, s.cx + 0.5, s.cy + 0.5, 0.0)
            entity = sapien.Entity()
            entity.set_name(f"camera:{s.name}:{pack}")
            entity.add_component(camera)
            self.scene.add_entity(entity)
            self._cameras[pack] = (entity, camera)
        return self._cameras[pack]

    def _names(self) -> tuple[dict[int, int], list[str]]:
        """Label of every entity with a physics body (per-scene id -> index) and the label names."""
        system = self.scene.get_physx_system()
        bodies = (list(system.get_rigid_static_components()) + list(system.get_rigid_dynamic_components())
                  + list(system.get_articulation_link_components()))
        ids, names = {}, []
        for body in bodies:
            ids[body.entity.per_scene_id] = len(names)
            names.append(body.get_name() or body.entity.get_name())
        return ids, names

    def _position(self, T_world_cam: np.ndarray, pack: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Render from ``T_world_cam`` with ``pack``: (Position picture, depth (H, W) along the optical axis with
        0 = none, valid pixels)."""
        s = self.spec
        entity, camera = self._camera(pack)
        entity.set_pose(sapien.Pose(np.asarray(T_world_cam, dtype=np.float64) @ _GL_FROM_OPTICAL))
        self.scene.update_render()
        camera.take_picture()
        pos = camera.get_picture("Position")
        z = -pos[..., 2]
        # the packs write w = 1 on geometry and clear the background to 0: its z = 0 is nearer than ``near`` (> 0)
        valid = (z >= s.near) & (z <= s.far)
        return pos, np.where(valid, z, np.float32(0.0)), valid

    def depth(self, T_world_cam: np.ndarray) -> np.ndarray:
        """Depth (H, W) along the optical axis (0 = none) only: no segmentation picture, points or labels."""
        return self._position(T_world_cam, "depth")[1]

    def shoot(self, T_world_cam: np.ndarray, labels: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[str]]:
        """Depth (H, W) along the optical axis (0 = none), world points of the depth > 0 pixels in
        row-major order (N, 3), labels (H, W) and label names; without ``labels`` the frame renders
        with the depth pack and its labels are all -1 (no names)."""
        pos, depth, valid = self._position(T_world_cam, "labelled" if labels else "depth")
        # the valid pixels' rows gathered by index (a boolean mask over the (H, W, 4) picture costs 3x more), and
        # the GL -> optical flip of y and z folded into the rotation: a sign change is exact, the points the same
        rows = np.take(pos.reshape(-1, 4), np.flatnonzero(valid), axis=0)[:, :3].astype(np.float64)
        points = rows @ (T_world_cam[:3, :3] * (1.0, -1.0, -1.0)).T + T_world_cam[:3, 3]
        if not labels:
            return depth, points, np.full(depth.shape, -1, dtype=np.int32), []
        seg = self._camera("labelled")[1].get_picture("Segmentation")[..., 1]
        ids, names = self._names()
        lookup = np.full(int(seg.max()) + 1, -1, dtype=np.int32)
        for sid, label in ids.items():
            if sid < len(lookup):
                lookup[sid] = label
        labels = np.where(valid, lookup[seg], -1).astype(np.int32)
        return depth, points, labels, names
