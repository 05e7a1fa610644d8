"""Whether a list of rays is an image in row-major order, and how wide it is.

`Tracer.trace` traces image-shaped rays, (H, W, 3), in packets of blocks of
neighbouring pixels (4 x 4 with packets of 16), which share more of the tree than a
row's 16 rays do. A caller who passes a camera's rays flattened, (H*W, 3), as
`Camera.rays` and most other libraries give them, has the same image in rows.
`grid_width` finds its width from a sample of the rays, so that such rays are traced
in blocks too, and `ImageWidths` keeps a Tracer's widths from one call to the next.

Which rays share a packet never changes a hit (the kernels' results do not depend on
the packets or work sizes; tests/test_runtimes.py), so a wrong answer costs time,
never correctness: 1M random rays traced as a 1024-wide image took as long as rows
(BENCHMARKS.md, "(N, 3) rays traced as the image they are").

The test, on SAMPLES evenly spaced rays, for each of the rays' directions (as unit
vectors) and origins (when there is one per ray and they are not all equal):
- a row step is the distance between rays i and i + 1 (the median over the
  samples), the spread the median distance between two samples;
- the rays are rows of an image only if a row step is at most ROW_COHERENCE of the
  spread: neighbours in the list are neighbours in space (not so for random rays);
- the width is the smallest divisor w of N (MIN_WIDTH <= w, at least `min_rows` rows)
  for which rays i and i + w are at most GRID_RATIO row steps apart: the next row's
  pixel under a pixel is about one step away, a pixel w < W along the row about w
  steps.
"""
import dataclasses
import functools
import threading

import numpy as np

SAMPLES = 64
"""Rays sampled for each distance (the median of 64 is robust to the few samples
that straddle the end of a row)."""

MIN_WIDTH = 16
"""The narrowest width looked for: a candidate w less than the true width lies w row
steps along the row, which must exceed GRID_RATIO with a margin (a wide lens's row
steps shrink towards the image's edges)."""

ROW_COHERENCE = 0.25
"""Rows are coherent when their step is at most this fraction of the rays' spread: a
W-pixel-wide camera's is about 3 / W (1/300 at 1024, 0.19 at MIN_WIDTH), random
rays' about 1."""

GRID_RATIO = 3.0
"""Ray i + w lies at most this many row steps from ray i at the image's width (about
one for square pixels)."""

MAX_WIDTH = 1 << 16
"""The widest image looked for."""


def grid_width(origins, directions, min_rows=4):
    """The width of the row-major image that the rays are, or 0.

    origins : (3,) or (N, 3);  directions : (N, 3), float32 or float64 (any length;
    non-finite or zero directions are left out of the distances);
    min_rows : the fewest rows an image must have (a band of blocks).
    Returns an int w, a divisor of N with N // w >= min_rows, or 0 when the rays do
    not look like an image (or look like one narrower than MIN_WIDTH)."""
    d = np.asarray(directions)
    plan = _plan(len(d), max(min_rows, 1))
    if plan is None:
        return 0
    parts = [(d, True)]
    o = np.asarray(origins)
    if o.ndim == 2:
        parts.append((o, False))
    with np.errstate(all="ignore"):     # NaN, inf and huge rays are left out, not errors
        return _search(plan, parts)


def _search(plan, parts):
    """grid_width's search with its plan, for each (rays (N, 3), unit)."""
    fits = np.ones(len(plan.widths), dtype=bool)
    varies = False
    for x, unit in parts:
        # every sample the search needs, in one read: the samples, the rays after
        # them, and the rays a candidate width after them (rays far apart in memory
        # miss the cache, but cost little beside numpy's calls: fewer calls, less time)
        points = _points(x, plan.index, unit)
        p = points[:, :SAMPLES]
        if (p == p[:, :1]).all():
            continue                # all samples alike (a camera's one origin): spread 0
        # row 0: the row step; row 1 + c: the distance a candidate width on
        dist = _distance(p[:, None, :], points[:, SAMPLES:].reshape(3, -1, SAMPLES))
        dist[plan.outside] = np.nan
        medians = _median(dist)
        step = medians[0]
        # the median distance between two samples, whatever the order of the list's parts
        spread = _median(_distance(p[:, :, None], p[:, None, :]).ravel())[0]
        if not spread > 0:          # all alike (or none usable): says nothing
            continue
        varies = True
        if not step <= ROW_COHERENCE * spread:
            return 0
        fits &= medians[1:] <= GRID_RATIO * step
    if not varies or not fits.any():
        return 0
    return int(plan.widths[np.argmax(fits)])     # the smallest that fits


QUICK_SAMPLES = 16
"""Rays sampled by `rows_coherent`."""


