"""Points put in spatial order on the device (kernels/point_order.cl).

Queries of many points (`contains`, the point queries) run faster in the Morton order
of the points' cells (kdray.points.spatial_order): near points then run one after
another on the same nodes and triangles in the caches. On the host the order's keys,
the points' sides of the box's middle, their gather into that order and their
rounding to the float32 rays the kernels read were four passes over the points on one
thread, half of a `contains` of 2^20 random points; here the keys are one kernel pass,
numpy sorts them (a radix sort of 16-bit keys), and a second pass gathers and rounds
the points into their order, on every core (BENCHMARKS.md, "Ray queries").

The keys are spatial_order's and the rays `rays32`'s, number for number: no answer
changes (tests/test_point_order.py). A device without cl_khr_fp64 cannot read the
float64 points: there the callers keep the host's way (`available`).
"""
import numpy as np

from . import device as _device
from .host import page_aligned_empty
from .points import spatial_grid


def available(tracer):
    """Whether the tracer's device runs these kernels (it has cl_khr_fp64)."""
    return _device.has_fp64(tracer.device)


def _program(tracer):
    """point_order.cl built for the tracer's device (kept with its other programs)."""
    return tracer._built("point_order.cl", {}, ("point_keys", "contains_rays"))


def spatial_order(tracer, points, lo, hi, centre=None, rel=None, sides=None):
    """(n,) uint32: kdray.points.spatial_order of points ((n, 3) float64, C-contiguous,
    world coordinates) over the box lo .. hi, its keys made on the tracer's device;
    centre: None, or the box's middle ((3,) float64) whose sides replace the cells' top
    bits (spatial_order's `sides`). rel ((n, 3) float32), sides ((n,) uint8): None, or
    arrays the same pass fills with each point relative to the tracer's origin in its
    units (ray_input.rays32's numbers) and its sides of centre (kdray.rays._sides' bits),
    for `contains_rays`."""
    n = len(points)
    keys = page_aligned_empty((n,), np.uint16)
    if n:
        grid_lo, scale = spatial_grid(lo, hi)
        c = np.zeros(3) if centre is None else np.asarray(centre, dtype=np.float64)
        buf, offset = tracer._input_buffer(points)
        tracer._run_items(_program(tracer), "point_keys", n,
                          (buf, np.uint32(offset), np.uint32(n), *grid_lo, *scale,
                           np.uint32(centre is not None), *c,
                           *np.asarray(tracer._origin, dtype=np.float64),
                           np.float64(tracer._scale)),
                          {"keys": keys, "rel": rel, "sides": sides})
    order = page_aligned_empty((n,), np.uint32)    # read by contains_rays (in place from a page)
    order[:] = np.argsort(keys, kind="stable")
    return order


def contains_rays(tracer, points, centre, directions):
    """(order, o, d): the rays of `contains` from points ((n, 3) float64, world
    coordinates, C-contiguous) in `spatial_order` over the tree's box with the sides of
    its middle centre ((3,) float64): order (n,) uint32, and slot j's ray from point
    order[j], its origin o[j] relative to the tracer's origin in its units
    (ray_input.rays32's numbers) and its direction d[j] = directions[s] ((8, 3) float32)
    for its sides s of the middle (kdray.rays._sides' bits); o and d (n, 3) float32
    (host.page_aligned_empty's)."""
    n = len(points)
    rel = page_aligned_empty((n, 3), np.float32)
    sides = page_aligned_empty((n,), np.uint8)
    order = spatial_order(tracer, points, *tracer._world_box, centre, rel, sides)
    o = page_aligned_empty((n, 3), np.float32)
    d = page_aligned_empty((n, 3), np.float32)
    if n:
        dir_buf = tracer._buffer(np.ascontiguousarray(directions, dtype=np.float32))
        tracer._run_items(_program(tracer), "contains_rays", n,
                          (*map(tracer._whole_input, (rel, sides, order)), np.uint32(0),
                           np.uint32(n), dir_buf),
                          {"o": o, "d": d})
    return order, o, d
