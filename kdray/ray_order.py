"""The order in which trace_rays and the ray queries take rays that share no path
through the tree.

Rays that come in no order (origins anywhere, directions anywhere: inside tests, ambient
occlusion, a user's own rays) are traced each on its own path (kernels/wide.cl and
queries.cl), and a work-item's rays then meet nodes and triangles that the rays before
them left in no cache. Taken grouped by their direction's octant and, within it, in Morton order of
the cell of a 16^3 grid over the scene's box where they enter it (kernels/ray_order.cl),
neighbouring rays enter close together and head the same way: their walks share nodes
and triangles in the caches, and more packets are traced as packets.

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

ORIGIN_BITS = 4
"""A side of the entry points' grid: 2^ORIGIN_BITS cells (kernels/ray_order.cl has 16),
so the key (octant and cell) fits in 15 bits, which numpy sorts by radix."""

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


def ray_keys(origins, directions, lo, hi, o_step=1):
    """(N,) uint16, in numpy (float64): kernels/ray_order.cl's keys (`device_keys`) of
    rays origins (M, 3), directions (N, 3) (o_step 0: one origin for all, M = 1) over
    the box lo .. hi, in one frame: each ray's octant (bit 12 + k: its direction's
    component k is negative) over the Morton code of the cell of a 16^3 grid over the
    box where the ray enters it (the origin, for a ray that starts inside). The kernel
    computes in float: a key may differ where the entry lies within rounding of a
    cell's side."""
    lo = np.asarray(lo, dtype=np.float64)
    size = np.asarray(hi, dtype=np.float64) - lo
    d = np.asarray(directions, dtype=np.float64)
    o = np.asarray(origins, dtype=np.float64).reshape(-1, 3)[:len(d) if o_step else 1] - lo
    side = float(1 << ORIGIN_BITS)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        near = (np.where(d < 0, size, 0.0) - o) / d
        t = np.fmax(np.fmax.reduce(near, axis=1), 0.0)        # fmax drops NaN
        cells = (o + t[:, None] * d) * (side / size)
    cell = np.where(cells >= side - 1, side - 1, np.where(cells > 0, cells, 0)).astype(np.uint16)
    key = np.zeros(len(d), dtype=np.uint16)
    for k in range(3):
        key |= MORTON_SPREAD[cell[:, k]] << np.uint16(k)
        key |= (d[:, k] < 0).astype(np.uint16) << np.uint16(12 + k)
    return key


def unordered(origins, directions, lo, hi, o_step=1):
    """Whether the rays (as `ray_keys` takes them) are in no order of their own: in more
    than UNORDERED_SHARE of the sample's neighbouring rays, the key falls."""
    n = len(directions)
    if n < max(ORDER_FROM, SAMPLE_RUN):
        return False
    starts = np.linspace(0, n - SAMPLE_RUN, SAMPLE_RUNS).astype(np.int64)
    rows = (starts[:, None] + np.arange(SAMPLE_RUN)).reshape(-1)
    o = origins[rows] if o_step else origins
    keys = ray_keys(o, directions[rows], lo, hi, o_step).reshape(SAMPLE_RUNS, SAMPLE_RUN)
    return float(np.mean(keys[:, 1:] < keys[:, :-1])) > UNORDERED_SHARE


def device_keys(tracer, origins, directions, lo, hi, o_step=1, buffers=None):
    """(N,) uint16: `ray_keys` of the rays, computed on the tracer's device
    (kernels/ray_order.cl): origins (M, 3) and directions (N, 3), float32 or float64
    arrays as the kernels read them, read in place on a CPU. buffers: None, or the
    device buffers the caller already holds them in, ((o_buf, o_offset), (d_buf,
    d_offset)) in elements, so that a GPU is not sent them twice."""
    n = len(directions)
    types = {"ORIGIN_T": C_TYPES[np.dtype(origins.dtype)],
             "DIRECTION_T": C_TYPES[np.dtype(directions.dtype)]}
    entry = tracer._built("ray_order.cl", types, ("ray_keys",))
    keys = page_aligned_empty((n,), np.uint16)
    if buffers is None:
        buffers = (tracer._input_buffer(np.ascontiguousarray(origins)),
                   tracer._input_buffer(np.ascontiguousarray(directions)))
    (o_buf, o_at), (d_buf, d_at) = buffers
    out = {"keys": tracer._output_buffer(keys)}
    lo = np.asarray(lo, dtype=np.float64)
    size = np.asarray(hi, dtype=np.float64) - lo
    local = min(KEYS_LOCAL, int(tracer.device.max_work_group_size))
    items = -(-n // local) * local
    tracer._enqueue(entry, "ray_keys", items, local,
                    (o_buf, d_buf, np.uint32(o_at), np.uint32(d_at), np.uint32(o_step),
                     np.uint32(n), *lo.astype(np.float32), *size.astype(np.float32),
                     out["keys"]))
    tracer._read_outputs(out, {"keys": keys})
    return keys


KEYS_LOCAL = 64
"""ray_keys' work-group size (one ray a work-item)."""


def ray_order(tracer, origins, directions, lo, hi, o_step=1, buffers=None):
    """None, or the (N,) uint32 order in which to trace rays (origins (M, 3),
    directions (N, 3), as the kernels read them, in the frame of the box lo .. hi)
    that are in no order of their own (`unordered`) through the tracer's tree, when
    it takes ORDER_TREE_BYTES or more on the device (`Tracer.device_bytes`): by their
    keys (`device_keys`, buffers as it takes them), stable (numpy's radix sort of
    16-bit keys)."""
    if tracer.device_bytes < ORDER_TREE_BYTES or not unordered(origins, directions, lo, hi,
                                                               o_step):
        return None
    key = device_keys(tracer, origins, directions, lo, hi, o_step, buffers)
    order = page_aligned_empty((len(key),), np.uint32)    # read in place (trace.py)
    order[:] = np.argsort(key, kind="stable")
    return order
