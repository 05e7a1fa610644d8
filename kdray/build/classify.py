"""Splitting a node's events between its children (Wald & Havran 2006, Sec. 5.2).

Given the chosen plane, every triangle of the node is classified by its events on
the split axis (errata 4), not by its vertices:

    END at or before the plane      -> left (below) only
    START at or after the plane     -> right (above) only
    PLANAR before / after the plane -> that side; PLANAR at it -> the side SAH chose
    everything else                 -> both: a straddler

Hot loops index with unsigned integers: numba then leaves out its negative-index
test, which otherwise keeps LLVM from vectorizing them.

One linear pass per axis moves the events of one-sided triangles to their child,
still sorted. Straddlers are re-clipped to each child's box (`clip.clip_split`),
their few new events are sorted and merged in. No node sorts all its events, so the
whole build is O(n log n) (errata 7).

Numba-compiled (`cache=True`; the first call compiles).
"""
import numpy as np
from numba import njit

from .clip import clip_split
from .events import END, START, box_events, key_bits, key_kind, key_uprim, sort_range

ON_LEFT = np.int8(1)
ON_RIGHT = np.int8(2)
ON_BOTH = np.int8(3)


@njit(cache=True)
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


@njit(cache=True)
def clip_straddlers(tri, strad, n, box, axis, pos, poly, left_box, right_box, left_ok, right_ok):
    """Clip each straddler to both children's boxes; *_ok[s] False: nothing left there."""
    for s in range(n):
        left_ok[s], right_ok[s] = clip_split(tri, strad[s], box, axis, pos, poly,
                                             left_box[s], right_box[s])


@njit(cache=True)
def split_runs(buf, off, counts, side, left, right, left_runs, right_runs):
    """Copy the events of one-sided triangles to `left` / `right`, run by run.

    Runs stay sorted. left, right : at least sum(counts) + 1 long (the branch-free
    copy writes one slot past the end). left_runs, right_runs : (3, 2) int64, written
    (start, count) per axis. Returns the number of left-only and right-only triangles.
    """
    wl = 0
    wr = 0
    start = off
    for k in range(3):
        left_runs[k, 0] = wl
        right_runs[k, 0] = wr
        for i in range(np.uint64(start), np.uint64(start + counts[k])):
            key = buf[i]
            s = side[key_uprim(key)]
            left[np.uint64(wl)] = key
            right[np.uint64(wr)] = key
            wl += s == ON_LEFT
            wr += s == ON_RIGHT
        left_runs[k, 1] = wl - left_runs[k, 0]
        right_runs[k, 1] = wr - right_runs[k, 0]
        start += counts[k]
    # Triangles per side: one START or PLANAR each in the x run.
    n_left = 0
    for i in range(np.uint64(left_runs[0, 1])):
        n_left += key_kind(left[i]) != END
    n_right = 0
    for i in range(np.uint64(right_runs[0, 1])):
        n_right += key_kind(right[i]) != END
    return n_left, n_right


@njit(cache=True)
def straddler_events(strad, n, boxes, ok, out, runs):
    """Events of the clipped straddlers in one child, each axis's run sorted.

    boxes : (>= n, 2, 3) float32;  ok : (>= n,) bool;  runs : (3, 2) int64, written.
    Returns the number of straddlers kept in this child.
    """
    w = 0
    kept = 0
    for k in range(3):
        runs[k, 0] = w
        for s in range(n):
            if ok[s]:
                w = box_events(boxes[s, 0, k], boxes[s, 1, k], strad[s], out, w)
                if k == 0:
                    kept += 1
        runs[k, 1] = w - runs[k, 0]
        sort_range(out, runs[k, 0], w)
    return kept


@njit(cache=True)
def merge_runs(a, a_runs, b, b_runs, out, w, counts):
    """Merge each axis's run of a and of b (both sorted) into out[w:]; counts (3,) is
    written with the merged runs' lengths. Returns the new write position.

    b (the straddlers' new events) is short next to a: the loop runs over b, and the
    a keys after the last b key, often most of them, are copied in one go (`_copy`).
    """
    for k in range(3):
        i = a_runs[k, 0]
        i_end = i + a_runs[k, 1]
        w0 = w
        for j in range(b_runs[k, 0], b_runs[k, 0] + b_runs[k, 1]):
            key = b[j]
            while i < i_end and a[np.uint64(i)] < key:
                out[np.uint64(w)] = a[np.uint64(i)]
                i += 1
                w += 1
            out[np.uint64(w)] = key
            w += 1
        w = _copy(a, i, i_end, out, w)
        counts[k] = w - w0
    return w


@njit(cache=True, inline="always")
def _copy(src, start, stop, dst, w):
    """dst[w:w + stop - start] = src[start:stop]; returns w + stop - start. Long blocks
    as a slice assignment (a memmove), short ones key by key (a slice costs ~50 cycles)."""
    n = stop - start
    if n >= 64:
        dst[w:w + n] = src[start:stop]
        return w + n
    for i in range(np.uint64(start), np.uint64(stop)):
        dst[np.uint64(w)] = src[i]
        w += 1
    return w
