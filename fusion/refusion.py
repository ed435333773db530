"""Re-fusion: the fusion loop run again on recorded hypothesis clouds, and its events compared with the recorded ones.

The thesis tuned its fusion offline on recorded runs; this is that analysis. Two timings:
- the recorded loop's (``cycles``: the fused contact lists it published, one per cycle): the
  loop steps when the recorded one did and takes each cloud in the cycle that took it (the
  first whose ``inputs`` name it), so the recorded parameters reproduce the recorded events
  even where a loaded machine delayed clouds and cycles; for what other condensation,
  tracking or generator weights would have made;
- a regular grid: clouds offered at the time their producer stamped them (``hdr.t_sim``) and
  the loop stepped every ``1 / rate_hz`` s, as an unloaded fusion module does; for another
  rate or timeouts, whose cycles the recorded ones are not.
"""

from __future__ import annotations

import dataclasses
import math
from bisect import bisect_left
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from contactflow.fusion.hypotheses import Hypotheses
from contactflow.fusion.loop import FusionLoop
from contactflow.fusion.messages import ContactEventMsg, ContactList, HypothesisCloud
from contactflow.fusion.service import FusionParams
from contactflow.nodes.status import Event
from contactflow.nodes.wire import MsgId


@dataclass(frozen=True)
class EventRecord:
    """A contact event, recorded or re-fused, reduced to what is compared."""

    event: Event
    t: float  # s, on the fusion's clock
    location: tuple[float, float, float]  # m, world
    robot: str = ""
    link: str = ""

    @classmethod
    def of(cls, msg: ContactEventMsg) -> EventRecord:
        x, y, z = msg.location
        return cls(msg.event, msg.t, (x, y, z), msg.robot, msg.link)


def _weighted(cloud: Hypotheses, w: float) -> Hypotheses:
    if w == 1.0:
        return cloud
    return dataclasses.replace(cloud, likelihood=np.clip(cloud.likelihood * w, 0.0, 1.0))


def refuse(clouds: Iterable[HypothesisCloud], params: FusionParams,
           weights: Mapping[str, float] | None = None,
           cycles: Sequence[ContactList] | None = None) -> list[EventRecord]:
    """The events the fusion with ``params`` makes from ``clouds`` (in any order).

    ``weights``: generator name -> factor on its hypotheses' likelihood (1 when not named).
    ``cycles``: the recorded fusion's contact lists, to step on its timing (module docstring);
    None or empty: a regular grid.
    """
    params.validate()
    weights = dict(weights or {})
    for g, w in weights.items():
        if not (math.isfinite(w) and w >= 0):
            raise ValueError(f"weight of generator {g!r}: {w!r} is not a finite number >= 0")
    ordered = sorted(clouds, key=lambda c: c.hdr.t_sim)
    if not ordered:
        return []
    steps = _recorded_steps(ordered, cycles) if cycles else _grid_steps(ordered, params)
    loop = FusionLoop(params.integrator(), params.condensation(), params.tracker(), drop_after=params.drop_after)
    out: list[EventRecord] = []
    for now, taken in steps:
        for c in taken:
            loop.offer(c.source, _weighted(c.hypotheses(), weights.get(c.generator, 1.0)), now,
                       robot=c.robot, link=c.link, msg=c.hdr.id)
        cycle = loop.step(now)
        if cycle is not None:
            out += [EventRecord(e.event, e.t, tuple(float(v) for v in np.asarray(e.location)), e.robot, e.link)
                    for e in cycle.events]
    return out


def _grid_steps(ordered: list[HypothesisCloud], params: FusionParams) -> Iterable[tuple[float, list[HypothesisCloud]]]:
    """Every ``1 / rate_hz`` s from the first cloud, each with the clouds stamped since the step before."""
    dt = 1.0 / params.rate_hz
    t0 = ordered[0].hdr.t_sim
    end = ordered[-1].hdr.t_sim + params.timeout + params.hold + params.wait_timeout + 4 * dt
    i, k = 0, 0
    while True:
        now = t0 + k * dt
        if now > end and i >= len(ordered):
            return
        j = i
        while j < len(ordered) and ordered[j].hdr.t_sim <= now:
            j += 1
        yield now, ordered[i:j]
        i, k = j, k + 1


