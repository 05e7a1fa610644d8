"""Splitting a node's events between its children (Wald & Havran 2006, Sec. 5.2).

Given the chosen plane, every triangle of the node is classified by its events on
the split axis (errata 4), not by its vertices:

    END at or before the plane      -> left (below) only
    START at or after the plane     -> right (above) only
    PLANAR before / after the plane -> that side; PLANAR at it -> the side SAH chose
    everything else                 -> both: a straddler

Hot loops index with unsigned integers: numba then leaves out its negative-index
test, which otherwise keeps LLVM from vectorizing them.

Straddlers are re-clipped to each child's box (`clip.clip_split`) and their few
new events sorted (`straddler_events`); then one linear pass per axis moves the
events of one-sided triangles to their child, still sorted, with the new events
merged in on the way (`split_merge`). No node sorts all its events, so the whole
build is O(n log n) (errata 7).

Numba-compiled (`cache=True`; the first call compiles).
"""
import numpy as np
from numba import njit

from .clip import clip_split
from .events import END, START, box_events, key_bits, key_kind, key_uprim, sorted_copy
from .jit import BORROW

ON_LEFT = np.int8(1)
ON_RIGHT = np.int8(2)
ON_BOTH = np.int8(3)


@njit(cache=True, **BORROW)
def classify(buf, start, count, split_bits, planar_left, side, strad):
    """Classify the triangles of one node by its run of events on the split axis.

    buf[start:start+count] : the split axis's sorted events;  split_bits : the plane's
    `position_bits`;  planar_left : where PLANAR-at-the-plane triangles go.
    Writes side[prim] (ON_LEFT / ON_RIGHT / ON_BOTH) for every triangle of the node
    and the straddlers, in event order, to strad. Returns their number.

    The run is sorted by position, so it falls in three ranges (found by bisection):
    before the plane every START makes its triangle ON_BOTH and every END or PLANAR
    ON_LEFT (a later END before the plane overrides the START's ON_BOTH); at the plane
    START -> ON_RIGHT, END -> ON_LEFT, PLANAR -> the chosen side; after it START and
    PLANAR -> ON_RIGHT while END keeps what its START wrote. The loops before and
    after the plane have no branch on the events (the kinds come in no order a
    branch predictor could learn).
    """
    stop = start + count
    at = _first_from(buf, start, stop, split_bits)
    after = _first_from(buf, at, stop, split_bits + np.uint64(1))
    for i in range(np.uint64(start), np.uint64(at)):
        key = buf[i]
        # END 0, PLANAR 1 -> ON_LEFT 1;  START 2 -> ON_BOTH 3
        side[key_uprim(key)] = np.int8(1 + (key_kind(key) & 2))
    for i in range(np.uint64(at), np.uint64(after)):
        key = buf[i]
        kind = key_kind(key)
        prim = key_uprim(key)
        if kind == START:
            side[prim] = ON_RIGHT
        elif kind == END:
            side[prim] = ON_LEFT
        else:
            side[prim] = ON_LEFT if planar_left else ON_RIGHT
    for i in range(np.uint64(after), np.uint64(stop)):
        key = buf[i]
        prim = key_uprim(key)
        s = side[prim]
        side[prim] = s if key_kind(key) == END else ON_RIGHT
    n = 0
    for i in range(np.uint64(start), np.uint64(at)):
        key = buf[i]
        prim = key_uprim(key)
        strad[n] = prim
        n += (key_kind(key) == START) & (side[prim] == ON_BOTH)
    return n


@njit(cache=True, inline="always")
def _first_from(buf, lo, hi, bits):
    """The first index i in [lo, hi) with key_bits(buf[i]) >= bits (hi if none);
    buf[lo:hi] sorted."""
    while lo < hi:
        mid = (lo + hi) >> 1
        if key_bits(buf[mid]) >= bits:
            hi = mid
        else:
            lo = mid + 1
    return lo


