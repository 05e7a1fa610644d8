"""The order in which trace_rays and the ray queries take rays that share no path
through the tree.

Rays that come in no order (origins anywhere, directions anywhere: inside tests, ambient
occlusion, a user's own rays) are traced each on its own path (kernels/wide.cl and
queries.cl), and a work-item's rays then meet nodes and triangles that the rays before
them left in no cache. Taken grouped by their direction's octant and, within it, in Morton order of
the cell of a 16^3 grid over the scene's box where they enter it (kernels/ray_order.cl),
neighbouring rays enter close together and head the same way: their walks share nodes
and triangles in the caches, and more packets are traced as packets.

Rays from one point (or from points within 1/64 of the box: a light's or a sensor's
position, a visibility test from a viewpoint) all enter in one cell, and that key
leaves them as they come. They are taken in the order of their directions instead
(`direction_keys`: a Morton order over the octahedral map of directions), so that
neighbouring rays point alike, as a camera's neighbouring pixels do, and a packet of
them walks the tree as one (kernels/packet.cl, kd_alone), at any size of tree: 2^20
rays from the bunny's centre in random directions, taken so, trace in 0.59x the time,
from a 1.6M-triangle scan's in 0.46x (BENCHMARKS.md, "Incoherent rays").

Rays from points spread over the scene whose directions follow their points (toward
a point light or along the sun's direction from points on a mesh: a shadow or
visibility test; along a smooth surface's normals) head alike wherever their origins lie
close, but octants and 16^3 cells leave too many of them apart. Where neighbouring
rays of a sample, taken by where they enter the box, head alike (`follow`), they are
taken in Morton order of the cell of a 32^3 grid where they enter the box
(`cell_keys`), at any size of tree, and packets of them walk as one.

`ray_order` decides from a sample whether the rays are in no such order already (a
camera's rows, a lidar's sweep, rays from one point in turn are), and gives the order
or None. The kernels read slot j's ray through order[j] and write its outputs at its
own index: no ray's answer depends on it, only the time (tests/test_trace.py).
"""
import numpy as np

from .host import page_aligned_empty
from .points import MORTON_SPREAD
from .ray_input import C_TYPES

ORDER_FROM = 1 << 17
"""Rays from which a trace considers ordering them: fewer share too few nodes for the
order to pay (`bench/ab_order.py --rays N`; BENCHMARKS.md, "Incoherent rays")."""

DIRECTION_ORDER_FROM = 1 << 15
"""Rays from about one point (`concentrated`) from which a trace considers ordering them
by direction: from 2^15 rays the packets that the order makes pay for it (`python
bench/ab_order.py --kinds centre --rays N`: trace 0.91-1.00 of the time at 2^15, 0.78
at 2^16, 1.47 at 2^12; count 0.79-0.81 at 2^15; BENCHMARKS.md, "Incoherent rays")."""

CONCENTRATED = 1.0 / 64
"""The share of the box's longest side within which a sample's origins count as one
point (`concentrated`). 2^20 rays in random directions from origins spread over a cube
of side s of it, taken by direction, trace in 0.67x the time of their own order at s =
0 on the bunny, 0.87x at 1/64 and 1.22x at 1/16; on bunny-1.6M in 0.65x the time of
the entry keys' order at 0, 0.83x at 1/64, 0.94x at 1/32 (`python bench/ab_order.py
--kinds spread=S --keys direction|entry`): packets of rays from origins that far apart
share too few nodes (`kd_alone` lets them walk as one), and direction keys then cost
more than they save (BENCHMARKS.md, "Incoherent rays")."""

ORIGIN_BITS = 4
"""A side of the entry points' grid: 2^ORIGIN_BITS cells, so the key (octant and cell)
fits in 15 bits, which numpy sorts by radix."""

CELL_BITS = 5
"""A side of `cell_keys`' grid: 2^CELL_BITS cells, a key of 15 bits, with no octant:
rays that head alike mostly share one."""

FOLLOW_COS = 0.9
"""Rays follow their origins (`follow`) where the median cosine between the directions
of neighbouring rays of the sample, taken in `cell_keys` order, is at least this (about
25 degrees): 1.000 for rays toward a point light or along the sun's direction from
points on the bunny, 0.97 for rays along the teapot's normals but 0.88-0.91 along the
bunny's, 0.46-0.52 for ambient-occlusion rays (cosine-weighted about each point's
normal), 0.67-0.81 for rays from a few dozen cameras to points on the bunny, about 0
for random directions. Those below it gain nothing from the cell order (BENCHMARKS.md,
"Rays that follow their origins")."""

