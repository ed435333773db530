"""Contact event tracker (thesis §4, ch. 3): condensed contacts in, made / broken events out.

Contacts of consecutive cycles are associated by distance (greedy, most likely first, within
``match_radius``). A contact seen for ``confirm`` consecutive cycles is *made*; a made contact
not seen for ``hold`` seconds is *broken*. Tracks keep a stable id, the robot and link of the
contact and a smoothed location, so a task can react to "contact made on the thumb".
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from contactflow.fusion.condensation import Contact
from contactflow.nodes.status import Event


@dataclass(frozen=True)
class TrackerParams:
    match_radius: float = 0.03  # m, a contact this close to a track continues it
    confirm: int = 1  # cycles a contact must be seen before it is made
    hold: float = 0.1  # s, a made contact unseen this long is broken
    smoothing: float = 0.5  # weight of the new location in the track's location

    def validate(self) -> None:
        if not self.match_radius > 0:
            raise ValueError(f"match_radius={self.match_radius} must be > 0")
        if self.confirm < 1:
            raise ValueError(f"confirm={self.confirm} must be >= 1")
        if self.hold < 0:
            raise ValueError(f"hold={self.hold} must be >= 0")
        if not 0.0 < self.smoothing <= 1.0:
            raise ValueError(f"smoothing={self.smoothing} must lie in (0, 1]")


@dataclass
class Track:
    id: int
    location: np.ndarray
    robot: str
    link: str
    likelihood: float
    seen: int = 1
    last_seen: float = 0.0
    made: bool = False
    sources: tuple[str, ...] = ()  # the fusion sources behind it when last seen
    sigma: float = 0.0  # m, its voxels' spread when last seen


@dataclass(frozen=True)
class ContactEvent:
    event: Event  # CONTACT_MADE or CONTACT_BROKEN
    id: int
    robot: str
    link: str
    location: np.ndarray
    likelihood: float
    t: float
    sources: tuple[str, ...] = ()  # the fusion sources (robot/generator) behind the contact
    sigma: float = 0.0  # m, the contact's voxels' spread when last seen


@dataclass
class ContactTracker:
    params: TrackerParams = field(default_factory=TrackerParams)

    def __post_init__(self) -> None:
        self.params.validate()
        self.tracks: list[Track] = []
        self._next_id = 1

    @property
    def made(self) -> list[Track]:
        return [t for t in self.tracks if t.made]

    def update(self, contacts: list[Contact], now: float, columns: Sequence[str] = ()) -> list[ContactEvent]:
        """Associate this cycle's contacts with the tracks; the events they cause.

        ``columns`` names the bits of each contact's ``sources`` (the fused cloud's columns).
        """
        p = self.params
        events: list[ContactEvent] = []
        free = list(range(len(self.tracks)))
        for c in sorted(contacts, key=lambda c: -c.likelihood):
            best, best_d = -1, p.match_radius
            for i in free:
                d = float(np.linalg.norm(self.tracks[i].location - c.location))
                if d <= best_d:
                    best, best_d = i, d
            sources = tuple(n for i, n in enumerate(columns) if n and (c.sources >> i) & 1)
            if best < 0:
                self.tracks.append(Track(self._next_id, np.array(c.location, dtype=float), c.robot, c.link,
                                         c.likelihood, last_seen=now, sources=sources, sigma=c.sigma))
                self._next_id += 1
                track = self.tracks[-1]
            else:
                free.remove(best)
                track = self.tracks[best]
                track.location = (1 - p.smoothing) * track.location + p.smoothing * np.asarray(c.location)
                track.seen += 1
                track.last_seen, track.likelihood = now, c.likelihood
                track.robot, track.link = c.robot or track.robot, c.link or track.link
                track.sources, track.sigma = sources or track.sources, c.sigma
            if not track.made and track.seen >= p.confirm:
                track.made = True
                events.append(self._event(Event.CONTACT_MADE, track, now))
        keep: list[Track] = []
        for i, t in enumerate(self.tracks):
            unseen = i in free
            if unseen and not t.made:
                continue  # a candidate must be seen in consecutive cycles
            if unseen and now - t.last_seen >= p.hold:
                events.append(self._event(Event.CONTACT_BROKEN, t, now))
                continue
            keep.append(t)
        self.tracks = keep
        return events

    def reset(self, now: float | None = None) -> list[ContactEvent]:
        """Forget every track; with ``now``, made contacts are reported broken."""
        events = [self._event(Event.CONTACT_BROKEN, t, now) for t in self.made] if now is not None else []
        self.tracks = []
        return events

    @staticmethod
    def _event(kind: Event, t: Track, now: float) -> ContactEvent:
        return ContactEvent(kind, t.id, t.robot, t.link, t.location.copy(), t.likelihood, now, t.sources, t.sigma)
