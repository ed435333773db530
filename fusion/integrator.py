"""Contact hypotheses integrator (thesis §4.6.1, Alg. 4.1): fuse generator clouds per cycle.

One fusion cycle waits until every active source has delivered a cloud (from faster sources
the newest one is used), writes each cloud into that source's column of the hypothesis space
(a voxel already holding another source's hypothesis is fused with it, a voxel holding an
older hypothesis of the same source gets the newer one), discards entries older than the
timeout and computes the fused likelihood of every voxel with the noisy-OR of eq. 4.14.
Voxels whose only evidence is support hypotheses are left out, and any voxel with a null
hypothesis is vetoed. Force magnitude and direction are averaged weighted by likelihood over
the hypotheses that carry a force.
Sources may be plugged and unplugged at any time. Everything is vectorised over voxels.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from contactflow.fusion.hypotheses import (
    VOXEL_SIZE,
    Hypotheses,
    HypothesisSpace,
    HypothesisType,
    rows_unique,
    voxel_keys,
)

_BYTE_WEIGHTS = (np.uint8(1) << np.arange(8, dtype=np.uint8))[:, None]


def source_bits(valid: np.ndarray) -> np.ndarray:
    """uint64 bitmask per row of a (columns, rows) validity array, 8 columns at a time."""
    out = np.zeros(valid.shape[1], dtype=np.uint64)
    for g in range(0, valid.shape[0], 8):
        part = valid[g:g + 8].view(np.uint8)
        byte = (part * _BYTE_WEIGHTS[: part.shape[0]]).sum(axis=0, dtype=np.uint8)
        out |= byte.astype(np.uint64) << np.uint64(g)
    return out


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
    _cache_loc: np.ndarray | None = None
    _cache_rows: np.ndarray | None = None
    _cache_gen: int = -1
    _cache_unique: bool = False


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
            rows, unique = self._rows(src, cloud)
            space.put(src.col, rows, cloud, unique)
        if space.expire(now - self.params.timeout):
            space.compact()
        self.cycles += 1
        return self.fuse(now)

    def _rows(self, src: Source, cloud: Hypotheses) -> tuple[np.ndarray, bool]:
        """Rows of a cloud's voxels and whether they are all distinct."""
        # Generators at fixed places (taxels, predictions) resend the same voxels: reuse rows.
        loc = src._cache_loc
        if (loc is not None and src._cache_gen == self.space.index.generation
                and loc.shape == cloud.location.shape and np.array_equal(loc, cloud.location)):
            return src._cache_rows, src._cache_unique  # type: ignore[return-value]
        rows = self.space.rows_for(voxel_keys(cloud.location, self.space.voxel_size))
        unique = rows_unique(rows, self.space.n)
        src._cache_loc, src._cache_rows, src._cache_gen = cloud.location, rows, self.space.index.generation
        src._cache_unique = unique
        return rows, unique

    def fuse(self, now: float) -> Fused:
        """Noisy-OR fusion (eq. 4.14) of the space as it is, applying the type rules."""
        space = self.space
        n = space.n
        ncol = max((s.col for s in self.sources.values()), default=-1) + 1
        names, robots, links = [""] * ncol, [""] * ncol, [""] * ncol
        for s in self.sources.values():
            names[s.col], robots[s.col], links[s.col] = s.name, s.robot, s.link
        if n == 0 or ncol == 0:
            return Fused.empty(now, ncol)
        # Whole-array passes over the (columns, rows) views; selecting the kept voxels comes
        # last (gathering first makes strided copies).
        lik = space.lik[:ncol, :n]
        valid = space.stamp[:ncol, :n] < np.inf
        kind = space.kind[:ncol, :n]
        regular = ((kind == int(HypothesisType.REGULAR)) & valid).any(axis=0)
        null = ((kind == int(HypothesisType.NULL)) & valid).any(axis=0)
        live = valid.any(axis=0)
        miss = np.prod(1.0 - lik, axis=0)
        # Force and direction average over the entries that carry a force (support and range
        # hypotheses know none and must not pull the magnitude towards zero).
        force = space.force[:ncol, :n]
        wf = lik * (force > 0.0)
        wsum = wf.sum(axis=0)
        fsum = np.einsum("cn,cn->n", wf, force)
        dsum = np.einsum("cn,can->an", wf, space.direction[:ncol, :, :n])
        keep = np.flatnonzero(regular & ~null & (miss < 1.0))
        if keep.size == n:
            def take(a: np.ndarray) -> np.ndarray:
                return a[..., :n].copy()
        else:
            def take(a: np.ndarray) -> np.ndarray:
                return np.take(a, keep, axis=-1)
        # Arrays of rows come out as transposed views of contiguous (3, k) / (S, k) copies.
        d = take(dsum)
        norm = np.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
        np.divide(d, norm, out=d, where=norm > 1e-12)
        d[:, norm <= 1e-12] = 0.0
        fk, wk = take(fsum), take(wsum)
        return Fused(
            location=take(space.center).T, likelihood=1.0 - take(miss),
            force=np.divide(fk, wk, out=np.zeros_like(fk), where=wk > 0),
            direction=d.T, sources=source_bits(take(valid)), per_source=take(lik).T,
            columns=names, robots=robots, links=links, stamp=now,
            vetoed=int(np.count_nonzero(null & live)), unsupported=int(np.count_nonzero(live & ~regular & ~null)),
        )

    def reset(self) -> None:
        """Empty the space; sources stay plugged."""
        self.space = HypothesisSpace(self.params.voxel_size)
        for s in self.sources.values():
            s.pending, s.pending_since, s._cache_loc, s._cache_rows = None, np.inf, None, None
            self.space.ensure_column(s.col)
