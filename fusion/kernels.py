"""Compiled (numba) kernels of the hypothesis space (voxel hashing and release, writing a cloud, expiry, the fused
pass, compaction) and of the robot's shapes (the cells of its surface and interior, for motion support and null
hypotheses).

Why compiled: on moving clouds every cycle hashes, writes and fuses every hypothesis again,
and as numpy passes that costs one array temporary per operation: the stateless numpy
reference of ``bench fusion`` (one sort and a few bincounts over the concatenated clouds, no
state at all) runs 3 x 10k moving hypotheses at 660-700 cycles/s here, and a stateful numpy
version with per-source replacement and timeouts would be slower still. These loops visit
each hypothesis and each row once. What bounds them is memory, not arithmetic: a hypothesis
lands on a random row (one hash probe, one record), and the fused pass streams every record.
They release the GIL, so a node's zenoh threads keep running while a cycle fuses. The shapes:
gridding each bi-sphere's box in numpy took 3-6 ms a cycle of a moving hand (three temporaries
per cell), the world waiting on it at every 20 Hz cycle.
"""

from __future__ import annotations

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.core import cgutils
from numba.extending import intrinsic

EMPTY = -1  # an empty hash slot (key and row); packed keys are never negative
GOLDEN = np.uint64(0x9E3779B97F4A7C15)
KEY_BITS = 21  # per axis of a packed voxel key (±5 km at 5 mm); the numpy packing in hypotheses.py uses these
KEY_OFFSET = 1 << (KEY_BITS - 1)
REGULAR, NULL = 0, 2  # HypothesisType values the fused pass tests
# the fields of an entry's record (rec[row, column, field]): one entry, one cache line
LIK, STAMP, FORCE, DX, DY, DZ, KIND, TAG = range(8)
FIELDS = 8
OUT_SOURCES = 8  # the first column of the per-source likelihoods in the fused pass's rows


@njit(cache=True, nogil=True, inline="always")
def _pack(i: int, j: int, k: int) -> int:
    """The packed key of voxel (i, j, k) (each within ±KEY_OFFSET)."""
    return ((((i + KEY_OFFSET) << KEY_BITS) | (j + KEY_OFFSET)) << KEY_BITS) | (k + KEY_OFFSET)


@njit(cache=True, nogil=True)
def point_keys(points: np.ndarray, voxel_size: float, out: np.ndarray) -> bool:
    """Packed voxel key of each point (a C-contiguous (n, 3) array) into ``out``; False when a point lies out
    of range (its key is then meaningless).

    No branch and no exit inside the loop, and the coordinates read from the flat buffer: the loop then
    vectorises and streams a cold cloud (a fresh cloud every cycle) at memory speed. With an exit at the
    first point out of range it ran 4x slower on a cold 100k cloud (1.19 against 0.31 ms).
    """
    flat = points.ravel()
    lim = float(KEY_OFFSET)
    ok = True
    for i in range(points.shape[0]):
        a = np.floor(flat[3 * i] / voxel_size)
        b = np.floor(flat[3 * i + 1] / voxel_size)
        c = np.floor(flat[3 * i + 2] / voxel_size)
        ok &= (abs(a) < lim) & (abs(b) < lim) & (abs(c) < lim)
        out[i] = _pack(np.int64(a), np.int64(b), np.int64(c))
    return ok


@njit(cache=True, nogil=True)
def _find(table: np.ndarray, shift: np.uint64, key: np.int64) -> np.int64:
    """The slot holding ``key``, or the empty slot that ends its probe chain (its row is -1)."""
    mask = table.shape[0] - 1
    s = np.int64((np.uint64(key) * GOLDEN) >> shift)
    while table[s, 0] != key and table[s, 0] != EMPTY:
        s = (s + 1) & mask
    return s


