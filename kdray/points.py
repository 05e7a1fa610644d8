"""Point queries: closest points, distances, signed distances, winding numbers, occupancy.

    near = tracer.closest_points(points)          # ClosestPoints: .distance .point .prim .u .v
    d = tracer.distance(points)                   # (N,) float32, unsigned
    s = tracer.signed_distance(points, sign="winding")   # negative inside
    w = tracer.winding_number(points)             # (N,) float64
    inside = tracer.occupancy(points)             # (N,) bool

The functions here take a Tracer (kdray.trace) and run kernels/points.cl on its device
and tree; the Tracer methods are thin faces over them. Points are (N, 3) or (..., 3),
world coordinates, float64 or float32, answered in the points' shape (less the last
axis); NaN or infinite points are refused.

The rules (docs/conventions.md, "Point queries"):
- the surface is the tree's triangles (zero-area triangles are no part of it, as for
  rays), in double: the points as given (float64) against the float32 triangles the
  tree holds, converted exactly; precision="double" against the input's float64
  triangles (a tree built with keep_double).
- closest_points: of equidistant triangles the lowest input id; nothing within
  max_distance is a miss (distance +inf, prim MISS, point and u, v 0).
- signed distance is negative inside (Open3D's and the SDF literature's sign; trimesh's
  `proximity.signed_distance` is positive inside). Inside is decided by sign="winding"
  (the generalized winding number above 1/2: meaningful for meshes with holes and
  self-intersections) or sign="parity" (the exact crossing count of kdray.rays.contains:
  right for every point of a closed mesh, and undefined for an open one, which is
  warned about).
"""
import dataclasses
import os
import sys
import warnings

import numpy as np

from . import device as _device
from . import ray_input
from .double import wants_double
from .errors import DeviceError, KdrayError
from .hits import TriangleAnswers
from .host import check_host_memory, page_aligned_empty, row_abs_max, take_rows
from .layout import MISS, device_triangles, is_leaf, leaf_offset, n_prims
from .validate import FLOAT32_MAX, real_number

RUN_CPU = 32
"""Consecutive points a work-item takes on a CPU device (one a work-item on a GPU), at
most: fewer in a launch too small to give every core work (`_run`)."""

WINDING_BETA = 5.0
"""winding_number's beta: a node's far-field expansion (to the third order) stands for
its triangles where the point is farther than beta times the node's radius from its
centre; nearer, their solid angles are summed exactly. The error falls about as
beta^-5; at 5 it is within 1e-4 of the exact sum (BENCHMARKS.md, "Point queries")."""

SIGN_BETA = 2.0
"""The beta of sign="winding" (occupancy, signed_distance): Barill et al. 2018's 2,
about 30 times faster than WINDING_BETA and within about 4e-3 of the exact sum, far
inside the 1/2 the sign is decided by."""

INSIDE_ABOVE = 0.5 + 2.0 ** -40
"""The generalized winding number above which a point is inside (sign="winding"). A
point on the surface has as its exact winding number the share of its neighbourhood
that is inside: 1/2 on a face, less at a convex edge or corner, more in a concave one.
So it is inside where that share is more than 1/2, and 2^-40 more, so that the sums'
rounding (which differs in the last bits between packet widths and runtimes: 0.5 on
one, 0.5000000000000001 on another) never decides a point on a face."""

NEAR_SURFACE = 1e-5
"""Points nearer the surface than this share of the scene box's largest side take the
generalized winding number's sign even on closed meshes (`inside`): a crossing so near
a ray's origin may be lost to the rounding of its t (kernels/triangle.cl) or of the
float32 copy of the mesh (within 6e-8 of the box's size)."""

SIGNS = ("winding", "parity")


class OpenMeshWarning(UserWarning):
    """sign="parity" on a mesh with open edges: a point's sign may be wrong where its
    ray leaves through a hole."""


@dataclasses.dataclass(eq=False)
class ClosestPoints(TriangleAnswers):
    """The nearest surface point of N points (in the points' shape).

    distance : float32 (float64 with precision="double"), world units; +inf on a miss
    point : (..., 3) float64 world coordinates of the nearest point (0 on a miss)
    prim : uint32 input triangle id (MISS on a miss)
    u, v : float32 barycentrics of `point` on its triangle, P = (1-u-v) v0 + u v1 + v v2
    object_table : the tree's KdTree.objects, which `object` looks up prim in"""

    distance: np.ndarray
    point: np.ndarray
    prim: np.ndarray
    u: np.ndarray
    v: np.ndarray
    object_table: np.ndarray = dataclasses.field(default=None, repr=False)


