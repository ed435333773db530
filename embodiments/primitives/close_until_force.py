"""Close until force: close a (parallel) gripper until the pads sense the grip force, then hold it."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from contactflow.embodiments.primitives.base import Capability, Primitive
from contactflow.embodiments.primitives.hands import ClosingRamp
from contactflow.nodes.status import Event


class CloseUntilForce(Primitive):
    """Close the hand slowly until every pad reports ``grip_force``; the grasp for hands without finger corrections."""

    requires = Capability(hand=True, tactile=True)
    events = (Event.SUCCESS, Event.FAILURE, Event.ERROR, Event.GRASP_STABLE)

    @dataclass(frozen=True)
    class Params(Primitive.Params):
        grip_force: float = 5.0  # N per pad (sum of taxel pressures)
        closing_velocity: float = 0.05  # m/s (rad/s for fingers)
        effort: float = 1.0  # 0..1 finger force limit
        timeout: float = 5.0  # s

    def begin(self) -> None:
        spec = self.r.spec.hand(self.hand_name)
        self.closed = np.asarray(spec.preshapes["closed"], dtype=np.float64)
        self.ramp = ClosingRamp(self.hand.positions(), self.closed, self.params.closing_velocity)

    def update(self) -> None:
        p = self.params
        forces = self.pad_forces()
        if forces and min(forces.values()) >= p.grip_force:
            self.hand.set_fingers(self.ramp.target, effort=p.effort)
            vals = {"force": min(forces.values()), "opening": float(np.abs(self.hand.positions()).sum())}
            self.emit_once(Event.GRASP_STABLE, f"pad forces {forces}", vals)
            self.succeed(**vals)
            return
        self.hand.set_fingers(self.ramp.advance(1.0 / p.rate_hz), effort=p.effort)
        stalled = self.ramp.observe(self.r.time, self.hand.positions())
        if self.ramp.reached and stalled:
            self.fail(f"closed without reaching {p.grip_force} N per pad ({forces})")
        elif self.elapsed > p.timeout:
            self.fail(f"grip force not reached after {p.timeout} s", event=Event.TIMEOUT)
