"""Events: where a triangle's box starts, ends or lies flat along one axis.

Every event is one uint64 key, so that sorting keys sorts events by position, then
type (END < PLANAR < START, Wald & Havran 2006), then triangle index, which makes
the order, and with it the whole build, deterministic::

    bits 32-63  position: the float32's bits mapped so that unsigned order is float
                order (-0.0 is stored as +0.0)
    bits 30-31  type: END = 0, PLANAR = 1, START = 2
    bits  0-29  triangle index (< 2**30 = layout.MAX_NODES)

A node's events are three sorted runs, one per axis (x, then y, then z), each listing
every triangle of the node once (PLANAR) or twice (START and END).

All functions are numba-compiled (`cache=True`: the first call in a fresh checkout
compiles them and stores the machine code in `__pycache__`).
"""
import concurrent.futures

import numpy as np
from numba import njit

from .jit import BORROW
from .threads import run_jobs

END = 0
PLANAR = 1
START = 2

_SIGN = np.uint64(0x80000000)
_ALL = np.uint64(0xFFFFFFFF)
_PRIM_MASK = np.uint64((1 << 30) - 1)
_U32 = np.uint64(32)
_U30 = np.uint64(30)
_U3 = np.uint64(3)


@njit(cache=True)
def position_bits(x):
    """float32 value -> uint64 in [0, 2**32) in the same order (-0.0 -> as +0.0)."""
    b = np.uint64(np.float32(np.float32(x) + np.float32(0.0)).view(np.uint32))
    if b >= _SIGN:
        return _ALL - b
    return b + _SIGN


@njit(cache=True)
def position_value(bits):
    """Inverse of `position_bits`: uint64 -> float32."""
    if bits >= _SIGN:
        b = bits - _SIGN
    else:
        b = _ALL - bits
    return np.uint32(b).view(np.float32)


@njit(cache=True)
def make_key(bits, kind, prim):
    """(position_bits, END/PLANAR/START, triangle index) -> uint64 key."""
    return (bits << _U32) | (np.uint64(kind) << _U30) | np.uint64(prim)


@njit(cache=True)
def key_bits(key):
    """The key's position bits (compare these, not floats)."""
    return key >> _U32


@njit(cache=True)
def key_kind(key):
    return np.int64((key >> _U30) & _U3)


@njit(cache=True)
def key_prim(key):
    return np.int64(key & _PRIM_MASK)


@njit(cache=True)
def key_uprim(key):
    """The key's triangle index as a uint64 (for indexing: no negative-index test)."""
    return key & _PRIM_MASK


@njit(cache=True, **BORROW)
def box_events(lo, hi, prim, out, w):
    """Write the events of one triangle's box [lo, hi] on one axis at out[w:];
    return the new write position."""
    if lo == hi:
        out[w] = make_key(position_bits(lo), PLANAR, prim)
        return w + 1
    out[w] = make_key(position_bits(lo), START, prim)
    out[w + 1] = make_key(position_bits(hi), END, prim)
    return w + 2


@njit(cache=True, nogil=True)
def event_counts(tri):
    """(3,) int64: the number of root events on each axis, 1 per triangle flat on
    that axis, else 2.  tri : (m, 3, 3) float32."""
    c = np.zeros(3, dtype=np.int64)
    for t in range(tri.shape[0]):
        for k in range(3):
            lo = min(tri[t, 0, k], tri[t, 1, k], tri[t, 2, k])
            hi = max(tri[t, 0, k], tri[t, 1, k], tri[t, 2, k])
            c[k] += 1 if lo == hi else 2
    return c


@njit(cache=True, nogil=True)
def part_axis_events(tri, k, pivot, below, keys, at):
    """Write the root's events on axis k at a position below `pivot` (below True;
    forward from keys[at]) or at or above it (below False; backward, ending before
    keys[at]), in triangle order either way; return the other end of the run.
    tri : (m, 3, 3) float32;  pivot : float32;  keys : uint64. (-0.0 and 0.0 are
    one position, as in the keys: float comparison treats them so.)"""
    if below:
        w = at
        for t in range(tri.shape[0]):
            lo = min(tri[t, 0, k], tri[t, 1, k], tri[t, 2, k])
            hi = max(tri[t, 0, k], tri[t, 1, k], tri[t, 2, k])
            if lo < pivot:
                keys[w] = make_key(position_bits(lo), PLANAR if lo == hi else START, t)
                w += 1
            if hi < pivot and lo != hi:
                keys[w] = make_key(position_bits(hi), END, t)
                w += 1
        return w
    w = at
    for t in range(tri.shape[0] - 1, -1, -1):
        lo = min(tri[t, 0, k], tri[t, 1, k], tri[t, 2, k])
        hi = max(tri[t, 0, k], tri[t, 1, k], tri[t, 2, k])
        if hi >= pivot and lo != hi:
            w -= 1
            keys[w] = make_key(position_bits(hi), END, t)
        if lo >= pivot:
            w -= 1
            keys[w] = make_key(position_bits(lo), PLANAR if lo == hi else START, t)
    return w


