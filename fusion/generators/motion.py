"""Motion estimation support generator (thesis §4.5.1, eq. 4.12-4.13): multi-contact, binary law.

The next joint configuration is extrapolated from the last two, q(t+1) = q(t) + (q(t) -
q(t-1)); the robot model at q(t+1) gives the surface the robot is about to occupy, where
support hypotheses of fixed likelihood ``weight`` (0.3 in the thesis) are placed.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from contactflow.embodiments.messages import RobotModel
from contactflow.fusion.generators.base import GeneratorModule, link_groups
from contactflow.fusion.geometry import PoseMemo, capsule_surface
from contactflow.fusion.hypotheses import (
    VOXEL_SIZE,
    Hypotheses,
    HypothesisType,
    unique_keys,
    voxel_centers,
    voxel_keys,
)
from contactflow.nodes.module import Port
from contactflow.nodes.status import Status

SurfaceAt = Callable[[np.ndarray], np.ndarray]
"""Robot surface samples (k, 3), world frame, at a joint configuration."""


@dataclass(frozen=True)
class MotionParams:
    rate_hz: float = 30.0  # Hz
    robot: str = "robot"
    weight: float = 0.3  # likelihood of every support hypothesis (thesis §4.5.1)
    voxel_size: float = VOXEL_SIZE  # m
    links: tuple[str, ...] = ()  # name prefixes of the links whose next surface gets support (each its own surface); () = all, one surface


def predict(q: np.ndarray, q_prev: np.ndarray) -> np.ndarray:
    """Eq. 4.12-4.13."""
    q = np.asarray(q, dtype=float)
    return q + (q - np.asarray(q_prev, dtype=float))


def support_cloud(points: np.ndarray, weight: float, voxel_size: float, stamp: float,
                  where: str = "motion_support") -> Hypotheses:
    """Support hypotheses of likelihood ``weight`` on the voxels holding ``points``: one per voxel, what
    ``voxelize`` makes of equally likely, forceless hypotheses, by a sort of their keys alone (the surface of
    the hands, 8k voxels, in a quarter of its time)."""
    keys = unique_keys(voxel_keys(points, voxel_size))
    return Hypotheses.make(voxel_centers(keys, voxel_size), weight, HypothesisType.SUPPORT, stamp=stamp, where=where)


class MotionSupportGenerator:
    def __init__(self, params: MotionParams | None = None) -> None:
        self.params = params or MotionParams()
        if not 0.0 <= self.params.weight <= 1.0:
            raise ValueError(f"motion_support: weight={self.params.weight} must lie in [0, 1]")
        self.q_prev: np.ndarray | None = None

    def update(self, q: np.ndarray, surface_at: SurfaceAt, stamp: float) -> Hypotheses:
        q = np.asarray(q, dtype=float).ravel()
        if self.q_prev is None or self.q_prev.shape != q.shape:
            self.q_prev = q
            return Hypotheses.empty(stamp)
        q_next = predict(q, self.q_prev)
        self.q_prev = q
        pts = np.asarray(surface_at(q_next), dtype=float).reshape(-1, 3)
        if pts.shape[0] == 0:
            return Hypotheses.empty(stamp)
        return support_cloud(pts, self.params.weight, self.params.voxel_size, stamp)


class MotionSupportHypothesesGenerator(GeneratorModule):
    """Support hypotheses where the robot will be next (eq. 4.12-4.13).

    The shell reads the posed spherical model the embodiment publishes from each joint state
    and applies eq. 4.12-4.13 to the bi-sphere centres, which are attached to the links (exact
    for translations, first order for rotations); the support goes on the surface of the
    extrapolated model. The core :class:`MotionSupportGenerator` extrapolates the joints instead.
    """

    Params = MotionParams
    inputs = (Port("robot_model", RobotModel, "posed bi-spheres of the robot, world"),)

    def setup(self, io) -> None:  # type: ignore[no-untyped-def]
        super().setup(io)
        self.reset()

    def reset(self) -> None:
        self._prev: list[np.ndarray] | None = None
        self._surfaces: dict[int, PoseMemo] = {}
        self._last: tuple[list[np.ndarray], Hypotheses] | None = None  # the surfaces of the last cloud, the cloud

    def step(self) -> Status:
        assert self.io is not None
        frames = self.io.take("robot_model")
        if not frames:
            return Status.RUNNING
        msg = frames[-1]
        groups = link_groups(msg, self.name, self.params.links)
        prev, self._prev = self._prev, groups
        if prev is None or [g.shape for g in prev] != [g.shape for g in groups]:
            return Status.RUNNING
        parts = []
        for i, (caps, before) in enumerate(zip(groups, prev, strict=True)):
            nxt = caps.copy()
            nxt[:, 0:3] = predict(caps[:, 0:3], before[:, 0:3])
            nxt[:, 4:7] = predict(caps[:, 4:7], before[:, 4:7])
            if i not in self._surfaces:
                self._surfaces[i] = PoseMemo(lambda c: capsule_surface(c, self.params.voxel_size))
            parts.append(self._surfaces[i](nxt))
        stamp = self.stamp_of(msg)
        if self._last is not None and all(a is b for a, b in zip(parts, self._last[0], strict=True)):
            self.publish_cloud(replace(self._last[1], stamp=stamp))  # nothing moved: the same support
            return Status.RUNNING
        pts = np.concatenate(parts)
        h = Hypotheses.empty(stamp)
        if pts.shape[0]:
            h = support_cloud(pts, self.params.weight, self.params.voxel_size, stamp, where=self.name)
        self._last = (parts, h)
        self.publish_cloud(h)
        return Status.RUNNING
