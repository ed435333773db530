"""Lift (§6.3.6): move the arm upward (world z) by a distance, watching that the grasp holds and the arm follows."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from contactflow.embodiments.primitives.base import Capability, Primitive
from contactflow.nodes.status import Event


class Lift(Primitive):
    """Raise the hand; a grasp that empties on the way (no pad contact, fingers closed) raises GRASP_LOST and fails."""

    requires = Capability()
    events = (Event.SUCCESS, Event.FAILURE, Event.ERROR, Event.GRASP_LOST)

    @dataclass(frozen=True)
    class Params(Primitive.Params):
        distance: float = 0.1  # m, lift height
        velocity: float = 0.05  # m/s
        watch_grasp: bool = True  # fail with GRASP_LOST when the hand empties
        timeout: float = 10.0  # s

    def begin(self) -> None:
        p = self.params
        if p.distance <= 0 or p.velocity <= 0:
            raise ValueError(f"{self.name}: params.distance and params.velocity must be > 0")
        T = self.r.frame_pose(self.ee_frame)
        self.z0 = float(T[2, 3])
        self.goal = T.copy()
        self.goal[2, 3] += p.distance
        self.had_grasp = self.holding()
        self.twist(np.array([0.0, 0.0, p.velocity, 0.0, 0.0, 0.0]))

    def update(self) -> None:
        p = self.params
        lifted = float(self.r.frame_pose(self.ee_frame)[2, 3]) - self.z0
        if p.watch_grasp and self.had_grasp and not self.holding():
            self.emit_once(Event.GRASP_LOST, "the hand emptied while lifting", {"lifted": lifted})
            self.fail("grasp lost", lifted=lifted)
            return
        if lifted >= p.distance:
            self.succeed(lifted=lifted, contacts=len(self.pads_in_contact()))
        elif self.blocked():
            self.relax()
            self.fail(f"blocked after {lifted:.3f} m: the grasped thing does not come up", lifted=lifted)
        elif self.elapsed > p.timeout:
            self.fail(f"lift not finished after {p.timeout} s", event=Event.TIMEOUT, lifted=lifted)
