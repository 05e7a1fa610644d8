"""Every hit along each ray: `intersections`, in compressed rows (`Intersections`),
sorted by t within each ray (ties by input id), each triangle once; and the float64
checks that rest on such lists (which float32 hits count in double precision, and
each ray's nearest that does: `counted_lists`), for every query's precision="double".

    hits = tracer.intersections(origins, directions, max_hits=None)
    hits.offsets (N + 1,) int64; per hit: hits.ray, .t, .prim, .u, .v, .object

A first pass lists each ray's GUESS_HITS nearest in slots of private memory and marks
the rays that had more; those are counted (kdray.query_rays.count_pass), then listed
again with as many slots (`list_hits`): no hit is dropped for want of room.
Intersections take the nearest hit's test (kernels/triangle.cl), so a ray through an
edge or a vertex lists every triangle that has it (docs/conventions.md, "Ray queries").
"""
import dataclasses
import functools

import numpy as np

from . import device as _device
from .double import flat_rays64, wants_double
from .errors import DeviceError, KdrayError
from .host import check_host_memory, page_aligned_empty, take_rows
from .query_rays import (LIST_MORE, LIST_SLOTS, WALK_FAULT, QueryRays, as_image,
                         check_fault, count_pass, launch)
from .tree import object_ids


GUESS_HITS = 8
"""Slots a ray gets in `intersections`' first pass (at most LIST_SLOTS), which lists
every hit of the rays that have no more (most rays: 0.4-0.7 hits a ray for a camera's
or random rays, 2.6 for rays aimed at a closed mesh from outside, of which 5 % have
more than 4); only the others are counted, then listed again with their own number
of slots."""

GUESS_CHUNK = 1 << 20
"""Rays `intersections` takes through its first pass at once: their slots (GUESS_HITS
a ray, 128 bytes) are reserved, and only their hits' pages are written."""

HIT_BYTES = 16
"""Host bytes of one listed hit: t (4), u and v (8), prim (4); ray and object are
made on the host when asked (8 bytes each)."""

COUNT_FIRST = 1 << 12
"""The rays with many hits `intersections` counts first, then twice as many at a time,
so that lists that cannot fit in memory are refused once the hits counted so far do
not fit, not after every ray is counted (a million rays through 40,000 stacked
triangles take minutes to count)."""

DEVICE_ROWS_FROM = 1 << 14
"""Hits from which a list's rows are gathered by a kernel (`_rows_on_device`) on a CPU
device: below, numpy's gather takes less than the kernel's launch and wait (Zen 4 VM:
3 hits 29 us against 87, 12,468 hits 77 against 102, 50,068 hits 223 against 141).
The same rows either way."""


@dataclasses.dataclass(eq=False)
class Intersections:
    """Every hit of N rays, in compressed rows: the hits of ray i are
    offsets[i] .. offsets[i + 1] - 1, sorted by t, ties by input triangle id.

    offsets : (N + 1,) int64
    t : (H,) float32 (float64 with precision="double"), in units of |direction|
    prim : (H,) uint32 input triangle id;  u, v : (H,) barycentrics as `Hits` has them
    object_table : the tree's KdTree.objects, which `object` looks up prim in
    shape : the rays' shape ((N,), or (H, W) for image-shaped rays: ray i is then the
        row-major ray i)."""

    offsets: np.ndarray
    t: np.ndarray
    prim: np.ndarray
    u: np.ndarray
    v: np.ndarray
    object_table: np.ndarray = dataclasses.field(default=None, repr=False)
    shape: tuple = None

    def __len__(self):
        return len(self.offsets) - 1

    @property
    def counts(self):
        """(N,) int64: hits of each ray (in the rays' shape)."""
        counts = np.diff(self.offsets)
        return counts if self.shape is None else counts.reshape(self.shape)

    @functools.cached_property
    def ray(self):
        """(H,) int64: the ray of each hit (its index in the flattened rays)."""
        return np.repeat(np.arange(len(self), dtype=np.int64), np.diff(self.offsets))

    @functools.cached_property
    def object(self):
        """(H,) uint32: each hit triangle's object (kdray.tree.object_ids)."""
        return object_ids(self.prim, self.object_table)

    def of(self, i):
        """(t, prim) of ray i's hits (views)."""
        a, b = self.offsets[i], self.offsets[i + 1]
        return self.t[a:b], self.prim[a:b]


