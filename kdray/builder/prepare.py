"""Mesh arrays -> the float32 triangles the tree stores.

    vertices  : (n, 3) float-like, world coordinates (read as float64)
    faces     : (m, 3) int, indices into vertices; triangle ids are row numbers
    ->
    triangles : (k, 3, 3) float32   kept triangles, relative to `origin`, in units of `scale`
    tri_ids   : (k,) uint32         input row of each kept triangle (input order kept)
    origin    : (3,) float64        centre of the box of the finite vertices the faces use
    bounds    : (2, 3) float32      box of the kept triangles (min, max), relative
    scale     : float               a power of two (`mesh_scale`): 1 for sizes 2^-28 .. 2^28
    flat      : (3,) int64          kept triangles flat on each axis (three equal coordinates
                                    there: one PLANAR event, not START and END; `events`)

A triangle is left out when a coordinate is not finite after the shift to float32, or
when its float32 cross product is zero: such a triangle can never be hit.

The per-triangle work is one numba pass (`_triangles`; `cache=True`): the same float64
subtraction, float32 rounding and float32 cross product as the numpy expressions
`(v[f] - origin).astype(float32)` and `np.cross(e1, e2)`, without their (m, 3, 3)
float64 temporaries, whose allocation and page faults cost more than the arithmetic.
"""
import dataclasses
import math

import numpy as np
from numba import njit

from .. import layout
from ..errors import MeshError, ParameterError
from ..mesh import check_arrays
from .threads import run_jobs


@dataclasses.dataclass(frozen=True)
class Prepared:
    triangles: np.ndarray
    tri_ids: np.ndarray
    origin: np.ndarray
    bounds: np.ndarray
    n_input_tris: int
    flat: np.ndarray
    scale: float = 1.0


SCALE_FREE = (2.0 ** -28, 2.0 ** 28)
"""Scene sizes stored at scale 1. The float32 triangle test's t is a sum of products of
three coordinates relative to a ray's origin (edge functions times a depth), which
overflow float32 from 2^42.7 and fall into its subnormals below 2^-42: so a scene at
scale 1 is at most 2^28 across, whose rays may start 2^14 (16,384) of its sizes
away, and at least 2^-28, whose triangles a twentieth of its size keep those
products normal; other scenes are stored at about 1. (At scale 1 up to 2^40, a
scene 2^39.5 across lost every hit of a ray from 1000 of its sizes away; down to
2^-40, one 2^-40 across took the farther of two surfaces 4e-6 apart as the nearest
hit for 746 rays in 20,000, its t off by up to 627 ulps.)"""

SIZE_LIMITS = (2.0 ** -126, 2.0 ** 126)
"""The scene sizes kdray represents (1.2e-38 .. 8.5e37): depths are float32, the tree's
scale a normal float32 power of two."""


def scale_for(size):
    """The tree's scale for a scene `size` across (the largest side of the used
    vertices' box, float64): 1 within SCALE_FREE, else the power of two nearest the
    size, so that the stored coordinates are about 1. Raises MeshError outside
    SIZE_LIMITS."""
    size = float(size)
    if size == 0.0 or SCALE_FREE[0] <= size <= SCALE_FREE[1]:
        return 1.0
    if not SIZE_LIMITS[0] <= size <= SIZE_LIMITS[1]:
        raise MeshError(f"the scene is {size:.3g} across; kdray represents scenes from "
                        f"{SIZE_LIMITS[0]:.2g} to {SIZE_LIMITS[1]:.2g} across (float32 depths)")
    return 2.0 ** round(math.log2(size))


FLOAT32_MAX = float(np.finfo(np.float32).max)


def mesh_scale(vertices, faces, used_box=None):
    """The builder's default scale (`scale_for`) of the vertices the faces use, left
    out those float32 cannot hold (their triangles are left out as non-finite, as
    `prepare` leaves out any such triangle). MeshError for a scene that float32 depths
    cannot hold.

    vertices : (n, 3) float64;  faces : (m, 3) int, valid indices (check_arrays);
    used_box : None, or `_used_box(vertices, faces)` when the caller has it.
    """
    lo, hi, found = _used_box(vertices, faces) if used_box is None else used_box
    if not found:
        # none that float32 holds: a scene too large says so (scale_for raises)
        pts = vertices[np.unique(faces)]
        pts = pts[np.isfinite(pts).all(axis=1)]
        if len(pts):
            scale_for(np.max(np.ptp(pts, axis=0)))
        return 1.0
    return scale_for(np.max(hi - lo))


