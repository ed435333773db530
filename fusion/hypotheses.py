"""Contact hypotheses as structure-of-arrays clouds, and the voxel hypothesis space (thesis §4.2).

A generator produces a :class:`Hypotheses` cloud: locations, one likelihood per hypothesis,
force magnitude and direction, a :class:`HypothesisType` per hypothesis and the time stamp of
the reading. The integrator keeps a :class:`HypothesisSpace`: the 3D world discretised in
voxels of fixed size, each occupied voxel holding one likelihood, time stamp, type and force
per contributing source (a column), plus the bitmask of its sources. Voxels are found through
:class:`VoxelIndex`, an open-addressing hash table of packed integer voxel coordinates that
inserts and looks up whole arrays at once in compiled loops (:mod:`~contactflow.fusion.kernels`).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

import numpy as np

from contactflow.fusion import kernels
from contactflow.fusion.kernels import KEY_BITS as _BITS
from contactflow.fusion.kernels import KEY_OFFSET as _OFFSET

VOXEL_SIZE = 0.005  # m, thesis §4.7: the same 5 mm in generators and integrator
_MASK21 = (1 << _BITS) - 1


class HypothesisType(IntEnum):
    """Regular: perceptual evidence. Support: context/prediction, never alone. Null: veto."""

    REGULAR = 0
    SUPPORT = 1
    NULL = 2


def voxel_coords(points: np.ndarray, voxel_size: float) -> np.ndarray:
    """Integer voxel coordinates (n, 3) of world points (n, 3)."""
    return np.floor(np.asarray(points, dtype=np.float64) / voxel_size).astype(np.int64)


def pack_keys(ijk: np.ndarray) -> np.ndarray:
    """Pack integer voxel coordinates into one int64 key (21 bits per axis, ±5 km at 5 mm)."""
    if ijk.size and (np.abs(ijk).max() >= _OFFSET):
        raise ValueError(f"voxel coordinates out of range ±{_OFFSET} (point too far from the origin)")
    u = ijk + _OFFSET
    return (u[:, 0] << (2 * _BITS)) | (u[:, 1] << _BITS) | u[:, 2]


def unpack_keys(keys: np.ndarray) -> np.ndarray:
    keys = np.asarray(keys, dtype=np.int64)
    return np.stack(((keys >> (2 * _BITS)) & _MASK21, (keys >> _BITS) & _MASK21, keys & _MASK21), axis=1) - _OFFSET


def voxel_keys(points: np.ndarray, voxel_size: float) -> np.ndarray:
    return pack_keys(voxel_coords(points, voxel_size))


def unique_keys(keys: np.ndarray, return_inverse: bool = False):  # type: ignore[no-untyped-def]
    """``np.unique`` of int64 voxel keys (sorted; with the inverse on request) by one sort: numpy 2.4's
    hash-based unique takes three times as long on them (15k keys: 1.9 -> 0.6 ms), at every cycle of
    the shape generators."""
    keys = np.asarray(keys, dtype=np.int64).ravel()
    order = np.argsort(keys, kind="stable") if return_inverse else None
    s = keys[order] if order is not None else np.sort(keys)
    first = np.ones(s.size, dtype=bool)
    first[1:] = s[1:] != s[:-1]
    if order is None:
        return s[first]
    inv = np.empty(keys.size, dtype=np.intp)
    inv[order] = np.cumsum(first) - 1
    return s[first], inv


def voxel_centers(keys: np.ndarray, voxel_size: float) -> np.ndarray:
    return (unpack_keys(keys).astype(np.float64) + 0.5) * voxel_size


def _check(name: str, a: np.ndarray, shape: tuple[int, ...], where: str) -> None:
    if a.shape != shape:
        raise ValueError(f"{where}: field {name!r} has shape {a.shape}, expected {shape}")
    if a.dtype.kind == "f" and a.size and not np.isfinite(a).all():
        raise ValueError(f"{where}: field {name!r} contains NaN or inf")


@dataclass(frozen=True, eq=False)
class Hypotheses:
    """A cloud of contact hypotheses from one source, as parallel numpy arrays.

    ``location`` (n, 3) world frame, m; ``likelihood`` (n,) in [0, 1]; ``kind`` (n,) uint8
    :class:`HypothesisType`; ``force`` (n,) N; ``direction`` (n, 3) unit vectors (zero when
    unknown); ``stamp`` the time of the reading the cloud was computed from, s.
    """

    location: np.ndarray
    likelihood: np.ndarray
    kind: np.ndarray
    force: np.ndarray
    direction: np.ndarray
    stamp: float = 0.0

    def __len__(self) -> int:
        return int(self.location.shape[0])

    @classmethod
    def make(
        cls,
        location: np.ndarray,
        likelihood: np.ndarray | float,
        kind: HypothesisType | np.ndarray = HypothesisType.REGULAR,
        force: np.ndarray | float = 0.0,
        direction: np.ndarray | None = None,
        stamp: float = 0.0,
        where: str = "hypotheses",
    ) -> Hypotheses:
        """Build a cloud, broadcasting scalars, and validate shapes and ranges."""
        loc = np.asarray(location, dtype=np.float64).reshape(-1, 3)
        n = loc.shape[0]
        lik = np.broadcast_to(np.asarray(likelihood, dtype=np.float64), (n,)).copy()
        knd = np.broadcast_to(np.asarray(kind, dtype=np.uint8), (n,)).copy()
        frc = np.broadcast_to(np.asarray(force, dtype=np.float64), (n,)).copy()
        if direction is None:
            dirn = np.zeros((n, 3))
        else:
            dirn = np.broadcast_to(np.asarray(direction, dtype=np.float64), (n, 3)).copy()
        h = cls(loc, lik, knd, frc, dirn, float(stamp))
        h.validate(where)
        return h

    @classmethod
    def empty(cls, stamp: float = 0.0) -> Hypotheses:
        return cls.make(np.zeros((0, 3)), 0.0, stamp=stamp)

    def validate(self, where: str = "hypotheses") -> None:
        n = len(self)
        _check("location", self.location, (n, 3), where)
        _check("likelihood", self.likelihood, (n,), where)
        _check("kind", self.kind, (n,), where)
        _check("force", self.force, (n,), where)
        _check("direction", self.direction, (n, 3), where)
        if n and (self.likelihood.min() < 0.0 or self.likelihood.max() > 1.0):
            raise ValueError(f"{where}: field 'likelihood' must lie in [0, 1]")
        if n and self.kind.max() > max(HypothesisType):
            raise ValueError(f"{where}: field 'kind' holds {int(self.kind.max())}, not a HypothesisType")
        if not np.isfinite(self.stamp):
            raise ValueError(f"{where}: field 'stamp' is not finite")

    def select(self, mask: np.ndarray) -> Hypotheses:
        return Hypotheses(self.location[mask], self.likelihood[mask], self.kind[mask], self.force[mask],
                          self.direction[mask], self.stamp)

    @staticmethod
    def concat(clouds: list[Hypotheses], stamp: float | None = None) -> Hypotheses:
        if not clouds:
            return Hypotheses.empty(stamp or 0.0)
        return Hypotheses(
            np.concatenate([c.location for c in clouds]),
            np.concatenate([c.likelihood for c in clouds]),
            np.concatenate([c.kind for c in clouds]),
            np.concatenate([c.force for c in clouds]),
            np.concatenate([c.direction for c in clouds]),
            max(c.stamp for c in clouds) if stamp is None else stamp,
        )


def voxelize(h: Hypotheses, voxel_size: float = VOXEL_SIZE, reduce: str = "max") -> Hypotheses:
    """Merge hypotheses that share a voxel; the result sits on voxel centres.

    ``reduce="sum"`` keeps the total probability of a single-contact generator (eq. 4.1);
    ``"max"`` suits multi-contact generators (eq. 4.2). Force and direction are averaged
    weighted by likelihood; the type of a voxel is the highest of its hypotheses (a null
    hypothesis wins over a support one, which wins over a regular one).
    """
    if reduce not in ("max", "sum"):
        raise ValueError(f"voxelize: reduce={reduce!r} is not 'max' or 'sum'")
    if len(h) == 0:
        return h
    keys, inv = unique_keys(voxel_keys(h.location, voxel_size), return_inverse=True)
    m = keys.shape[0]
    if reduce == "sum":
        lik = np.minimum(np.bincount(inv, weights=h.likelihood, minlength=m), 1.0)
    else:
        lik = np.zeros(m)
        np.maximum.at(lik, inv, h.likelihood)
    kind = np.zeros(m, dtype=np.uint8)
    np.maximum.at(kind, inv, h.kind)
    w = h.likelihood + 1e-12
    wsum = np.bincount(inv, weights=w, minlength=m)
    force = np.bincount(inv, weights=w * h.force, minlength=m) / wsum
    direction = np.stack([np.bincount(inv, weights=w * h.direction[:, a], minlength=m) for a in range(3)], axis=1)
    direction = normalise(direction)
    return Hypotheses(voxel_centers(keys, voxel_size), lik, kind, force, direction, h.stamp)


def normalise(v: np.ndarray) -> np.ndarray:
    """Unit vectors along the last axis; zero vectors stay zero."""
    norm = np.sqrt(np.einsum("...i,...i->...", v, v))[..., None]
    return np.divide(v, norm, out=np.zeros_like(v), where=norm > 1e-12)


def _grown(a: np.ndarray, valid: int, size: int) -> np.ndarray:
    """A zeroed array of ``size`` starting with the first ``valid`` entries of ``a``."""
    out = np.zeros(size, dtype=a.dtype)
    out[:valid] = a[:valid]
    return out


class VoxelIndex:
    """Open-addressing (linear probing) hash table: packed voxel key -> row number.

    Lookups, insertions and releases take whole arrays and run as one compiled loop
    (:mod:`~contactflow.fusion.kernels`); the load factor stays under one half. A new key takes the
    row released last, or with none free the next row: rows are numbered densely, in insertion order
    until a row is released.
    """

    def __init__(self, capacity: int = 1024) -> None:
        self._alloc(max(16, 1 << int(np.ceil(np.log2(max(capacity, 1) * 2)))))
        self.row_keys = np.zeros(max(capacity, 16), dtype=np.int64)
        """Key of each row, in row order (valid up to ``count``, and not for free rows)."""
        self.free = np.zeros(self.row_keys.shape[0], dtype=np.int64)
        """Released rows, a stack (valid up to ``nfree``)."""
        self.count = 0
        self.nfree = 0

    def _alloc(self, size: int) -> None:
        self.size = size
        self.shift = np.uint64(64 - int(np.log2(size)))
        # (key, row) pairs side by side: a probe touches one cache line, not two
        self.table = np.full((size, 2), kernels.EMPTY, dtype=np.int64)

    def lookup(self, keys: np.ndarray) -> np.ndarray:
        """Row of each key, -1 where absent."""
        keys = np.ascontiguousarray(keys, dtype=np.int64)
        out = np.empty(keys.shape[0], dtype=np.int64)
        kernels.index_lookup(self.table, self.shift, keys, out)
        return out

    def reserve(self, more: int) -> int:
        """Room for ``more`` new keys (table under half full, rows); returns the count it allows."""
        end = self.count + more
        if end > self.size // 2:
            self._grow(end)
        if end > self.row_keys.shape[0]:
            size = max(end, 2 * self.row_keys.shape[0])
            self.row_keys = _grown(self.row_keys, self.count, size)
            self.free = _grown(self.free, self.nfree, size)
        return end

    def insert(self, keys: np.ndarray) -> np.ndarray:
        """Row of each key, adding absent keys (duplicates in ``keys`` share one new row)."""
        keys = np.ascontiguousarray(keys, dtype=np.int64)
        self.reserve(keys.shape[0])
        out = np.empty(keys.shape[0], dtype=np.int64)
        self.count, self.nfree, _, _ = kernels.index_insert(self.table, self.shift, self.row_keys, self.count,
                                                            self.free, self.nfree, keys, out, np.empty_like(out),
                                                            self.row_keys.shape[0])
        return out

    def release(self, rows: np.ndarray) -> None:
        """Forget the keys of ``rows`` (rows in the index, each once); new keys take these rows first."""
        self.nfree = kernels.index_release(self.table, self.shift, self.row_keys, self.free, self.nfree,
                                           np.ascontiguousarray(rows, dtype=np.int64))

    def _grow(self, needed: int) -> None:
        size = self.size
        while needed > size // 2:
            size *= 2
        old = self.table
        self._alloc(size)
        kernels.index_move(old, self.table, self.shift)

    def rebuild(self, keys: np.ndarray, size: int | None = None) -> None:
        """Start over with ``keys`` as rows 0..n-1 (keys must be unique; they may be the first n of ``row_keys``:
        each lands on its own row). A table of the same size is emptied in place."""
        n = keys.shape[0]
        size = size or self.size
        while n > size // 2:
            size *= 2
        if size == self.size:
            self.table.fill(kernels.EMPTY)
        else:
            self._alloc(size)
        self.count = self.nfree = 0
        if n:
            rows = self.insert(keys)
            if not np.array_equal(rows, np.arange(n)):
                raise ValueError("VoxelIndex.rebuild: keys are not unique")


class HypothesisSpace:
    """The hypothesis space HS: occupied voxels with per-source likelihood, stamp, type, force.

    Sources are columns (at most 64, so a voxel's sources fit a uint64 bitmask). An entry (a row's
    column) is one record of :data:`~contactflow.fusion.kernels.FIELDS` floats, ``rec[row, col, field]``,
    so that writing a hypothesis touches one cache line and the fused pass reads the records in
    memory order; ``center[axis, row]`` holds the voxel centres. An entry is empty when its stamp is
    ``+inf`` and its likelihood 0. Entries expire in the fused pass (:meth:`fuse`), which reads every
    record anyway. Rows whose every column is empty are dead. A row whose last entry expires there is
    released at once, and the next new voxel takes it: on moving clouds, where voxels die and are born every
    cycle, the rows stay as many as the live voxels. Dead rows left otherwise (a cleared column, clouds that
    shrink) are dropped in bulk, in place, when they are over ``DEAD_SHARE`` of the rows.
    """

    MAX_SOURCES = 64
    # dead rows are dropped once they are over this share of the rows: the fused pass reads every row, and the
    # in-place compaction (kernels.compact_rows) is cheap enough to run often (3 x 10k moving clouds, against half:
    # mean cycle rate 1.24-1.29x, median 1.09-1.16x; at 5 % the compactions cost more than the rows they drop)
    DEAD_SHARE = 0.15

    def __init__(self, voxel_size: float = VOXEL_SIZE, capacity: int = 1024, columns: int = 1) -> None:
        if not voxel_size > 0:
            raise ValueError(f"HypothesisSpace: voxel_size={voxel_size} must be > 0")
        self.voxel_size = float(voxel_size)
        self.index = VoxelIndex(capacity)
        self.n = 0
        self.cap = 0
        self.ncol = 0
        self._tag = 0.0  # the number of the last write, in each entry it wrote (kernels.TAG)
        self.center = np.zeros((3, 0))
        self._keys = np.zeros(0, dtype=np.int64)  # a put's scratch: the packed key of each hypothesis
        self._rows = np.zeros(0, dtype=np.int64)  # and its row
        self._born = np.zeros(0, dtype=np.int64)  # and the rows it gave new voxels
        self._alloc_rows(max(capacity, 16), columns)

    @staticmethod
    def _empty_records(rows: int, ncol: int) -> np.ndarray:
        """Empty records, each on a cache line of its own (numpy aligns large arrays to 16 bytes only, and
        a record across two lines costs a put two misses)."""
        size = rows * ncol * kernels.FIELDS
        buf = np.zeros(size + kernels.FIELDS)
        first = (-buf.ctypes.data % 64) // buf.itemsize
        rec = buf[first:first + size].reshape(rows, ncol, kernels.FIELDS)
        rec[:, :, kernels.STAMP] = np.inf
        return rec

    def _alloc_rows(self, cap: int, ncol: int) -> None:
        n, c = self.n, self.ncol
        rec = self._empty_records(cap, ncol)
        center = np.zeros((3, cap))
        if n:
            center[:, :n] = self.center[:, :n]
            rec[:n, :c] = self.rec[:n, :c]
        self.rec, self.center = rec, center
        self.cap, self.ncol = cap, ncol

    @property
    def lik(self) -> np.ndarray:
        """Likelihood of each entry, ``lik[col, row]`` (a view)."""
        return self.rec[:, :, kernels.LIK].T

    @property
    def stamp(self) -> np.ndarray:
        """Stamp of each entry, ``stamp[col, row]``, ``+inf`` where empty (a view)."""
        return self.rec[:, :, kernels.STAMP].T

    def ensure_column(self, col: int) -> None:
        if not 0 <= col < self.MAX_SOURCES:
            raise ValueError(f"HypothesisSpace: source column {col} outside [0, {self.MAX_SOURCES})")
        if col >= self.ncol:
            self._alloc_rows(self.cap, col + 1)  # exactly: the fused pass streams whole rows

    def _room(self, more: int) -> None:
        """Index and rows large enough for ``more`` new voxels."""
        end = self.index.reserve(more)
        if end > self.cap:
            cap = self.cap
            while cap < end:
                cap *= 2
            self._alloc_rows(cap, self.ncol)

    def put(self, col: int, h: Hypotheses) -> None:
        """Write one source's hypotheses into its column, adding rows for new voxels (the newest
        reading of a source wins; several hypotheses of one cloud in one voxel keep the most likely)."""
        self.ensure_column(col)
        m = len(h)
        if not m:
            return
        if self._keys.shape[0] < m:
            self._keys = np.empty(max(m, 2 * self._keys.shape[0]), dtype=np.int64)
            self._rows = np.empty(self._keys.shape[0], dtype=np.int64)
            self._born = np.empty(self._keys.shape[0], dtype=np.int64)
        keys = self._keys[:m]
        if not kernels.point_keys(np.ascontiguousarray(h.location, dtype=np.float64), self.voxel_size, keys):
            raise ValueError(f"voxel coordinates out of range ±{_OFFSET} (point too far from the origin)")
        self._tag += 1.0
        idx = self.index
        lik, kind, force, direction = h.likelihood, h.kind, h.force, np.ascontiguousarray(h.direction)
        done = 0
        while True:  # the rows grow when a new voxel finds no room, by doubling at most, so to what the clouds need
            idx.count, idx.nfree, wrote = kernels.cloud_put(
                idx.table, idx.shift, idx.row_keys, idx.count, idx.free, idx.nfree, self.rec, self.center,
                self.voxel_size, col, keys[done:], lik[done:], kind[done:], force[done:], direction[done:],
                float(h.stamp), self._tag, self._rows[done:m], self._born[done:m], min(self.cap, idx.row_keys.shape[0]))
            done += wrote
            self.n = idx.count  # the rows a growth keeps
            if done == m:
                break
            self._room(min(m - done, max(idx.count, 1024)))

    def clear_column(self, col: int) -> None:
        if col < self.ncol:
            self.rec[:, col, kernels.LIK] = 0.0
            self.rec[:, col, kernels.STAMP] = np.inf

    def fuse(self, ncol: int, older_than: float) -> tuple:
        """Expire entries stamped before ``older_than`` and fuse the first ``ncol`` columns
        (:func:`~contactflow.fusion.kernels.fuse_rows`); the rows whose last entry expired are released
        to new voxels. Returns (out, source bits, vetoed, unsupported, live rows)."""
        *fused, died = kernels.fuse_rows(self.rec, self.center, ncol, self.n, older_than)
        self.index.release(died)
        return tuple(fused)

    def live(self) -> np.ndarray:
        return (self.rec[: self.n, :, kernels.STAMP] < np.inf).any(axis=1)

    def compact(self, force: bool = False, live_rows: int | None = None) -> bool:
        """Drop dead rows when they are over ``DEAD_SHARE`` of the rows (or always with ``force``); ``live_rows``,
        when the caller knows it, spares a scan when there is nothing to drop."""
        if not force:
            live = int(np.count_nonzero(self.live())) if live_rows is None else live_rows
            if self.n - live <= self.DEAD_SHARE * max(self.n, 64):
                return False
        self.n = kernels.compact_rows(self.rec, self.center, self.index.row_keys, self.ncol, self.n)
        self.index.rebuild(self.index.row_keys[: self.n])
        return True

    @property
    def keys(self) -> np.ndarray:
        """Packed voxel key of each row (valid up to ``n``)."""
        return self.index.row_keys

    def centers(self, rows: np.ndarray | None = None) -> np.ndarray:
        """Voxel centres (k, 3) of ``rows`` (a transposed view of a (3, k) array)."""
        return (self.center[:, : self.n].copy() if rows is None else np.take(self.center, rows, axis=1)).T

    def __len__(self) -> int:
        return int(np.count_nonzero(self.live()))
