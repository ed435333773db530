"""Synthetic scenes with known answers, shared by tests and benchmarks (no simulator needed)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from contactflow.recognition.geometry import intrinsics, look_at
from contactflow.recognition.synthetic import Scene, box_mesh, cylinder_mesh, sphere_mesh

TABLE_TOP = 0.0  # m, world z of the table surface


@dataclass(frozen=True)
class Placed:
    """An object resting on the table: kind ("box", "cylinder", "sphere"), size (m), pose."""

    kind: str
    size: tuple[float, float, float]  # box: x, y, z; cylinder: radius, height, -; sphere: radius, -, -
    xy: tuple[float, float]
    yaw: float = 0.0

    @property
    def center(self) -> np.ndarray:
        h = {"box": self.size[2], "cylinder": self.size[1], "sphere": 2 * self.size[0]}[self.kind]
        return np.array([self.xy[0], self.xy[1], TABLE_TOP + h / 2])

    def mesh(self):
        if self.kind == "box":
            return box_mesh(self.size, self.center, self.yaw)
        if self.kind == "cylinder":
            return cylinder_mesh(self.size[0], self.size[1], self.center)
        if self.kind == "sphere":
            return sphere_mesh(self.size[0], self.center)
        raise ValueError(f"Placed.kind: unknown shape {self.kind!r}")


@dataclass
class TableScene:
    """A table (1.2 x 0.8 m, top at z = 0) with objects, seen by a Kinect-like camera."""

    objects: list[Placed]
    eye: tuple[float, float, float] = (0.0, 0.0, 0.8)
    target: tuple[float, float, float] = (0.55, 0.0, 0.0)
    width: int = 640
    height: int = 480
    extra: list = field(default_factory=list)  # more meshes (e.g. robot links)

    def __post_init__(self) -> None:
        self.scene = Scene()
        self.scene.add(box_mesh((1.2, 0.8, 0.04), (0.6, 0.0, TABLE_TOP - 0.02)))
        for o in self.objects:
            self.scene.add(o.mesh())
        for m in self.extra:
            self.scene.add(m)
        self.K = intrinsics(self.width, self.height)
        self.pose = look_at(np.array(self.eye), np.array(self.target))

    def render(self, noise: float = 0.0, seed: int = 0) -> np.ndarray:
        return self.scene.render(self.K, self.pose, self.width, self.height, noise, np.random.default_rng(seed))


def three_objects() -> TableScene:
    """Two boxes and a cylinder well apart on the table."""
    return TableScene([
        Placed("box", (0.06, 0.05, 0.12), (0.45, 0.10), 0.3),
        Placed("box", (0.08, 0.08, 0.08), (0.65, -0.15)),
        Placed("cylinder", (0.035, 0.15, 0.0), (0.55, 0.25)),
    ])