def list_hits(tracer, rays, caps, crossing=False, nearest_k=False):
    """(Intersections, more) of `rays` (their float32 t, u, v) with at most caps[i]
    hits of ray i ((N,) int64; at least its distinct hits for every hit; or an int,
    the same for all; crossing: its crossings, the count's rule, not every hit), its
    nearest in (t, input id) order: the kernel fills each ray's slots (list_rays; a cap
    of at most LIST_SLOTS for all, `_first_pass`), then the slots left empty are
    dropped. more: (N,) bool, the rays that had
    more hits than caps[i]. nearest_k: the caps are the nearest hits wanted (max_hits,
    or a ray's exact count), not whether there are more: a ray's walk ends once its
    slots are taken and the last hit is final (queries.cl, kd_list_done), and `more`
    is then not known."""
    cap = int(caps) if np.ndim(caps) == 0 else None      # the same for every ray
    if cap is not None and cap <= LIST_SLOTS:
        n_found, more, first, slots = _first_pass(tracer, rays, cap, crossing, nearest_k)
        return _gathered(tracer, n_found, first, slots), more
    caps = np.broadcast_to(np.asarray(caps, dtype=np.int64), (rays.n,))
    offsets = _offsets(caps)
    total = int(offsets[-1])
    _check_hits_memory(total * (HIT_BYTES + 4) + rays.n * 12, total, rays.n)
    t = page_aligned_empty((total,), np.float32)
    uv = page_aligned_empty((total, 2), np.float32)
    prim = page_aligned_empty((total,), np.uint32)
    found = page_aligned_empty((rays.n,), np.uint32)
    # a launch's rays and slots fit the device (a ray's slots counted at their mean)
    mean = HIT_BYTES * total / max(rays.n, 1)
    # (the float32 rays, their float64 copies, t ranges, offsets, caps, count, slots)
    o_bytes, d_bytes = rays.ray_bytes()
    step = tracer._launch_size([(o_bytes + 24) * rays.o_step, d_bytes + 24, 8 * rays.t_step, 16,
                                int(mean) + 1])
    start = 0
    while start < rays.n:
        stop = min(rays.n, start + step)
        # and no more slots than the device's largest buffer holds
        limit = int(tracer.device.max_mem_alloc_size) // 8
        while stop - start > 1 and offsets[stop] - offsets[start] > limit:
            stop = start + (stop - start) // 2
        a, b = int(offsets[start]), int(offsets[stop])
        if b - a > limit:
            raise DeviceError(f"ray {start}'s {b - a} hits do not fit in one buffer on "
                              f"{tracer.device.name.strip()}: ask for fewer (max_hits)")
        extra = (np.uint32(crossing), np.uint32(nearest_k),
                 (offsets[start:stop] - a).astype(np.uint64), caps[start:stop].astype(np.uint32))
        launch(tracer, "list_rays", rays, start, stop, extra,
                {"t": t[a:b] if b > a else np.empty(1, np.float32),
                 "uv": uv[a:b] if b > a else np.empty((1, 2), np.float32),
                 "prim": prim[a:b] if b > a else np.empty(1, np.uint32),
                 "found": found[start:stop]}, exact=tracer.refine)
        start = stop
    n_found, more = _found(found)
    if (n_found == caps).all():
        return Intersections(offsets, t, prim, uv[:, 0], uv[:, 1],
                             object_table=tracer.tree.objects), more
    return _gathered(tracer, n_found, offsets[:-1], (t, uv, prim)), more