POINT_HOST_BYTES = 96
"""Host bytes a point needs at most while it is queried (its float64 copy, the order
and the answers): `check_points` checks the host has them before any copy."""


def check_points(points):
    """(p (N, 3) float64, shape) for points given as (..., 3): KdrayError for non-numbers
    (ray_input.numbers: strings, bools, ragged lists), another last axis, more points
    than the host's memory holds (checked before any copy), or a point that is not
    finite (naming it)."""
    p = ray_input.numbers("points", points)
    if p.ndim < 1 or p.shape[-1] != 3:
        raise KdrayError(f"points must be an (N, 3) array, got shape {p.shape}")
    shape = p.shape[:-1]
    n = p.size // 3
    check_host_memory(n * POINT_HOST_BYTES, f"querying {n:,} points", "ask for fewer points at once")
    p = np.ascontiguousarray(p.reshape(-1, 3), dtype=np.float64)
    if not np.isfinite(p).all():         # the whole array first: a row's test is slower
        i = int(np.flatnonzero(~np.isfinite(p).all(axis=1))[0])
        raise KdrayError(f"points must be finite, point {i} is {p[i].tolist()}")
    return p, shape


SORT_FROM = 4096
"""Point counts from which queries run in `spatial_order` (below, sorting costs more
than it saves)."""

GRID_CELLS = 32
"""`spatial_order`'s cells a side (5 bits of each axis in a 15-bit key)."""


MORTON_SPREAD = np.array([sum(((i >> b) & 1) << (3 * b) for b in range(5)) for i in range(32)],
                         dtype=np.uint16)
"""MORTON_SPREAD[i]: the 5 bits of i (0..31) spread to every third bit (0, 3, 6, 9, 12):
a cell index's part of a Morton code (here and kdray.ray_order)."""


def spatial_grid(lo, hi):
    """(lo, scale), (3,) float32 each: `spatial_order`'s grid over the box lo .. hi, a
    point's cell on axis k ((float32(p) - lo) * scale, clamped to 0 .. GRID_CELLS - 1;
    kernels/point_order.cl computes it alike)."""
    lo = np.asarray(lo, dtype=np.float64)
    with np.errstate(divide="ignore", over="ignore"):
        scale = GRID_CELLS / (np.asarray(hi, np.float64) - lo)
    # a flat box's axis: the largest float32, so that a point on it is in cell 0 and
    # one beside it clamped (infinity would make 0 * inf a NaN)
    scale = np.minimum(scale, np.finfo(np.float32).max)
    return lo.astype(np.float32), scale.astype(np.float32)


def spatial_order(points, lo, hi, sides=None):
    """(n,) int64 permutation that puts points (n, 3) in Morton order of a 32^3 grid over
    the box lo .. hi (points outside it clamped to its cells): queries of near points
    then run one after another in a work-item, on the same nodes and triangles in cache.
    sides: None, or (n,) uint8 whose bit k is the point's side of the box's middle on
    axis k, which then replaces the top bit of its cell on that axis (the middle's
    cell is computed in float32 and may round the other way): the points of each
    octant, in that order, are one run (`kdray.rays.contains`). Bunny, 2^19 points,
    Intel's CPU runtime: contains 1.5-1.6x, distance 1.2-1.3x, for less sorting time
    than it saves (16-bit keys: numpy's radix sort). Answers do not depend on it."""
    lo, scale = spatial_grid(lo, hi)
    # float32: half the memory traffic of float64, and fine enough for 32 cells a side;
    # columns made contiguous (numpy is slow on rows of three, and on strided columns)
    x = np.empty((3, len(points)), dtype=np.float32)
    np.copyto(x, points.T, casting="unsafe")
    code = np.zeros(len(points), dtype=np.uint16)
    with np.errstate(invalid="ignore", over="ignore"):
        for k in range(3):
            col = x[k]
            col -= np.float32(lo[k])
            col *= np.float32(scale[k])
            code |= np.take(MORTON_SPREAD, np.clip(col, 0, 31, out=col).astype(np.uint8)) << k
    if sides is not None:
        # the cells' top bits (bit 4 of each axis's cell) are the code's bits 12, 13, 14
        code &= np.uint16(0x0FFF)
        code |= sides.astype(np.uint16) << 12
    return np.argsort(code, kind="stable")


def _ordered(tracer, rel):
    """(rel in spatial order, order or None): `spatial_order` over the tree's box, for
    SORT_FROM points or more."""
    if len(rel) < SORT_FROM:
        return rel, None
    lo, hi = (np.asarray(b, dtype=np.float64) for b in tracer.tree.bounds)
    order = spatial_order(rel, lo, hi)
    return take_rows(rel, order), order


