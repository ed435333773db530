"""The object sets of the chapter 8 experiments, as open3d meshes (thesis §8.5, Fig. 8.5).

Shape classification: training shapes 1-9 (pure boxes, cylinders, spheres) and test
shapes 10-18 (everyday-like objects), the layout of Table 8.1. Object recognition: nine
same-colour, same-material boxes (Table 8.2), two of which share their dimensions and
differ only in weight (one is hollow), so vision alone cannot tell them apart.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import open3d as o3d

from contactflow.recognition.shape import BOX, CYLINDER, SPHERE
from contactflow.recognition.synthetic import box_mesh, cone_mesh, cylinder_mesh, sphere_mesh

GRAVITY = 9.81  # m/s²
WOOD_DENSITY = 450.0  # kg/m³, the boxes are of one material (pine)


@dataclass(frozen=True)
class ShapeObject:
    number: int
    name: str
    label: str  # expected V4 class
    make: Callable[[], o3d.geometry.TriangleMesh]  # mesh centred on the origin, upright


def _bottle() -> o3d.geometry.TriangleMesh:
    body = cylinder_mesh(0.035, 0.17, (0, 0, -0.025))
    neck = cone_mesh(0.035, 0.05, (0, 0, 0.06))
    return body + neck


def _lying_tube() -> o3d.geometry.TriangleMesh:
    return cylinder_mesh(0.03, 0.16, axis=(1.0, 0.3, 0.0))


def _cup() -> o3d.geometry.TriangleMesh:
    m = cone_mesh(0.05, 0.12, (0, 0, -0.05))
    m.rotate(np.diag([1.0, -1.0, -1.0]), center=(0, 0, 0))  # upside down: wide on top
    return m


TRAINING_SHAPES = (
    ShapeObject(1, "cube", BOX, lambda: box_mesh((0.10, 0.10, 0.10))),
    ShapeObject(2, "flat box", BOX, lambda: box_mesh((0.20, 0.10, 0.05))),
    ShapeObject(3, "tall box", BOX, lambda: box_mesh((0.12, 0.06, 0.15))),
    ShapeObject(4, "large box", BOX, lambda: box_mesh((0.25, 0.15, 0.08))),
    ShapeObject(5, "cylinder", CYLINDER, lambda: cylinder_mesh(0.04, 0.12)),
    ShapeObject(6, "wide cylinder", CYLINDER, lambda: cylinder_mesh(0.06, 0.08)),
    ShapeObject(7, "thin cylinder", CYLINDER, lambda: cylinder_mesh(0.03, 0.20)),
    ShapeObject(8, "ball", SPHERE, lambda: sphere_mesh(0.05)),
    ShapeObject(9, "small ball", SPHERE, lambda: sphere_mesh(0.035)),
)

TEST_SHAPES = (
    ShapeObject(10, "book", BOX, lambda: box_mesh((0.15, 0.15, 0.04), yaw=0.4)),
    ShapeObject(11, "juice carton", BOX, lambda: box_mesh((0.07, 0.05, 0.18), yaw=0.2)),
    ShapeObject(12, "long box", BOX, lambda: box_mesh((0.22, 0.08, 0.08), yaw=0.7)),
    ShapeObject(13, "small cube", BOX, lambda: box_mesh((0.05, 0.05, 0.05), yaw=0.3)),
    ShapeObject(14, "tuna can", CYLINDER, lambda: cylinder_mesh(0.05, 0.05)),
    ShapeObject(15, "bottle", CYLINDER, _bottle),
    ShapeObject(16, "lying tube", CYLINDER, _lying_tube),
    ShapeObject(17, "mug", CYLINDER, lambda: cylinder_mesh(0.045, 0.10)),
    ShapeObject(18, "cup", CYLINDER, _cup),
)


@dataclass(frozen=True)
class RecognitionBox:
    name: str
    size: tuple[float, float, float]  # m
    fill: float = 1.0  # fraction of solid material (a hollow box weighs less)

    @property
    def mass(self) -> float:  # kg
        return WOOD_DENSITY * float(np.prod(self.size)) * self.fill

    @property
    def weight(self) -> float:  # N
        return self.mass * GRAVITY


RECOGNITION_BOXES = (
    RecognitionBox("A", (0.20, 0.10, 0.05)),
    RecognitionBox("B", (0.15, 0.10, 0.06)),
    RecognitionBox("C", (0.12, 0.08, 0.08)),
    RecognitionBox("D", (0.10, 0.10, 0.10)),
    RecognitionBox("E", (0.22, 0.06, 0.04)),
    RecognitionBox("F", (0.16, 0.12, 0.03)),
    RecognitionBox("G", (0.18, 0.09, 0.07)),
    RecognitionBox("H", (0.15, 0.10, 0.06), fill=0.4),  # B's twin, hollow
    RecognitionBox("I", (0.13, 0.07, 0.04)),
)
