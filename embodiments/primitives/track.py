"""Track (thesis Figs. 6.2-6.3): localize an object in the head camera's cloud and turn the head to keep it in view."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from contactflow.embodiments.primitives.base import Capability, Primitive, PrimitiveError
from contactflow.nodes.status import Event


class Track(Primitive):
    """Active object tracking with head movements: Fig. 6.2's Localize Object and Move Head in one loop.

    Every ``period`` the object is localized in the camera cloud: the robot's own points are
    removed (spherical model), so are the support's (the plane under ``target``, fitted by
    RANSAC on the first frame), and the object is the cluster nearest its last position, within
    ``radius`` (it starts at ``target``, e.g. a detection's centroid). At the control rate the
    head turns toward it: joint velocities = ``gain`` x pinv(angular Jacobian of the camera in
    the head joints) x gaze error (optical axis x unit direction to the object). It runs beside
    a manipulation task until stopped (Fig. 6.3) or for ``duration``; OBJECT_LOST ends it when
    the object was not seen for ``lost_after``.
    """

    requires = Capability(camera=True)
    commands_arm = False
    events = (Event.SUCCESS, Event.FAILURE, Event.ERROR, Event.OBJECT_DETECTED, Event.OBJECT_LOST)

    @dataclass(frozen=True)
    class Params(Primitive.Params):
        camera: str = "kinect"  # camera on the head
        target: tuple[float, ...] = ()  # [x, y, z] m (world), where the object is first looked for
        radius: float = 0.08  # m, the object's points lie this close to its last position
        min_points: int = 30  # a cluster with fewer points is not the object
        period: float = 0.2  # s between localizations (5 Hz)
        gain: float = 4.0  # 1/s, head angular velocity per rad of gaze error
        max_speed: float = 1.5  # rad/s per head joint
        self_margin: float = 0.01  # m, camera points this close to the robot's spherical model are the robot
        min_height: float = 0.01  # m, points this close to the support plane are the support
        lost_after: float = 1.0  # s without seeing the object: OBJECT_LOST
        duration: float = 0.0  # s, succeed after tracking this long (0: until stopped)

    def setup(self, io) -> None:  # type: ignore[no-untyped-def]
        super().setup(io)
        from contactflow.recognition import open3d_backend

        open3d_backend.load()  # the plane fit and the clustering load open3d (1.2 s): at setup, not in the first look

    def begin(self) -> None:
        p = self.params
        if self.r.head is None:
            raise PrimitiveError(f"{self.name}: {self.r.spec.name} has no head to track with")
        if len(p.target) != 3 or not np.all(np.isfinite(p.target)):
            raise PrimitiveError(f"{self.name}: params.target must be [x, y, z] (m, world), got {list(p.target)}")
        self.cam_link = self.r.spec.camera(p.camera).link
        self.where = np.asarray(p.target, dtype=np.float64)
        self.q_cmd = self.r.head.q()
        self.support = None
        self.next_look = self.r.time
        self.seen_at = self.r.time
        self.looks = self.sightings = 0

    def gaze_error(self) -> np.ndarray:
        """Rotation (axis x sin angle, world) that turns the optical axis onto the object."""
        T = self.r.camera_pose(self.params.camera)
        d = self.where - T[:3, 3]
        return np.cross(T[:3, 2], d / np.linalg.norm(d))

    def localize(self) -> bool:
        from contactflow.recognition.pipeline import detect_plane, extract_clusters

        p = self.params
        pts = np.asarray(self.r.camera(p.camera).points)
        if self.support is None:
            # the support seen around the object before anything moved it
            near = pts[(np.linalg.norm(pts[:, :2] - self.where[:2], axis=1) < 0.25) & (pts[:, 2] < self.where[2])]
            self.support, _ = detect_plane(near, distance=0.005, min_inliers=p.min_points) if len(near) else (None, None)
        pts = pts[np.linalg.norm(pts - self.where, axis=1) < p.radius]
        model = getattr(self.r, "spherical", None)
        if model is not None and len(pts):
            pts = pts[model.clear_of(pts, p.self_margin)]
        if self.support is not None and len(pts):
            pts = pts[self.support.height(pts) > p.min_height]
        clusters = extract_clusters(pts, min_size=p.min_points) if len(pts) >= p.min_points else []
        if not clusters:
            return False
        self.where = min((c.centroid for c in clusters), key=lambda c: float(np.linalg.norm(c - self.where)))
        return True

    def update(self) -> None:
        p = self.params
        now = self.r.time
        if now >= self.next_look:
            self.next_look = now + p.period
            self.looks += 1
            if self.localize():
                if not self.sightings:
                    self.emit_once(Event.OBJECT_DETECTED, "tracking", dict(zip("xyz", map(float, self.where), strict=True)))
                self.sightings += 1
                self.seen_at = now
            elif now - self.seen_at >= p.lost_after:
                self.fail(f"object not seen for {now - self.seen_at:.1f} s near {np.round(self.where, 3).tolist()}",
                          event=Event.OBJECT_LOST, **self.values())
                return
        head = self.r.head
        J = head.jacobian(self.cam_link)[3:]
        qd = np.clip(p.gain * np.linalg.pinv(J) @ self.gaze_error(), -p.max_speed, p.max_speed)
        self.q_cmd = np.clip(self.q_cmd + qd / p.rate_hz, head.lower, head.upper)
        head.move_joints(self.q_cmd)
        if p.duration and self.elapsed >= p.duration:
            self.succeed(**self.values())

    def values(self) -> dict[str, float]:
        err = float(np.degrees(np.arcsin(min(1.0, np.linalg.norm(self.gaze_error())))))
        return dict(x=float(self.where[0]), y=float(self.where[1]), z=float(self.where[2]), gaze_error_deg=err,
                    seen=float(self.sightings), looks=float(self.looks))
