"""Contact hypotheses integrator (thesis §4.6.1, Alg. 4.1): fuse generator clouds per cycle.

One fusion cycle waits until every active source has delivered a cloud (from faster sources
the newest one is used), writes each cloud into that source's column of the hypothesis space
(a voxel already holding another source's hypothesis is fused with it, a voxel holding an
older hypothesis of the same source gets the newer one), discards entries older than the
timeout and computes the fused likelihood of every voxel with the noisy-OR of eq. 4.14.
Voxels whose only evidence is support hypotheses are left out, and any voxel with a null
hypothesis is vetoed. Force magnitude and direction are averaged weighted by likelihood over
the hypotheses that carry a force.
Sources may be plugged and unplugged at any time. Hashing, writing and the fused pass are
compiled loops over voxels (:mod:`~contactflow.fusion.kernels`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from contactflow.fusion import kernels
from contactflow.fusion.hypotheses import VOXEL_SIZE, Hypotheses, HypothesisSpace


@dataclass(frozen=True)
class IntegratorParams:
    voxel_size: float = VOXEL_SIZE  # m, hypothesis space resolution (thesis §4.7: 5 mm)
    timeout: float = 0.5  # s, a source's hypothesis is discarded when older than this
    wait_timeout: float = 0.25  # s, a cycle stops waiting for a late source after this
    source_timeout: float = 2.0  # s, a source silent this long is no longer waited for
    auto_plug: bool = True  # plug unknown sources on their first cloud

    def validate(self) -> None:
        for name in ("voxel_size", "timeout", "wait_timeout", "source_timeout"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name}={getattr(self, name)} must be > 0")


@dataclass
class Source:
    """A plugged generator: its column in the space and its latest undelivered cloud."""

    name: str
    col: int
    robot: str = ""
    link: str = ""
    last_rx: float = -np.inf
    pending: Hypotheses | None = None
    pending_since: float = np.inf


@dataclass
class Fused:
    """Fused hypotheses H(x) = p(c | x, g1..gn) of the voxels that survive the type rules."""

    location: np.ndarray  # (k, 3) voxel centres, m, world frame
    likelihood: np.ndarray  # (k,) noisy-OR of the sources (eq. 4.14)
    force: np.ndarray  # (k,) N, likelihood-weighted mean
    direction: np.ndarray  # (k, 3) likelihood-weighted mean unit direction
    sources: np.ndarray  # (k,) uint64 bitmask of contributing columns
    per_source: np.ndarray  # (k, S) likelihood of each column (0 where absent)
    columns: list[str]  # source name of each column ("" for free columns)
    robots: list[str]  # robot of each column
    links: list[str]  # link of each column
    stamp: float
    vetoed: int = 0  # voxels removed by null hypotheses this cycle
    unsupported: int = 0  # voxels with support hypotheses only, left out this cycle

    def __len__(self) -> int:
        return int(self.location.shape[0])

    @classmethod
    def empty(cls, stamp: float = 0.0, ncol: int = 0) -> Fused:
        return cls(np.zeros((0, 3)), np.zeros(0), np.zeros(0), np.zeros((0, 3)), np.zeros(0, dtype=np.uint64),
                   np.zeros((0, ncol)), [""] * ncol, [""] * ncol, [""] * ncol, stamp)


@dataclass
class Integrator:
    """The pure integrator: plug sources, offer clouds, run cycles."""

    params: IntegratorParams = field(default_factory=IntegratorParams)

    def __post_init__(self) -> None:
        self.params.validate()
        self.space = HypothesisSpace(self.params.voxel_size)
        self.sources: dict[str, Source] = {}
        self.cycles = 0

    # -- sources -----------------------------------------------------------------------
    def plug(self, name: str, robot: str = "", link: str = "", now: float | None = None) -> Source:
        """Add a source (idempotent); it gets the lowest free column."""
        src = self.sources.get(name)
        if src is not None:
            src.robot, src.link = robot or src.robot, link or src.link
            return src
        used = {s.col for s in self.sources.values()}
        col = next(c for c in range(HypothesisSpace.MAX_SOURCES + 1) if c not in used)
        if col >= HypothesisSpace.MAX_SOURCES:
            raise ValueError(f"integrator: cannot plug {name!r}, all {HypothesisSpace.MAX_SOURCES} columns in use")
        self.space.ensure_column(col)
        self.space.clear_column(col)
        src = Source(name, col, robot, link, last_rx=-np.inf if now is None else now)
        self.sources[name] = src
        return src

    def unplug(self, name: str) -> None:
        """Remove a source and every hypothesis it contributed."""
        src = self.sources.pop(name, None)
        if src is None:
            raise KeyError(f"integrator: source {name!r} is not plugged (plugged: {sorted(self.sources)})")
        self.space.clear_column(src.col)
        self.space.compact()

    def active(self, now: float) -> list[Source]:
        """Sources the next cycle waits for: plugged and heard from within ``source_timeout``."""
        limit = now - self.params.source_timeout
        return [s for s in self.sources.values() if s.last_rx >= limit or s.pending is not None]

    def offer(self, name: str, cloud: Hypotheses, now: float, robot: str = "", link: str = "") -> None:
        """Hand a cloud to the integrator; a newer cloud of the same source replaces a pending one, unless it is empty."""
        src = self.sources.get(name)
        if src is None:
            if not self.params.auto_plug:
                raise KeyError(f"integrator: cloud from unplugged source {name!r}")
            src = self.plug(name, robot, link, now)
        elif robot or link:
            src.robot, src.link = robot or src.robot, link or src.link
        if src.pending is None:
            src.pending_since = now
        # an empty cloud adds nothing to the space (older hypotheses stay until they expire), so it keeps a
        # pending one: a brief touch one source felt while the cycle waited for another is not dropped unseen
        if len(cloud) or src.pending is None:
            src.pending = cloud
        src.last_rx = now

    # -- cycle -------------------------------------------------------------------------
    def ready(self, now: float) -> bool:
        """True when every active source has delivered, or the wait for late ones timed out."""
        active = self.active(now)
        waiting = [s for s in active if s.pending is not None]
        if not waiting:
            return False
        if len(waiting) == len(active):
            return True
        return now - min(s.pending_since for s in waiting) >= self.params.wait_timeout

    def cycle(self, now: float) -> Fused | None:
        """Run one fusion cycle if :meth:`ready`, else None."""
        if not self.ready(now):
            return None
        return self.integrate(now)

    def integrate(self, now: float) -> Fused:
        """Write every pending cloud into the space, expire old entries and fuse."""
        space = self.space
        for src in self.sources.values():
            cloud = src.pending
            if cloud is None:
                continue
            src.pending, src.pending_since = None, np.inf
            if len(cloud) == 0:
                continue
            space.put(src.col, cloud)
        self.cycles += 1
        return self.fuse(now)

    def fuse(self, now: float) -> Fused:
        """Noisy-OR fusion (eq. 4.14) of the space, applying the type rules, after expiring the
        entries older than the timeout."""
        space = self.space
        n = space.n
        ncol = max((s.col for s in self.sources.values()), default=-1) + 1
        names, robots, links = [""] * ncol, [""] * ncol, [""] * ncol
        for s in self.sources.values():
            names[s.col], robots[s.col], links[s.col] = s.name, s.robot, s.link
        if n == 0 or ncol == 0:
            return Fused.empty(now, ncol)
        out, bits, vetoed, unsupported, live = space.fuse(ncol, now - self.params.timeout)
        space.compact(live_rows=live)
        # the fields are views of the pass's rows (kernels.fuse_rows)
        return Fused(location=out[:, 0:3], likelihood=out[:, 3], force=out[:, 4], direction=out[:, 5:8], sources=bits,
                     per_source=out[:, kernels.OUT_SOURCES:], columns=names, robots=robots, links=links, stamp=now,
                     vetoed=vetoed, unsupported=unsupported)

    def reset(self) -> None:
        """Empty the space; sources stay plugged."""
        self.space = HypothesisSpace(self.params.voxel_size)
        for s in self.sources.values():
            s.pending, s.pending_since = None, np.inf
            self.space.ensure_column(s.col)
