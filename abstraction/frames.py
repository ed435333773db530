"""The task frame an ATD's coordinates are written in, and its mapping into the world frame.

Thesis ATDs give positions in the robot's task frame (Fig. 7.2: x to the side, y away from
the robot, z up from the table). Each robot profile says where that frame sits in its world;
the translator maps the whole ATD (objects, obstacles, targets, paths) into the world frame
before the factory sees it, and plan parameters bound at run time go through the same map.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from contactflow.abstraction.atd import Atd

Vec3 = tuple[float, float, float]


@dataclass(frozen=True, slots=True)
class TaskFrame:
    """world = Rz(yaw) · p + origin."""

    yaw: float = 0.0  # rad, rotation about the world z axis
    origin: Vec3 = (0.0, 0.0, 0.0)  # m, task-frame origin in the world

    def direction(self, v: Vec3) -> Vec3:
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        return (round(c * v[0] - s * v[1], 12), round(s * v[0] + c * v[1], 12), float(v[2]))

    def point(self, p: Vec3) -> Vec3:
        d = self.direction(p)
        return (d[0] + self.origin[0], d[1] + self.origin[1], d[2] + self.origin[2])

    def extent(self, size: Vec3) -> Vec3:
        """Full sizes of an axis-aligned box after the rotation (right angles stay exact)."""
        d = self.direction(size)
        return (abs(d[0]), abs(d[1]), abs(d[2]))


WORKCELL = TaskFrame(yaw=-math.pi / 2, origin=(0.0, 0.0, 0.75))
"""The thesis layout: y of the ATD points away from the robot (world +x), z = 0 on the table top."""


def to_world(atd: Atd, frame: TaskFrame) -> Atd:
    """The same ATD with every coordinate expressed in the world frame."""
    def opt(p, fn):
        return None if p is None else fn(p)

    objects = {n: dataclasses.replace(o, location=opt(o.location, frame.point),
                                      approach=opt(o.approach, frame.direction), size=opt(o.size, frame.extent))
               for n, o in atd.objects.items()}
    obstacles = tuple(dataclasses.replace(o, position=frame.point(o.position), size=frame.extent(o.size))
                      for o in atd.obstacles)
    states = tuple(dataclasses.replace(s, target=opt(s.target, frame.point),
                                       path=tuple(frame.point(p) for p in s.path),
                                       object_size=opt(s.object_size, frame.extent))
                   for s in atd.states)
    return dataclasses.replace(atd, objects=objects, obstacles=obstacles, states=states)


def params_to_world(params: Mapping[str, Any], frame: TaskFrame) -> dict[str, Any]:
    """Plan parameters in the world frame: ``*_location`` are points, ``*_approach`` directions."""
    out: dict[str, Any] = {}
    for k, v in params.items():
        if isinstance(v, list | tuple) and len(v) == 3 and k.endswith("_location"):
            out[k] = list(frame.point(tuple(float(a) for a in v)))
        elif isinstance(v, list | tuple) and len(v) == 3 and k.endswith("_approach"):
            out[k] = list(frame.direction(tuple(float(a) for a in v)))
        else:
            out[k] = v
    return out