def _unordered(a, order, dtype=None):
    """a (rows in spatial order) back in the callers' order, as `dtype` (a's when None):
    one pass."""
    if a is None:
        return None
    if order is None:
        return a if dtype is None else a.astype(dtype)
    if a.ndim == 1:
        out = np.empty(a.shape, dtype=dtype or a.dtype)
        out[order] = a                   # a scatter: as fast as a gather in one dimension
        return out
    # rows: gathered by the inverse permutation (a scatter of rows is twice as slow)
    inverse = np.empty_like(order)
    inverse[order] = np.arange(len(order), dtype=order.dtype)
    out = take_rows(a, inverse)
    return out if dtype is None else out.astype(dtype, copy=False)


REACH = 2.0 ** 300
"""The farthest a point may lie from the tree's origin, in the tree's units (about its
size): the kernels' squared and cubed distances (the winding number's solid angles)
stay finite in double up to about 2^340, and no answer is lost to them here."""


def _relative(tracer, p):
    """(N, 3) float64 points relative to the tree's origin in its units (scale a power
    of two: the division is exact). KdrayError for a point beyond REACH, naming it."""
    rel = np.ascontiguousarray((p - tracer._origin) / tracer._scale)
    far = row_abs_max(rel) > REACH
    if far.any():
        i = int(np.flatnonzero(far)[0])
        raise KdrayError(f"point {i} ({p[i].tolist()}) lies beyond the point queries' "
                         f"reach, {REACH * tracer._scale:.3g} from the scene's centre in "
                         f"each axis (2^300 times the tree's unit, where double arithmetic "
                         f"of cubed distances stays finite)")
    return rel


def _made(tracer, key, make):
    """The point queries' datum `key` of the Tracer's tree, make() the first time (kept
    in a dict the Tracer empties when it takes a tree, Tracer._upload): under the
    Tracer's lock, so that threads sharing it make each once."""
    state = tracer._point_queries
    with tracer._lock:
        if key not in state:
            state[key] = make()
        return state[key]


def _program(tracer, geometry64, outputs=()):
    """points.cl built for the tracer's device and tree: {"program", "closest_points",
    "winding_points", "run": points a work-item takes at most, "local"}."""
    cpu = tracer._cpu
    run = RUN_CPU if cpu else 1
    local = tracer.local_size if cpu else min(64, int(tracer.device.max_work_group_size))
    defines = {"STACK_SIZE": tracer.packet_stack_size, "LOCAL_SIZE": local}
    if tracer.packet > 1:
        # leaves in runs of a packet: a run's boxes tested at once (points.cl)
        defines["PACKET"] = tracer.packet
        if tracer._plain_vector_ops:
            defines["KD_PLAIN_VECTOR_OPS"] = None
    if geometry64:
        defines["GEOMETRY64"] = None
        defines["SLACK"] = float(_slack(tracer)).hex()
        # world squared distances to the tree's units (a power of 4: exact)
        defines["SCALE_INV2"] = float(1.0 / (tracer._scale * tracer._scale)).hex()
    for name in outputs:
        defines[f"OUT_{name}"] = None
    entry = tracer._built("points.cl", defines, ("closest_points", "winding_points"))
    entry["run"], entry["local"] = run, local
    return entry


def _need_fp64(tracer):
    if not _device.has_fp64(tracer.device):
        raise DeviceError(f"point queries need double precision, which "
                          f"{tracer.device.name.strip()} does not have")


def _tris64(tracer):
    """The device buffer of the input's float64 triangles in world coordinates, as the
    exact tests take them with the points as given (9 doubles an input id;
    kernels/points.cl, GEOMETRY64)."""
    def make():
        t64 = np.ascontiguousarray(tracer.tree.triangles64, dtype=np.float64)
        return tracer._tree_buffer(t64.reshape(-1))
    return _made(tracer, "tris64", make)


def _world_points(p, order, geometry64):
    """(points64,): the points as given (world), in the order the kernels take them,
    for GEOMETRY64's exact tests; () without."""
    if not geometry64:
        return ()
    return (np.ascontiguousarray(p if order is None else take_rows(p, order)),)


def _relative64(tracer, ids):
    """(k, 3, 3) float64: the input's float64 triangles of input ids `ids`, relative to
    the tree's origin in its units (as its float32 copies are)."""
    t64 = np.asarray(tracer.tree.triangles64, dtype=np.float64)[ids]
    return (t64 - tracer._origin) / tracer._scale


