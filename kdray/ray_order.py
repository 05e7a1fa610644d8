"""The order in which trace_rays takes rays that share no path through the tree.

Rays that come in no order (origins anywhere, directions anywhere: inside tests, ambient
occlusion, a user's own rays) are traced each on its own path (kernels/lanes_trace.cl),
and a work-item's rays then meet nodes and triangles that the rays before them left in
no cache. Taken grouped by their direction's octant and, within it, in Morton order of
their origin's cell in a 16^3 grid over the scene's box, neighbouring rays start close
together and head the same way: their walks share nodes and triangles in the caches,
and more packets are traced as packets (one origin or close origins, one octant).

`ray_order` decides from a sample whether the rays are in no such order already (a
camera's rows, a lidar's sweep, rays from one point in turn are), and gives the order
or None. trace_rays reads the rays through the order and writes each ray's outputs at
its own index: no ray's hit depends on it, only the time (tests/test_trace.py).
"""
import numpy as np

from .host import page_aligned_empty
from .points import morton_code

ORDER_FROM = 1 << 14
"""Rays from which a trace considers ordering them (below, a few milliseconds' trace
has little cache to lose)."""

ORIGIN_BITS = 4
"""A side of the origins' grid: 2^ORIGIN_BITS cells, so the key (octant and cell) fits
in 15 bits, which numpy sorts by radix."""

ORDER_TREE_BYTES = 32 << 20
"""Trees on the device from which rays in no order are ordered (nodes, triangles and
their ids: `Tracer.device_bytes`). The order costs the host about 18 ms a million
rays, and the kernel as much again to read the rays and write their hits out of
memory order, which a tree that the caches mostly hold does not win back (Zen 4 VM,
2026-12-05, 2^20 rays, trace's time ordered / not: bunny, 4 MB, 1.13 for uniform
rays; bunny-1.6M, 90 MB: uniform 0.94, ambient-occlusion rays 0.65)."""

SAMPLE_RUNS, SAMPLE_RUN = 32, 16
"""The sample `ray_order` decides on: SAMPLE_RUNS runs of SAMPLE_RUN consecutive rays,
spread evenly over the rays."""

UNORDERED_SHARE = 0.25
"""Rays are taken in an order of their own when more than this share of the sample's
neighbouring rays fall in key (`ray_keys`): about half of them in random rays, a few
in a camera's rows or a lidar's sweep, none in rays already in order."""


def ray_keys(origins, directions, lo, hi, o_step=1):
    """(N,) uint16: each ray's octant (bit k: direction's component k is negative) in
    bits 12-14 over the Morton code of its origin's cell (`morton_code`, 2^ORIGIN_BITS
    cells a side over the box lo .. hi) in bits 0-11. origins (M, 3), directions
    (N, 3): any float type, in the box's coordinates; o_step 0: one origin for all
    (M = 1, cell 0)."""
    d = directions
    key = (d[:, 0] < 0).view(np.uint8).astype(np.uint16) << 12
    key |= (d[:, 1] < 0).view(np.uint8).astype(np.uint16) << 13
    key |= (d[:, 2] < 0).view(np.uint8).astype(np.uint16) << 14
    if o_step:
        key |= morton_code(origins, lo, hi, ORIGIN_BITS)
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


def ray_order(origins, directions, lo, hi, o_step=1, tree_bytes=ORDER_TREE_BYTES):
    """None, or the (N,) uint32 order in which to trace rays that are in no order of
    their own (`unordered`) through a tree of tree_bytes on the device (at least
    ORDER_TREE_BYTES): by `ray_keys`, stable (numpy's radix sort of 16-bit keys)."""
    if tree_bytes < ORDER_TREE_BYTES or not unordered(origins, directions, lo, hi, o_step):
        return None
    key = ray_keys(origins, directions, lo, hi, o_step)
    order = page_aligned_empty((len(key),), np.uint32)    # read in place (trace.py)
    order[:] = np.argsort(key, kind="stable")
    return order