@njit(cache=True, nogil=True)
def axis_events(tri, k, keys, start):
    """Write the root's events on axis k, in triangle order, at keys[start:]; return
    the end of the run. tri : (m, 3, 3) float32;  keys : uint64."""
    return part_axis_events(tri, k, np.float32(np.inf), True, keys, start)


_DIGITS = ((30, 11), (41, 11), (52, 12))
"""(shift, bits) of the three radix digits of the key's position and type (bits 30-63)."""


@njit(cache=True, nogil=True)
def radix_sort_events(keys, start, stop, tmp, tmp_start):
    """Sort keys[start:stop] by position and type (key bits 30-63), stably: an LSD
    radix sort in three passes of 11, 11 and 12 bits (~10 ns a key, against ~40 for
    numpy's stable sort of the whole keys).

    keys, tmp : uint64;  tmp[tmp_start:tmp_start + stop - start] is overwritten.
    A run whose keys come in triangle order for equal (position, type), as
    `axis_events` writes them, ends up in full key order: the same as sorting it.
    A pass whose digit is the same in every key is skipped.
    """
    n = stop - start
    hist = np.zeros((3, 4096), dtype=np.int64)
    for i in range(np.uint64(start), np.uint64(stop)):
        key = keys[i]
        hist[0, (key >> np.uint64(30)) & np.uint64(0x7FF)] += 1
        hist[1, (key >> np.uint64(41)) & np.uint64(0x7FF)] += 1
        hist[2, key >> np.uint64(52)] += 1
    src = keys
    src_start = start
    dst = tmp
    dst_start = tmp_start
    in_tmp = False
    for d in range(3):
        shift = np.uint64(_DIGITS[d][0])
        size = 1 << _DIGITS[d][1]
        mask = np.uint64(size - 1)
        pos = np.empty(size, dtype=np.int64)
        total = dst_start
        skip = False
        for b in range(size):
            if hist[d, b] == n:
                skip = True
            pos[b] = total
            total += hist[d, b]
        if skip:
            continue
        for i in range(np.uint64(src_start), np.uint64(src_start + n)):
            key = src[i]
            b = (key >> shift) & mask
            dst[np.uint64(pos[b])] = key
            pos[b] += 1
        src, dst = dst, src
        src_start, dst_start = dst_start, src_start
        in_tmp = not in_tmp
    if in_tmp:
        keys[start:stop] = src[src_start:src_start + n]


SPLIT_TRIS = 30000
"""On two threads, meshes of at least this many triangles make and sort z's root events
in two jobs (`sorted_root_events`); in smaller ones the pivot's sample and the fourth
job's hand-over cost more than the balance saves (10k and 20k triangles 1.03 of the
time, 40k 0.97, 1.6M 0.92: BENCHMARKS.md)."""