@intrinsic
def _prefetch(typingctx, arr, index):
    """Start loading the cache line of ``arr[index]`` (a tuple index) for a write (LLVM's prefetch)."""

    def codegen(context, builder, signature, args):
        aryty, idxty = signature.args
        ary = context.make_array(aryty)(context, builder, args[0])
        idx = [builder.extract_value(args[1], i) for i in range(len(idxty))]
        ptr = cgutils.get_item_pointer(context, builder, aryty, ary, idx, wraparound=False)
        i8p, i32 = ir.IntType(8).as_pointer(), ir.IntType(32)
        fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(ir.VoidType(), [i8p, i32, i32, i32]),
                                            "llvm.prefetch.p0")
        builder.call(fn, [builder.bitcast(ptr, i8p), ir.Constant(i32, 1), ir.Constant(i32, 3), ir.Constant(i32, 1)])
        return context.get_dummy_value()

    return types.void(arr, index), codegen


AHEAD = 64  # keys or hypotheses a loop loads ahead (a probe or a record that misses the caches; 3 x 100k moving: 64 puts in 5.8-5.9 ms a cycle, 16 in 6.6-6.9, 128 in 6.0-6.3)


@njit(cache=True, nogil=True)
def index_insert(table: np.ndarray, shift: np.uint64, row_keys: np.ndarray, count: int, free: np.ndarray, nfree: int,
                 keys: np.ndarray, out: np.ndarray, born: np.ndarray, max_rows: int) -> tuple[int, int, int, int]:
    """Row of each key into ``out``; an absent key takes the row freed last (``free[:nfree]``, a stack) or, with
    none free, the next new row (``count`` on). The rows taken go to ``born``. Returns (count, nfree, rows taken,
    keys done).

    It stops before the first absent key that finds no room: the table at half full, or no free row and
    ``count`` at ``max_rows`` (the rows the caller has). The caller grows them and goes on from the keys
    done, so the rows grow to what the clouds need, not to a bound that takes every key for new.
    The probe of the key ``AHEAD`` on is loaded early: a probe misses the caches, and its branch
    stalls the loop.
    """
    m = keys.shape[0]
    half = table.shape[0] >> 1
    nborn = 0
    for i in range(m):
        if i + AHEAD < m:
            _prefetch(table, (np.int64((np.uint64(keys[i + AHEAD]) * GOLDEN) >> shift), 0))
        k = keys[i]
        s = _find(table, shift, k)
        if table[s, 0] == EMPTY:
            if count - nfree >= half or (nfree == 0 and count >= max_rows):
                return count, nfree, nborn, i
            if nfree > 0:
                nfree -= 1
                r = free[nfree]
            else:
                r = count
                count += 1
            table[s, 0] = k
            table[s, 1] = r
            row_keys[r] = k
            born[nborn] = r
            nborn += 1
        out[i] = table[s, 1]
    return count, nfree, nborn, m


@njit(cache=True, nogil=True)
def index_release(table: np.ndarray, shift: np.uint64, row_keys: np.ndarray, free: np.ndarray, nfree: int,
                  rows: np.ndarray) -> int:
    """Forget the voxel of each of ``rows`` (rows in the table) and push the rows on the free stack; returns nfree.

    Deletion by backward shift: each entry after the hole in its probe chain that may sit in it moves in, so
    no tombstone is left to lengthen later probes.
    """
    mask = table.shape[0] - 1
    for i in range(rows.shape[0]):
        r = rows[i]
        s = _find(table, shift, row_keys[r])
        j = s
        while True:
            j = (j + 1) & mask
            kj = table[j, 0]
            if kj == EMPTY:
                break
            h = np.int64((np.uint64(kj) * GOLDEN) >> shift)
            # the entry at j may fill the hole at s unless its home slot h lies cyclically in (s, j]
            if (h <= s or h > j) if j > s else (h <= s and h > j):
                table[s, 0] = kj
                table[s, 1] = table[j, 1]
                s = j
        table[s, 0] = EMPTY
        table[s, 1] = EMPTY
        free[nfree] = r
        nfree += 1
    return nfree


