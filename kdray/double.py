"""Float64 answers on request (precision="double"): the t, u, v of hits the kernels found,
recomputed on the host in float64 from the input's triangles and the caller's rays.

    t, u, v = plane_hits(triangles, origins, directions)   # (k,) float64 each
    t, uv = hits_double(tree.triangles64, hits.prim, origins, directions)   # all rays

The kernels decide which triangle a ray hits (float32, watertight); this module only
computes where on that triangle, from its float64 vertices: t from the triangle's
plane, u and v as the barycentrics of o + t d in it. The arithmetic is taken relative
to the triangle's first vertex, so that its error is a few float64 roundings of the
ray's distance to that vertex (relative to t: about 1e-16 times that distance over t,
divided by the cosine of the angle of incidence). Where that ratio passes
CANCELLATION (a triangle much larger than t: a ground plane under a small object),
t is computed again in double-double arithmetic (Dekker's error-free sums and
products, about 106 bits: the edges and the origin's offset exact, the plane's
products carried in two parts), which holds it to a few float64 roundings of the
exact t up to triangles 2^50 times t.
"""
import numpy as np

from .errors import KdrayError


def _dot(a, b):
    """Row-wise dot products of (k, 3) arrays, as (a0 b0 + a1 b1) + a2 b2."""
    return (a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1]) + a[:, 2] * b[:, 2]


def _cross(a, b):
    return np.stack([a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1],
                     a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
                     a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]], axis=1)


CANCELLATION = 8.0
"""plane_hits' t is computed again in double-double where |n| |v0 - o| over |n . (v0 -
o)| (the plane's cancellation: the triangle's reach from the hit over t cos) passes
this: more than 3 of float64's bits lost (below, t's error is at most some 8 times a
few roundings). Double-double costs about 1.1 us a hit on a Zen 4 core, plain
float64 0.17 (2^20 random triangles, ad hoc): taken for the hits that need it only."""

_SPLIT = 134217729.0
"""2^27 + 1: Veltkamp's split of a float64 into two halves of 26 bits (no fma in numpy)."""


def _two_sum(a, b):
    """(s, e): s = fl(a + b) and a + b = s + e exactly (Knuth)."""
    s = a + b
    bb = s - a
    return s, (a - (s - bb)) + (b - bb)


def _two_prod(a, b):
    """(p, e): p = fl(a b) and a b = p + e exactly (Dekker, with Veltkamp's split)."""
    p = a * b
    ca, cb = _SPLIT * a, _SPLIT * b
    ah, bh = ca - (ca - a), cb - (cb - b)
    al, bl = a - ah, b - bh
    return p, ((ah * bh - p) + ah * bl + al * bh) + al * bl


def _dd_add(x, y):
    """The double-double sum of x and y ((hi, lo) pairs of arrays)."""
    s, e = _two_sum(x[0], y[0])
    e = e + (x[1] + y[1])
    hi = s + e
    return hi, e - (hi - s)


def _dd_mul(x, y):
    """The double-double product of x and y ((hi, lo) pairs of arrays)."""
    p, e = _two_prod(x[0], y[0])
    e = e + (x[0] * y[1] + x[1] * y[0])
    hi = p + e
    return hi, e - (hi - p)


def _dd_dot(x, y):
    """The double-double dot product of 3-vectors of (hi, lo) pairs."""
    return _dd_add(_dd_add(_dd_mul(x[0], y[0]), _dd_mul(x[1], y[1])), _dd_mul(x[2], y[2]))


def _t_double_double(tri, o, d):
    """(k,) float64 t of rays o + t d at the planes of triangles tri ((k, 3, 3)), from
    double-double arithmetic: the edges v1 - v0, v2 - v0 and the offset v0 - o are
    exact as pairs (_two_sum), the normal and the dot products carry about 106 bits,
    and the quotient is corrected once by its remainder."""
    def minus(a, b):
        return [_two_sum(a[:, k], -b[:, k]) for k in range(3)]
    e1, e2, a = minus(tri[:, 1], tri[:, 0]), minus(tri[:, 2], tri[:, 0]), minus(tri[:, 0], o)

    def neg(x):
        return -x[0], -x[1]
    n = [_dd_add(_dd_mul(e1[(k + 1) % 3], e2[(k + 2) % 3]),
                 neg(_dd_mul(e1[(k + 2) % 3], e2[(k + 1) % 3]))) for k in range(3)]
    zero = np.zeros(len(d))
    num = _dd_dot(n, a)
    den = _dd_dot(n, [(d[:, k], zero) for k in range(3)])
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        q = num[0] / den[0]
        rest = _dd_add(num, neg(_dd_mul((q, zero), den)))
        return q + rest[0] / den[0]