FOLLOW_ORDER_FROM = 1 << 16
"""Rays that follow their origins (`follow`) from which a trace considers ordering them
(BENCHMARKS.md, "Incoherent rays")."""

ORDER_TREE_BYTES = 16 << 20
"""Trees on the device from which rays in no order are ordered (nodes, triangles and
their ids: `Tracer.device_bytes`). The order costs its keys and their sort, and the
kernel more time to read the rays and write their hits out of memory order, which a
tree that the caches mostly hold does not win back: on a CPU with 32 MB of L3, the
bunny's 4.7 MB tree does not gain, bunny-x4's 19 MB does (`bench/ab_order.py`;
BENCHMARKS.md, "Incoherent rays")."""


SAMPLE_RUNS, SAMPLE_RUN = 32, 16
"""The sample `ray_order` decides on: SAMPLE_RUNS runs of SAMPLE_RUN consecutive rays,
spread evenly over the rays."""

UNORDERED_SHARE = 0.25
"""Rays are taken in an order of their own when more than this share of the sample's
neighbouring rays fall in key (`ray_keys`): about half of them in random rays, a few
in a camera's rows or a lidar's sweep, none in rays already in order."""


def _entry_cells(origins, directions, lo, hi, o_step, side):
    """(N, 3) int64 cells (0 .. side - 1 on each axis) of a side^3 grid over the box lo ..
    hi where rays origins (M, 3), directions (N, 3) (o_step 0: one origin for all, M =
    1) enter it, the origin for a ray that starts inside, in float64 (kernels/
    ray_order.cl's kd_entry in float); NaN and points beyond the box clamped."""
    lo = np.asarray(lo, dtype=np.float64)
    size = np.asarray(hi, dtype=np.float64) - lo
    d = np.asarray(directions, dtype=np.float64)
    o = np.asarray(origins, dtype=np.float64).reshape(-1, 3)[:len(d) if o_step else 1] - lo
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        near = (np.where(d < 0, size, 0.0) - o) / d
        t = np.fmax(np.fmax.reduce(near, axis=1), 0.0)        # fmax drops NaN
        cells = (o + t[:, None] * d) * (side / size)
    return np.where(cells >= side - 1, side - 1, np.where(cells > 0, cells, 0)).astype(np.int64)


def _morton(cell):
    """(N,) uint16: the Morton code of cells (N, 3) (each 0 .. 31; bit 3 b + k: bit b
    of the cell's index on axis k)."""
    key = np.zeros(len(cell), dtype=np.uint16)
    for k in range(3):
        key |= MORTON_SPREAD[cell[:, k]] << np.uint16(k)
    return key


def ray_keys(origins, directions, lo, hi, o_step=1):
    """(N,) uint16, in numpy (float64): kernels/ray_order.cl's keys (`device_keys`) of
    rays origins (M, 3), directions (N, 3) (o_step 0: one origin for all, M = 1) over
    the box lo .. hi, in one frame: each ray's octant (bit 12 + k: its direction's
    component k is negative) over the Morton code of the cell of a 16^3 grid over the
    box where the ray enters it (the origin, for a ray that starts inside). The kernel
    computes in float: a key may differ where the entry lies within rounding of a
    cell's side (and, for float32 origins, the box's corner is float32 too: far from 0,
    a grid shifted by its rounding)."""
    d = np.asarray(directions, dtype=np.float64)
    key = _morton(_entry_cells(origins, d, lo, hi, o_step, float(1 << ORIGIN_BITS)))
    for k in range(3):
        key |= (d[:, k] < 0).astype(np.uint16) << np.uint16(12 + k)
    return key


def cell_keys(origins, directions, lo, hi, o_step=1):
    """(N,) uint16, in numpy (float64): kernels/ray_order.cl's cell keys (`device_keys`
    with keys="cell") of rays as `ray_keys` takes them: the Morton code of the cell of a
    32^3 grid over the box where each ray enters it (bit 3 b + k: bit b of the cell's
    index on axis k), with no octant. The kernel computes as `ray_keys`' does."""
    return _morton(_entry_cells(origins, directions, lo, hi, o_step, float(1 << CELL_BITS)))