@njit(cache=True, nogil=True)
def index_move(old: np.ndarray, table: np.ndarray, shift: np.uint64) -> None:
    """Insert every (key, row) entry of the table ``old`` into the empty ``table`` (a larger one), rows kept."""
    for s in range(old.shape[0]):
        k = old[s, 0]
        if k != EMPTY:
            t = _find(table, shift, k)
            table[t, 0] = k
            table[t, 1] = old[s, 1]


@njit(cache=True, nogil=True)
def index_lookup(table: np.ndarray, shift: np.uint64, keys: np.ndarray, out: np.ndarray) -> None:
    """Row of each key into ``out``, -1 where absent."""
    for i in range(keys.shape[0]):
        out[i] = table[_find(table, shift, keys[i]), 1]


@njit(cache=True, nogil=True)
def cloud_put(table: np.ndarray, shift: np.uint64, row_keys: np.ndarray, count: int, free: np.ndarray, nfree: int,
              rec: np.ndarray, center: np.ndarray, voxel_size: float, col: int, keys: np.ndarray, h_lik: np.ndarray,
              h_kind: np.ndarray, h_force: np.ndarray, h_dir: np.ndarray, h_stamp: float, tag: float,
              rows: np.ndarray, born: np.ndarray, max_rows: int) -> tuple[int, int, int]:
    """Write one cloud (its packed voxel ``keys``) into column ``col`` of the records, giving each new voxel a
    row (a free one first, :func:`index_insert`) and its centre; returns the new (row count, free rows,
    hypotheses written). Several hypotheses of the cloud in one voxel keep the most likely: the entry's TAG
    field tells this write (``tag``) from an older one.

    Two passes, each with one random access per hypothesis, loaded ``AHEAD`` hypotheses early: the
    probes (:func:`index_insert`, rows into ``rows``), then the records. A record holds all fields of
    an entry, so a write touches one cache line, not one per field. It writes the hypotheses up to the
    first new voxel that found no room (the table half full, or ``max_rows`` rows and none free): the
    caller grows them and writes the rest with the same ``tag``.
    """
    count, nfree, nborn, m = index_insert(table, shift, row_keys, count, free, nfree, keys, rows, born, max_rows)
    mask = (1 << KEY_BITS) - 1
    for b in range(nborn):  # the new voxels' rows
        r = born[b]
        for a in range(3):
            center[a, r] = (((row_keys[r] >> (KEY_BITS * (2 - a))) & mask) - KEY_OFFSET + 0.5) * voxel_size
    for i in range(m):
        if i + AHEAD < m:
            _prefetch(rec, (rows[i + AHEAD], col, 0))
        r = rows[i]
        if rec[r, col, TAG] == tag and h_lik[i] < rec[r, col, LIK]:
            continue
        rec[r, col, TAG] = tag
        rec[r, col, LIK] = h_lik[i]
        rec[r, col, STAMP] = h_stamp
        rec[r, col, FORCE] = h_force[i]
        rec[r, col, DX] = h_dir[i, 0]
        rec[r, col, DY] = h_dir[i, 1]
        rec[r, col, DZ] = h_dir[i, 2]
        rec[r, col, KIND] = h_kind[i]
    return count, nfree, m


@njit(cache=True, nogil=True)
def compact_rows(rec: np.ndarray, center: np.ndarray, row_keys: np.ndarray, ncol: int, n: int) -> int:
    """Move the live rows of ``[0, n)`` (an entry of any column not expired) down over the dead ones, in order,
    with their centres and keys, and empty the records left behind; returns the live count. One pass in memory
    order, in place (the index is rebuilt from ``row_keys`` after it)."""
    w = 0
    for r in range(n):
        alive = False
        for c in range(ncol):
            alive |= rec[r, c, STAMP] < np.inf
        if not alive:
            continue
        if w != r:
            for c in range(ncol):
                for f in range(FIELDS):
                    rec[w, c, f] = rec[r, c, f]
            for a in range(3):
                center[a, w] = center[a, r]
            row_keys[w] = row_keys[r]
        w += 1
    for r in range(w, n):
        for c in range(ncol):
            for f in range(FIELDS):
                rec[r, c, f] = 0.0
            rec[r, c, STAMP] = np.inf
    return w