def _check_hits_memory(nbytes, hits, rays, what=""):
    """KdrayError, before they are allocated, where nbytes for a list of `hits` hits of
    `rays` rays (`what` it is, if more than that) are more host memory than is
    available."""
    check_host_memory(nbytes, f"the {hits:,} hits of {rays:,} rays{' ' + what if what else ''}",
                      "list fewer rays at a time, or fewer hits a ray (max_hits)")


def _offsets(counts):
    """(N + 1,) int64: the compressed rows' offsets of (N,) counts."""
    offsets = np.zeros(len(counts) + 1, dtype=np.int64)
    np.cumsum(counts, out=offsets[1:])
    return offsets


def _found(found):
    """(n, more) of list_rays' or list_first's counts (found: (N,) uint32): each ray's
    hits listed ((N,) int64) and whether it had more (LIST_MORE); DeviceError where a
    walk met a corrupt tree."""
    # one pass finds the marked rays (LIST_MORE, WALK_FAULT), then only they are read
    marked = np.flatnonzero(found >= np.uint32(LIST_MORE))
    check_fault(found[marked] == WALK_FAULT, "intersections")
    more = np.zeros(len(found), dtype=bool)
    more[marked] = True
    n_found = found.astype(np.int64)
    n_found[marked] &= ~LIST_MORE
    return n_found, more


def _gathered(tracer, counts, first, slots):
    """An Intersections of the hits listed in slots (t, uv, prim: (S,), (S, 2), (S,)):
    ray i's counts[i] hits ((N,) int64) from slot first[i] on ((N,) uint32 or int64).
    A run that reaches past the slots written takes what is there (past the end, the
    last slot): its caller puts those rays' hits in place. Gathered on the device where
    the slots are host memory it reads in place (`_rows_on_device`) and there are
    DEVICE_ROWS_FROM hits or more, else by numpy."""
    offsets = _offsets(counts)
    on_device = tracer._zero_copy and offsets[-1] >= DEVICE_ROWS_FROM
    rows = _rows_on_device if on_device else _rows_on_host
    t, uv, prim = rows(tracer, counts, offsets, first, slots)
    return Intersections(offsets, t, prim, uv[:, 0], uv[:, 1], object_table=tracer.tree.objects)


def _rows_on_host(tracer, counts, offsets, first, slots):
    """(t, uv, prim) of `_gathered`'s rows (counts (N,), offsets (N + 1,) int64) by
    numpy: one index for the three gathers, made over the hits, not over every slot
    (most are empty)."""
    keep = np.arange(offsets[-1]) + np.repeat(first - offsets[:-1], counts)
    return tuple(take_rows(a, keep, mode="clip") for a in slots)


def _rows_on_device(tracer, counts, offsets, first, slots):
    """(t, uv, prim) of `_gathered`'s rows (counts (N,), offsets (N + 1,) int64), copied by
    kernels/hit_rows.cl, a ray a work-item: on a CPU about a quarter of numpy's time,
    which made an index over the hits and took three times with it on one thread."""
    n, total = len(offsets) - 1, int(offsets[-1])
    t = page_aligned_empty((total,), np.float32)
    uv = page_aligned_empty((total, 2), np.float32)
    prim = page_aligned_empty((total,), np.uint32)
    if not total:
        return t, uv, prim
    first = first if first.dtype in (np.uint32, np.int64) else first.astype(np.int64)
    first_t = "uint" if first.dtype == np.uint32 else "long"
    entry = tracer._built("hit_rows.cl", {"FIRST_T": first_t}, ("hit_rows",))
    (f_buf, f_at), (o_buf, o_at) = (tracer._input_buffer(a) for a in (first, offsets))
    tracer._run_items(entry, "hit_rows", n,
                      (f_buf, np.uint32(f_at), o_buf, np.uint32(o_at), np.uint32(n),
                       np.uint64(len(slots[0])), *map(tracer._whole_input, slots)),
                      {"t": t, "uv": uv, "prim": prim})
    return t, uv, prim