def plane_hits(triangles, origins, directions, exact=None):
    """(t, u, v), (k,) float64 each: where rays o + t d meet the planes of their
    triangles, P = (1 - u - v) v0 + u v1 + v v2.

    triangles : (k, 3, 3) float64 world;  origins, directions : (k, 3) float64.
    exact : None, or (k,) bool: the hits whose t is computed again in double-double
    where the plane's products cancel (CANCELLATION); the others keep plain float64's
    t (hits that will not count: a ray's origin on its triangle's plane cancels
    completely, and its t is of no use).
    A ray parallel to its triangle's plane gives a non-finite t.
    """
    tri = np.asarray(triangles, dtype=np.float64)
    o = np.asarray(origins, dtype=np.float64)
    d = np.asarray(directions, dtype=np.float64)
    e1 = tri[:, 1] - tri[:, 0]
    e2 = tri[:, 2] - tri[:, 0]
    a = tri[:, 0] - o
    n = _cross(e1, e2)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        ahead = _dot(n, a)
        t = ahead / _dot(n, d)
        lost = np.sqrt(_dot(n, n) * _dot(a, a)) > CANCELLATION * np.abs(ahead)
    if exact is not None:
        lost &= exact
    if lost.any():
        t[lost] = _t_double_double(tri[lost], o[lost], d[lost])
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        h = t[:, None] * d - a                       # the hit point relative to v0
        nn = _dot(n, n)
        u = _dot(_cross(h, e2), n) / nn
        v = _dot(_cross(e1, h), n) / nn
    return t, u, v


CHUNK = 1 << 18
"""Hits `hits_double` takes at a time: plane_hits' temporaries (about 400 bytes a hit)
stay within some 100 MB however many hits there are."""


ON_PLANE = 2.0 ** -50
"""A double-precision hit does not count where its ray's origin lies on the hit
triangle's float64 plane within this share of the larger of the largest coordinate of
the origin's offset to the triangle's vertices and the origin's largest world
coordinate (8 float64 roundings of either: a point sampled on the triangle, a + u
(b - a) + v (c - a), is off its plane by the rounding of its world coordinates, which
exceed the triangle's size where the mesh lies far from the world's origin), as the
float32 test's t must pass its own rounding error (`hits_double(..., on_plane=True)`;
kdray.hit_lists.nearest_in_range)."""


def _on_plane(tri, o):
    """(k,) bool: whether each origin o (k, 3) lies on its triangle's (k, 3, 3) plane
    within ON_PLANE of its reach, or of its own largest coordinate where that is more;
    both in world coordinates (a degenerate triangle: False)."""
    n = _cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    reach = np.maximum(np.abs(tri - o[:, None, :]).max(axis=(1, 2)), np.abs(o).max(axis=1))
    with np.errstate(invalid="ignore", divide="ignore"):
        off = np.abs(_dot(n, tri[:, 0] - o)) / np.sqrt(_dot(n, n))
    return off <= ON_PLANE * reach


