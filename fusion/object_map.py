"""Object map: where fused contacts have touched things in a region, kept after the touch (a map of objects found by contact)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class ObjectMapParams:
    region: tuple[float, ...] = ()  # m, world box [xmin, ymin, zmin, xmax, ymax, zmax] whose touched things are objects; (): no map
    merge: float = 0.04  # m, a contact this close to an object's estimate is on that object
    memory: int = 8  # touches an estimate averages (the latest ones)

    def validate(self) -> None:
        if self.region and (len(self.region) != 6 or any(lo >= hi for lo, hi in zip(self.region[:3], self.region[3:], strict=True))):
            raise ValueError(f"map_region: expected [xmin, ymin, zmin, xmax, ymax, zmax] with min < max, got {list(self.region)}")
        if self.merge <= 0 or self.memory < 1:
            raise ValueError(f"map_merge={self.merge} must be > 0 m and map_memory={self.memory} >= 1")


@dataclass
class MappedObject:
    """One object the contacts found: its estimated location and who touched and claimed it."""

    id: int
    location: np.ndarray  # m, world
    sightings: int = 0  # fusion cycles in which a contact lay on it
    touched: dict[str, float] = field(default_factory=dict)  # robot -> s, its last touch
    claims: int = 0  # claims since its last touch
    touches: list[np.ndarray] = field(default_factory=list)  # m, where its past touches lay (the mean of each)
    first: np.ndarray | None = None  # m, the touch under way (None: none): its first contact,
    last: np.ndarray | None = None  # its latest,
    total: np.ndarray | None = None  # the sum of its contacts, one per cycle,
    count: int = 0  # and their number
    carried: bool = False  # the touch under way moved it: a hand carries it

    def sighted(self, c: np.ndarray, moved: float) -> None:
        """A contact on it this cycle: the touch under way goes on (or begins); moved farther than ``moved`` m from
        where it began, it is carried, and where it was before says nothing."""
        if self.first is None:
            self.first, self.total, self.count = c, np.zeros(3), 0
        self.last, self.total, self.count = c, self.total + c, self.count + 1
        if np.linalg.norm(c - self.first) > moved:
            self.touches, self.carried = [], True

    def ended(self, memory: int) -> None:
        """No contact on it this cycle: the touch under way (if any) ended, where a carried object was let go."""
        if self.first is not None:
            self.touches = [*self.touches, self.current()][-memory:]
            self.first, self.last, self.total, self.count, self.carried = None, None, None, 0, False

    def current(self) -> np.ndarray:
        assert self.last is not None and self.total is not None
        return self.last if self.carried else self.total / self.count

    def estimate(self, memory: int) -> np.ndarray:
        """Where it is: carried, its latest contact; else the mean of its last ``memory`` touches (the one under
        way, the mean of its contacts so far, counted once)."""
        if self.carried:
            return self.current()
        return np.mean([*self.touches, *([self.current()] if self.first is not None else [])][-memory:], axis=0)


class ObjectMap:
    """Touched objects of a region, from the contacts of every fusion cycle.

    A contact inside the region and farther than ``merge`` from every estimate starts an object;
    one within ``merge`` of an estimate is a sighting of it. The cycles in a row with sightings of
    an object are one touch, and the estimate is the mean of its last ``memory`` touches, each the
    mean of its sightings: a touch held for many cycles weighs as much as a brief one (counted per
    cycle, the last touches of melfa's poke grid outweighed the others: 2.3-2.9 cm off the can's
    centre, 0.7-1.6 cm counted per touch).
    A touch whose sightings move farther than ``merge`` from its first is a hand carrying the
    object: the estimate follows its latest sighting, and the object is dropped once it left the
    region (taken away). A robot *claims* an object before it goes for it: the claims since its
    last touch tell the robots how often a hand went for it and found nothing there.
    """

    def __init__(self, params: ObjectMapParams) -> None:
        params.validate()
        self.params = params
        self.objects: list[MappedObject] = []
        self._next = 1
        self._lo, self._hi = np.asarray(params.region[:3]), np.asarray(params.region[3:])

    def inside(self, p: np.ndarray) -> bool:
        return bool(np.all(p >= self._lo) and np.all(p <= self._hi))

    def touch(self, locations: list[np.ndarray], robots: list[str], now: float) -> None:
        """One fusion cycle's contacts (world locations and the robots they touch)."""
        p = self.params
        seen: dict[int, list[np.ndarray]] = {}
        for loc, robot in zip(locations, robots, strict=True):
            c = np.asarray(loc, dtype=np.float64)
            near = min(self.objects, key=lambda o: float(np.linalg.norm(o.location - c)), default=None)
            if near is not None and np.linalg.norm(near.location - c) <= p.merge:
                seen.setdefault(near.id, []).append(c)
                near.touched[robot] = now
                near.claims = 0
            elif self.inside(c):
                self.objects.append(MappedObject(self._next, c, touched={robot: now}))
                seen[self._next] = [c]
                self._next += 1
        for o in self.objects:
            if o.id in seen:  # several contacts on it in one cycle: their mean
                o.sightings += 1
                o.sighted(np.mean(seen[o.id], axis=0), p.merge)
            else:
                o.ended(p.memory)
            o.location = o.estimate(p.memory)
        self.objects = [o for o in self.objects if self.inside(o.location)]
        self._merge()

    def _merge(self) -> None:
        """Two estimates that came within ``merge`` are one object (touches on its two sides), under the older id."""
        keep: list[MappedObject] = []
        for o in sorted(self.objects, key=lambda o: o.id):
            into = next((k for k in keep if np.linalg.norm(k.location - o.location) <= self.params.merge), None)
            if into is None:
                keep.append(o)
                continue
            # its touches join the older object's, and a touch under way on it goes on as the older's
            if o.first is not None:
                into.ended(self.params.memory)
                into.first, into.last, into.total, into.count, into.carried = o.first, o.last, o.total, o.count, o.carried
            into.touches = [*into.touches, *o.touches][-self.params.memory:]
            into.location = into.estimate(self.params.memory)
            into.sightings += o.sightings
            into.touched = {r: max(into.touched.get(r, t), o.touched.get(r, t)) for r, t in (into.touched | o.touched).items()}
            into.claims = min(into.claims, o.claims)
        self.objects = keep

    def claim(self, object_id: int) -> bool:
        """A robot goes for ``object_id``; False if the map has no such object (any more)."""
        o = next((o for o in self.objects if o.id == object_id), None)
        if o is not None:
            o.claims += 1
        return o is not None
