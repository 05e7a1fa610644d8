"""Ray queries beyond the nearest hit: any hit, crossing counts, inside tests (every
hit: kdray.hit_lists).

    tracer.occluded(origins, directions, t_min=0, t_max=inf)    # (N,) bool
    tracer.count(origins, directions)                           # (N,) int32 crossings
    tracer.contains(points)                                     # (N,) bool, closed meshes

The functions here take a Tracer (kdray.trace) and run kernels/queries.cl (or, for
`occluded`, trace's any-hit walk) on its device and tree; `Tracer.occluded` and the
others are thin faces over them. Rays are given as `Tracer.trace` takes them
(kdray.query_rays).

Which hits (docs/conventions.md, "Ray queries"):
- occluded and intersections take the nearest hit's test (kernels/triangle.cl): a ray
  through an edge or a vertex hits every triangle that has it, so `occluded` is exactly
  `trace(...).hit` and intersections' first hit is trace's hit (ties by input id).
- count takes the crossing rule: edge functions with exact signs, an exactly zero one
  decided as if the ray were moved by a fixed infinitesimal step in its sheared plane,
  so a ray through an edge or a vertex shared by consistently oriented triangles
  crosses there once. `count` <= the number of intersections; they differ only where
  a ray meets an edge or a vertex.
- A triangle in several leaves of the tree is counted and listed once.
"""
import numpy as np

from . import point_order, ray_input
from .double import flat_rays64, wants_double
from .host import available_memory, page_aligned_empty, take_rows
from .hit_lists import HIT_BYTES, counted_lists, flat_t, hits_counted64, list_hits
from .points import SORT_FROM, check_points, spatial_order
from .query_rays import (WALK_FAULT, QueryRays, as_image, check_fault, check_t,
                         count_pass, launch, launches)


CONTAINS_DIRECTION = np.array([0.5377513, 0.6153846, 0.5763888], dtype=np.float32)
"""The direction `contains` casts a point's ray along, its components' signs those of
the point's offset from the box's centre (`contains_directions`): fixed, so that an
answer is the same every run, and not in any axis plane or along a diagonal, where
meshes built on grids have their edges (a ray through an edge or vertex is still
counted exactly)."""


def contains_directions(tracer, points):
    """(N, 3) float32: the direction of each point's ray in `contains` (points (N, 3)
    float64, world coordinates): CONTAINS_DIRECTION with each component's sign that of
    the point's offset from the centre of the tree's box (+ at the centre), away from
    the centre towards the nearest corner, so that the ray leaves the box soon: half
    the walk, on average, of one direction for all (random points in a box)."""
    return np.take(_OCTANT_DIRECTIONS, _sides(tracer, points), axis=0)


def _sides(tracer, points):
    """(N,) uint8: bit k set where the point (points (N, 3) float64, world coordinates)
    is at or above the middle of the tree's box on axis k: its octant of the box."""
    c = _middle(tracer)
    # column by column, in uint8: 3x as fast as comparing the (N, 3) array with c
    sides = (points[:, 0] >= c[0]).view(np.uint8)
    for k in (1, 2):
        sides |= (points[:, k] >= c[k]).view(np.uint8) << k
    return sides


def _middle(tracer):
    """(3,) float64: the middle of the tree's box in world coordinates, whose sides
    `_sides` tells."""
    lo, hi = tracer._world_box
    return 0.5 * (lo + hi)


_OCTANT_DIRECTIONS = np.where((np.arange(8)[:, None] >> np.arange(3)) & 1 == 1,
                              CONTAINS_DIRECTION, -CONTAINS_DIRECTION)
"""(8, 3) float32: the direction of `contains_directions` for each octant (`_sides`)."""

COUNT_LIST_BYTES = 1 << 30
"""The most host memory the hits listed to count rays with many take at once (`_counts`,
whose answers need none of them after; and no more than a quarter of what is
available): the rays are listed in groups that fit, so that a count's memory does not
grow with its hits."""


def occluded(tracer, origins, directions, t_min=0.0, t_max=np.inf, precision="single"):
    """(N,) bool (the rays' shape): whether each ray hits anything with t_min < t <
    t_max, the same answers as `trace(...).hit`: `trace`'s traversal (render.cl,
    trace_rays with ANY_HIT), each ray over its own range, stopped at the first hit it
    finds; rays that share no path walk the wide nodes (kernels/wide.cl).
    precision="double": `trace(..., precision="double").hit`, the hits that count in
    float64 (`_any_counted64`)."""
    double = wants_double(precision, tracer.tree)
    o, d, shape = ray_input.flat_rays(origins, directions)
    t_min, t_max = check_t(t_min, "t_min", shape), check_t(t_max, "t_max", shape)
    hits = tracer._trace_rays(o, d, shape, t_min, t_max, (), any_hit=True)
    if double:
        return _any_counted64(tracer, hits.prim, origins, directions, t_min,
                              t_max).reshape(shape)
    return hits.hit.reshape(shape)


