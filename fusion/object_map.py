"""Object map: where fused contacts have touched things in a region, kept after the touch (a map of objects found by contact)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class ObjectMapParams:
    region: tuple[float, ...] = ()  # m, world box [xmin, ymin, zmin, xmax, ymax, zmax] whose touched things are objects; (): no map
    merge: float = 0.04  # m, a contact this close to an object's estimate is on that object
    memory: int = 8  # an estimate moves 1/min(sightings, memory) of the way to each sighting: a carried object is followed

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


class ObjectMap:
    """Touched objects of a region, from the contacts of every fusion cycle.

    A contact inside the region and farther than ``merge`` from every estimate starts an object;
    one within ``merge`` of an estimate is a sighting of it, and the estimate moves 1/n of the way
    to it, n its sightings up to ``memory`` (the mean of its first sightings, then a moving
    average), so an object a hand carries is followed, and dropped once it left the region (taken
    away). A robot *claims* an object before it goes for it: the claims
    since its last touch tell the robots how often a hand went for it and found nothing there.
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
        for loc, robot in zip(locations, robots, strict=True):
            c = np.asarray(loc, dtype=np.float64)
            near = min(self.objects, key=lambda o: float(np.linalg.norm(o.location - c)), default=None)
            if near is not None and np.linalg.norm(near.location - c) <= p.merge:
                near.sightings += 1
                near.location = near.location + (c - near.location) / min(near.sightings, p.memory)
                near.touched[robot] = now
                near.claims = 0
            elif self.inside(c):
                self.objects.append(MappedObject(self._next, c, 1, {robot: now}))
                self._next += 1
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
            n = into.sightings + o.sightings
            into.location = (into.location * into.sightings + o.location * o.sightings) / n
            into.sightings = n
            into.touched = {r: max(into.touched.get(r, t), o.touched.get(r, t)) for r, t in (into.touched | o.touched).items()}
            into.claims = min(into.claims, o.claims)
        self.objects = keep

    def claim(self, object_id: int) -> bool:
        """A robot goes for ``object_id``; False if the map has no such object (any more)."""
        o = next((o for o in self.objects if o.id == object_id), None)
        if o is not None:
            o.claims += 1
        return o is not None
