"""Wait event (§6.3.6 auxiliary): wait for a sensed condition (grasp lost/stable, contact, motion) or a delay."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from contactflow.embodiments.primitives.base import Primitive
from contactflow.nodes.status import Event


class WaitEvent(Primitive):
    """Emits ``event`` when its condition holds: grasp_lost / grasp_stable (pads and finger joints), contact (F/T), or after ``delay``.

    Used as a helper next to another primitive (e.g. watch for GRASP_LOST while transporting)
    or alone as a delay (``event: success``). ``finish`` ends the primitive with SUCCESS when the
    event fired; otherwise it keeps running and emits once.
    """

    events = (Event.SUCCESS, Event.FAILURE, Event.ERROR, Event.GRASP_LOST, Event.GRASP_STABLE, Event.CONTACT)
    commands_arm = False

    @dataclass(frozen=True)
    class Params(Primitive.Params):
        event: str = "success"  # grasp_lost | grasp_stable | contact | success (= plain delay)
        delay: float = 0.0  # s before the condition is checked (the whole wait for "success")
        force_threshold: float = 5.0  # N, for "contact"
        finish: bool = True  # end with SUCCESS after the event
        grace: float = 0.2  # s a tactile condition must hold

    def begin(self) -> None:
        try:
            self.event = Event(self.params.event)
        except ValueError:
            raise ValueError(f"{self.name}: params.event {self.params.event!r} is not an event") from None
        if self.event not in (Event.GRASP_LOST, Event.GRASP_STABLE, Event.CONTACT, Event.SUCCESS):
            raise ValueError(f"{self.name}: cannot wait for {self.event} (grasp_lost, grasp_stable, contact, success)")
        self.f0 = self.wrench_in("world")[:3] if self.event is Event.CONTACT else np.zeros(3)
        self.since: float | None = None
        self.fired = False

    def holds(self) -> bool:
        if self.event is Event.SUCCESS:
            return True
        if self.event is Event.CONTACT:
            return bool(np.linalg.norm(self.wrench_in("world")[:3] - self.f0) > self.params.force_threshold)
        held = self.holding()
        return not held if self.event is Event.GRASP_LOST else held

    def update(self) -> None:
        p = self.params
        if self.elapsed < p.delay or self.fired:
            return
        if self.holds():
            self.since = self.r.time if self.since is None else self.since
            if self.r.time - self.since >= (0.0 if self.event in (Event.SUCCESS, Event.CONTACT) else p.grace):
                self.fired = True
                if self.event is not Event.SUCCESS:
                    self.emit_once(self.event, f"{self.event} observed")
                if p.finish:
                    self.succeed(waited=self.elapsed)
        else:
            self.since = None