def mesh_origin(vertices, faces, used_box=None):
    """(3,) float64: the builder's default origin, the centre of the float64 box of the
    vertices the faces use that float32 can hold (`_used_box`); None when there is none.

    vertices : (n, 3) float64;  faces : (m, 3) int, valid indices (check_arrays);
    used_box : as for `mesh_scale`.
    """
    lo, hi, found = _used_box(vertices, faces) if used_box is None else used_box
    if not found:
        return None
    return 0.5 * (lo + hi)


@njit(cache=True)
def _used_box(vertices, faces):
    """(lo (3,) float64, hi (3,) float64, found): the box of the vertices that the faces
    use and float32 can hold (no coordinate non-finite or beyond FLOAT32_MAX: `prepare`
    leaves out their triangles, so they neither place nor size the tree); found False
    when there is none.

    vertices : (n, 3) float64;  faces : (m, 3) int64, valid indices.
    """
    used = np.zeros(vertices.shape[0], dtype=np.bool_)
    for t in range(faces.shape[0]):
        for i in range(3):
            used[faces[t, i]] = True
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    found = False
    for j in range(vertices.shape[0]):
        if not used[j]:
            continue
        x = vertices[j, 0]
        y = vertices[j, 1]
        z = vertices[j, 2]
        if not (abs(x) <= FLOAT32_MAX and abs(y) <= FLOAT32_MAX and abs(z) <= FLOAT32_MAX):
            continue                                # not finite, or beyond float32 (NaN too)
        found = True
        lo[0] = min(lo[0], x)
        lo[1] = min(lo[1], y)
        lo[2] = min(lo[2], z)
        hi[0] = max(hi[0], x)
        hi[1] = max(hi[1], y)
        hi[2] = max(hi[2], z)
    return lo, hi, found


@njit(cache=True, nogil=True)
def _triangles(vertices, faces, origin, inv_scale, start, stop, tri, ids):
    """The kept triangles of faces[start:stop] relative to `origin`, in units of
    1 / inv_scale (a power of two), in input order, written to tri[start:], ids[start:].

    vertices : (n, 3) float64;  faces : (m, 3) int64, valid indices;  origin : (3,)
    float64;  tri : (m, 3, 3) float32, ids : (m,) uint32.
    Returns (kept, lo (3,) float32, hi (3,) float32, flat (3,) int64): each
    coordinate is the float64 difference times inv_scale (exact) rounded to float32; a
    triangle is kept when its nine input coordinates are within FLOAT32_MAX (what
    float32 holds, whatever the scale), its nine coordinates are finite and one
    component of the float32 cross product of its edges (v1 - v0) x (v2 - v0) is not
    zero (each product and difference rounded to float32, as numpy's `np.cross`
    does); lo, hi is the box of the kept triangles (inf, -inf when none); flat[k]
    counts the kept triangles whose three coordinates on axis k are equal.
    """
    lo = np.full(3, np.inf, dtype=np.float32)
    hi = np.full(3, -np.inf, dtype=np.float32)
    flat = np.zeros(3, dtype=np.int64)
    w = start
    for t in range(start, stop):
        finite = True
        for i in range(3):
            row = faces[t, i]
            for c in range(3):
                x = np.float32((vertices[row, c] - origin[c]) * inv_scale)
                # (a vertex float32 cannot hold is left out at any scale, as at 1)
                finite &= np.isfinite(x) & (abs(vertices[row, c]) <= FLOAT32_MAX)
                tri[w, i, c] = x
        if not finite:
            continue
        a0 = tri[w, 1, 0] - tri[w, 0, 0]
        a1 = tri[w, 1, 1] - tri[w, 0, 1]
        a2 = tri[w, 1, 2] - tri[w, 0, 2]
        b0 = tri[w, 2, 0] - tri[w, 0, 0]
        b1 = tri[w, 2, 1] - tri[w, 0, 1]
        b2 = tri[w, 2, 2] - tri[w, 0, 2]
        if a1 * b2 - a2 * b1 == 0 and a2 * b0 - a0 * b2 == 0 and a0 * b1 - a1 * b0 == 0:
            continue
        for c in range(3):
            x0 = tri[w, 0, c]
            x1 = tri[w, 1, c]
            x2 = tri[w, 2, c]
            lo[c] = min(lo[c], x0, x1, x2)
            hi[c] = max(hi[c], x0, x1, x2)
            flat[c] += (x0 == x1) & (x1 == x2)
        ids[w] = t
        w += 1
    return w - start, lo, hi, flat