def _first_pass(tracer, rays, cap, crossing, nearest_k):
    """(n, more, first, slots): `list_hits`'s pass over `rays` with the same cap <=
    LIST_SLOTS for all, by list_first, which writes each work-item's hits one after
    another, so that only the slots of hits are written (the arrays' other pages are
    never touched): ray i's n[i] hits ((N,) int64) from slot first[i] on ((N,)
    uint32) of slots (t (S,) float32, uv (S, 2) float32, prim (S,) uint32), in (t,
    input id) order; more as `list_hits`'s."""
    cl = _device._cl()
    total = rays.n * cap
    _check_hits_memory(total * HIT_BYTES + rays.n * 24, total, rays.n)
    t = page_aligned_empty((total,), np.float32)
    uv = page_aligned_empty((total, 2), np.float32)
    prim = page_aligned_empty((total,), np.uint32)
    found = page_aligned_empty((rays.n,), np.uint32)
    first = page_aligned_empty((rays.n,), np.uint32)
    # (the float32 rays, their float64 copies, t ranges, count, first slot, slots)
    o_bytes, d_bytes = rays.ray_bytes()
    widths = [(o_bytes + 24) * rays.o_step, d_bytes + 24, 8 * rays.t_step, 8, HIT_BYTES * cap]
    step = min(tracer._launch_size(widths), int(tracer.device.max_mem_alloc_size) // (8 * cap))
    for start in range(0, rays.n, step):
        stop = min(rays.n, start + step)
        a, b = start * cap, stop * cap
        # where the launch's next hits go: a counter the work-items add to
        next_hit = cl.Buffer(tracer.context, cl.mem_flags.READ_WRITE | cl.mem_flags.COPY_HOST_PTR,
                             hostbuf=np.zeros(1, dtype=np.uint32))
        out = {"t": t[a:b], "uv": uv[a:b], "prim": prim[a:b], "found": found[start:stop],
               "first": first[start:stop]}
        device_out = launch(tracer, "list_first", rays, start, stop,
                             (np.uint32(crossing), np.uint32(cap), np.uint32(nearest_k), next_hit),
                             out, exact=tracer.refine, read=False)
        # the slots as far as the hits go (a device other than a CPU copies no more)
        hits = np.zeros(1, dtype=np.uint32)
        cl.enqueue_copy(tracer.queue, hits, next_hit)
        used = {name: array[:int(hits[0])] if name in ("t", "uv", "prim") else array
                for name, array in out.items()}
        used = {name: array for name, array in used.items() if array.size}   # no 0 bytes
        tracer._read_outputs({name: device_out[name] for name in used}, used)
        if start:
            first[start:stop] += np.uint32(a)    # the slots' total fits (memory)
    n_found, more = _found(found)
    return n_found, more, first, (t, uv, prim)


def intersections(tracer, origins, directions, t_min=0.0, t_max=np.inf, max_hits=None,
                  precision="single"):
    """Every hit of each ray with t_min < t < t_max, sorted by t (ties by input id),
    each triangle once: an `Intersections`. max_hits=k keeps each ray's k nearest (the
    first k of the whole list). A first pass lists each ray's GUESS_HITS nearest and
    marks the rays that had more; those are counted, then listed again with as many
    slots: no hit is dropped for want of room (KdrayError when they do not fit in
    memory). precision="double": t, u, v in float64 from the tree's float64 triangles
    and the rays as given (kdray.double), sorted by that t."""
    double = wants_double(precision, tracer.tree)
    if max_hits is not None:
        if isinstance(max_hits, bool) or not isinstance(max_hits, (int, np.integer)):
            raise KdrayError(f"max_hits must be None or an integer >= 1, got "
                             f"{type(max_hits).__name__} {max_hits!r:.60}".replace("\n", " "))
        if max_hits < 1:
            raise KdrayError(f"max_hits must be at least 1, got {max_hits}")
        # a Python int (numpy's small integers overflow in the slots' sizes), and no
        # more than a ray can have: each triangle is listed once
        max_hits = min(int(max_hits), max(1, len(tracer.tree.triangles)))
    rays = as_image(tracer, QueryRays(tracer, origins, directions, t_min, t_max), origins,
                  directions)
    if rays.n <= GUESS_CHUNK:
        hits = _listed(tracer, rays, max_hits)
    else:
        hits = _concatenated([_listed(tracer, rays.subset(slice(a, a + GUESS_CHUNK)), max_hits)
                              for a in range(0, rays.n, GUESS_CHUNK)])
    hits.t *= np.float32(tracer._scale)      # a power of two: exact
    if double:
        hits, at_origin = _double(tracer, hits, origins, directions)
        hits = _in_range(tracer, hits, at_origin, origins, directions, t_min, t_max, max_hits)
    hits.shape = None if len(rays.shape) == 1 else rays.shape
    return hits


def flat_t(t, n):
    """(n,) float64 view of a t range's end: a number, or an array of the rays' shape."""
    t = np.asarray(t, dtype=np.float64)
    return np.broadcast_to(t.reshape(-1) if t.ndim else t, (n,))


def hits_counted64(tracer, prim, o, d, lo, hi, rays=None):
    """(h,) bool: whether each hit the kernels found (prim (h,) input ids, MISS: none)
    counts in float64 (_counted64) for its ray, row `rays[i]` (or i) of o, d (N, 3)
    float64 and lo, hi (N,)."""
    from .double import hits_double
    t, _, at_origin = hits_double(tracer.tree.triangles64, prim, o, d, rays=rays,
                                  tree=tracer.tree, on_plane=True)
    at = slice(None) if rays is None else rays
    return _counted64(t, at_origin, lo[at], hi[at])


def _counted64(t, at_origin, lo, hi):
    """(h,) bool: whether each double-precision hit counts: lo < t < hi (float64 t)
    and its ray's origin not on its float64 plane (kdray.double.ON_PLANE: a ray from a
    point on its triangle meets that plane at about t = 0, on either side)."""
    return (t > lo) & (t < hi) & ~at_origin


def _in_range(tracer, hits, at_origin, origins, directions, t_min, t_max, max_hits):
    """Double-precision `hits` (Intersections sorted by float64 t; at_origin, _double's)
    less those that do not count (_counted64): the float32 test found them in (t_min,
    t_max), but the float64 triangle, within float32 rounding of the tree's, puts them
    outside or at the origin (a ray from a point on its triangle). A ray whose list
    was cut at max_hits and has fewer that count is listed again with room for more
    (`counted_lists`), so that it keeps its max_hits nearest that count."""
    o, d = flat_rays64(origins, directions)
    n = len(d)
    lo, hi = flat_t(t_min, n), flat_t(t_max, n)
    ray = hits.ray
    keep = _counted64(hits.t, at_origin, lo[ray], hi[ray])
    if keep.all():
        return hits
    parts = [(ray[keep], hits.t[keep], hits.prim[keep], hits.u[keep], hits.v[keep])]
    # rays cut at max_hits with fewer that count (none can have more hits than the tree
    # has triangles: intersections' bound)
    again = np.zeros(0, np.int64)
    if max_hits is not None and max_hits < len(tracer.tree.triangles):
        counted = np.bincount(ray[keep], minlength=n)
        again = np.flatnonzero((np.diff(hits.offsets) == max_hits) & (counted < max_hits))
    if again.size:
        cap = max_hits + int((max_hits - counted[again]).max())
        old = ~np.isin(parts[0][0], again)
        parts = [tuple(a[old] for a in parts[0]),
                 counted_lists(tracer, o, d, lo, hi, again, cap, max_hits)]
    ray, t, prim, u, v = (np.concatenate(c) for c in zip(*parts))
    order = np.argsort(ray, kind="stable")             # each ray's hits stay in t order
    offsets = np.concatenate([[0], np.cumsum(np.bincount(ray, minlength=n))])
    return Intersections(offsets, t[order], prim[order], u[order], v[order],
                         object_table=hits.object_table)


def counted_lists(tracer, o, d, lo, hi, rays, cap, max_hits):
    """(ray, t, prim, u, v) of the max_hits nearest hits that count (_counted64) of each
    ray of `rays` ((k,) int64 rows of o, d (N, 3) float64 and lo, hi (N,)), in (ray, t)
    order: each ray's cap nearest float32 hits listed, made float64 (_double), those
    that do not count dropped; a ray cut at cap with fewer than max_hits that count is
    listed again with twice the room (never more than the tree's triangles), so that
    the hits that do not count cost their rays a few lists, not one a hit."""
    parts = []
    most = len(tracer.tree.triangles)
    while rays.size:
        listed = intersections(tracer, o[rays], d[rays], lo[rays], hi[rays], cap)
        hits, at_origin = _double(tracer, listed, o[rays], d[rays])
        ray = hits.ray
        keep = _counted64(hits.t, at_origin, lo[rays][ray], hi[rays][ray])
        counted = np.bincount(ray[keep], minlength=len(rays))
        done = (counted >= max_hits) | (np.diff(hits.offsets) < cap) | (cap >= most)
        # a done ray's first max_hits that count (a ray's hits are in t order)
        rank = np.cumsum(keep) - 1
        rank -= np.concatenate([[0], np.cumsum(counted)])[ray]
        take = keep & done[ray] & (rank < max_hits)
        parts.append((rays[ray[take]], hits.t[take], hits.prim[take], hits.u[take],
                      hits.v[take]))
        rays, cap = rays[~done], min(most, 2 * cap)
    return tuple(np.concatenate(c) for c in zip(*parts))


def _kernel_normal(tri):
    """(k, 3) float32 unit normals of float32 triangles (k, 3, 3) as the kernels make
    them (ops.h: kd_normalize(kd_cross(p1 - p0, p2 - p0)), each operation in float32
    in the same order)."""
    a, b = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    c = np.stack([a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1], a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
                  a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]], axis=1)
    c = c / np.abs(c).max(axis=1, keepdims=True)
    return c / np.sqrt((c[:, :1] * c[:, :1] + c[:, 1:2] * c[:, 1:2]) + c[:, 2:] * c[:, 2:])