@njit(cache=True, **BORROW)
def clip_straddlers(tri, strad, n, box, axis, pos, poly, left_box, right_box, left_ok, right_ok):
    """Clip each straddler to both children's boxes; *_ok[s] False: nothing left there."""
    for s in range(n):
        left_ok[s], right_ok[s] = clip_split(tri, strad[s], box, axis, pos, poly,
                                             left_box[s], right_box[s])


@njit(cache=True, **BORROW)
def split_merge(src, off, counts, side, new_left, new_left_runs, new_right, new_right_runs,
                dst, w_right, w_left, right_counts, left_counts):
    """Both children's sorted events in one pass over the node's: the events of
    one-sided triangles, run by run, merged with the straddlers' new events.

    src[off:] : the node's runs (counts (3,));  new_left, new_right : the straddlers'
    events in each child (`straddler_events`; runs (3, 2) start, count);  dst : the
    buffer the children go to, the right child's runs from w_right and the left
    child's from w_left (each may write one slot past its end: the branch-free copy
    writes every event to both children and moves on in one). right_counts,
    left_counts (3,) are written. Returns the triangles on each side (n_left,
    n_right: one START or PLANAR each in the x run).

    The straddlers' events are few: the node's events go in stretches up to the next
    new event of either child (one compare an event), then that child's new events
    below the next node event are written.
    """
    wl = w_left
    wr = w_right
    start = off
    for k in range(3):
        wl0 = wl
        wr0 = wr
        jl = new_left_runs[k, 0]
        jl_end = jl + new_left_runs[k, 1]
        jr = new_right_runs[k, 0]
        jr_end = jr + new_right_runs[k, 1]
        # the next new event of each child; all ones (past every key) when none is left
        next_l = new_left[jl] if jl < jl_end else _NONE
        next_r = new_right[jr] if jr < jr_end else _NONE
        i = np.uint64(start)
        end = np.uint64(start + counts[k])
        while True:
            stop_key = min(next_l, next_r)
            while i < end:
                key = src[i]
                if key > stop_key:                  # keys are distinct: > is >=
                    break
                s = side[key_uprim(key)]
                dst[np.uint64(wl)] = key
                dst[np.uint64(wr)] = key
                wl += s == ON_LEFT
                wr += s == ON_RIGHT
                i += np.uint64(1)
            key = src[i] if i < end else _NONE
            if stop_key == _NONE:
                break
            while next_l < key:
                dst[np.uint64(wl)] = next_l
                wl += 1
                jl += 1
                next_l = new_left[jl] if jl < jl_end else _NONE
            while next_r < key:
                dst[np.uint64(wr)] = next_r
                wr += 1
                jr += 1
                next_r = new_right[jr] if jr < jr_end else _NONE
        left_counts[k] = wl - wl0
        right_counts[k] = wr - wr0
        start += counts[k]
    n_left = 0
    for i in range(np.uint64(w_left), np.uint64(w_left + left_counts[0])):
        n_left += key_kind(dst[i]) != END
    n_right = 0
    for i in range(np.uint64(w_right), np.uint64(w_right + right_counts[0])):
        n_right += key_kind(dst[i]) != END
    return n_left, n_right


_NONE = np.uint64(0xFFFFFFFFFFFFFFFF)
"""Above every event key (positions use at most 32 bits, the key's top bits)."""


@njit(cache=True, **BORROW)
def straddler_events(strad, n, boxes, ok, out, runs, scratch):
    """Events of the clipped straddlers in one child, each axis's run sorted.

    boxes : (>= n, 2, 3) float32;  ok : (>= n,) bool;  runs : (3, 2) int64, written;
    scratch : (>= 2 n,) uint64, overwritten (each run is written there in straddler
    order, then sorted into out: `events.sorted_copy`).
    Returns the number of straddlers kept in this child.
    """
    w = 0
    kept = 0
    for k in range(3):
        runs[k, 0] = w
        g = 0
        for s in range(n):
            if ok[s]:
                g = box_events(boxes[s, 0, k], boxes[s, 1, k], strad[s], scratch, g)
                if k == 0:
                    kept += 1
        sorted_copy(scratch, 0, g, out, w)
        w += g
        runs[k, 1] = g
    return kept
