"""One fusion loop (thesis Algorithm 4.1) for stations and services: offered clouds, a wait-all cycle, contacts, events."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

from contactflow.fusion.condensation import CondensationParams, Contact, condense
from contactflow.fusion.events import ContactEvent, ContactTracker, TrackerParams
from contactflow.fusion.hypotheses import Hypotheses
from contactflow.fusion.integrator import Fused, Integrator, IntegratorParams
from contactflow.nodes.wire import MsgId


@dataclass(frozen=True, slots=True)
class Cycle:
    """What one fusion cycle produced."""

    fused: Fused
    contacts: list[Contact]
    events: list[ContactEvent]


@dataclass
class FusionLoop:
    """Integrator, condensation and event tracker run as one loop.

    A cycle runs when every active source has offered a cloud, or the wait for late ones
    timed out (Algorithm 4.1's wait-all); sources silent for ``drop_after`` s are unplugged.
    When nobody talks any more a cycle still runs while contacts are tracked, so their
    hypotheses expire and the contacts break.
    """

    integrator_params: IntegratorParams = field(default_factory=IntegratorParams)
    condensation: CondensationParams = field(default_factory=CondensationParams)
    tracker_params: TrackerParams = field(default_factory=TrackerParams)
    drop_after: float = math.inf  # s

    def __post_init__(self) -> None:
        self.integrator = Integrator(self.integrator_params)
        self.tracker = ContactTracker(self.tracker_params)
        self._ids: dict[str, MsgId] = {}  # source -> the message its last offered cloud came in

    def offer(self, source: str, cloud: Hypotheses, now: float, robot: str = "", link: str = "",
              msg: MsgId | None = None) -> None:
        """A source's cloud for the next cycle (an empty cloud is a reading too: it feels nothing).

        ``msg`` is the message the cloud came in, named in the ``inputs`` of what it leads to.
        """
        self.integrator.offer(source, cloud, now, robot=robot, link=link)
        if msg is not None:
            self._ids[source] = msg

    def inputs(self, sources: Sequence[str]) -> list[MsgId]:
        """The messages of the last clouds of ``sources`` (an event's, a contact's): their provenance."""
        return [self._ids[s] for s in sources if s in self._ids]

    def step(self, now: float) -> Cycle | None:
        """Run a cycle if one is due; None while the integrator waits for its sources."""
        integ = self.integrator
        for s in list(integ.sources.values()):
            if s.pending is None and s.last_rx < now - self.drop_after:
                integ.unplug(s.name)
        fused = integ.cycle(now)
        if fused is None:
            if integ.active(now) or not self.tracker.tracks:
                return None
            fused = integ.integrate(now)
        contacts = condense(fused, self.condensation)
        return Cycle(fused, contacts, self.tracker.update(contacts, now, fused.columns))

    def retune(self, integrator: IntegratorParams, condensation: CondensationParams, tracker: TrackerParams) -> None:
        """New parameters; a new voxel grid or timing keeps the plugged sources, the space starts empty."""
        if integrator != self.integrator_params:
            sources = self.integrator.sources
            self.integrator = Integrator(integrator)
            for s in sources.values():
                self.integrator.plug(s.name, s.robot, s.link, s.last_rx)
        self.integrator_params, self.condensation, self.tracker_params = integrator, condensation, tracker
        self.tracker.params = tracker
