"""Compiled (numba) kernels of the hypothesis space (voxel hashing, writing a cloud, expiry, the fused pass) and
of the robot's shapes (the cells of its surface and interior, for motion support and null hypotheses).

Why compiled: on moving clouds every cycle hashes, writes and fuses every hypothesis again,
and as numpy passes that costs one array temporary per operation. The stateless numpy
reference of ``bench fusion`` (one sort and a few bincounts over the concatenated clouds, no
state at all) is already at the 1 kHz goal for 3 x 10k hypotheses, so a stateful numpy
version with per-source replacement and timeouts cannot reach it; these loops visit each
hypothesis and each row once. They release the GIL, so a node's zenoh threads keep running
while a cycle fuses. The shapes: gridding each bi-sphere's box in numpy took 3-6 ms a cycle of
a moving hand (three temporaries per cell), the world waiting on it at every 20 Hz cycle.
"""

from __future__ import annotations

import numpy as np
from numba import njit

EMPTY = -1  # an empty hash slot (key and row); packed keys are never negative
GOLDEN = np.uint64(0x9E3779B97F4A7C15)
KEY_BITS = 21  # per axis of a packed voxel key (±5 km at 5 mm); the numpy packing in hypotheses.py uses these
KEY_OFFSET = 1 << (KEY_BITS - 1)
REGULAR, NULL = 0, 2  # HypothesisType values the fused pass tests


@njit(cache=True, nogil=True, inline="always")
def _pack(i: int, j: int, k: int) -> int:
    """The packed key of voxel (i, j, k) (each within ±KEY_OFFSET)."""
    return ((((i + KEY_OFFSET) << KEY_BITS) | (j + KEY_OFFSET)) << KEY_BITS) | (k + KEY_OFFSET)


@njit(cache=True, nogil=True)
def point_keys(points: np.ndarray, voxel_size: float, out: np.ndarray) -> bool:
    """Packed voxel key of each point into ``out``; False when a point lies out of range."""
    c = np.empty(3, dtype=np.int64)
    for i in range(points.shape[0]):
        for a in range(3):
            c[a] = np.int64(np.floor(points[i, a] / voxel_size))
            if c[a] >= KEY_OFFSET or c[a] <= -KEY_OFFSET:
                return False
        out[i] = _pack(c[0], c[1], c[2])
    return True


@njit(cache=True, nogil=True)
def key_centers(keys: np.ndarray, voxel_size: float, out: np.ndarray) -> None:
    """Voxel centre (3, n) of each packed key into ``out``, m."""
    mask = (1 << KEY_BITS) - 1
    for i in range(keys.shape[0]):
        k = keys[i]
        for a in range(3):
            out[a, i] = (((k >> (KEY_BITS * (2 - a))) & mask) - KEY_OFFSET + 0.5) * voxel_size


@njit(cache=True, nogil=True)
def _find(table: np.ndarray, shift: np.uint64, key: np.int64) -> np.int64:
    """The slot holding ``key``, or the empty slot that ends its probe chain (its row is -1)."""
    mask = table.shape[0] - 1
    s = np.int64((np.uint64(key) * GOLDEN) >> shift)
    while table[s, 0] != key and table[s, 0] != EMPTY:
        s = (s + 1) & mask
    return s


@njit(cache=True, nogil=True)
def index_insert(table: np.ndarray, shift: np.uint64, row_keys: np.ndarray, count: int, keys: np.ndarray,
                 out: np.ndarray) -> int:
    """Row of each key into ``out``, numbering absent keys from ``count`` on; returns the new count.

    The caller keeps the table under half full and ``row_keys`` large enough.
    """
    for i in range(keys.shape[0]):
        k = keys[i]
        s = _find(table, shift, k)
        if table[s, 0] == EMPTY:
            table[s, 0] = k
            table[s, 1] = count
            row_keys[count] = k
            count += 1
        out[i] = table[s, 1]
    return count


