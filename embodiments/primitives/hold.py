"""Hold (§6.3.6): keep the fingers closed at the desired force and watch the grasp (raises GRASP_LOST)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from contactflow.embodiments.primitives.base import Capability, Primitive
from contactflow.nodes.status import Event


class Hold(Primitive):
    """Keep squeezing with ``effort``; runs for ``duration`` s (0: until stopped) unless the grasp is lost."""

    requires = Capability(hand=True, tactile=True)
    events = (Event.SUCCESS, Event.FAILURE, Event.ERROR, Event.GRASP_LOST, Event.GRASP_STABLE)
    commands_arm = False  # the fingers only: it runs beside the transport that carries what it holds

    @dataclass(frozen=True)
    class Params(Primitive.Params):
        effort: float = 1.0  # 0..1 finger force limit (when ``force`` is 0)
        force: float = 0.0  # N, squeeze each finger drive gives (0: ``effort``); sets the effort to give it
        duration: float = 0.0  # s, 0 = until stopped
        min_contacts: int = 1  # pads that must stay in contact (or fingers held open by the object)
        grace: float = 0.2  # s a loss must last to count (debounce)

    def begin(self) -> None:
        spec = self.r.spec.hand(self.hand_name)
        p = self.params
        effort = p.effort if p.force <= 0 else min(1.0, p.force / spec.force_limit)
        self.hand.set_fingers(np.asarray(spec.preshapes["closed"], dtype=np.float64), effort=effort)
        self.lost_since: float | None = None
        self.stable_sent = False

    def update(self) -> None:
        p = self.params
        n = len(self.pads_in_contact())
        if n >= p.min_contacts or self.holding():
            self.lost_since = None
            if not self.stable_sent:
                self.stable_sent = True
                self.emit_once(Event.GRASP_STABLE, f"{n} pads in contact", {"contacts": float(n)})
        else:
            self.lost_since = self.r.time if self.lost_since is None else self.lost_since
            if self.r.time - self.lost_since >= p.grace:
                self.emit_once(Event.GRASP_LOST, f"only {n} pads in contact", {"contacts": float(n)})
                self.fail("grasp lost", contacts=n)
                return
        if p.duration > 0 and self.elapsed >= p.duration:
            self.succeed(contacts=n)