def _slack(tracer):
    """How far (tree units) the float64 triangles may lie outside the float32 ones the
    tree's regions bound: the largest distance between a float64 vertex and its float32
    copy, doubled, plus a float rounding of the scene's size."""
    def make():
        tree = tracer.tree
        t64 = _relative64(tracer, tree.tri_ids)
        gap = np.abs(t64 - np.asarray(tree.triangles, dtype=np.float64)).max(initial=0.0)
        size = float(np.abs(np.asarray(tree.bounds, dtype=np.float64)).max())
        return 2.0 * float(np.sqrt(3.0) * gap) + size * 2.0 ** -23
    return _made(tracer, "slack", make)


def _launch(tracer, entry, kernel_name, n, args, outputs):
    """Run kernel_name over n points: args (after the tree's buffers), outputs (dict name
    -> host array or None, in argument order)."""
    if n == 0:
        return
    device_out = {name: None if a is None else tracer._output_buffer(a)
                  for name, a in outputs.items()}
    local = entry["local"]
    run = _run(tracer, entry, n)
    items = -(-n // run)
    tracer._enqueue(entry, kernel_name, -(-items // local) * local, local,
                    (tracer._nodes, tracer._tris, tracer._tri_ids, tracer._bounds,
                     np.uint32(tracer._n_nodes), *args, np.uint32(run),
                     *device_out.values()))
    tracer._read_outputs({k: v for k, v in device_out.items() if v is not None}, outputs)


def _run(tracer, entry, n):
    """Points a work-item takes of a launch of n: entry["run"] (RUN_CPU on a CPU), or
    fewer, down to 1, where n points in runs of that many would fill fewer work-groups
    than the tracer's traces launch (`Tracer.groups`, enough to fill the device): a
    group's work-items run one after another on one core, and 100 points in runs of 32
    were one core's."""
    return max(1, min(entry["run"], -(-n // (tracer.groups * entry["local"]))))


def _steps(tracer, n, widths):
    """(start, stop) of each launch over n points; widths: bytes a point of each buffer."""
    step = tracer._launch_size(widths, what="point")
    return [(start, min(n, start + step)) for start in range(0, n, step)]


def _check_fault(values, what):
    if np.isnan(values).any():
        raise DeviceError(f"{what}: the walk met a tree deeper than its depth or with more "
                          f"leaves than nodes; the tree is corrupt (kdray info --check)")


def _closest(tracer, points, max_distance, precision, outputs):
    """(distance (N,) float32 (float64 with precision="double") world units, point (N,
    3) float64 world or None, uv (N, 2) float32 or None, prim (N,) uint32 or None,
    shape); outputs: which of "POINT" (needs "ID"), "UV", "ID" to compute."""
    _need_fp64(tracer)
    geometry64 = wants_double(precision, tracer.tree)
    p, shape = check_points(points)
    limit = real_number(max_distance, "max_distance", KdrayError)
    if not limit >= 0:
        raise KdrayError(f"max_distance must be >= 0, got {max_distance!r}")
    n = len(p)
    widths = {"POINT": 24, "UV": 8, "ID": 4}
    # the relative points, d, the outputs; with geometry64 the world points in order
    check_host_memory(n * (24 + 8 + sum(widths[k] for k in outputs) + 24 * geometry64),
                      f"the closest points of {n} points", "ask for fewer points at once")
    rel, order = _ordered(tracer, _relative(tracer, p))
    world = _world_points(p, order, geometry64)
    entry = _program(tracer, geometry64, outputs)
    geometry = (_tris64(tracer),) if geometry64 else ()
    with np.errstate(over="ignore"):                # 1e308 squared: inf, not OverflowError
        max_d2 = np.float64(limit / tracer._scale) ** 2
    d = page_aligned_empty((n,), np.float64)
    q = page_aligned_empty((n, 3), np.float64) if "POINT" in outputs else None
    uv = page_aligned_empty((n, 2), np.float32) if "UV" in outputs else None
    prim = page_aligned_empty((n,), np.uint32) if "ID" in outputs else None
    for start, stop in _steps(tracer, n, [24, 8] + [widths[k] for k in outputs]):
        part = slice(start, stop)
        _launch(tracer, entry, "closest_points", stop - start,
                (*geometry, tracer._buffer(rel[part]),
                 *(tracer._buffer(pts[part]) for pts in world), max_d2,
                 np.uint32(stop - start)),
                {"d": d[part], "point": None if q is None else q[part],
                 "uv": None if uv is None else uv[part],
                 "prim": None if prim is None else prim[part]})
    _check_fault(d, "closest points")
    d *= tracer._scale
    if q is not None:                               # world coordinates, 0 on a miss
        if not geometry64:                          # (GEOMETRY64's are world already)
            q *= tracer._scale
            q += tracer._origin
        q[prim == MISS] = 0.0
    dtype = np.float64 if geometry64 else np.float32
    if not geometry64:
        far = np.flatnonzero(np.isfinite(d) & (d > FLOAT32_MAX))
        if far.size:
            i = int(order[far[0]]) if order is not None else int(far[0])
            raise KdrayError(f"the distance of point {i} to the surface, {float(d[far[0]]):.4g}, "
                             f"is beyond float32's range (precision='double' holds it)")
    return (_unordered(d, order, dtype), _unordered(q, order), _unordered(uv, order),
            _unordered(prim, order), shape)


def closest_points(tracer, points, max_distance=np.inf, precision="single"):
    """ClosestPoints of each point: the nearest point of the surface within
    max_distance (world units), its distance, triangle and barycentrics. A walk of the
    tree nearest region first, pruned by the best distance so far; of equidistant
    triangles the lowest input id. precision="double": against the input's float64
    triangles (a tree built with keep_double), distance float64."""
    d, q, uv, prim, shape = _closest(tracer, points, max_distance, precision,
                                     ("POINT", "UV", "ID"))
    return ClosestPoints(distance=d.reshape(shape), point=q.reshape(shape + (3,)),
                         prim=prim.reshape(shape), u=uv[:, 0].reshape(shape),
                         v=uv[:, 1].reshape(shape), object_table=tracer.tree.objects)


def distance(tracer, points, max_distance=np.inf, precision="single"):
    """(N,) unsigned distance from each point to the surface (float32; float64 with
    precision="double"), +inf beyond max_distance: closest_points' distance alone
    (nothing else is computed or moved)."""
    d, _, _, _, shape = _closest(tracer, points, max_distance, precision, ())
    return d.reshape(shape)


def winding_number(tracer, points, beta=WINDING_BETA, precision="single"):
    """(N,) float64 generalized winding number of the surface at each point: 1 inside a
    closed, outward-oriented mesh and 0 outside, fractional near holes (Jacobson et
    al. 2013). Triangles near the point are summed exactly (solid angles in double),
    farther groups by their far-field expansion to the third order where the point is
    beyond beta times their radius (Barill et al. 2018); beta=inf sums every triangle.
    Within 1e-4 of the exact sum at the default beta. precision="double": the near
    triangles are the input's float64 ones (the tree's float32 copies otherwise), so
    that a point within the copies' rounding of the surface is on its own side."""
    _need_fp64(tracer)
    geometry64 = wants_double(precision, tracer.tree)
    beta = real_number(beta, "beta", KdrayError)
    if not beta >= 1.0:
        raise KdrayError(f"beta must be at least 1 (the expansion needs the point outside "
                         f"the group's sphere), got {beta!r}")
    p, shape = check_points(points)
    n = len(p)
    check_host_memory(n * (48 + 24 * geometry64), f"the winding numbers of {n} points",
                      "ask for fewer points at once")
    rel, order = _ordered(tracer, _relative(tracer, p))
    world = _world_points(p, order, geometry64)
    entry = _program(tracer, geometry64)
    geometry = (_tris64(tracer),) if geometry64 else ()
    moments, owned = _winding_data(tracer, geometry64)
    w = page_aligned_empty((n,), np.float64)
    for start, stop in _steps(tracer, n, [24, 8]):
        part = slice(start, stop)
        _launch(tracer, entry, "winding_points", stop - start,
                (*geometry, tracer._buffer(rel[part]),
                 *(tracer._buffer(pts[part]) for pts in world), moments, owned,
                 np.float64(beta * beta),
                 np.uint32(stop - start)), {"w": w[part]})
    _check_fault(w, "winding number")
    return _unordered(w, order).reshape(shape)


def _check_sign(sign):
    if not (isinstance(sign, str) and sign in SIGNS):
        raise KdrayError(f"sign must be one of {', '.join(SIGNS)}, got {sign!r}")


def occupancy(tracer, points, sign="winding", precision="single"):
    """(N,) bool: whether each point is inside the surface, by its winding number above
    1/2 (sign="winding", at SIGN_BETA) or by the parity of its crossing count
    (sign="parity", kdray.rays.contains; an OpenMeshWarning for a mesh with open
    edges). precision="double": inside the input's float64 triangles where a point is
    within NEAR_SURFACE of the surface (`inside`)."""
    _check_sign(sign)
    if sign == "parity":
        check_points(points)            # bad points: their error, not the warning first
        _warn_open(tracer)
    return inside(tracer, points, sign, precision)


def inside(tracer, points, sign, precision="single"):
    """`occupancy` without its warning (for callers that warned once already). With
    sign="winding" on a closed, consistently oriented mesh (`closed_cycle`) the winding
    number is the exact integer of one ray's crossings (kdray.rays.crossing_windings),
    as cheap as `contains`, and inside where it is 1 or more: the sign of the
    generalized winding number wherever that is within 1/2 of the integer; the
    generalized winding number for rays with more crossings than the kernel keeps.
    precision="double": the points within NEAR_SURFACE of the box's size of the surface
    (far beyond the float32 copies' rounding, 2^-24 of it) take the generalized winding
    number of the input's float64 triangles, with sign="parity" too on a closed mesh
    (where the two agree; on an open one parity stays the float32 copies')."""
    from .rays import contains, crossing_windings, WINDING_RAW
    double = wants_double(precision, tracer.tree)
    closed = _made(tracer, "closed_cycle", lambda: closed_cycle(tracer.tree))
    if sign == "parity" and not (double and closed):
        return contains(tracer, points)
    if not closed:
        return winding_number(tracer, points, SIGN_BETA, precision) > INSIDE_ABOVE
    p, shape = check_points(points)
    if sign == "parity":
        result, raw = contains(tracer, p), np.zeros(len(p), bool)
    else:
        w = crossing_windings(tracer, p)
        result, raw = w >= 1, w == WINDING_RAW
    # the generalized winding number where the crossings cannot tell: rays with more
    # crossings than the kernel keeps, and points so near the surface that a crossing
    # may be lost to the rounding of its t or of the float32 copy of the mesh
    lo, hi = tracer._world_box
    near = np.isfinite(distance(tracer, p, NEAR_SURFACE * float(np.max(hi - lo))))
    redo = np.flatnonzero(near | raw)
    if redo.size:
        result[redo] = winding_number(tracer, p[redo], SIGN_BETA, precision) > INSIDE_ABOVE
    return result.reshape(shape)


def signed_distance(tracer, points, sign="winding", max_distance=np.inf, precision="single"):
    """(N,) distance to the surface, negative inside (`occupancy` with `sign`), float32
    (float64 with precision="double"). A point on the surface has distance 0 either way.
    Beyond max_distance: +inf outside, -inf inside."""
    _check_sign(sign)
    if sign == "parity":
        check_points(points)            # bad points: their error, not the warning first
        _warn_open(tracer)
    return signed(tracer, points, sign, max_distance, precision)


def signed(tracer, points, sign, max_distance=np.inf, precision="single"):
    """`signed_distance` without its warning."""
    d = distance(tracer, points, max_distance, precision)
    return np.where(inside(tracer, points, sign, precision), -d, d)


def closed_cycle(tree):
    """Whether the tree's triangles form a closed, consistently oriented surface: each
    directed edge (`_directed_edges`) appears as often as its reverse, so that every
    ray's crossings, summed with their facings, give the winding number of its origin."""
    a, b, n = _directed_edges(tree)
    return bool(np.array_equal(np.sort(a * n + b), np.sort(b * n + a)))


def _directed_edges(tree):
    """(a, b, n): the tree's triangles' directed edges a[i] -> b[i] ((3m,) int64 vertex
    ids, three a triangle, vertices welded where their float32 coordinates are equal)
    and n, above every id, so that a * n + b is an edge's key."""
    tris = np.asarray(tree.triangles, dtype=np.float32).reshape(-1, 3)
    _, vid = np.unique(tris.view(np.dtype((np.void, 12))).ravel(), return_inverse=True)
    f = vid.reshape(-1, 3).astype(np.int64)
    n = int(f.max()) + 1 if f.size else 1
    return f.reshape(-1), f[:, [1, 2, 0]].reshape(-1), n


def open_edges(tree):
    """The number of edges of the tree's triangles not shared by exactly two triangles
    in opposite directions (vertices welded where their float32 coordinates are equal):
    0 for a closed, consistently oriented mesh."""
    a, b, n = _directed_edges(tree)
    directed = np.unique(a * n + b)
    reverse = np.isin(b * n + a, directed)
    # an edge is closed when its reverse is there too; count each open undirected edge once
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    return int(len(np.unique((lo * n + hi)[~reverse])))


def _warn_open(tracer):
    n_open = _made(tracer, "open_edges", lambda: open_edges(tracer.tree))
    if n_open:
        warnings.warn(f"sign='parity' on a mesh with {n_open} open edges: a "
                      f"point's sign is undefined where its ray leaves through a hole; "
                      f"sign='winding' is meant for such meshes", OpenMeshWarning,
                      stacklevel=_caller_level())


def _caller_level():
    """The stacklevel of warnings.warn, called by the caller of this function, that
    names the first frame outside the kdray package: the user's line, whether it
    called kdray.points or a Tracer method."""
    package = os.path.dirname(os.path.abspath(__file__))
    frame, level = sys._getframe(2), 2
    while frame is not None and os.path.abspath(frame.f_code.co_filename).startswith(
            package + os.sep):
        frame, level = frame.f_back, level + 1
    return level


NODE_VALUES = 32
"""winding_points: float32 values a node (kernels/points.cl)."""

_MONOMIALS = [(0, 0, 0), (1, 1, 1), (2, 2, 2), (0, 0, 1), (0, 0, 2), (0, 1, 1), (1, 1, 2),
              (0, 2, 2), (1, 2, 2), (0, 1, 2)]
"""The cubic monomials d_i d_j d_k (i <= j <= k) in the kernel's order."""


def winding_moments(nodes, tris, tri_ids, depth, parent):
    """(moments (n_nodes, NODE_VALUES) float32, owned (n,) uint8) for winding_points.

    nodes, tris (n, 3, 3) float32 (or float64: _winding_data), tri_ids : the device's
    layout (layout.device_triangles); depth, parent : KdTree._topology's. Each input id
    is owned by its first copy; a node's values are over the triangles its subtree
    owns, with x the surface point, c the node's centre and n the unit normal (Barill
    et al. 2018's expansion of w = 1/4pi sum of the integrals of (x - q).n / |x - q|^3):
        0-2 c, the area-weighted centroid rounded to float32 (the moments are about it
        exactly);  3 radius (to the farthest corner of their vertices' box; -1: the
        node owns nothing);  4-6 N = integral of n;  7 area;
        8 tr C, 9-11 C's diagonal, 12-14 C01 + C10, C02 + C20, C12 + C21, with
        C = integral of (x - c) n^T;  15-17 2 a + b, with T_ijk = integral of
        n_i (x - c)_j (x - c)_k, a_k = T_iik and b_i = T_ijj;  18-27 the coefficients
        of the cubic sum T_ijk d_i d_j d_k in the monomials _MONOMIALS;  28-31 unused."""
    n_nodes = len(nodes)
    ids = np.asarray(tri_ids)
    owned = np.zeros(len(ids), dtype=np.uint8)
    real = np.flatnonzero(ids != MISS)
    _, first = np.unique(ids[real], return_index=True)
    own = real[first]
    owned[own] = 1
    # each owned copy's leaf: the last non-empty leaf (node order) starting at or before it
    leaves = np.flatnonzero(is_leaf(nodes))
    starts = leaf_offset(nodes)[leaves].astype(np.int64)
    has = n_prims(nodes)[leaves] > 0
    leaves, starts = leaves[has], starts[has]
    leaf = leaves[np.searchsorted(starts, own, side="right") - 1]
    t = np.asarray(tris, dtype=np.float64)[own]
    a, b, c = t[:, 0], t[:, 1], t[:, 2]
    half_n = 0.5 * np.cross(b - a, c - a)              # area times unit normal
    area = np.linalg.norm(half_n, axis=1)
    centroid = (a + b + c) / 3.0
    order = np.argsort(depth, kind="stable")[::-1]
    levels = np.split(order, np.flatnonzero(np.diff(depth[order])) + 1)
    # each node's area, area * centroid, N and box, added up the tree
    sums = np.zeros((n_nodes, 7))
    np.add.at(sums, leaf, np.concatenate([area[:, None], area[:, None] * centroid, half_n],
                                         axis=1))
    lo = np.full((n_nodes, 3), np.inf)
    hi = np.full((n_nodes, 3), -np.inf)
    np.minimum.at(lo, leaf, t.min(axis=1))
    np.maximum.at(hi, leaf, t.max(axis=1))
    for at in levels[:-1]:                              # deepest first; the root last
        up = parent[at]
        np.add.at(sums, up, sums[at])
        np.minimum.at(lo, up, lo[at])
        np.maximum.at(hi, up, hi[at])
    S, N = sums[:, 0], sums[:, 4:7]
    present = np.isfinite(lo).all(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        centre = np.where((S > 0)[:, None], sums[:, 1:4] / S[:, None], 0.5 * (lo + hi))
    # the centre the kernel reads (float32), and every moment about it exactly: a
    # cluster far from the tree's origin is off its float32 centre by a rounding of
    # that distance (2e-4 at 3000), a fifth of a 1e-3 sphere's radius
    centre = np.where(present[:, None], centre, 0.0).astype(np.float32).astype(np.float64)
    corner = np.maximum(np.abs(np.where(present[:, None], centre - lo, 0.0)),
                        np.abs(np.where(present[:, None], hi - centre, 0.0)))
    radius = np.where(present, np.linalg.norm(corner, axis=1), -1.0)
    # C = integral of (x - c) n^T and T_ijk = integral of n_i (x - c)_j (x - c)_k, each
    # triangle's about its leaf's centre c (vertices relative to it: small where the
    # leaf is, so nothing cancels), then each node's shifted to its parent's centre
    # (x - c' = (x - c) + d, d = c - c') and added: C' = C + d N^T,
    # T'_ijk = T_ijk + C_ji d_k + d_j C_ki + d_j d_k N_i. (Sums about the tree's
    # origin, shifted to a centre at the end, had cancelled: 1e13 of a 1e-3 cluster's
    # moments 3000 away.)
    ar, br, cr = (v - centre[leaf] for v in (a, b, c))
    sr = ar + br + cr
    # integral of (x - c)(x - c)^T over a triangle: area / 12 (sum of v v^T + S S^T)
    G = (np.einsum("ki,kj->kij", ar, ar) + np.einsum("ki,kj->kij", br, br)
         + np.einsum("ki,kj->kij", cr, cr) + np.einsum("ki,kj->kij", sr, sr)) / 12.0
    C = np.zeros((n_nodes, 3, 3))
    T = np.zeros((n_nodes, 3, 3, 3))
    np.add.at(C, leaf, np.einsum("ki,kj->kij", sr / 3.0, half_n))
    np.add.at(T, leaf, np.einsum("ki,kjl->kijl", half_n, G))
    for at in levels[:-1]:
        up = parent[at]
        d = centre[at] - centre[up]
        Na, Ca = N[at], C[at]
        np.add.at(C, up, Ca + np.einsum("ni,nj->nij", d, Na))
        np.add.at(T, up, T[at] + np.einsum("nji,nk->nijk", Ca, d)
                  + np.einsum("nj,nki->nijk", d, Ca) + np.einsum("nj,nk,ni->nijk", d, d, Na))
    va = np.einsum("niik->nk", T)
    vb = np.einsum("nijj->ni", T)
    sym = np.zeros((n_nodes, len(_MONOMIALS)))
    for m, (i, j, l) in enumerate(_MONOMIALS):
        perms = {(i, j, l), (i, l, j), (j, i, l), (j, l, i), (l, i, j), (l, j, i)}
        sym[:, m] = sum(T[:, p, q, r] for p, q, r in perms)
    moments = np.concatenate([
        centre, radius[:, None], N, S[:, None], np.trace(C, axis1=1, axis2=2)[:, None],
        C[:, [0, 1, 2], [0, 1, 2]], (C[:, 0, 1] + C[:, 1, 0])[:, None],
        (C[:, 0, 2] + C[:, 2, 0])[:, None], (C[:, 1, 2] + C[:, 2, 1])[:, None],
        2.0 * va + vb, sym, np.zeros((n_nodes, NODE_VALUES - 28))], axis=1)
    return np.ascontiguousarray(moments, dtype=np.float32), owned


def _winding_data(tracer, geometry64=False):
    """(moments buffer, owned buffer) of the tracer's tree, made once: of its float32
    triangles, or with geometry64 of the input's float64 ones (relative to the tree's
    origin in its units), whose exact solid angles the near field then sums (a small
    object far from the tree's origin: its float32 copy is moved by a rounding of that
    distance, and the expansion of the copy missed the float64 sum by 5e-4)."""
    def make():
        nodes, tris, tri_ids = device_triangles(tracer.tree, tracer.packet)
        if geometry64:
            ids = np.asarray(tri_ids)
            real = ids != MISS                      # a packet run's padding: not owned
            tris = np.zeros((len(ids), 3, 3))
            tris[real] = _relative64(tracer, ids[real])
        depth, parent, _ = tracer.tree._topology()
        moments, owned = winding_moments(nodes, tris, tri_ids, depth, parent)
        return tracer._tree_buffer(moments.reshape(-1)), tracer._tree_buffer(owned)
    return _made(tracer, "winding64" if geometry64 else "winding", make)