PARALLEL_FACES = 20000
"""Meshes with at least this many faces make their triangles in two or more pieces
on the builder's threads: the pass is bound by the first writes to the new (m, 3, 3)
array, which threads take in parallel, and the pool's threads are started for the
root's events next anyway (BENCHMARKS.md: from 40k triangles on 2 threads about 2 %
of a build; at 10k no gain)."""


def _is_scale(value):
    """layout.is_scale, False for an integer beyond float64 (2**1025)."""
    try:
        return layout.is_scale(value)
    except OverflowError:
        return False


def check_origin(origin):
    """A given origin as (3,) float64: ParameterError unless 3 finite numbers (bools
    and strings are refused, not converted)."""
    given = origin
    try:
        origin = np.asarray(origin)
    except ValueError:                          # a ragged list
        origin = np.zeros(0)
    if (origin.dtype.kind not in "fiu" or origin.shape != (3,)
            or not np.isfinite(origin.astype(np.float64)).all()):
        raise ParameterError(f"origin must be 3 finite numbers, got {given!r:.80}")
    return origin.astype(np.float64)


def prepare(vertices, faces, origin=None, pool=None, threads=1, scale=None):
    """Validate mesh arrays and make the kept float32 triangles; raises MeshError (the
    arrays) or ParameterError (an origin or scale that is not one).

    origin, scale : None (the centre of the used vertices' box; `mesh_scale`) or the
        values to use instead, so that a subset of a mesh keeps the float32
        coordinates it has in the whole mesh;  pool, threads : a concurrent.futures
        executor of `threads` threads to make the triangles of large meshes on
        (PARALLEL_FACES), or None.
    """
    v, f = check_arrays(vertices, faces)
    m = len(f)
    if m >= layout.MAX_NODES:
        raise MeshError(f"{m} triangles; a tree holds fewer than {layout.MAX_NODES}")

    # the used vertices' box, found once for both defaults
    used_box = _used_box(v, f) if origin is None or scale is None else None
    if origin is None:
        origin = mesh_origin(v, f, used_box)
        if origin is None:
            mesh_scale(v, f, used_box)          # a scene beyond float32 says so first
            raise MeshError("no triangles left after removing degenerate ones (no vertex "
                            "that float32 holds)")
    else:
        origin = check_origin(origin)

    if scale is None:
        scale = mesh_scale(v, f, used_box)
    elif (isinstance(scale, bool) or not isinstance(scale, (int, float, np.integer, np.floating))
          or not _is_scale(scale)):
        raise ParameterError(f"scale must be a power of two from 2^-126 to 2^127, got {scale!r:.60}")
    scale = float(scale)

    tri = np.empty((m, 3, 3), dtype=np.float32)
    tri_ids = np.empty(m, dtype=np.uint32)
    pieces = threads if pool is not None and threads > 1 and m >= PARALLEL_FACES else 1
    cuts = [m * i // pieces for i in range(pieces + 1)]
    jobs = [(_triangles, v, f, origin, 1.0 / scale, a, b, tri, tri_ids)
            for a, b in zip(cuts, cuts[1:])]
    done = run_jobs(pool, jobs)
    kept = [piece[0] for piece in done]
    lo = np.min([piece[1] for piece in done], axis=0)
    hi = np.max([piece[2] for piece in done], axis=0)
    flat = np.sum([piece[3] for piece in done], axis=0)
    if sum(kept) < m:                   # degenerate triangles left out: keep the rest only
        tri = np.concatenate([tri[a:a + k] for a, k in zip(cuts, kept)])
        tri_ids = np.concatenate([tri_ids[a:a + k] for a, k in zip(cuts, kept)])
    if len(tri) == 0:
        raise MeshError("no triangles left after removing degenerate ones")
    bounds = np.stack([lo, hi])
    return Prepared(tri, tri_ids, origin, bounds, m, flat, scale)