def direction_keys(directions):
    """(N,) uint16, in numpy (float64): kernels/ray_order.cl's direction keys
    (`device_keys` with keys="direction") of directions (N, 3): the Morton code of each
    one's cell in a 256 x 256 grid over the octahedral map of directions (bit 2 b: bit b
    of the cell's column u, bit 2 b + 1: of its row v). The kernel computes in float: a
    key may differ where the direction lies within rounding of a cell's side."""
    d = np.asarray(directions, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        p = d / np.abs(d).sum(axis=1)[:, None]
    u, v = p[:, 0], p[:, 1]
    low = p[:, 2] < 0                        # the lower half, folded over the corners
    u, v = (np.where(low, (1 - np.abs(v)) * np.where(u < 0, -1.0, 1.0), u),
            np.where(low, (1 - np.abs(u)) * np.where(v < 0, -1.0, 1.0), v))
    key = np.zeros(len(d), dtype=np.uint16)
    for shift, x in ((0, u), (1, v)):
        c = (x + 1) * 128
        cell = np.where(c >= 255, 255, np.where(c > 0, c, 0)).astype(np.uint16)
        for b in range(8):
            key |= ((cell >> np.uint16(b)) & np.uint16(1)) << np.uint16(2 * b + shift)
    return key


def _sample_rows(n):
    """(SAMPLE_RUNS * SAMPLE_RUN,) int64: the rows of n rays that `unordered` and
    `concentrated` look at (SAMPLE_RUNS runs of SAMPLE_RUN, spread evenly)."""
    starts = np.linspace(0, n - SAMPLE_RUN, SAMPLE_RUNS).astype(np.int64)
    return (starts[:, None] + np.arange(SAMPLE_RUN)).reshape(-1)


def concentrated(origins, directions, lo, hi, o_step=1):
    """Whether the rays (as `ray_keys` takes them) leave from about one point: one origin
    (o_step 0), or the sample's finite origins within CONCENTRATED of the box's longest
    side on every axis (within one cell of `ray_keys`' grid, which then tells the rays
    apart by octant only)."""
    if not o_step:
        return True
    n = len(directions)
    if n < SAMPLE_RUN:
        return False
    o = np.asarray(origins[_sample_rows(n)], dtype=np.float64)
    o = o[np.isfinite(o).all(axis=1)]
    side = float(np.max(np.asarray(hi, np.float64) - np.asarray(lo, np.float64)))
    return len(o) > 0 and float(np.ptp(o, axis=0).max()) <= CONCENTRATED * side


def follow(origins, directions, lo, hi, o_step=1):
    """Whether the rays (as `ray_keys` takes them, from spread origins) head alike where
    they enter the box close together: the sample's rays with a finite, nonzero
    direction, taken in `cell_keys` order, have a median cosine of FOLLOW_COS or more
    between neighbours' directions (rays toward a point light or along the sun's
    direction from points on a mesh; not rays in random directions)."""
    n = len(directions)
    if not o_step or n < SAMPLE_RUN:
        return False
    rows = _sample_rows(n)
    o = np.asarray(origins[rows], dtype=np.float64)
    d = np.asarray(directions[rows], dtype=np.float64)
    with np.errstate(invalid="ignore", over="ignore"):
        length = np.linalg.norm(d, axis=1)
        ok = np.isfinite(o).all(axis=1) & np.isfinite(length) & (length > 0)
    if np.count_nonzero(ok) < 2:
        return False
    o, d = o[ok], d[ok] / length[ok, None]
    d = d[np.argsort(cell_keys(o, d, lo, hi), kind="stable")]
    return float(np.median(np.sum(d[1:] * d[:-1], axis=1))) >= FOLLOW_COS


def unordered(origins, directions, lo, hi, o_step=1, keys="entry"):
    """Whether the rays (as `ray_keys` takes them) are in no order of their own: in more
    than UNORDERED_SHARE of the sample's neighbouring rays, the key (keys: "entry",
    `ray_keys`; "direction", `direction_keys`; "cell", `cell_keys`) falls."""
    n = len(directions)
    least = {"entry": ORDER_FROM, "direction": DIRECTION_ORDER_FROM, "cell": FOLLOW_ORDER_FROM}
    if n < max(least[keys], SAMPLE_RUN):
        return False
    rows = _sample_rows(n)
    if keys == "direction":
        key = direction_keys(directions[rows])
    else:
        of = ray_keys if keys == "entry" else cell_keys
        key = of(origins[rows] if o_step else origins, directions[rows], lo, hi, o_step)
    key = key.reshape(SAMPLE_RUNS, SAMPLE_RUN)
    return float(np.mean(key[:, 1:] < key[:, :-1])) > UNORDERED_SHARE


def device_keys(tracer, origins, directions, lo, hi, o_step=1, buffers=None, keys="entry"):
    """(N,) uint16: the rays' keys (keys: "entry", `ray_keys`; "direction",
    `direction_keys` of their directions; "cell", `cell_keys`), computed on the
    tracer's device (kernels/ray_order.cl): origins (M, 3) and directions (N, 3),
    float32 or float64 arrays as the kernels read them, read in place on a CPU.
    buffers: None, or the device buffers the caller already holds them in, ((o_buf,
    o_offset), (d_buf, d_offset)) in elements, so that a GPU is not sent them twice."""
    n = len(directions)
    types = {"ORIGIN_T": C_TYPES[np.dtype(origins.dtype)],
             "DIRECTION_T": C_TYPES[np.dtype(directions.dtype)]}
    entry = tracer._built("ray_order.cl", types, ("ray_keys", "direction_keys"))
    out = page_aligned_empty((n,), np.uint16)
    if buffers is None:
        buffers = (tracer._input_buffer(np.ascontiguousarray(origins)),
                   tracer._input_buffer(np.ascontiguousarray(directions)))
    (o_buf, o_at), (d_buf, d_at) = buffers
    if keys == "direction":
        name, args = "direction_keys", (d_buf, np.uint32(d_at), np.uint32(n))
    else:
        lo = np.asarray(lo, dtype=np.float64)
        size = np.asarray(hi, dtype=np.float64) - lo
        # a side of the grid, and whether the octant is in the key
        grid = (1 << ORIGIN_BITS, 1) if keys == "entry" else (1 << CELL_BITS, 0)
        name, args = "ray_keys", (o_buf, d_buf, np.uint32(o_at), np.uint32(d_at),
                                  np.uint32(o_step), np.uint32(n), *lo.astype(origins.dtype),
                                  *size.astype(np.float32), *map(np.uint32, grid))
    tracer._run_items(entry, name, n, args, {"keys": out}, local=KEYS_LOCAL)
    return out


KEYS_LOCAL = 64
"""ray_keys' work-group size (one ray a work-item)."""


def ray_order(tracer, origins, directions, lo, hi, o_step=1, buffers=None):
    """None, or the (N,) uint32 order in which to trace rays (origins (M, 3),
    directions (N, 3), as the kernels read them, in the frame of the box lo .. hi)
    that are in no order of their own (`unordered`): rays from about one point
    (`concentrated`) by their directions and rays that `follow` their origins by the
    32^3 cell where they enter the box, through any tree; others by their octant and
    where they enter the box through a tree that takes ORDER_TREE_BYTES or more on the
    device (`Tracer.device_bytes`); by their keys (`device_keys`, buffers as it takes
    them), stable (numpy's radix sort of 16-bit keys)."""
    n = len(directions)
    if n < min(DIRECTION_ORDER_FROM, FOLLOW_ORDER_FROM, ORDER_FROM):
        return None                     # fewer than any order takes: no sample
    if concentrated(origins, directions, lo, hi, o_step):
        keys = "direction"
    elif n >= FOLLOW_ORDER_FROM and follow(origins, directions, lo, hi, o_step):
        keys = "cell"
    elif tracer.device_bytes >= ORDER_TREE_BYTES:
        keys = "entry"
    else:
        return None
    if not unordered(origins, directions, lo, hi, o_step, keys):
        return None
    key = device_keys(tracer, origins, directions, lo, hi, o_step, buffers, keys)
    order = page_aligned_empty((len(key),), np.uint32)    # in place from a page (device_tree.py)
    order[:] = np.argsort(key, kind="stable")
    return order