def nearest_in_range(tracer, hits, at_origin, origins, directions, t_min, t_max):
    """Tracer.trace's double-precision `hits` (Hits, float64 t, u, v; at_origin (N,)
    bool, hits_double's) with each hit that does not count (_counted64) replaced by the
    ray's nearest that does (`counted_lists`), or a miss; that hit's
    normal is its triangle's, computed on the host as the kernel computes it."""
    from .layout import MISS
    n = len(hits.t)
    lo, hi = flat_t(t_min, n), flat_t(t_max, n)
    o, d = flat_rays64(origins, directions)
    out = np.flatnonzero((hits.prim != MISS) & ~_counted64(hits.t, at_origin, lo, hi))
    if out.size == 0:
        return hits
    # each listed with room for two: its nearest (this hit) does not count
    rows, *found = counted_lists(tracer, o, d, lo, hi, out, 2, 1)
    t, prim = hits.t.copy(), hits.prim.copy()
    t[out], prim[out] = np.inf, MISS
    t[rows], prim[rows] = found[0], found[1]
    answers = {"t": t, "prim": prim}
    for name, value in (("u", found[2]), ("v", found[3])):
        if getattr(hits, name) is not None:
            a = getattr(hits, name).copy()
            a[out] = 0.0
            a[rows] = value
            answers[name] = a
    if hits.normal is not None:
        normal = hits.normal.copy()
        normal[out] = 0.0
        tri = tracer.tree.triangles[tracer.tree.stored_index()[found[1]]]
        normal[rows] = _kernel_normal(tri)
        answers["normal"] = normal
    return dataclasses.replace(hits, **answers)


