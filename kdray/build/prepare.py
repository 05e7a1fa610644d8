"""Mesh arrays -> the float32 triangles the tree stores.

    vertices  : (n, 3) float-like, world coordinates (read as float64)
    faces     : (m, 3) int, indices into vertices; triangle ids are row numbers
    ->
    triangles : (k, 3, 3) float32   kept triangles, relative to `origin`
    tri_ids   : (k,) uint32         input row of each kept triangle (input order kept)
    origin    : (3,) float64        centre of the box of the finite vertices the faces use
    bounds    : (2, 3) float32      box of the kept triangles (min, max), relative

A triangle is left out when a coordinate is not finite after the shift to float32, or
when its float32 cross product is zero: such a triangle can never be hit.
"""
import dataclasses

import numpy as np

from .. import layout
from ..errors import MeshError
from ..mesh import check_arrays


@dataclasses.dataclass(frozen=True)
class Prepared:
    triangles: np.ndarray
    tri_ids: np.ndarray
    origin: np.ndarray
    bounds: np.ndarray
    n_input_tris: int


def mesh_origin(vertices, faces):
    """(3,) float64: the builder's default origin, the centre of the float64 box of the
    finite vertices the faces use; None when there is none.

    vertices : (n, 3) float64;  faces : (m, 3) int, valid indices (check_arrays).
    """
    used = np.zeros(len(vertices), dtype=bool)
    used[faces.ravel()] = True
    used &= np.isfinite(vertices).all(axis=1)
    if not used.any():
        return None
    pts = vertices[used]
    return 0.5 * (pts.min(axis=0) + pts.max(axis=0))


def prepare(vertices, faces, origin=None):
    """Validate mesh arrays and make the kept float32 triangles; raises MeshError.

    origin : None (the centre of the used vertices' box) or a (3,) float64 to use
        instead, so that a subset of a mesh keeps the float32 coordinates it has in
        the whole mesh.
    """
    v, f = check_arrays(vertices, faces)
    m = len(f)
    if m >= layout.MAX_NODES:
        raise MeshError(f"{m} triangles; a tree holds fewer than {layout.MAX_NODES}")

    if origin is None:
        origin = mesh_origin(v, f)
        if origin is None:
            raise MeshError("no triangles left after removing degenerate ones (no finite vertex)")
    else:
        origin = np.asarray(origin, dtype=np.float64)
        if origin.shape != (3,) or not np.isfinite(origin).all():
            raise MeshError(f"origin must be 3 finite numbers, got {origin!r}")

    with np.errstate(over="ignore", invalid="ignore"):
        tri = v[f]
        tri -= origin                                  # in place: one (m, 3, 3) float64 array
        tri = tri.astype(np.float32)
        finite = np.isfinite(tri).all(axis=(1, 2))
        e1 = tri[:, 1] - tri[:, 0]
        e2 = tri[:, 2] - tri[:, 0]
        cross = np.cross(e1, e2)                       # float32, as the kernels see it
    keep = finite & (cross != 0).any(axis=1)
    if not keep.any():
        raise MeshError("no triangles left after removing degenerate ones")
    tri_ids = np.flatnonzero(keep).astype(np.uint32)
    if len(tri_ids) < m:
        tri = np.ascontiguousarray(tri[keep])
    flat = tri.reshape(-1, 9)                # a reduction over rows of 9 is the fast one in numpy
    lo = flat.min(axis=0).reshape(3, 3).min(axis=0)
    hi = flat.max(axis=0).reshape(3, 3).max(axis=0)
    bounds = np.stack([lo, hi]).astype(np.float32)
    return Prepared(tri, tri_ids, origin, bounds, m)
