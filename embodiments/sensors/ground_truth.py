"""Ground truth for evaluation: object poses and every true contact. Primitives and fusion never read it."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class TrueContact:
    """A physics contact point between two named bodies (``robot/link`` for robot links)."""

    body_a: str
    body_b: str
    position: np.ndarray  # world
    normal: np.ndarray  # world, from a to b
    force: float  # N, normal force


@dataclass(frozen=True)
class GroundTruth:
    t: float
    object_poses: dict[str, np.ndarray]
    contacts: list[TrueContact]


def body_name(body) -> str:
    art = getattr(body, "articulation", None)
    if art is not None:
        return f"{art.get_name()}/{body.get_name()}"
    return body.entity.get_name()


def read_ground_truth(world, t: float | None = None) -> GroundTruth:
    """Object poses and true contacts of ``world`` now."""
    dt = world.params.timestep
    contacts = []
    for c in world.contacts():
        a, b = body_name(c.bodies[0]), body_name(c.bodies[1])
        for p in c.points:
            f = float(np.linalg.norm(p.impulse)) / dt
            if f <= 0.0:
                continue
            contacts.append(TrueContact(a, b, np.asarray(p.position, dtype=np.float64),
                                        np.asarray(p.normal, dtype=np.float64), f))
    poses = {n: o.pose() for n, o in world.objects.items() if not o.spec.static} | world.bottle_poses()
    return GroundTruth(world.time if t is None else t, poses, contacts)