def _listed(tracer, rays, max_hits):
    """`intersections`' hits of `rays` (float32, in the tree's units): every ray's
    GUESS_HITS nearest (its max_hits when fewer), then the rays that had more counted
    and listed again in full, each ray's hits put in place once."""
    guess = min(GUESS_HITS, LIST_SLOTS, max_hits or LIST_SLOTS)
    # max_hits within the guess: the first pass is a k-nearest query, its walks ending
    # at the k-th hit's leaf; else it must see whether a ray has more
    final = max_hits is not None and max_hits <= guess
    n, more, first, slots = _first_pass(tracer, rays, guess, False, final)
    redo = () if final else np.flatnonzero(more)
    if not len(redo):
        return _gathered(tracer, n, first, slots)
    # the rays with more: their whole lists in their places (all of them: the answer)
    again = _relisted(tracer, rays, redo, max_hits)
    if len(redo) == rays.n:
        return again
    n[redo] = again.counts
    # the whole list, and the index of the relisted hits in it (and its making's)
    total = int(n.sum())
    _check_hits_memory(total * HIT_BYTES + rays.n * 8 + len(again.t) * 24, total, rays.n)
    hits = _gathered(tracer, n, first, slots)
    at = np.arange(len(again.t)) + np.repeat(hits.offsets[redo] - again.offsets[:-1], n[redo])
    for name in ("t", "prim", "u", "v"):
        getattr(hits, name)[at] = getattr(again, name)
    return hits