def _any_counted64(tracer, prim, origins, directions, t_min, t_max):
    """(N,) bool: `occluded` in double precision, from the any-hit walk's triangles
    (prim (N,) uint32 input ids, MISS where none): a ray whose triangle counts in
    float64 (_counted64) is occluded; one whose triangle does not (its float64 t out of
    range, or its origin on its float64 plane: a ray from a surface point) is occluded
    where any other of its float32 hits counts, which its nearest that counts
    (`counted_lists`) says. Float64 only drops hits, so a ray with no float32 hit
    stays unoccluded, as `trace`'s double hits do."""
    from .layout import MISS
    n = len(prim)
    o, d = flat_rays64(origins, directions)
    lo, hi = flat_t(t_min, n), flat_t(t_max, n)
    hit = prim != MISS
    counted = hit & hits_counted64(tracer, prim, o, d, lo, hi)
    doubt = np.flatnonzero(hit & ~counted)
    if doubt.size:
        # each listed with room for two: most such rays start on the triangle found
        ray = counted_lists(tracer, o, d, lo, hi, doubt, 2, 1)[0]
        counted[ray] = True
    return counted


def _counts(tracer, rays, crossing):
    """(N,) int32 exact counts of distinct triangles hit (crossing: the count's rule):
    `count_pass`'s, its rays whose count was lost mended in place."""
    counts, raw = count_pass(tracer, rays, crossing)
    # listed, which deduplicates, a group of rays at a time (COUNT_LIST_BYTES; every
    # hit found, copies too, a slot)
    caps = counts[raw].astype(np.int64)
    have = available_memory()
    most = COUNT_LIST_BYTES if have is None else min(COUNT_LIST_BYTES, have // 4)
    for group in _groups(caps, most // (HIT_BYTES + 4)):
        listed, _ = list_hits(tracer, rays.subset(raw[group]), caps[group], crossing)
        counts[raw[group]] = np.diff(listed.offsets)
    return counts


def _groups(sizes, most):
    """Slices of consecutive entries of sizes ((k,) int64) whose sums are at most `most`
    (one entry a group where it alone is more), in order."""
    ends = np.cumsum(sizes)
    start = 0
    while start < len(sizes):
        before = int(ends[start - 1]) if start else 0
        stop = max(start + 1, int(np.searchsorted(ends, before + most, side="right")))
        yield slice(start, stop)
        start = stop


def count(tracer, origins, directions, t_min=0.0, t_max=np.inf, precision="single"):
    """(N,) int32 (the rays' shape): how many times each ray crosses the surface with
    t_min < t < t_max, under the crossing rule (module docstring): a ray through an edge
    or a vertex shared by consistently oriented triangles crosses there once.
    precision="double": the crossings that count in float64 (`_crossings64`)."""
    double = wants_double(precision, tracer.tree)
    rays = as_image(tracer, QueryRays(tracer, origins, directions, t_min, t_max), origins,
                  directions)
    counts = _counts(tracer, rays, True)
    if double:
        counts = _crossings64(tracer, rays, counts, origins, directions, t_min, t_max)
    return counts.reshape(rays.shape)


def _crossings64(tracer, rays, counts, origins, directions, t_min, t_max):
    """(N,) int32: `count` in double precision, from its float32 counts ((N,) int32,
    exact): each ray that crosses anything has its crossings listed (the same rule,
    `list_hits`), and those that do not count in float64 (_counted64: float64 t out of
    range, or the origin on the float64 plane) are dropped, a group of rays of at most
    COUNT_LIST_BYTES of lists at a time."""
    n = len(counts)
    o, d = flat_rays64(origins, directions)
    lo, hi = flat_t(t_min, n), flat_t(t_max, n)
    rows = np.flatnonzero(counts > 0)
    caps = counts[rows].astype(np.int64)
    have = available_memory()
    most = COUNT_LIST_BYTES if have is None else min(COUNT_LIST_BYTES, have // 4)
    out = counts.copy()
    # a listed crossing: its slot and count (HIT_BYTES + 4), then its ray, float64 t,
    # uv and tests on the host (about 64)
    for group in _groups(caps, most // (HIT_BYTES + 4 + 64)):
        at = rows[group]
        listed, _ = list_hits(tracer, rays.subset(at), caps[group], True)
        keep = hits_counted64(tracer, listed.prim, o, d, lo, hi, rays=at[listed.ray])
        out[at] = np.bincount(listed.ray[keep], minlength=len(at))
    return out


WINDING = 2
"""count_rays' `crossing` argument for crossings summed with their facings (KD_WINDING;
0: every triangle hit, 1: crossings)."""
WINDING_RAW = 0x7FFFFFFF
"""count_rays' mark of a ray whose count was lost (kernels/queries.cl, kd_count_hit:
more crossings than it keeps, KD_SEEN, coming far out of their order) in its winding
mode (KD_WINDING)."""


def _contains_rays(tracer, p):
    """(rays, order): the rays of `contains` from points p ((N, 3) float64, world
    coordinates, finite), in spatial order (kdray.points.spatial_order: near points
    one after another, the points of each octant of the box one run, so that the
    directions are 8 repeated rows) from SORT_FROM points on (order None below and the
    directions `contains_directions`), which changes no answer."""
    if len(p) < SORT_FROM:
        return QueryRays(tracer, p, contains_directions(tracer, p), 0.0, np.inf), None
    if point_order.available(tracer):
        # the keys, the gather and the rounding on the device (kdray.point_order)
        order, o32, d32 = point_order.contains_rays(tracer, p, _middle(tracer),
                                                    _OCTANT_DIRECTIONS)
        return QueryRays.relative(tracer, o32, d32, lambda: (take_rows(p, order), d32)), order
    sides = _sides(tracer, p)
    order = spatial_order(p, *tracer._world_box, sides)
    d = np.repeat(_OCTANT_DIRECTIONS, np.bincount(sides, minlength=8), axis=0)
    # the points made float32 and relative to the tree first, then put in order: half
    # the bytes of float64 rows to gather (the same numbers either way)
    o32, d32 = ray_input.rays32(p, d, 1, tracer._origin, tracer._scale)
    ordered = page_aligned_empty(p.shape, np.float32)
    take_rows(o32, order, out=ordered)
    return QueryRays.relative(tracer, ordered, d32, lambda: (take_rows(p, order), d)), order


def _unsorted(a, order):
    """a ((N,), in the order of `_contains_rays`' rays) in the points' order: a new
    array, scattered once."""
    if order is None:
        return a
    out = np.empty_like(a)
    out[order] = a
    return out


def crossing_windings(tracer, points):
    """(N,) int64 (points (N, 3) float64, world coordinates, finite): each point's ray
    of `contains` (contains_directions) with its crossings' facings summed, +1 where
    the ray leaves through a triangle's front and -1 where it enters (kernels/queries.cl,
    kd_facing): on a closed, consistently oriented mesh the exact winding number of the
    point (points.closed_cycle). WINDING_RAW for a ray whose count was lost (more than
    32 crossings far out of their order in a k-d walk, kernels/queries.cl)."""
    def windings(p):
        rays, order = _contains_rays(tracer, p)
        out = page_aligned_empty((rays.n,), np.uint32)
        for start, stop in launches(tracer, rays, [4]):
            launch(tracer, "count_rays", rays, start, stop, (np.uint32(WINDING),),
                    {"out": out[start:stop]})
        check_fault(out == WALK_FAULT, "winding")
        w = np.where(out == WINDING_RAW, WINDING_RAW, out.view(np.int32)).astype(np.int64)
        return _unsorted(w, order)
    return _in_point_chunks(tracer, points, windings)


POINT_CHUNK = 1 << 30
"""Points `contains` and `crossing_windings` order and answer at a time at most: their
order and counts are uint32 (kdray.point_order), so more points than 2^32 are taken in
parts (the answers do not depend on it)."""

POINT_DEVICE_BYTES = (24, 80)
"""(largest buffer, all buffers) device bytes a point of `contains` takes in
kdray.point_order: the float64 point itself, then with its keys, order, sides and
float32 rays (67 bytes, and room)."""


def point_chunk(tracer):
    """Points `contains` answers at a time on the tracer's device: POINT_CHUNK, or fewer
    where the whole set's float64 points would pass the device's largest buffer, or
    (a device with memory of its own: a GPU) their buffers together a quarter of its
    memory; a CPU device's buffers are the host's arrays, whose memory is checked
    before (check_points)."""
    device = tracer.device
    most = int(device.max_mem_alloc_size) // POINT_DEVICE_BYTES[0]
    if not tracer._zero_copy:
        most = min(most, int(device.global_mem_size) // (4 * POINT_DEVICE_BYTES[1]))
    return max(1, min(POINT_CHUNK, most))


def _in_point_chunks(tracer, p, answer):
    """answer(p) ((N,) array for points p (N, 3)) for `point_chunk` points at a time,
    the parts' answers concatenated (one part: answer(p) itself)."""
    chunk = point_chunk(tracer)
    if len(p) <= chunk:
        return answer(p)
    return np.concatenate([answer(p[a:a + chunk]) for a in range(0, len(p), chunk)])


def contains(tracer, points):
    """(N,) bool (the points' shape (..., 3) less its last axis): whether each point is
    inside the mesh, by the parity of `count` along a fixed direction from the point
    (`contains_directions`: CONTAINS_DIRECTION, away from the box's centre): exact for
    a closed, consistently oriented mesh, with no jitter, vote or second ray, and the
    same every run.

    A point on the surface (within the rounding of a hit's t, kernels/triangle.cl) is
    answered as if moved an infinitesimal step along its direction: inside where that
    direction points into the mesh. For a mesh that is not closed, parity has no
    meaning (a ray may leave through a hole): the answer is that of the one ray.
    KdrayError for points that are not finite or not (..., 3)."""
    p, shape = check_points(points)
    if len(p) == 0:
        return np.zeros(shape, dtype=bool)
    def inside(p):
        rays, order = _contains_rays(tracer, p)
        # the parity from each count's low byte (a cast, one byte a point from there
        # on): half the time of `% 2 == 1` and a copy before the scatter
        parity = _counts(tracer, rays, True).astype(np.uint8)
        parity &= 1
        return _unsorted(parity.view(bool), order)
    return _in_point_chunks(tracer, p, inside).reshape(shape)