@njit(cache=True, nogil=True)
def index_lookup(table: np.ndarray, shift: np.uint64, keys: np.ndarray, out: np.ndarray) -> None:
    """Row of each key into ``out``, -1 where absent."""
    for i in range(keys.shape[0]):
        out[i] = table[_find(table, shift, keys[i]), 1]


@njit(cache=True, nogil=True)
def column_put(lik: np.ndarray, stamp: np.ndarray, kind: np.ndarray, force: np.ndarray, direction: np.ndarray,
               col: int, rows: np.ndarray, h_lik: np.ndarray, h_kind: np.ndarray, h_force: np.ndarray,
               h_dir: np.ndarray, h_stamp: float, mark: np.ndarray, tag: int) -> None:
    """Write one cloud into column ``col``; several hypotheses in one voxel keep the most likely.

    ``mark`` holds, per row, the ``tag`` of the last write, so a second hypothesis of the same
    cloud in a row is told from an older cloud's entry.
    """
    for i in range(rows.shape[0]):
        r = rows[i]
        if mark[r] == tag and h_lik[i] < lik[col, r]:
            continue
        mark[r] = tag
        lik[col, r] = h_lik[i]
        stamp[col, r] = h_stamp
        kind[col, r] = h_kind[i]
        force[col, r] = h_force[i]
        for a in range(3):
            direction[col, a, r] = h_dir[i, a]


@njit(cache=True, nogil=True)
def fuse_rows(lik: np.ndarray, stamp: np.ndarray, kind: np.ndarray, force: np.ndarray, direction: np.ndarray,
              center: np.ndarray, ncol: int, n: int, older_than: float):
    """Expire the entries stamped before ``older_than``, then eq. 4.14 with the type rules over
    rows ``[0, n)`` of the first ``ncol`` columns.

    Returns (location (3, k), likelihood, force, direction (3, k), source bits, per-source
    likelihood (ncol, k), vetoed, unsupported, live rows) of the k kept voxels: those
    with a regular hypothesis, no null one and a fused likelihood above zero. Force and
    direction average, weighted by likelihood, over the entries that carry a force. Expiry
    rides on this pass so the columns are read once per cycle.
    """
    # Column by column, so each inner loop runs over contiguous memory and vectorises; which
    # columns hold an entry is random from row to row, so the loops are branch-free.
    miss = np.ones(n)
    wsum = np.zeros(n)
    fsum = np.zeros(n)
    dsum = np.zeros((3, n))
    bits = np.zeros(n, dtype=np.uint64)
    regular = np.zeros(n, dtype=np.bool_)
    null = np.zeros(n, dtype=np.bool_)
    for c in range(ncol):
        bit = np.uint64(1) << np.uint64(c)
        for r in range(n):
            st = stamp[c, r]
            old = st < older_than
            stamp[c, r] = np.inf if old else st
            lik[c, r] = 0.0 if old else lik[c, r]
            v = (st >= older_than) & (st < np.inf)
            kd = kind[c, r]
            bits[r] |= bit * v
            regular[r] |= v & (kd == REGULAR)
            null[r] |= v & (kd == NULL)
            p = lik[c, r]
            miss[r] *= 1.0 - p
            f = force[c, r]
            w = p * (f > 0.0)
            wsum[r] += w
            fsum[r] += w * f
        for a in range(3):
            for r in range(n):
                dsum[a, r] += lik[c, r] * (force[c, r] > 0.0) * direction[c, a, r]
    keep = np.empty(n, dtype=np.int64)
    k = 0
    vetoed = 0
    unsupported = 0
    live = 0
    for r in range(n):
        live += bits[r] != 0
        vetoed += null[r]
        unsupported += (bits[r] != 0) & (not regular[r]) & (not null[r])
        keep[k] = r
        k += regular[r] & (not null[r]) & (miss[r] < 1.0)
    keep = keep[:k]
    loc = np.empty((3, k))
    dmean = np.empty((3, k))
    per = np.empty((ncol, k))
    fused = np.empty(k)
    fmean = np.empty(k)
    kbits = np.empty(k, dtype=np.uint64)
    for j in range(k):
        r = keep[j]
        fused[j] = 1.0 - miss[r]
        w = wsum[r]
        fmean[j] = fsum[r] / w if w > 0.0 else 0.0
        kbits[j] = bits[r]
        dx, dy, dz = dsum[0, r], dsum[1, r], dsum[2, r]
        norm = np.sqrt(dx * dx + dy * dy + dz * dz)
        scale = 1.0 / norm if norm > 1e-12 else 0.0
        dmean[0, j] = dx * scale
        dmean[1, j] = dy * scale
        dmean[2, j] = dz * scale
    for a in range(3):
        for j in range(k):
            loc[a, j] = center[a, keep[j]]
    for c in range(ncol):
        for j in range(k):
            per[c, j] = lik[c, keep[j]]
    return loc, fused, fmean, dmean, kbits, per, vetoed, unsupported, live