def hits_double(triangles64, prim, origins, directions, rays=None, origin=None, tree=None,
                on_plane=False):
    """(t (N,), uv (N, 2)) float64 of N rays at the triangles the kernels found.

    triangles64 : (n_input_tris, 3, 3) float64 world (KdTree.triangles64);
    prim : (N,) uint32 input triangle id per ray, MISS on a miss;
    origins, directions : (N, 3) float64, or with `rays` ((N,) int64) rows of them:
    ray i is origins[rays[i]], directions[rays[i]]; with origin ((3,) float64) the
    origins are relative to it, and so are the triangles taken. t is +inf and uv 0 on
    a miss. tree : the KdTree the hits are of, or None: where a float64 triangle has
    no plane the ray meets (its vertices collinear in float64 though not in the
    tree's float32 copy, which the kernel hit; or the ray in its plane), t, u, v come
    from that float32 copy's plane, in float64 (else they stay NaN or inf).
    on_plane : also return (N,) bool, the hits whose ray's origin lies on the float64
    triangle's plane (_on_plane, ON_PLANE), from the same gathered triangles; their t
    is plain float64's (plane_hits' `exact`), as they do not count.
    Host memory: 24 bytes a ray for the answers, and CHUNK rays' temporaries.
    """
    from .layout import MISS
    t = np.full(len(prim), np.inf)
    uv = np.zeros((len(prim), 2))
    at_origin = np.zeros(len(prim), dtype=bool)
    for a in range(0, len(prim), CHUNK):
        hit = np.flatnonzero(prim[a:a + CHUNK] != MISS) + a
        at = hit if rays is None else rays[hit]
        tri = triangles64[prim[hit]]
        if origin is not None:
            tri = tri - origin
        # a hit at its ray's origin never counts: its t is not made exact
        on = _on_plane(tri, origins[at]) if on_plane else None
        t[hit], uv[hit, 0], uv[hit, 1] = plane_hits(tri, origins[at], directions[at],
                                                    None if on is None else ~on)
        if on_plane:
            at_origin[hit] = on
    bad = np.flatnonzero((prim != MISS) & ~(np.isfinite(t) & np.isfinite(uv).all(axis=1)))
    if tree is not None and bad.size:
        at = bad if rays is None else rays[bad]
        tri = stored_triangles(tree, prim[bad])
        if origin is not None:
            tri = tri - origin
        t[bad], uv[bad, 0], uv[bad, 1] = plane_hits(tri, origins[at], directions[at])
    return (t, uv, at_origin) if on_plane else (t, uv)


def flat_rays64(origins, directions):
    """(o, d): (N, 3) float64 each of rays given as (..., 3) directions and origins of
    their shape or one (3,) origin (broadcast: a view)."""
    d = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    return np.broadcast_to(np.asarray(origins, dtype=np.float64).reshape(-1, 3), d.shape), d


def double_hits(tree, hits, origins, directions, on_plane=False):
    """(Hits, at_origin): `hits` (kdray.Hits of the rays origins, directions) with t, u,
    v recomputed in float64 from the tree's float64 triangles (hits_double), and with
    on_plane (N,) bool, the hits whose ray's origin lies on their float64 plane (else
    None)."""
    from .hits import Hits
    o, d = flat_rays64(origins, directions)
    t, uv, *at_origin = hits_double(tree.triangles64, hits.prim, o, d, tree=tree,
                                    on_plane=on_plane)
    return (Hits(t=t, prim=hits.prim, u=uv[:, 0], v=uv[:, 1], normal=hits.normal,
                 object_table=hits.object_table), at_origin[0] if on_plane else None)


def stored_triangles(tree, ids):
    """(k, 3, 3) float64 world: the tree's float32 triangles of input ids `ids` ((k,),
    each one the tree keeps)."""
    return tree.world(np.asarray(tree.triangles)[tree.stored_index()[ids]].astype(np.float64))


def need_double(tree):
    """KdrayError's message when `tree` has no float64 triangles, else None."""
    if tree.triangles64 is None:
        return ("precision='double' needs the tree's float64 triangles: build it with "
                "kdray.build(..., keep_double=True) or attach them with "
                "tree.with_double(vertices, faces)")
    return None


def wants_double(precision, tree):
    """True for precision "double" (KdrayError when `tree` has no float64 triangles),
    False for "single"; KdrayError for anything else."""
    if not (isinstance(precision, str) and precision in ("single", "double")):
        shown = " ".join(repr(precision).split())      # one line, an array's repr too
        raise KdrayError(f"precision must be 'single' or 'double', got {shown:.80}")
    missing = need_double(tree) if precision == "double" else None
    if missing:
        raise KdrayError(missing)
    return precision == "double"
