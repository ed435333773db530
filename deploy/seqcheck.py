"""Loss accounting for reliable streams: every sequence number is received or reported missing.

Messages carry ``hdr.seq`` per source (``Header``). A :class:`SequenceMonitor` follows each
source: a jump forward is a gap (reported with its range, never hidden), a number seen twice
is a duplicate, a fall back to 1 is a restart of the source (a new incarnation, not loss).
"""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass(frozen=True)
class Gap:
    source: str
    first_missing: int
    last_missing: int

    @property
    def count(self) -> int:
        return self.last_missing - self.first_missing + 1


@dataclass
class SourceTrack:
    first: int
    last: int
    received: int = 1
    duplicates: int = 0
    restarts: int = 0
    gaps: list[Gap] = field(default_factory=list)

    @property
    def missing(self) -> int:
        return sum(g.count for g in self.gaps)


class SequenceMonitor:
    """Tracks sequence numbers per source; ``observe`` returns the gap a message reveals."""

    def __init__(self) -> None:
        self.sources: dict[str, SourceTrack] = {}

    def observe(self, source: str, seq: int) -> Gap | None:
        t = self.sources.get(source)
        if t is None:
            self.sources[source] = SourceTrack(first=seq, last=seq)
            return None
        if seq == t.last + 1:
            t.last, t.received = seq, t.received + 1
            return None
        if seq > t.last + 1:
            gap = Gap(source, t.last + 1, seq - 1)
            t.gaps.append(gap)
            t.last, t.received = seq, t.received + 1
            return gap
        if seq <= 1 < t.last:
            t.restarts += 1
            t.last, t.received = seq, t.received + 1
            return None
        t.duplicates += 1
        return None

    def accounted(self, source: str) -> bool:
        """True when received + reported missing covers every number from first to last."""
        t = self.sources[source]
        return t.restarts > 0 or t.received + t.missing == t.last - t.first + 1

    def gaps(self) -> list[Gap]:
        return [g for t in self.sources.values() for g in t.gaps]