@njit(cache=True, nogil=True)
def fuse_rows(rec: np.ndarray, center: np.ndarray, ncol: int, n: int, older_than: float):
    """Expire the entries stamped before ``older_than``, then eq. 4.14 with the type rules over
    rows ``[0, n)`` of the first ``ncol`` columns.

    Returns (out (k, OUT_SOURCES + ncol), source bits (k,), vetoed, unsupported, live rows, died) for the k
    kept voxels, ``died`` being the rows whose last entry expired in this pass. Kept are the voxels with a
    regular hypothesis, no null one and a fused likelihood above zero. A row
    of ``out`` holds the location, the fused likelihood, force and direction, then each column's
    likelihood (0 where absent). Force and direction average, weighted by likelihood, over the entries
    that carry a force. Expiry rides on this pass so the records are read once per cycle.
    """
    # Row by row over the records in memory order; the kept voxels go to one output array, row by row too: one
    # stream in, one stream out. A row is read in two passes: its types, stamps and likelihoods (the expiry, the
    # type rules, eq. 4.14), then, only when it is kept, its forces, directions and per-source likelihoods
    # (from the cache: the first pass just loaded them). Most rows of a live loop are support and null
    # hypotheses (the swept and the occupied volume of the arm), never kept: they skip the second pass. Which
    # columns hold an entry is random from row to row, so the first pass has no branch on it.
    out = np.empty((n + 1, OUT_SOURCES + ncol))
    kbits = np.empty(n + 1, dtype=np.uint64)
    died = np.empty(n + 1, dtype=np.int64)
    k = 0
    nd = 0
    vetoed = 0
    unsupported = 0
    live = 0
    for r in range(n):
        miss = 1.0
        bits = np.uint64(0)
        regular = False
        null = False
        expired = False
        for c in range(ncol):
            st = rec[r, c, STAMP]
            if st < older_than:  # expired: emptied for good (a store on every entry would dirty every line)
                expired = True
                st = np.inf
                rec[r, c, STAMP] = st
                rec[r, c, LIK] = 0.0
            v = st < np.inf
            kd = rec[r, c, KIND]
            bits |= np.uint64(v) << np.uint64(c)
            regular |= v & (kd == REGULAR)
            null |= v & (kd == NULL)
            miss *= 1.0 - rec[r, c, LIK]
        live += bits != 0
        died[nd] = r
        nd += expired & (bits == 0)
        vetoed += null
        unsupported += (bits != 0) & (not regular) & (not null)
        if not (regular and not null and miss < 1.0):
            continue
        wsum = 0.0
        fsum = 0.0
        dx = 0.0
        dy = 0.0
        dz = 0.0
        for c in range(ncol):
            p = rec[r, c, LIK]
            f = rec[r, c, FORCE]
            w = p * (f > 0.0)
            wsum += w
            fsum += w * f
            dx += w * rec[r, c, DX]
            dy += w * rec[r, c, DY]
            dz += w * rec[r, c, DZ]
            out[k, OUT_SOURCES + c] = p
        for a in range(3):
            out[k, a] = center[a, r]
        out[k, 3] = 1.0 - miss
        out[k, 4] = fsum / wsum if wsum > 0.0 else 0.0
        norm = np.sqrt(dx * dx + dy * dy + dz * dz)
        scale = 1.0 / norm if norm > 1e-12 else 0.0
        out[k, 5] = dx * scale
        out[k, 6] = dy * scale
        out[k, 7] = dz * scale
        kbits[k] = bits
        k += 1
    return out[:k], kbits[:k], vetoed, unsupported, live, died[:nd]


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
