"""Look-ahead (thesis §5.5): run a primitive in a copy of the predicted world, faster than real time, and say what it did.

A :class:`Snapshot` is what a predictor holds now: the robot's embodiment, base and joints,
its arms' commanded joints, and every object of its belief at its predicted pose. From it
:func:`look_ahead` builds a fresh SAPIEN world, hosts the primitive on an in-process runner
around it (as a node would, over the same modules) and runs it to its outcome or for
``horizon`` s, then reports the primitive's events and how each object moved, turned and
whether the robot touched it ("will this transport knock the bottle over?").
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

FELL = 0.5  # rad an object's up axis turns before it counts as knocked over


@dataclass(frozen=True)
class Snapshot:
    robot: str  # the robot's name
    embodiment: str  # its registry name
    base: np.ndarray  # (4, 4) world pose of its base
    control_rate: float  # Hz of the world's ticks
    q: np.ndarray  # every joint, in the simulation's order
    q_cmd: Mapping[str, np.ndarray]  # arm -> its commanded joints
    objects: tuple[tuple[Any, np.ndarray], ...]  # (ObjectSpec, (4, 4) predicted pose) of the belief, fixtures too


@dataclass(frozen=True)
class Outcome:
    outcome: str  # success | failure | error | timeout
    duration: float  # s of simulated time
    wall: float  # s of wall time, building included
    events: tuple[tuple[float, str, str], ...]  # (t from the start, event, detail)
    objects: tuple[str, ...]  # the movable objects
    moved: tuple[float, ...]  # m, per object
    tilted: tuple[float, ...]  # rad, per object
    touched: tuple[str, ...]  # objects the robot touched


def look_ahead(snap: Snapshot, primitive: str, params: Mapping[str, Any], horizon: float) -> Outcome:
    """Run ``primitive`` with ``params`` from ``snap`` for at most ``horizon`` s of simulated time."""
    from contactflow.embodiments.primitives.runner import LocalPrimitiveRunner, run_primitive
    from contactflow.embodiments.sensors.ground_truth import body_name
    from contactflow.embodiments.sim_robot import SimRobot, SimRobotParams
    from contactflow.embodiments.world import World, WorldParams

    began = time.perf_counter()
    world = World(WorldParams(camera_backend="raycast"))
    for spec, T in snap.objects:
        if spec.static:
            world.add_object(spec).set_pose(T)
    sim = SimRobot(world, snap.embodiment, name=snap.robot, base=snap.base,
                   params=SimRobotParams(control_rate=snap.control_rate))
    sim.art.set_state(snap.q)
    sim.mixer.hold(snap.q)
    for arm, q in snap.q_cmd.items():
        sim.arm(arm).stream(q, np.zeros(len(q)))
    movable = []
    for spec, T in snap.objects:  # after the robot's settling: a held object would have fallen meanwhile
        if not spec.static:
            obj = world.add_object(spec)
            obj.set_pose(T)
            movable.append((obj, T))
    names = {obj.name for obj, _ in movable}
    touched: set[str] = set()
    own = f"{snap.robot}/"

    def watch(w: World) -> None:
        for c in w.contacts():
            a, b = body_name(c.bodies[0]), body_name(c.bodies[1])
            if a.startswith(own) and b in names:
                touched.add(b)
            elif b.startswith(own) and a in names:
                touched.add(a)

    world.add_hook(watch)
    t0, times = sim.time, []
    events = run_primitive(LocalPrimitiveRunner(sim), primitive, dict(params), max_time=horizon, times=times)
    final = events[-1].event if events else "timeout"
    moved, tilted = [], []
    for obj, T in movable:
        now = obj.pose()
        moved.append(float(np.linalg.norm(now[:3, 3] - T[:3, 3])))
        tilted.append(float(np.arccos(np.clip(now[:3, 2] @ T[:3, 2], -1.0, 1.0))))
    return Outcome(str(final), sim.time - t0, time.perf_counter() - began,
                   tuple((t, str(e.event), str(e.detail)) for t, e in zip(times, events, strict=True)),
                   tuple(obj.name for obj, _ in movable), tuple(moved), tuple(tilted), tuple(sorted(touched)))
