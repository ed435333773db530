"""Null hypotheses generator (thesis §4.2.1): where contacts cannot be.

Two sources of certainty that a voxel holds no contact: the space the robot's volume swept
in the last ``memory`` seconds (shrunk by ``margin`` so the surface, where contacts are, is
never vetoed) and known free boxes of the workspace. Any hypothesis fused with a null one is
discarded by the integrator.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from contactflow.embodiments.messages import RobotModel
from contactflow.fusion.generators.base import GeneratorModule, link_groups
from contactflow.fusion.geometry import PoseMemo, grid_points, interior_points
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


@dataclass(frozen=True)
class NullParams:
    rate_hz: float = 15.0  # Hz
    robot: str = "robot"
    margin: float = 0.015  # m, depth under the robot surface from which space counts as swept
    memory: float = 0.5  # s, how long swept space stays null
    voxel_size: float = VOXEL_SIZE  # m
    links: tuple[str, ...] = ()  # name prefixes of the links whose swept volume is null; () = all


class NullGenerator:
    """Keeps the swept voxels (keys and the last time each was swept) and the free boxes."""

    def __init__(self, params: NullParams | None = None, free_boxes: Sequence[tuple[np.ndarray, np.ndarray]] = ()) -> None:
        self.params = params or NullParams()
        self.keys = np.zeros(0, dtype=np.int64)
        self.when = np.zeros(0)
        vs = self.params.voxel_size
        boxes = [grid_points(lo, hi, vs) for lo, hi in free_boxes]
        self.free = unique_keys(voxel_keys(np.concatenate(boxes), vs)) if boxes else np.zeros(0, dtype=np.int64)
        self._last: tuple[np.ndarray, float, float, Hypotheses] | None = None  # points, since, computed at, cloud

    def update(self, inside: np.ndarray | None, stamp: float) -> Hypotheses:
        """Add the points now inside the robot (deeper than ``margin``, see
        :func:`~contactflow.fusion.geometry.interior_points`); null hypotheses of all. The same points
        (the same array) for longer than ``memory`` make the same cloud, computed once."""
        last = self._last
        same = inside is not None and last is not None and inside is last[0]
        if same and last[2] - last[1] > self.params.memory:
            # every other point expired before that cloud was made: the swept voxels are these, swept now
            self.when = np.full_like(self.when, stamp)
            return replace(last[3], stamp=stamp)
        out = self._update(inside, stamp)
        self._last = (inside, last[1] if same else stamp, stamp, out) if inside is not None else None
        return out

    def _update(self, inside: np.ndarray | None, stamp: float) -> Hypotheses:
        p = self.params
        if p.memory <= 0:  # only where the robot is now: nothing to merge with what it swept
            self.keys = unique_keys(voxel_keys(inside, p.voxel_size)) if inside is not None else self.keys[:0]
            self.when = np.full(self.keys.size, stamp)
        elif inside is not None:
            inside = np.asarray(inside, dtype=float).reshape(-1, 3)
            keys = np.concatenate([self.keys, voxel_keys(inside, p.voxel_size)])
            when = np.concatenate([self.when, np.full(inside.shape[0], stamp)])
            order = np.lexsort((-when, keys))  # newest first within a key
            keys, when = keys[order], when[order]
            first = np.ones(keys.size, dtype=bool)
            first[1:] = keys[1:] != keys[:-1]
            self.keys, self.when = keys[first], when[first]
        fresh = self.when >= stamp - p.memory
        self.keys, self.when = self.keys[fresh], self.when[fresh]
        keys = unique_keys(np.concatenate([self.keys, self.free])) if self.free.size else self.keys  # both sorted, unique
        if keys.size == 0:
            return Hypotheses.empty(stamp)
        return Hypotheses.make(voxel_centers(keys, p.voxel_size), 1.0, HypothesisType.NULL, stamp=stamp, where="null")


class NullHypothesesGenerator(GeneratorModule):
    """Swept robot volume to null hypotheses."""

    Params = NullParams
    inputs = (Port("robot_model", RobotModel, "posed bi-spheres of the robot, world"),)

    def setup(self, io) -> None:  # type: ignore[no-untyped-def]
        super().setup(io)
        self.reset()

    def reset(self) -> None:
        self.core = NullGenerator(self.params)
        self._inside: dict[int, PoseMemo] = {}
        self._parts: list[np.ndarray] = []
        self._all = np.zeros((0, 3))

    def step(self) -> Status:
        assert self.io is not None
        frames = self.io.take("robot_model")
        if not frames:
            return Status.RUNNING
        msg = frames[-1]
        parts = []
        for i, caps in enumerate(link_groups(msg, self.name, self.params.links)):
            if i not in self._inside:
                self._inside[i] = PoseMemo(lambda c: interior_points(c, self.params.voxel_size, self.params.margin))
            parts.append(self._inside[i](caps))
        if len(parts) != len(self._parts) or any(a is not b for a, b in zip(parts, self._parts, strict=False)):
            self._parts, self._all = parts, np.concatenate(parts)  # a new array only when a group moved
        self.publish_cloud(self.core.update(self._all, self.stamp_of(msg)))
        return Status.RUNNING