def sorted_root_events(tri, room=0, threads=1, pool=None, empty=None, flat=None):
    """Events of the root node, each axis's run sorted (the build's only full sort).

    tri : (m, 3, 3) float32;  room : int, unused keys to leave after the events (the
    builder's event stack grows there: `subdivide.subdivide`);  threads : the three axes are made and
    sorted on up to this many threads (the numba functions release the GIL), or on
    `pool` (a concurrent.futures executor: the builder's kept one, `threads.kept_pool`)
    when one is given;  empty : None
    or a function n -> (n,) uint64 array to hold the keys (the builder's: `scratch.take`);
    flat : None, or (3,) int64 the triangles flat on each axis (`prepare.Prepared.flat`),
    which saves counting them here.
    Returns (keys (e + room,) uint64, counts (3,) int64): keys[:e] are the x run, then
    y, then z, `counts` long.

    Keys are distinct (they hold the triangle index) and each run is written in
    triangle order, so the radix sort on position and type (`radix_sort_events`)
    gives the one sorted order.

    On two threads, three axes would leave one thread idle for a third of the time:
    there, from SPLIT_TRIS triangles, z is made and sorted in two jobs, its events
    below a pivot and those at or above (`part_axis_events`), each sorted where it
    ends up in the run. The pivot is the median of a sample of the triangles' z
    extents, so that the two are about even; it only balances the threads: the run
    is the same for any pivot.
    """
    def run(jobs):
        if pool is not None or threads <= 1:
            return run_jobs(pool, jobs)
        with concurrent.futures.ThreadPoolExecutor(min(threads, 3)) as own:
            return run_jobs(own, jobs)

    m = tri.shape[0]
    counts = event_counts(tri) if flat is None else 2 * m - np.asarray(flat, dtype=np.int64)
    e = int(counts.sum())
    keys = np.empty(e + room, dtype=np.uint64) if empty is None else empty(e + room)
    # The sort's scratch: the second half of keys when the events fit in the first
    # (the builder's second event buffer, `subdivide.split_keys`: the pages the sort
    # faults in are the ones the root's children are written to, not new ones), else
    # an array of its own.
    half = (e + room) // 2
    tmp, tmp_start = (keys, half) if half >= e else (np.empty(e, dtype=np.uint64), 0)
    start = np.r_[0, np.cumsum(counts)]

    def axis(k):
        axis_events(tri, k, keys, start[k])
        radix_sort_events(keys, start[k], start[k + 1], tmp, tmp_start + start[k])

    if threads != 2 or m < SPLIT_TRIS:
        run([(axis, k) for k in range(3)])
        return keys, counts

    sample = tri[::max(1, m // 1024), :, 2]
    pivot = np.float32(np.median(np.concatenate([sample.min(axis=1), sample.max(axis=1)])))

    def side(below):
        """z's events below the pivot (from the run's start) or at or above it
        (ending at the run's end), sorted."""
        at = start[2] if below else start[3]
        end = part_axis_events(tri, 2, pivot, below, keys, at)
        first, stop = (at, end) if below else (end, at)
        radix_sort_events(keys, first, stop, tmp, tmp_start + first)

    run([(axis, 0), (axis, 1), (side, True), (side, False)])
    return keys, counts


RANK_SORT_MAX = 64
"""Keys sorted at once by rank (`sorted_copy`); longer runs are sorted in blocks of
this many, then merged."""


@njit(cache=True, **BORROW)
def _rank_scatter(src, start, stop, dst, at):
    """dst[at:at + n] = src[start:stop] sorted, n = stop - start, keys distinct: each
    key goes to its rank, the number of keys below it. n^2 compares, but with no
    branch on the keys and in vectors (the inner loop indexes with unsigned integers
    so that LLVM vectorizes it). Equal keys would share a rank, leaving a slot of dst
    unwritten: the builder's runs cannot have them (a key holds its triangle index
    and event type; a leaf lists a triangle once)."""
    for i in range(np.uint64(start), np.uint64(stop)):
        key = src[i]
        r = np.uint64(0)
        for j in range(np.uint64(start), np.uint64(stop)):
            r += np.uint64(src[j] < key)
        dst[np.uint64(at) + r] = key


@njit(cache=True, **BORROW)
def _merge_runs(src, s0, dst, d0, n, width):
    """dst[d0:d0 + n] = src[s0:s0 + n] with each pair of neighbouring sorted runs of
    `width` keys (the last ones may be shorter) merged into one (equal keys: the first
    run's first)."""
    for lo in range(0, n, 2 * width):
        mid = min(lo + width, n)
        hi = min(lo + 2 * width, n)
        i = lo
        j = mid
        w = d0 + lo
        while i < mid and j < hi:
            if src[s0 + j] < src[s0 + i]:
                dst[w] = src[s0 + j]
                j += 1
            else:
                dst[w] = src[s0 + i]
                i += 1
            w += 1
        while i < mid:
            dst[w] = src[s0 + i]
            i += 1
            w += 1
        while j < hi:
            dst[w] = src[s0 + j]
            j += 1
            w += 1


@njit(cache=True, **BORROW)
def sorted_copy(src, start, stop, dst, at):
    """dst[at:at + n] = src[start:stop] sorted (n = stop - start), for distinct keys
    (`_rank_scatter`); src[start:stop] is overwritten (the merges' scratch). Any
    integer dtype.

    Runs of the builder's size (a node's straddlers' events on one axis, a leaf's
    triangles: most under 32 keys) sort by rank, branch-free and in vectors: 2-4x
    as fast as an insertion sort there (BENCHMARKS.md), and with no numba
    runtime call (numba's ndarray.sort needs one). Longer runs in blocks of
    RANK_SORT_MAX, merged pairwise, back and forth between dst and src.
    """
    n = stop - start
    for lo in range(0, n, RANK_SORT_MAX):
        _rank_scatter(src, start + lo, start + min(lo + RANK_SORT_MAX, n), dst, at + lo)
    width = RANK_SORT_MAX
    in_dst = True
    while width < n:
        if in_dst:
            _merge_runs(dst, at, src, start, n, width)
        else:
            _merge_runs(src, start, dst, at, n, width)
        in_dst = not in_dst
        width *= 2
    if not in_dst:
        for i in range(n):
            dst[at + i] = src[start + i]
