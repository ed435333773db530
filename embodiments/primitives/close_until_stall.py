"""Close until stall: a gripper without tactile pads closes at a limited effort until its jaws stop on an object."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from contactflow.embodiments.primitives.base import Capability, Primitive
from contactflow.embodiments.primitives.hands import ClosingRamp
from contactflow.nodes.status import Event


class CloseUntilStall(Primitive):
    """Close with ``effort`` until the jaws stall held open by an object (the gripper's own grip sensing).

    Grippers without tactile pads (Baxter's, App. A.4) know they hold something when the
    motor stalls before the fingers meet: the grip force is then the effort limit. Closing
    all the way means the object was missed.
    """

    requires = Capability(hand=True)
    events = (Event.SUCCESS, Event.FAILURE, Event.ERROR, Event.GRASP_STABLE)

    @dataclass(frozen=True)
    class Params(Primitive.Params):
        closing_velocity: float = 0.05  # m/s (rad/s for fingers)
        effort: float = 0.5  # 0..1 of the finger force limit: the grip force
        settle: float = 0.3  # s the jaws must stay stalled
        min_opening: float = 0.002  # m (rad) of finger travel short of closed: the jaws meet an object
        timeout: float = 5.0  # s

    def begin(self) -> None:
        spec = self.r.spec.hand(self.hand_name)
        self.closed = np.asarray(spec.preshapes["closed"], dtype=np.float64)
        self.ramp = ClosingRamp(self.hand.positions(), self.closed, self.params.closing_velocity)
        self.since: float | None = None

    def update(self) -> None:
        p = self.params
        self.hand.set_fingers(self.ramp.advance(1.0 / p.rate_hz), effort=p.effort)
        stalled = self.ramp.observe(self.r.time, self.hand.positions())
        opening = float(np.abs(self.hand.positions() - self.closed).sum())
        if stalled and opening >= p.min_opening:
            self.since = self.r.time if self.since is None else self.since
            if self.r.time - self.since >= p.settle:
                self.emit_once(Event.GRASP_STABLE, f"jaws stalled {opening:.4f} open", {"opening": opening})
                self.succeed(opening=opening)
            return
        self.since = None
        if stalled:
            self.fail(f"closed to {opening:.4f} without meeting an object")
        elif self.elapsed > p.timeout:
            self.fail(f"jaws still moving after {p.timeout} s", event=Event.TIMEOUT)
