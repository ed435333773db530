"""Joint command mixing: concurrent command sources combined per joint with configurable weights (thesis §6.3.1)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

MAX_CACHED = 64  # joint-name lists whose indices are kept (a subscriber's sources may name any subset)


@dataclass
class _Command:
    idx: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    weight: float
    t: float


@dataclass
class JointCommandMixer:
    """Weighted average per joint of the fresh commands of every source.

    A command is fresh for ``timeout`` seconds; joints no fresh source commands keep their
    last mixed target (a real joint controller holds position).
    """

    joint_names: list[str]
    timeout: float = 0.1  # s
    _sources: dict[str, _Command] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self._index = {n: i for i, n in enumerate(self.joint_names)}
        self._indices: dict[tuple[str, ...], np.ndarray] = {}  # a source's joint names -> their indices (sources repeat them)
        self.q = np.zeros(len(self.joint_names))
        self.qd = np.zeros(len(self.joint_names))

    def hold(self, q: np.ndarray) -> None:
        self.q = np.asarray(q, dtype=np.float64).copy()
        self.qd[:] = 0.0

    def submit(self, source: str, names: list[str] | tuple[str, ...], q: np.ndarray, qd: np.ndarray | None = None,
               weight: float = 1.0, t: float = 0.0) -> None:
        if weight < 0 or not np.isfinite(weight):
            raise ValueError(f"command from {source!r}: weight must be finite and >= 0, got {weight}")
        idx = self._indices.get(tuple(names))
        if idx is None:
            try:
                idx = np.array([self._index[n] for n in names], dtype=np.int64)
            except KeyError as exc:
                raise ValueError(f"command from {source!r}: unknown joint {exc.args[0]!r}") from None
            if len(np.unique(idx)) != len(idx):
                raise ValueError(f"command from {source!r}: a joint is named twice in {list(names)}")
            if len(self._indices) < MAX_CACHED:
                self._indices[tuple(names)] = idx
        q = np.asarray(q, dtype=np.float64)
        qd = np.zeros_like(q) if qd is None else np.asarray(qd, dtype=np.float64)
        if q.shape != (len(idx),) or qd.shape != (len(idx),):
            raise ValueError(f"command from {source!r}: {len(idx)} joints but q {q.shape}, qd {qd.shape}")
        if not (np.all(np.isfinite(q)) and np.all(np.isfinite(qd))):
            raise ValueError(f"command from {source!r}: non-finite position or velocity")
        self._sources[source] = _Command(idx, q, qd, float(weight), t)

    def mix(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(q, qd, commanded mask) at time ``t``."""
        wsum = np.zeros(len(self.joint_names))
        qs = np.zeros_like(wsum)
        qds = np.zeros_like(wsum)
        for name, c in list(self._sources.items()):
            if t - c.t > self.timeout:
                del self._sources[name]
                continue
            wsum[c.idx] += c.weight  # a source names each joint once (submit checks): no np.add.at needed
            qs[c.idx] += c.weight * c.q
            qds[c.idx] += c.weight * c.qd
        mask = wsum > 0
        self.q[mask] = qs[mask] / wsum[mask]
        self.qd[mask] = qds[mask] / wsum[mask]
        self.qd[~mask] = 0.0
        return self.q.copy(), self.qd.copy(), mask
