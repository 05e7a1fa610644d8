"""Rays that leave a surface: their origins moved off it, as pbrt's OffsetRayOrigin.

    hits = tracer.trace(o, d, precision="double")             # points on the surface
    p = o + hits.t[:, None] * d
    origins = offset_origins(tracer.tree, p, hits.prim, new_directions)
    tracer.occluded(origins, new_directions)                   # never the triangle left

A point on a triangle, in float64 (sampled on the mesh, or a hit's o + t d), lies
within rounding of the tree's float32 triangle, on either side of it: a ray from it
hits its own triangle at a t of about that rounding about half the time (a visibility
or ambient-occlusion ray "occluded" by the surface it leaves), or in double precision
at a t <= 0. `offset_origins` moves each point along its triangle's normal, to the
side its direction leaves on, just far enough that the origin the kernels take (its
float32 rounding relative to the tree) lies strictly on that side of the tree's
triangle and of the input's float64 triangle: a ray that meets neither plane again
cannot hit its triangle, at any scale or offset, and a ray that leaves a mesh misses
it as it should. The move is a few float32 roundings of the coordinates (2^-21 of
the largest coordinate relative to the tree, and of the triangle's), far below a
fixed epsilon's where the scene is large and above it only where float32 holds no
more; no other triangle is considered (a ray from a concave crease may hit the
triangle beside it at a small t, as it does in exact arithmetic).
"""
import numpy as np

from .errors import ParameterError
from .layout import MISS
from .ray_input import numbers

OFFSET_ROUNDINGS = 4.0
"""How many of the origin's worst roundings (its float32 rounding relative to the
tree, the triangle's float32 rounding, and float64's on the way) the origin is moved
beyond the plane: one is what may put it back, the rest margin."""


def offset_origins(tree, points, prim, directions):
    """(N, 3) float64 world origins: each point moved off its triangle toward the side
    its direction leaves on (module docstring).

    tree : kdray.KdTree (Tracer.tree) the rays will be traced in.
    points : (N, 3) numbers (integers or floats), world points on (or near) the
        triangles.
    prim : (N,) integers, each point's input triangle id (Hits.prim, a face index);
        MISS (0xFFFFFFFF) or a triangle the tree dropped (degenerate): the point as
        given.
    directions : (N, 3) numbers, the rays' directions (any length).
    A point or a direction that is not finite, or a zero direction, stays as given
    (the ray misses). ParameterError for arrays that are not numbers, shapes that
    differ or a prim beyond the input's triangles.
    """
    # numbers only (bools, strings, objects refused, never converted), as every query
    p = np.array(numbers("points", points, ParameterError), dtype=np.float64)
    d = np.asarray(numbers("directions", directions, ParameterError), dtype=np.float64)
    prim = np.asarray(prim)
    if p.ndim != 2 or p.shape[1] != 3 or d.shape != p.shape:
        raise ParameterError(f"points and directions must be (N, 3) arrays of one shape, got "
                             f"{p.shape} and {d.shape}")
    if prim.shape != (len(p),) or not np.issubdtype(prim.dtype, np.integer):
        raise ParameterError(f"prim must be (N,) = ({len(p)},) integers, got {prim.shape} "
                             f"{prim.dtype}")
    prim = prim.astype(np.int64)
    miss = prim == int(MISS)
    if np.any(~miss & ((prim < 0) | (prim >= tree.n_input_tris))):
        raise ParameterError(f"prim must name input triangles 0 .. {tree.n_input_tris - 1} "
                             f"(or be MISS)")
    k = np.where(miss, -1, tree.stored_index()[np.where(miss, 0, prim)])    # -1: dropped
    with np.errstate(invalid="ignore", over="ignore"):
        ok = (k >= 0) & np.isfinite(p).all(axis=1) & np.isfinite(d).all(axis=1) \
            & (d != 0).any(axis=1)
    if not ok.any():
        return p
    rows = np.flatnonzero(ok)
    origin, scale = np.asarray(tree.origin, dtype=np.float64), float(tree.scale)
    tri = np.asarray(tree.triangles)[k[rows]].astype(np.float64)       # relative, exact
    rel = (p[rows] - origin) / scale
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.linalg.norm(n, axis=1)[:, None]
    side = np.where(np.einsum("ij,ij->i", n, d[rows]) < 0.0, -1.0, 1.0)
    n *= side[:, None]                                   # toward the side the ray leaves on
    behind = np.maximum(0.0, -np.einsum("ij,ij->i", n, rel - tri[:, 0]))
    # the roundings that may move the origin back across a plane, in the tree's units:
    # the origin's float32 rounding, the triangle's (the input's float64 triangle lies
    # within it of the tree's), float64's of the world coordinates and their difference
    big = np.maximum(np.abs(rel).max(axis=1), np.abs(tri).max(axis=(1, 2)))
    world = (np.abs(p[rows]).max(axis=1) + np.abs(origin).max()) / scale
    rounding = np.sqrt(3.0) * (2.0 ** -24 * big + 2.0 ** -51 * world) + 2.0 ** -1000
    moved = rel + (behind + OFFSET_ROUNDINGS * rounding)[:, None] * n
    p[rows] = origin + scale * moved
    return p