def _recorded_steps(ordered: list[HypothesisCloud],
                    cycles: Sequence[ContactList]) -> list[tuple[float, list[HypothesisCloud]]]:
    """The recorded cycles, each with the clouds it took. A cloud no cycle names was replaced before a cycle ran
    (two came between cycles): it goes with the next cloud of its source that one names; with none, to the first
    cycle at or after its stamp. Clouds after the last cycle were never fused."""
    recorded = sorted(cycles, key=lambda c: c.stamp)
    times = [c.stamp for c in recorded]
    first: dict[MsgId, int] = {}
    for k, c in enumerate(recorded):
        for m in c.hdr.inputs:
            first.setdefault(m, k)
    taken: list[list[HypothesisCloud]] = [[] for _ in recorded]
    by_source: dict[str, list[HypothesisCloud]] = {}
    for c in ordered:
        by_source.setdefault(c.source, []).append(c)
    for mine in by_source.values():
        mine.sort(key=lambda c: c.hdr.seq)
        later: int | None = None
        for c in reversed(mine):
            k = first.get(c.hdr.id)
            if k is not None:
                later = k
            elif later is not None:
                k = later
            else:
                k = bisect_left(times, c.hdr.t_sim)
            if k < len(recorded):
                taken[k].append(c)
    return [(t, sorted(cs, key=lambda c: c.hdr.t_sim)) for t, cs in zip(times, taken, strict=True)]


@dataclass
class Comparison:
    """Recorded events against re-fused ones: matched pairs, timing and location differences."""

    recorded: dict[str, int]  # event kind -> count
    refused: dict[str, int]  # event kind -> count
    matched: int = 0  # pairs of one kind within the time and distance windows
    dt_mean: float = 0.0  # s, mean |t_refused - t_recorded| of matched pairs
    dt_max: float = 0.0  # s
    dist_mean: float = 0.0  # m, mean location difference of matched pairs
    dist_max: float = 0.0  # m
    unmatched_recorded: list[EventRecord] = field(default_factory=list)
    unmatched_refused: list[EventRecord] = field(default_factory=list)

    def as_dict(self) -> dict[str, object]:
        return {"recorded": self.recorded, "refused": self.refused, "matched": self.matched,
                "dt_mean": self.dt_mean, "dt_max": self.dt_max, "dist_mean": self.dist_mean, "dist_max": self.dist_max,
                "unmatched_recorded": len(self.unmatched_recorded), "unmatched_refused": len(self.unmatched_refused)}


def _counts(events: list[EventRecord]) -> dict[str, int]:
    out: dict[str, int] = {}
    for e in events:
        out[e.event.value] = out.get(e.event.value, 0) + 1
    return out


def compare(recorded: list[EventRecord], refused: list[EventRecord], window: float = 0.1,
            radius: float = 0.03, offset: float = 0.0) -> Comparison:
    """Pair each recorded event with the nearest-in-time re-fused event of its kind.

    A pair is within ``window`` s and ``radius`` m; ``offset`` s is subtracted from the
    re-fused times (a replay runs on another clock).
    """
    free = sorted(refused, key=lambda e: e.t)
    used = [False] * len(free)
    dts, dists, missing = [], [], []
    for r in sorted(recorded, key=lambda e: e.t):
        best, best_dt = -1, window
        for j, f in enumerate(free):
            if used[j] or f.event != r.event:
                continue
            dt = abs(f.t - offset - r.t)
            if dt <= best_dt and math.dist(f.location, r.location) <= radius:
                best, best_dt = j, dt
        if best < 0:
            missing.append(r)
            continue
        used[best] = True
        dts.append(best_dt)
        dists.append(math.dist(free[best].location, r.location))
    return Comparison(_counts(recorded), _counts(refused), len(dts),
                      float(np.mean(dts)) if dts else 0.0, max(dts, default=0.0),
                      float(np.mean(dists)) if dists else 0.0, max(dists, default=0.0),
                      missing, [f for j, f in enumerate(free) if not used[j]])