def rows_coherent(origins, directions):
    """Whether rays next to each other in the list are next to each other in space, by
    grid_width's row test (a row step at most ROW_COHERENCE of the spread) on
    QUICK_SAMPLES evenly spaced rays, the spread taken between samples half the list
    apart: a check of some 60 us, which a camera's rays pass and rays in no order
    (random ones, for a start) fail, so that a width found for one is not used for the
    other. Arguments as grid_width's; False for fewer than 2 * QUICK_SAMPLES rays."""
    d = np.asarray(directions)
    n = len(d)
    if n < 2 * QUICK_SAMPLES:
        return False
    i = np.linspace(0, n - 2, QUICK_SAMPLES).astype(np.int64)
    index = np.concatenate([i, i + 1])
    parts = [(d, True)]
    o = np.asarray(origins)
    if o.ndim == 2:
        parts.append((o, False))
    varies = False
    with np.errstate(all="ignore"):
        for x, unit in parts:
            points = _points(x, index, unit)
            p = points[:, :QUICK_SAMPLES]
            if (p == p[:, :1]).all():
                continue
            step = _median(_distance(p, points[:, QUICK_SAMPLES:]))[0]
            spread = _median(_distance(p, np.roll(p, QUICK_SAMPLES // 2, axis=1)))[0]
            if not spread > 0:
                continue
            varies = True
            if not step <= ROW_COHERENCE * spread:
                return False
    return varies


WIDTHS_KEPT = 8
"""Ray counts whose image width an `ImageWidths` remembers."""


class ImageWidths:
    """The image widths a Tracer found for the ray counts it traced lately (the last
    WIDTHS_KEPT counts): widths[n] is the one kept for n rays.

    The search (grid_width) takes about 0.5 ms after an idle moment, 3-4 % of a
    2^20-ray trace of a small mesh. A caller tracing rays of the same count again
    mostly passes the same camera's: the width found for the last rays of that count
    is used at once, and the search runs while the kernel works, its answer kept for
    the next call. A stale width never changes a hit (packets do not: tested), only
    the time of that call. Rays that fail `rows_coherent` (random rays, say, between
    two calls of a camera's of the same count) are rows at once, and leave the width
    kept for the count as it was."""

    def __init__(self):
        self._widths = {}                 # n -> width, the oldest count first
        self._lock = threading.Lock()     # a Tracer's threads share it

    def __getitem__(self, n):
        with self._lock:
            return self._widths[n]

    def width(self, origins, directions, min_rows):
        """(width, search) for (N, 3) rays (grid_width's arguments): the width of the
        image they are to be traced as (0: rows), and None or the search to run while
        the kernel traces them."""
        n = len(directions)
        if not rows_coherent(origins, directions):
            return 0, None

        def search():
            found = grid_width(origins, directions, min_rows=min_rows)
            with self._lock:
                self._widths.pop(n, None)
                self._widths[n] = found
                while len(self._widths) > WIDTHS_KEPT:
                    self._widths.pop(next(iter(self._widths)))     # the oldest count
            return found

        with self._lock:
            kept = self._widths.get(n)
        if kept is not None:
            return kept, search
        return search(), None


@dataclasses.dataclass(frozen=True)
class _Plan:
    """What grid_width reads of N rays, for C candidate widths. widths: (C,) int64,
    increasing; index: ((C + 2) * SAMPLES,) int64: SAMPLES evenly spaced indices i
    below N - 1, then each i + 1, then i + w for each width w (i where that is N or
    more); outside: (C + 1, SAMPLES) bool, where i + w is N or more (row 0, i + 1:
    none), left out of the medians: at most a quarter of a candidate's samples, as
    w <= N / 4."""
    widths: np.ndarray
    index: np.ndarray
    outside: np.ndarray


@functools.lru_cache(maxsize=16)
def _plan(n, min_rows):
    """grid_width's _Plan for n rays and images of min_rows rows or more, or None when
    no width is possible (cached: a caller traces the same count again and again)."""
    widths = _divisors(n)
    widths = widths[(widths >= MIN_WIDTH) & (widths <= MAX_WIDTH) & (widths * min_rows <= n)]
    if len(widths) == 0:
        return None
    i = np.linspace(0, n - 2, SAMPLES).astype(np.int64)
    below = i[None, :] + widths[:, None]
    outside = np.concatenate([np.zeros((1, SAMPLES), dtype=bool), below >= n])
    index = np.concatenate([i, i + 1, np.where(below < n, below, i[None, :]).ravel()])
    plan = _Plan(widths=widths, index=index, outside=outside)
    for array in (plan.widths, plan.index, plan.outside):
        array.setflags(write=False)     # shared by every call with this n
    return plan


def _divisors(n):
    """The divisors of n >= 1, increasing, (k,) int64."""
    k = np.arange(1, int(np.sqrt(n)) + 2, dtype=np.int64)
    k = k[(k * k <= n) & (n % k == 0)]
    return np.unique(np.concatenate([k, n // k]))


def _points(x, index, unit):
    """x[index] in float64 (index: (M,) int; x (N, 3)) by component, (3, M), as unit
    vectors when `unit` (NaN for a zero row). By component, each a contiguous row:
    numpy's loops over a last axis of 3 are several times slower."""
    p = np.ascontiguousarray(x[index].T, dtype=np.float64)
    if unit:
        p /= np.sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2])
    return p


def _distance(p, q):
    """|p - q| of points by component (3, ...) (broadcast): (...), NaN or inf where p
    or q is not finite."""
    r = p - q
    return np.sqrt(r[0] * r[0] + r[1] * r[1] + r[2] * r[2])


def _median(dist):
    """Medians of the finite values of `dist` (..., S) along its last axis, (M,) for
    its M rows: NaN for a row with none."""
    dist = np.sort(dist.reshape(-1, dist.shape[-1]), axis=-1)     # NaN and inf last
    finite = np.count_nonzero(np.isfinite(dist), axis=-1)
    middle = dist[np.arange(len(dist)), np.maximum(finite - 1, 0) // 2]
    middle[finite == 0] = np.nan
    return middle