def _relisted(tracer, rays, redo, max_hits):
    """The Intersections of rays `redo` ((k,) int64) in full (their max_hits nearest):
    counted, then listed with as many slots; a ray whose count was lost gets one a hit
    found, copies too (`count_pass`), the slots its copies leave empty then dropped,
    not counted exactly by a list of its own first. Counted COUNT_FIRST rays first,
    then twice as many at a time: KdrayError once the hits counted so far do not fit
    in memory."""
    sub = rays.subset(redo)
    caps = np.empty(sub.n, dtype=np.int64)
    start, step = 0, COUNT_FIRST
    while start < sub.n:
        stop = min(sub.n, start + step)
        part = caps[start:stop]
        part[:] = count_pass(tracer, sub.subset(slice(start, stop)), False)[0]
        if max_hits is not None:
            np.minimum(part, int(max_hits), out=part)
        # list_hits's check of the lists, on the hits counted so far
        counted = int(caps[:stop].sum())
        _check_hits_memory(counted * (HIT_BYTES + 4) + sub.n * 12, counted, stop,
                           "counted so far")
        start, step = stop, 2 * step
    return list_hits(tracer, sub, caps, nearest_k=True)[0]


def _concatenated(parts):
    """One Intersections of the rays of `parts` (Intersections of consecutive rays)."""
    hits, rays = sum(len(q.t) for q in parts), sum(len(q.offsets) - 1 for q in parts)
    _check_hits_memory(hits * HIT_BYTES + rays * 8, hits, rays)
    offsets = [parts[0].offsets]
    for part in parts[1:]:
        offsets.append(part.offsets[1:] + offsets[-1][-1])
    return Intersections(np.concatenate(offsets),
                         *(np.concatenate([getattr(q, name) for q in parts])
                           for name in ("t", "prim", "u", "v")),
                         object_table=parts[0].object_table)


def _double(tracer, hits, origins, directions):
    """(hits with t, u, v in float64 (kdray.double.hits_double) and sorted again by (t,
    input id) within each ray, (H,) bool in that order: the hits whose ray's origin
    lies on their float64 plane)."""
    from .double import hits_double
    o, d = flat_rays64(origins, directions)
    n = len(hits.prim)
    # the rays' index, t and uv, the order and its sort's keys, the four answers
    _check_hits_memory(n * (8 + 24 + 8 + 16 + 28), n, len(hits.offsets) - 1,
                       "in double precision")
    ray = hits.ray
    t, uv, at_origin = hits_double(tracer.tree.triangles64, hits.prim, o, d, rays=ray,
                                   tree=tracer.tree, on_plane=True)
    order = np.lexsort((hits.prim, t, ray))
    return Intersections(hits.offsets, t[order], hits.prim[order], uv[order, 0],
                         uv[order, 1], object_table=hits.object_table), at_origin[order]
