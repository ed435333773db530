"""Place location (perceptual): a free spot on the support in a region, away from every sensed object."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from contactflow.embodiments.primitives.base import (
    Primitive,
    hand_pose_for,
    pose6,
    top_grasp_pose,
    wall_yaws,
)
from contactflow.nodes.status import Event


def free_spot(occupied: np.ndarray, region: np.ndarray, clearance: float, step: float = 0.02) -> np.ndarray | None:
    """The grid point of ``region`` [xmin, ymin, xmax, ymax] farthest from ``occupied`` (N,2) beyond ``clearance``."""
    xs = np.arange(region[0], region[2] + 1e-9, step)
    ys = np.arange(region[1], region[3] + 1e-9, step)
    grid = np.stack(np.meshgrid(xs, ys, indexing="ij"), axis=-1).reshape(-1, 2)
    if len(occupied) == 0:
        return grid[len(grid) // 2]
    d = np.min(np.linalg.norm(grid[:, None, :] - occupied[None, ::max(1, len(occupied) // 500), :], axis=2), axis=1)
    best = int(np.argmax(d))
    return grid[best] if d[best] >= clearance else None


class PlaceLocation(Primitive):
    """A location on a support: ``free`` = the spot farthest from what the camera sees above it;
    ``random`` = uniform in the region without sensing (the blind random strategy of §3.4.3);
    ``at`` = the given ``spot`` (e.g. where an exploring hand touched something), with the hand turned for the walls."""

    commands_arm = False
    events = (Event.SUCCESS, Event.FAILURE, Event.ERROR)

    @dataclass(frozen=True)
    class Params(Primitive.Params):
        region: tuple[float, ...] = (0.4, 0.1, 0.7, 0.5)  # m, [xmin, ymin, xmax, ymax] on the support
        support_z: float = 0.75  # m, height of the support surface
        clearance: float = 0.08  # m from any sensed object
        height: float = 0.1  # m, approach height of the hand above the support
        yaw: float = 1.5707963267948966  # rad
        camera: str = "kinect"
        mode: str = "free"  # free | random | at
        seed: int = 0  # random mode
        spot: tuple[float, ...] = ()  # m, at mode: [x, y] of the location
        walls: tuple[float, ...] = ()  # m, random and at modes: [xmin, ymin, xmax, ymax] inner sides of the container grasped in (none: no walls)
        wall_margin: float = 0.055  # m, a spot this close to a wall gets the hand's ``wall_side`` toward it
        wall_side: tuple[float, ...] = (1.0, 0.0)  # hand-frame (x, y) direction put toward a nearby wall (per hand, measured)

    def update(self) -> None:
        p = self.params
        region = np.asarray(p.region, dtype=np.float64)
        if region.shape != (4,) or region[0] > region[2] or region[1] > region[3]:
            raise ValueError(f"{self.name}: params.region must be [xmin, ymin, xmax, ymax], got {p.region}")
        if p.mode in ("random", "at"):
            if p.mode == "random":  # a blind grasp guess
                x, y = np.random.default_rng([p.seed, int(self.r.time * 1000)]).uniform(region[:2], region[2:])
            elif len(p.spot) != 2:
                raise ValueError(f"{self.name}: params.spot must be [x, y], got {p.spot}")
            else:
                x, y = (float(v) for v in p.spot)
            self._spot(x, y, wall_yaws([p.yaw], (x, y), p.walls, p.wall_margin, p.wall_side)[0])
            return
        if p.mode != "free":
            raise ValueError(f"{self.name}: params.mode must be free, random or at, got {p.mode!r}")
        if not self.r.spec.cameras:
            raise ValueError(f"{self.name}: mode free needs a camera on {self.r.spec.name}")
        pts = np.asarray(self.r.camera(p.camera).points)
        model = getattr(self.r, "spherical", None)
        sel = (pts[:, 2] > p.support_z + 0.01) & (pts[:, 2] < p.support_z + 0.5)
        pts = pts[sel]
        if model is not None and len(pts):
            pts = pts[model.clear_of(pts, 0.02)]
        spot = free_spot(pts[:, :2], region, p.clearance)
        if spot is None:
            self.fail("no free place in the region")
            return
        self._spot(spot[0], spot[1], p.yaw)

    def _spot(self, x: float, y: float, yaw: float) -> None:
        """Succeed with the hand pose that puts its grasp centre (where it holds an object) over (x, y)."""
        p = self.params
        self.succeed(**pose6(hand_pose_for(self.r.spec.name, top_grasp_pose((x, y, p.support_z + p.height), yaw))))