@njit(cache=True, nogil=True, inline="always")
def _part_distance(x: float, y: float, z: float, cap: np.ndarray) -> float:
    """Signed distance of a point to one bi-sphere (eq. B.3 then B.2), as ``geometry.capsule_distance``."""
    ax, ay, az = cap[4] - cap[0], cap[5] - cap[1], cap[6] - cap[2]
    len2 = ax * ax + ay * ay + az * az
    lam = ((x - cap[0]) * ax + (y - cap[1]) * ay + (z - cap[2]) * az) / (len2 if len2 > 0.0 else 1.0)
    lam = min(max(lam, 0.0), 1.0)
    dx, dy, dz = x - (cap[0] + lam * ax), y - (cap[1] + lam * ay), z - (cap[2] + lam * az)
    return np.sqrt(dx * dx + dy * dy + dz * dz) - (cap[3] + lam * (cap[7] - cap[3]))


@njit(cache=True, nogil=True)
def shape_cells(caps: np.ndarray, first: np.ndarray, hi: np.ndarray, step: float, band: float, depth: float,
                surface: bool) -> np.ndarray:
    """Packed keys of the cells (one global grid of cell ``step``) of each part's box, from cell ``first``
    (m, 3) while the cell centre is under ``hi`` (m, 3), that lie within ``band`` of the surface of the
    union of bi-spheres (``surface``) or deeper than ``depth`` inside their own part; a cell near several
    parts comes once per part (the caller makes them unique). One visit per cell, no temporaries."""
    m = caps.shape[0]
    size = 0
    for c in range(m):
        n = 1
        for a in range(3):
            n *= max(np.int64(np.ceil(hi[c, a] / step - 0.5)) - first[c, a] + 1, 0)  # +1: rounding at hi
        size += n
    out = np.empty(size, dtype=np.int64)
    k = 0
    for c in range(m):
        if not surface and max(caps[c, 3], caps[c, 7]) <= depth:
            continue
        i = first[c, 0]
        while (i + 0.5) * step < hi[c, 0]:
            x = (i + 0.5) * step
            j = first[c, 1]
            while (j + 0.5) * step < hi[c, 1]:
                y = (j + 0.5) * step
                kk = first[c, 2]
                while (kk + 0.5) * step < hi[c, 2]:
                    z = (kk + 0.5) * step
                    d = _part_distance(x, y, z, caps[c])
                    keep = d < -depth
                    if surface:
                        keep = abs(d) <= band
                        if keep:  # near this part's surface; on the union's only if no part holds it deeper
                            for o in range(m):
                                if o != c and _part_distance(x, y, z, caps[o]) < -band:
                                    keep = False
                                    break
                    if keep:
                        out[k] = _pack(i, j, kk)
                        k += 1
                    kk += 1
                j += 1
            i += 1
    return out[:k]
