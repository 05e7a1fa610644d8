"""Point queries (kdray.points, kdray.sdf, kernels/points.cl) against independent
oracles: the float64 brute force over every triangle (kdray.reference.closest_points,
computed unlike the kernel, and reference.winding_number, the exact sum of solid
angles), and geometry (points on a closed mesh's vertices and edges are at distance
0; a grid cube's distances are known in closed form)."""
import sys
import warnings

import numpy as np
import pytest

from helpers import edge_midpoints, grid_cube, icosphere, real_mesh_arrays, run
from kdray import points as kpoints
from kdray import reference
from kdray.builder import build
from kdray.errors import KdrayError
from kdray.layout import MISS
from kdray.sdf import sdf_grid, sdf_samples
from kdray.trace import PACKETS, Tracer


@pytest.fixture(scope="module")
def spot():
    v, f = real_mesh_arrays("spot.obj")
    return v, f, build(v, f, keep_double=True)


def by_input_id(tree):
    """(m, 3, 3) float64 world triangles the tree holds (its float32 ones), by input id;
    zero-area triangles, which the tree leaves out, as NaN."""
    tri = np.full((tree.n_input_tris, 3, 3), np.nan)
    tri[tree.tri_ids] = tree.world(tree.triangles)
    return tri


def sample_points(v, f, n, seed):
    """Seeded points of four kinds, n of each: uniform in the box padded by half its
    size; 1e-6 of the box's size off the surface along the normal (both sides); on
    vertices; on edge midpoints."""
    rng = np.random.default_rng(seed)
    lo, hi = v.min(axis=0), v.max(axis=0)
    size = float((hi - lo).max())
    box = rng.uniform(lo - 0.5 * (hi - lo), hi + 0.5 * (hi - lo), (n, 3))
    tri = v[f[rng.integers(0, len(f), n)]]
    b = rng.dirichlet([1, 1, 1], n)
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normal /= np.linalg.norm(normal, axis=1)[:, None]
    side = np.where(rng.random(n) < 0.5, -1.0, 1.0)[:, None]
    near = np.einsum("ki,kij->kj", b, tri) + side * 1e-6 * size * normal
    on_vertex = v[np.unique(f)][rng.integers(0, len(np.unique(f)), n)]
    mids = edge_midpoints(v, f)
    on_edge = mids[rng.integers(0, len(mids), n)]
    return np.concatenate([box, near, on_vertex, on_edge])


def check_distances(got, want, size, rtol_p99=1e-6, rtol_max=4e-6):
    """Relative error p99 and max within bounds; points on the surface (want 0) within
    a float rounding of the scene's size."""
    on = want <= 1e-12 * size
    assert (np.abs(got[on]) <= 1e-6 * size).all()
    rel = np.abs(got[~on] - want[~on]) / want[~on]
    assert np.quantile(rel, 0.99) <= rtol_p99 and rel.max() <= rtol_max, (
        np.quantile(rel, 0.99), rel.max())


def test_closest_points_match_brute_force(runtime, spot):
    v, f, tree = spot
    n = runtime.small(150, 6)
    p = sample_points(v, f, n, seed=1)
    tracer = Tracer(tree, device=runtime.spec)
    tracer._poison_outputs = True
    near = tracer.closest_points(p)
    want_d, want_prim = reference.closest_points(by_input_id(tree), p)
    size = float(np.ptp(v, axis=0).max())
    check_distances(near.distance.astype(np.float64), want_d, size)
    assert near.distance.dtype == np.float32 and near.hit.all()
    # the point, its triangle and barycentrics agree with each other
    tri = by_input_id(tree)[near.prim]
    bary = ((1 - near.u - near.v)[:, None] * tri[:, 0] + near.u[:, None] * tri[:, 1]
            + near.v[:, None] * tri[:, 2])
    assert np.allclose(bary, near.point, atol=1e-6 * size)
    assert np.allclose(np.linalg.norm(near.point - p, axis=1), near.distance, rtol=1e-5,
                       atol=1e-6 * size)
    # the triangle is the brute force's wherever the nearest is clearly one triangle
    d2 = reference.point_triangle_d2(p, np.nan_to_num(by_input_id(tree), nan=1e30))
    second = np.partition(d2, 1, axis=1)[:, 1]
    clear = np.sqrt(second) > want_d * (1 + 1e-4) + 1e-9 * size
    assert (near.prim[clear] == want_prim[clear]).all()
    # the distance alone: the same numbers
    assert np.array_equal(tracer.distance(p), near.distance)


def test_ties_go_to_the_lowest_input_id(tracers):
    """A point on a vertex or an edge of the grid cube is at distance 0 from several
    triangles: the lowest input id wins, as for equal t in trace."""
    v, f = grid_cube(2)
    tracer = tracers(build(v, f))
    p = np.concatenate([v, edge_midpoints(v, f)])
    near = tracer.closest_points(p)
    assert (near.distance == 0).all()
    d2 = reference.point_triangle_d2(p, v[f])
    assert (near.prim == np.argmax(d2 == 0, axis=1)).all()
    # in closed form: the distance from the cube [-2, 2]^3 of points outside and inside
    rng = np.random.default_rng(2)
    q = rng.uniform(-5, 5, (400, 3))
    outside = np.linalg.norm(np.maximum(np.abs(q) - 2, 0), axis=1)
    inside = 2 - np.abs(q).max(axis=1)
    want = np.where(outside > 0, outside, inside)
    assert np.allclose(tracer.distance(q), want, rtol=1e-6, atol=1e-12)
    signed = tracer.signed_distance(q, sign="parity")
    assert np.allclose(signed, np.where(outside > 0, want, -want), rtol=1e-6, atol=1e-12)


def test_ties_do_not_depend_on_the_points_before(tracers):
    """Points outside the grid cube nearest to a corner tie between the triangles that
    share it: the lowest input id, alone and after a point whose nearest triangle is
    another of them (a work-item tests the previous point's triangle first; the bound
    it sets must not skip the region of a tying lower id)."""
    v, f = grid_cube(1)
    tracer = tracers(build(v, f))
    rng = np.random.default_rng(8)
    corners = v[(np.abs(v) == 1).all(axis=1)]
    c = corners[rng.integers(0, len(corners), 300)]
    p = c + np.sign(c) * rng.uniform(0.01, 2.0, (300, 3))        # beyond the corner
    d2 = reference.point_triangle_d2(p, v[f])
    lowest = np.argmax(d2 == d2.min(axis=1, keepdims=True), axis=1)
    tying = [np.flatnonzero(row == row.min()) for row in d2]
    assert all(len(t) > 1 for t in tying)
    # each point after a point beside it whose nearest triangle is its highest tying id
    highest = np.array([t[-1] for t in tying])
    tri = v[f[highest]]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    before = tri.mean(axis=1) + 0.01 * normal / np.linalg.norm(normal, axis=1)[:, None]
    pairs = np.stack([before, p], axis=1).reshape(-1, 3)
    assert (tracer.closest_points(pairs).prim[0::2] == highest).all()
    assert (tracer.closest_points(pairs).prim[1::2] == lowest).all()
    assert (tracer.closest_points(p).prim == lowest).all()
    assert all(tracer.closest_points(p[i:i + 1]).prim[0] == lowest[i] for i in range(0, 300, 37))


def test_answers_do_not_depend_on_the_points_a_work_item_takes(tracers, spot):
    """A launch of few points gives each work-item fewer of them (points._run), so that
    every core gets some: the same answers, bit for bit, as in runs of RUN_CPU (the
    points in one call), in calls of a few points each, and in runs of one."""
    tracer = tracers(spot[2])
    tracer._poison_outputs = True
    rng = np.random.default_rng(12)
    lo, hi = spot[2].world_box()
    p = lo - 0.2 + (hi - lo + 0.4) * rng.random((1500, 3))
    whole = tracer.closest_points(p)
    w = tracer.winding_number(p)
    parts = [tracer.closest_points(p[i:i + 37]) for i in range(0, len(p), 37)]
    for name in ("distance", "point", "prim", "u", "v"):
        want = getattr(whole, name)
        assert np.array_equal(np.concatenate([getattr(a, name) for a in parts]), want), name
    assert np.array_equal(np.concatenate([tracer.winding_number(p[i:i + 37])
                                          for i in range(0, len(p), 37)]), w)
    groups = tracer.groups
    try:
        tracer.groups = len(p)                   # runs of one point a work-item
        assert kpoints._run(tracer, {"run": kpoints.RUN_CPU, "local": 8}, len(p)) == 1
        ones = tracer.closest_points(p)
        assert all(np.array_equal(getattr(ones, n), getattr(whole, n))
                   for n in ("distance", "point", "prim", "u", "v"))
        assert np.array_equal(tracer.winding_number(p), w)
    finally:
        tracer.groups = groups


def test_ties_at_shared_edges_go_to_the_lowest_input_id(tracers):
    """A point on an edge two triangles share, or beyond it (off the surface along the
    bisector of their normals), is exactly as near to both wherever the edge lies (an
    icosphere's edges, not a grid's): the lower input id, in both precisions, whichever
    region of each triangle the rounding puts the point in."""
    v, f = icosphere(2)
    tree = build(v, f, keep_double=True)
    tracer = tracers(tree)
    edges = {}
    for i, face in enumerate(f):
        for k in range(3):
            a, b = sorted((face[k], face[(k + 1) % 3]))
            edges.setdefault((a, b), []).append((i, list(face).index(a), list(face).index(b)))
    faces = np.array([[i for i, _, _ in sides] for sides in edges.values()])   # (E, 2)
    ends = np.array([sides[0][1:] for sides in edges.values()])   # the edge's corners in face 0
    lowest = faces.min(axis=1)
    rng = np.random.default_rng(12)
    t = rng.uniform(0.25, 0.75, len(faces))[:, None]
    beyond = rng.uniform(1e-6, 0.05, (len(faces), 1))
    # the triangles each precision measures: the input's, or the tree's float32 copies
    for precision, tri in (("double", v[f]), ("single", by_input_id(tree))):
        a, b = tri[faces[:, 0], ends[:, 0]], tri[faces[:, 0], ends[:, 1]]
        on = a + t * (b - a)
        pair = tri[faces]                                          # (E, 2, 3, 3)
        n = np.cross(pair[:, :, 1] - pair[:, :, 0], pair[:, :, 2] - pair[:, :, 0])
        n /= np.linalg.norm(n, axis=2, keepdims=True)
        out = n.sum(axis=1)
        out /= np.linalg.norm(out, axis=1, keepdims=True)
        off = on + beyond * np.linalg.norm(b - a, axis=1)[:, None] * out
        for p in (on, off):
            assert (tracer.closest_points(p, precision=precision).prim == lowest).all()


def test_slivers_are_as_near_as_their_edges(tracers):
    """A sliver (its apex 1e-9 to 2.3e-12 of its size off the opposite edge: a plane
    lost to rounding) is measured by its edges: the distance of points near its
    vertices and edges equals the exact one (in rationals) to 1e-15 of its size."""
    from fractions import Fraction

    def exact(p, tri):
        P, *T = ([Fraction(float(x)) for x in q] for q in (p, *tri))

        def seg(a, b):
            ab = [y - x for x, y in zip(a, b)]
            ap = [y - x for x, y in zip(a, P)]
            s = sum(x * y for x, y in zip(ap, ab)) / sum(x * x for x in ab)
            s = min(max(s, Fraction(0)), Fraction(1))
            return sum((x - s * y) ** 2 for x, y in zip(ap, ab))
        return float(min(seg(T[0], T[1]), seg(T[1], T[2]), seg(T[2], T[0]))) ** 0.5

    base = np.array([[0.8063436218297209, -0.8646434752767338, 0.34546162820072834],
                     [-0.05491058804152682, 0.354855553877627, -0.9206838897907708]])
    rng = np.random.default_rng(13)
    for off in (1e-9, 1e-11, 2.3e-12):
        side = np.cross(base[1] - base[0], [0.3, 0.5, 0.8])
        apex = base[0] + 0.4 * (base[1] - base[0]) + off * side / np.linalg.norm(side)
        tri = np.vstack([base, apex])
        far = np.array([[5, 5, 5], [5, 6, 5], [6, 5, 5.0]])
        tracer = tracers(build(np.vstack([tri, far]), np.array([[0, 1, 2], [3, 4, 5]]),
                               keep_double=True))
        p = tri[rng.integers(0, 3, 40)] + rng.normal(size=(40, 3)) * 1e-11
        want = np.array([exact(q, tri) for q in p])
        got = tracer.closest_points(p, precision="double")
        assert (got.prim == 0).all()
        assert np.abs(got.distance - want).max() <= 2e-15


def exact_d2(p, tri):
    """The exact squared distance (a Fraction) from point p (3,) to triangle tri (3, 3):
    the plane's where p's projection lies in the triangle (by the signs of its edge
    functions, in rationals), else the nearest edge's."""
    from fractions import Fraction
    P, A, B, C = ([Fraction(float(x)) for x in q] for q in (p, *tri))

    def sub(x, y):
        return [i - j for i, j in zip(x, y)]

    def dot(x, y):
        return sum(i * j for i, j in zip(x, y))

    def cross(x, y):
        return [x[1] * y[2] - x[2] * y[1], x[2] * y[0] - x[0] * y[2], x[0] * y[1] - x[1] * y[0]]

    def seg(a, b):
        ab, ap = sub(b, a), sub(P, a)
        s = min(max(dot(ap, ab) / dot(ab, ab), Fraction(0)), Fraction(1))
        return dot(sub(ap, [s * x for x in ab]), sub(ap, [s * x for x in ab]))

    n = cross(sub(B, A), sub(C, A))
    h = dot(n, sub(P, A)) / dot(n, n)
    q = sub(P, [h * x for x in n])
    if all(dot(n, cross(sub(y, x), sub(q, x))) >= 0 for x, y in ((A, B), (B, C), (C, A))):
        return h * h * dot(n, n)
    return min(seg(A, B), seg(B, C), seg(C, A))


@pytest.mark.parametrize("width", [2.0 ** -25, 1e-7, 1e-6])
def test_thin_triangles_are_measured_from_their_face(tracers, width):
    """A thin triangle (not a sliver: its smallest angle, about `width`, above 2^-26),
    with points near its face: each region of the point is told from the exact one to
    the triangle's size times 2^-52 or so (Ericson's products of dot products had put
    points in an edge's region, 1e-3 of their distance away at 2^-25), so the distance
    is the exact one (in rationals) to 1e-15 of the size, in both precisions, and the
    point is its u, v's to the float32 rounding of u and v."""
    rng = np.random.default_rng(21)
    a, b = np.zeros(3), np.array([1.0, 0.5, 0.25])
    side = np.cross(b, [0.3, -0.5, 0.8])
    side /= np.linalg.norm(side)
    c = 0.5 * b + width * side
    tri = np.vstack([a, b, c]).astype(np.float32).astype(np.float64)   # both precisions'
    tracer = tracers(build(tri, np.array([[0, 1, 2]]), origin=np.zeros(3), keep_double=True))
    normal = np.cross(tri[1] - tri[0], tri[2] - tri[0])
    normal /= np.linalg.norm(normal)
    w = rng.dirichlet([1, 1, 1], 60)
    w[:20, 2] *= 1e-3                                  # near the long edges
    w /= w.sum(axis=1, keepdims=True)
    p = w @ tri + rng.uniform(-3, 3, (60, 1)) * width * normal
    want = np.array([float(exact_d2(q, tri)) for q in p]) ** 0.5
    for precision in ("double", "single"):
        got = tracer.closest_points(p, precision=precision)
        assert (got.prim == 0).all()
        # single: rounded to float32 once, half an ulp at most
        tol = 1e-15 + (0.0 if precision == "double" else 2.0 ** -24 * want)
        assert (np.abs(got.distance - want) <= tol).all(), np.abs(got.distance - want).max()
        at = ((1 - got.u - got.v)[:, None] * tri[0] + got.u[:, None] * tri[1]
              + got.v[:, None] * tri[2])
        assert np.abs(at - got.point).max() <= 2.0 ** -22


def test_double_distances_of_a_small_triangle_far_from_the_trees_origin(tracers):
    """precision="double" tests the point as given against the world float64 triangle:
    a triangle 3e-4 across beside one 4e3 across (the tree's origin some 1400 away),
    points 1e-6 to 1e-10 above it, at the exact distance (rationals) to a few double
    roundings of the triangle's size, as in a tree of its own (taken relative to the
    tree's origin, they had been 3.2e-15 off at 1e-10: roundings of 1400)."""
    tri = np.array([[0.0, 0.0, 0.0], [3e-4, 0.0, 1e-5], [1e-4, 2.5e-4, 2e-5]])
    big = np.array([[-1e3, -1e3, -10.0], [3e3, -1e3, -10.0], [-1e3, 3e3, -10.0]])
    tree = build(np.vstack([tri, big]), np.array([[0, 1, 2], [3, 4, 5]]), keep_double=True)
    assert np.abs(tree.origin).max() > 500
    tracer = tracers(tree)
    n = np.cross(tri[1] - tri[0], tri[2] - tri[0])
    rng = np.random.default_rng(24)
    w = rng.dirichlet([2, 2, 2], 30)
    p = w @ tri + np.geomspace(1e-10, 1e-6, 30)[:, None] * n / np.linalg.norm(n)
    want = np.array([float(exact_d2(q, tri)) for q in p]) ** 0.5
    got = tracer.closest_points(p, precision="double")
    assert (got.prim == 0).all()
    assert np.abs(got.distance - want).max() <= 1e-18
    assert np.abs(np.linalg.norm(got.point - p, axis=1) - want).max() <= 1e-18


def test_a_triangle_given_twice_ties_in_any_vertex_order(tracers):
    """The same triangle given six times, its vertices in each order (either
    orientation), is measured alike, bit for bit: of points nearest it the lowest of
    its input ids wins (it had depended on which vertex came first)."""
    from itertools import permutations
    rng = np.random.default_rng(22)
    tri = rng.normal(size=(3, 3))
    others = rng.normal(size=(5, 3, 3)) + 3.0
    copies = np.array([tri[list(k)] for k in permutations(range(3))])
    order = rng.permutation(len(others) + len(copies))
    tris = np.concatenate([others, copies])[order]
    first = int(np.flatnonzero(order >= len(others)).min())      # the copies' lowest id
    v = tris.reshape(-1, 3)
    tracer = tracers(build(v, np.arange(len(v)).reshape(-1, 3), keep_double=True))
    p = rng.dirichlet([1, 1, 1], 1000) @ tri + rng.normal(size=(1000, 3)) * 0.3
    d2 = reference.point_triangle_d2(p, tris)
    mine = d2[:, order >= len(others)].min(axis=1) < 0.5 * d2[:, order < len(others)].min(axis=1)
    assert mine.sum() > 900
    for precision in ("double", "single"):
        assert (tracer.closest_points(p[mine], precision=precision).prim == first).all()


def test_max_distance_and_misses(tracers, spot):
    v, f, tree = spot
    tracer = tracers(tree)
    p = sample_points(v, f, 50, seed=3)[:50]
    full = tracer.closest_points(p)
    limit = float(np.median(full.distance))
    near = tracer.closest_points(p, max_distance=limit)
    kept = full.distance <= np.float32(limit)
    assert np.array_equal(near.distance[kept], full.distance[kept])
    assert np.array_equal(near.prim[kept], full.prim[kept])
    assert (near.distance[~kept] == np.inf).all() and (near.prim[~kept] == MISS).all()
    assert (near.point[~kept] == 0).all() and not near.hit[~kept].any()
    assert (tracer.distance(p, max_distance=0.0)[full.distance > 0] == np.inf).all()
    # shapes are kept; no points, no answers
    assert tracer.distance(p[:12].reshape(3, 4, 3)).shape == (3, 4)
    assert tracer.closest_points(np.zeros((0, 3))).distance.shape == (0,)


def test_precision_double(tracers, spot):
    """precision="double": against the input's float64 triangles, float64 distances."""
    v, f, tree = spot
    tracer = tracers(tree)
    p = sample_points(v, f, 100, seed=4)
    d = tracer.distance(p, precision="double")
    assert d.dtype == np.float64
    want, _ = reference.closest_points(v[f], p)
    size = float(np.ptp(v, axis=0).max())
    on = want <= 1e-12 * size
    assert (d[on] <= 1e-13 * size).all()
    rel = np.abs(d[~on] - want[~on]) / want[~on]
    # 1e-12 of the distance, or of the scene's size for the points 1e-6 of it away
    assert ((rel <= 1e-12) | (np.abs(d - want)[~on] <= 1e-15 * size)).all(), rel.max()
    near = tracer.closest_points(p, precision="double")
    assert np.array_equal(near.distance, d)
    with pytest.raises(KdrayError, match="keep_double"):
        tracers(build(v, f)).distance(p, precision="double")


def test_precision_double_signs_a_small_object_in_a_large_scene(tracers):
    """A closed box 0.01 across, 1e3 from the origin of a closed slab 1e4 wide: its
    float32 copy is 4.8e-5 larger on one side. With precision="double" points 1e-5 off
    its faces, outside and inside, take the float64 box's side (winding and parity,
    signed_distance, occupancy, winding_number); in single precision they take the
    copy's, as documented."""
    def box(lo, hi):
        v = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                      for z in (lo[2], hi[2])], float)
        f = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                      [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
        return v, f
    sv, sf = box([-5000, -1, -5000], [5000, 0, 5000])
    lo, side = np.array([1234.5671, 1.0003, 2345.6789]), 0.01
    bv, bf = box(lo, lo + side)
    tree = build(np.vstack([sv, bv]), np.vstack([sf, bf + 8]), keep_double=True)
    tracer = tracers(tree)
    centre, off = lo + side / 2, 1e-5
    axes = np.concatenate([np.eye(3), -np.eye(3)])
    outside = centre + (side / 2 + off) * axes
    inside = centre + (side / 2 - off) * axes
    p = np.concatenate([outside, inside])
    want = np.repeat([off, -off], 6)
    for sign in ("winding", "parity"):
        d = tracer.signed_distance(p, sign, precision="double")
        assert np.allclose(d, want, rtol=0, atol=1e-11)          # the points' rounding
        assert (tracer.occupancy(p, sign, precision="double") == (want < 0)).all()
    w = tracer.winding_number(p, precision="double")
    assert np.allclose(w, want < 0, atol=1e-9)
    # the float32 copy reaches x = 1234.5771484375, 4.8e-5 past the box's 1234.5771
    copy = tree.world(np.asarray(tree.triangles, np.float64))[12:].reshape(-1, 3)
    assert copy[:, 0].max() > lo[0] + side + 2 * off
    assert tracer.occupancy(outside[:1])[0] and tracer.signed_distance(outside[:1])[0] < 0
    with pytest.raises(KdrayError, match="keep_double"):
        tracers(build(bv, bf)).occupancy(p, precision="double")


@pytest.mark.parametrize("scale, shift", [(1e-20, 0.0), (1.0, 1e6), (1e20, 3e21)])
def test_any_scale_and_offset(tracers, scale, shift):
    """The same relative accuracy far from the origin and at extreme scales."""
    v, f = icosphere(2)
    p = sample_points(v, f, 40, seed=5)
    tracer = tracers(build(v * scale + shift, f, keep_double=True))
    q = p * scale + shift
    tree = tracer.tree
    want, _ = reference.closest_points(by_input_id(tree), q)
    size = 2.0 * scale
    got = tracer.distance(q).astype(np.float64)
    if shift:
        # the points' own rounding in float64 at the offset: 1e-6 of 1e6 is 1e-16 of it
        check_distances(got[:40], want[:40], size)
        assert np.allclose(got, want, rtol=1e-6, atol=1e-9 * shift)
    else:
        check_distances(got, want, size)
    w = tracer.winding_number(q[:40])
    assert np.abs(w - reference.winding_number(by_input_id(tree), q[:40])).max() <= 1e-4


def test_winding_number_within_1e4_of_the_exact_sum(runtime, spot):
    v, f, tree = spot
    n = runtime.small(60, 4)
    p = sample_points(v, f, n, seed=6)[:2 * n]        # box and near-surface points
    tracer = Tracer(tree, device=runtime.spec)
    tracer._poison_outputs = True
    want = reference.winding_number(by_input_id(tree)[np.isfinite(by_input_id(tree)).all(axis=(1, 2))], p)
    w = tracer.winding_number(p)
    assert np.abs(w - want).max() <= 1e-4
    assert np.abs(tracer.winding_number(p, beta=np.inf) - want).max() <= 1e-10
    # the sign's quicker expansion: right wherever the exact number is 0.1 from 1/2
    clear = np.abs(want - 0.5) > 0.1
    assert (tracer.occupancy(p)[clear] == (want > 0.5)[clear]).all()


def test_winding_number_of_a_small_object_far_from_the_trees_origin(tracers):
    """A sphere of radius 1e-3 beside a triangle 1.2e4 across, which puts the tree's
    origin some 3000 away: the expansion's centres and moments are exact about the
    float32 centres the kernel reads, summed up the tree by shifts (not about the
    tree's origin: they had cancelled), and with precision="double" they are of the
    float64 triangles (the float32 copy is moved by 2.4e-4, a quarter of the radius).
    Within 1e-4 of the exact sum in both precisions (had been 4e-4 and 8e-4)."""
    v, f = icosphere(2)
    v = v * 1e-3
    big = np.array([[-3e3, -3e3, -30.0], [9e3, -3e3, -30.0], [-3e3, 9e3, -30.0]])
    tree = build(np.vstack([v, big]), np.vstack([f, [[len(v), len(v) + 1, len(v) + 2]]]),
                 keep_double=True)
    assert np.abs(tree.origin).max() > 1e3
    tracer = tracers(tree)
    p = np.random.default_rng(23).normal(size=(200, 3)) * 3e-3
    for precision, tri in (("double", np.vstack([v, big])[np.vstack(
            [f, [[len(v), len(v) + 1, len(v) + 2]]])]), ("single", by_input_id(tree))):
        want = reference.winding_number(tri, p)
        got = tracer.winding_number(p, precision=precision)
        assert np.abs(got - want).max() <= 1e-4, (precision, np.abs(got - want).max())


def test_signs_on_closed_meshes(tracers):
    """On a closed mesh parity and winding agree with the exact winding number for
    every point farther from the surface than its rounding (the float32 triangles are
    the input's within 6e-8 here); the points on vertices and edges are within it."""
    v, f = icosphere(2)
    tracer = tracers(build(v, f))
    p = sample_points(v, f, 200, seed=7)
    exact = reference.winding_number(v[f], p)
    d = tracer.distance(p)
    off = d > 1e-7
    assert off[:400].all() and not off[400:].any()
    inside = exact > 0.5
    assert (tracer.occupancy(p, sign="parity")[off] == inside[off]).all()
    assert (tracer.occupancy(p, sign="winding")[off] == inside[off]).all()
    for sign in ("parity", "winding"):
        s = tracer.signed_distance(p, sign=sign)
        assert ((s < 0) == inside)[off].all() and (np.abs(s) == d).all()


def test_winding_sign_on_closed_meshes_is_the_crossings_integer(runtime, spot):
    """On a closed, consistently oriented mesh the winding sign comes from one ray's
    crossings summed with their facings (kdray.rays.crossing_windings): the exact
    integer, so the generalized winding number's sign wherever that is near an integer;
    overlapping and inside-out components count as the winding number counts them."""
    from kdray import rays as krays
    v, f, tree = spot
    tracer = Tracer(tree, device=runtime.spec)
    assert kpoints.closed_cycle(tree)
    assert not kpoints.closed_cycle(build(*real_mesh_arrays("teapot.obj")))
    p = sample_points(v, f, runtime.small(3000, 40), seed=9)[:2 * runtime.small(3000, 40)]
    gwn = tracer.winding_number(p)
    clear = np.abs(gwn - np.round(gwn)) < 0.1
    assert clear.mean() > 0.95
    w = krays.crossing_windings(tracer, p)
    assert (w[clear] == np.round(gwn[clear])).all()
    assert (tracer.occupancy(p)[clear] == (gwn > 0.5)[clear]).all()

    # two overlapping spheres (winding 2 where they overlap: inside, though parity says
    # outside) and an inside-out one (-1: outside), each closed
    a, fa = icosphere(2)
    two = build(np.concatenate([a, a + [0.8, 0, 0], a * 0.5 + [5, 0, 0]]),
                np.concatenate([fa, fa + len(a), fa[:, ::-1] + 2 * len(a)]))
    tracer = Tracer(two, device=runtime.spec)
    assert kpoints.closed_cycle(two)
    q = np.array([[0.4, 0.05, 0.02], [-0.6, 0.1, 0.0], [1.5, 0.0, 0.1], [5.0, 0.01, 0.0],
                  [3.0, 0.0, 0.0]])
    assert krays.crossing_windings(tracer, q).tolist() == [2, 1, 1, -1, 0]
    assert tracer.occupancy(q).tolist() == [True, True, True, False, False]
    assert tracer.occupancy(q, sign="parity")[0] == False   # noqa: E712 (even crossings)

    # 34 nested spheres: the centre's ray crosses them all, more than the kernel keeps
    # hits of: exact where the ray walks the wide nodes (packet programs: each triangle
    # in one leaf, so none need be kept) and where it walks the k-d tree (its hits come
    # in t order: kd_count_hit); tests/test_rays.py has rays whose count is lost
    b, fb = icosphere(0)
    shells = build(np.concatenate([b * (1 + 0.1 * k) for k in range(34)]),
                   np.concatenate([fb + k * len(b) for k in range(34)]))
    tracer = Tracer(shells, device=runtime.spec)
    centre = np.array([[0.01, 0.02, 0.03]])
    assert krays.crossing_windings(tracer, centre)[0] == 34
    assert tracer.occupancy(centre)[0] and abs(tracer.winding_number(centre)[0] - 34) < 1e-3


def test_points_on_a_face_are_outside_on_every_packet_and_runtime(runtime):
    """A point on a face of a closed mesh has winding number 1/2 exactly; the sums
    round it apart in the last bits by packet width and runtime (0.5 or
    0.5000000000000001): sign="winding" takes a point inside only 2^-40 above 1/2
    (INSIDE_ABOVE), so points on the grid cube's faces, edges and corners are outside
    (signed distance +0.0) whatever the packets (had been about half of them inside,
    213 with one packet width and 205 with another)."""
    v, f = grid_cube(1)
    tree = build(v, f)
    rng = np.random.default_rng(25)
    k = runtime.small(400, 40)
    p = rng.integers(-8, 9, (k, 3)) / 8.0
    p[np.arange(k), rng.integers(0, 3, k)] = rng.choice([-1.0, 1.0], k)    # on a face
    packets = (1,) if runtime.simulator else (1, *PACKETS)
    for packet in packets:
        tracer = Tracer(tree, device=runtime.spec, packet=packet)
        assert not tracer.occupancy(p).any(), packet
        d = tracer.signed_distance(p)
        assert (d == 0).all() and not np.signbit(d).any(), packet
        w = tracer.winding_number(p, beta=2.0)
        assert np.abs(w[(np.abs(p) == 1).sum(axis=1) == 1] - 0.5).max() <= 1e-12


def test_parity_on_an_open_mesh_warns(tracers):
    v, f = grid_cube(1)
    assert kpoints.open_edges(build(v, f)) == 0
    tracer = tracers(build(v, f[2:]))     # a unit square of a face (2 triangles) less
    assert kpoints.open_edges(tracer.tree) == 4
    with pytest.warns(kpoints.OpenMeshWarning, match="4 open edges"):
        tracer.occupancy(np.zeros((1, 3)), sign="parity")
    # the warning names the caller's line, through a Tracer or kdray.points
    for call in (lambda: tracer.signed_distance(np.zeros((1, 3)), sign="parity"),
                 lambda: kpoints.signed_distance(tracer, np.zeros((1, 3)), sign="parity")):
        with pytest.warns(kpoints.OpenMeshWarning) as said:
            call()
        assert said[0].filename == __file__
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        tracer.occupancy(np.zeros((1, 3)))            # winding: no warning
        # bad points are their own error, with no warning before it
        for call in (tracer.occupancy, tracer.signed_distance):
            with pytest.raises(KdrayError):
                call(np.zeros((1, 2)), sign="parity")
        # the hole is a quarter of a face: 1/24 of the centre's solid angle
        assert abs(tracer.winding_number(np.zeros((1, 3)))[0] - 23 / 24) < 1e-4


def test_answers_do_not_depend_on_work_sizes_or_packets(runtime, spot, monkeypatch):
    """Closest points bit for bit at any work size and packet width (a packet's box
    test only skips triangles); winding numbers to double's rounding (packets sum a
    run's solid angles, in vector arithmetic, before adding them)."""
    v, f, tree = spot
    p = sample_points(v, f, runtime.small(40, 3), seed=8)

    def answers(tracer):
        near = tracer.closest_points(p)
        return (near.distance, near.prim, near.point, near.u, near.v,
                tracer.closest_points(p, precision="double").distance,
                tracer.winding_number(p[:len(p) // 2], beta=2.0))

    want = answers(Tracer(tree, device=runtime.spec, packet=1))
    monkeypatch.setattr(kpoints, "RUN_CPU", 3)
    options = [dict(packet=1, local_size=1), dict(packet=1, local_size=4)]
    if not runtime.simulator:
        options += [dict(packet=k) for k in PACKETS]
        options.append(dict(packet=PACKETS[0], plain_vector_ops=True))
    for opts in options:
        plain = opts.pop("plain_vector_ops", False)
        other = Tracer(tree, device=runtime.spec, **opts)
        other._plain_vector_ops = plain or other._plain_vector_ops
        got = answers(other)
        for a, b in zip(got[:-1], want[:-1]):
            assert np.array_equal(a, b), opts
        assert np.allclose(got[-1], want[-1], rtol=0, atol=1e-12), opts


def test_spatial_order_changes_no_answer(tracers, spot):
    """From SORT_FROM points on, queries run in spatial order (kdray.points.
    spatial_order) and their answers are put back: the same as in smaller calls."""
    v, f, tree = spot
    tracer = tracers(tree)
    p = sample_points(v, f, kpoints.SORT_FROM // 4 + 77, seed=9)
    p = np.concatenate([p, 5 * p[:100]])                 # some outside the box too
    assert len(p) >= kpoints.SORT_FROM
    chunks = [p[i:i + 1000] for i in range(0, len(p), 1000)]
    near = tracer.closest_points(p)
    parts = [tracer.closest_points(c) for c in chunks]
    for name in ("distance", "point", "prim", "u", "v"):
        assert np.array_equal(getattr(near, name),
                              np.concatenate([getattr(c, name) for c in parts])), name
    assert np.array_equal(tracer.winding_number(p, beta=2.0),
                          np.concatenate([tracer.winding_number(c, beta=2.0) for c in chunks]))
    assert np.array_equal(tracer.contains(p), np.concatenate([tracer.contains(c) for c in chunks]))


def test_bad_input_is_refused(tracers, spot):
    tracer = tracers(spot[2])
    for bad, match in ((np.array([[0.0, np.nan, 0.0]]), "finite, point 0"),
                       (np.zeros((3, 2)), r"\(N, 3\)"), (np.array(["a", "b", "c"]), "numbers")):
        for query in (tracer.distance, tracer.closest_points, tracer.winding_number,
                      tracer.occupancy, tracer.signed_distance):
            with pytest.raises(KdrayError, match=match):
                query(bad)
    for limit in (-1.0, np.nan, "far"):
        with pytest.raises(KdrayError, match="max_distance"):
            tracer.distance(np.zeros((1, 3)), max_distance=limit)
    with pytest.raises(KdrayError, match="beta"):
        tracer.winding_number(np.zeros((1, 3)), beta=0.5)
    # an integer beyond float64's range is as large as inf; a 0-d array is its number
    far = np.array([[1e30, 0.0, 0.0]])
    assert tracer.distance(far, max_distance=np.array(2e30)) == tracer.distance(far)
    assert tracer.distance(far, max_distance=10 ** 400) == tracer.distance(far)
    assert tracer.winding_number(far, beta=10 ** 400) == tracer.winding_number(far, beta=np.inf)
    # points beyond the queries' reach (2^300 of the tree's unit) are refused, naming them
    size = float(np.abs(spot[0]).max())
    for query in (tracer.distance, tracer.winding_number, tracer.signed_distance):
        with pytest.raises(KdrayError, match="point 1 .* beyond the point queries' reach"):
            query(np.array([[0.0, 0.0, 0.0], [1e95 * size, 0.0, 0.0]]))
    within = tracer.distance(np.array([[1e85 * size, 0.0, 0.0]]), precision="double")
    assert np.allclose(within, 1e85 * size, rtol=1e-12)
    with pytest.raises(KdrayError, match="sign must be"):
        tracer.signed_distance(np.zeros((1, 3)), sign="vote")
    with pytest.raises(KdrayError, match="resolution"):
        sdf_grid(tracer, 1)
    with pytest.raises(KdrayError, match="padding"):
        sdf_grid(tracer, 8, padding=-1)
    with pytest.raises(KdrayError, match=r"4096\^3 grid needs about 25[67]"):
        sdf_grid(tracer, 4096)


def test_grids_and_samples(tracers):
    v, f = grid_cube(1)
    tracer = tracers(build(v, f))
    grid = sdf_grid(tracer, 5, padding=0.25)           # [-1.5, 1.5]^3, spacing 0.75
    assert grid.spacing == 0.75 and grid.origin.tolist() == [-1.5, -1.5, -1.5]
    x = 0.75 * np.arange(5) - 1.5
    q = np.stack(np.meshgrid(x, x, x, indexing="ij"), axis=-1)
    outside = np.linalg.norm(np.maximum(np.abs(q) - 1, 0), axis=-1)
    want = np.where(outside > 0, outside, -(1 - np.abs(q).max(axis=-1)))
    assert np.allclose(grid.values, want, atol=1e-7) and grid.values.dtype == np.float32
    occupancy = sdf_grid(tracer, 5, padding=0.25, sign="parity", occupancy=True)
    assert occupancy.values.dtype == np.uint8
    assert np.array_equal(occupancy.values, (want < 0).astype(np.uint8))
    p, s = sdf_samples(tracer, 1000, sigma=0.01, uniform=0.2, seed=3)
    assert p.shape == (1000, 3) and s.shape == (1000,)
    again = sdf_samples(tracer, 1000, sigma=0.01, uniform=0.2, seed=3)
    assert np.array_equal(p, again[0]) and np.array_equal(s, again[1])
    assert (np.abs(s[:800]) < 0.06).all()              # near the surface
    assert np.allclose(s, tracer.signed_distance(p))
    # a sigma of -0 is 0: the surface points themselves (numpy's normal refuses -0.0)
    flat = sdf_samples(tracer, 100, sigma=-0.0, uniform=0.0, seed=3)
    assert np.array_equal(flat[0], sdf_samples(tracer, 100, sigma=0.0, uniform=0.0, seed=3)[0])


def write_obj(path, v, f):
    """path, written as an OBJ of vertices v (n, 3) and faces f (m, 3) (0-based)."""
    path.write_text("".join(f"v {a} {b} {c}\n" for a, b, c in v)
                    + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in f))
    return path


def test_sdf_command(tmp_path, capsys):
    v, f = icosphere(1)
    mesh = write_obj(tmp_path / "ball.obj", v, f)
    out = tmp_path / "grid.npz"
    code, stdout, _ = run(capsys, "sdf", mesh, "-o", out, "--resolution", 9)
    assert code == 0 and "9^3 grid" in stdout
    grid = np.load(out)
    assert grid["sdf"].shape == (9, 9, 9) and str(grid["sign"]) == "winding"
    assert grid["sdf"][4, 4, 4] < 0 < grid["sdf"][0, 0, 0]
    code, stdout, _ = run(capsys, "sdf", mesh, "-o", out, "--samples", 100, "--seed", 1,
                          "--sign", "parity")
    samples = np.load(out)
    assert code == 0 and samples["points"].shape == (100, 3) and samples["sdf"].shape == (100,)
    code, _, err = run(capsys, "sdf", mesh, "-o", out, "--resolution", 1)
    assert code == 1 and "resolution must be from 2" in err and "Traceback" not in err
    code, _, err = run(capsys, "sdf", mesh, "-o", mesh, "--resolution", 4)
    assert code != 0 and mesh.read_text().startswith("v ")
    for clash in (["--occupancy"], ["--resolution", 8]):
        code, _, err = run(capsys, "sdf", mesh, "-o", out, *clash, "--samples", 5)
        assert code == 2 and "cannot be combined with --samples" in err
    for name, value in (("--sigma", 0.1), ("--uniform", 0.5), ("--seed", 0)):
        code, _, err = run(capsys, "sdf", mesh, "-o", out, name, value)
        assert code == 2 and f"{name} goes with --samples" in err
    # the samples' own values are refused before any work: before the scene is read
    for argv, words in (((0,), "sample count"), ((5, "--sigma", -1), "sigma"),
                        ((5, "--uniform", 2), "uniform"), ((5, "--seed", -1), "seed")):
        code, _, err = run(capsys, "sdf", tmp_path / "absent.obj", "-o", out, "--samples",
                           *argv)
        assert code == 1 and words in err and err.count("\n") == 1, err



def test_sdf_command_checks_the_grids_memory_before_any_work(tmp_path, capsys, monkeypatch):
    """The memory a grid needs is said for its own values: 4 bytes a point for
    distances, 1 for occupancy (the audit's case: 65 GiB said for a float32 grid)."""
    monkeypatch.setattr("kdray.host.available_memory", lambda: 20 * 2**30)
    v, f = icosphere(0)
    mesh = write_obj(tmp_path / "ball.obj", v, f)
    out = tmp_path / "grid.npz"
    code, _, err = run(capsys, "sdf", mesh, "-o", out, "--resolution", 3000)
    assert code == 1 and "3000^3 grid needs about 101" in err and "Traceback" not in err
    code, _, err = run(capsys, "sdf", mesh, "-o", out, "--resolution", 3000, "--occupancy")
    assert code == 1 and "3000^3 grid needs about 25" in err and not out.exists()


def test_samples_uniform_in_the_padded_box_not_the_cube(tracers):
    """sdf_samples' uniform points lie in the scene's box widened by padding times its
    largest side on each axis (a 4 x 1 x 0 rectangle: not the grid's 4.8-wide cube),
    and fill it; round(count * uniform) of them, after the surface's."""
    v = np.array([[0, 0, 0], [4, 0, 0], [4, 1, 0], [0, 1, 0]], dtype=np.float64)
    tracer = tracers(build(v, np.array([[0, 1, 2], [0, 2, 3]])))
    p, _ = sdf_samples(tracer, 4000, sigma=0.0, uniform=0.5, padding=0.1, seed=1)
    box = p[2000:]
    assert (p[:2000, 2] == 0).all()                    # the surface's, sigma 0
    lo, hi = np.array([-0.4, -0.4, -0.4]), np.array([4.4, 1.4, 0.4])
    assert (box >= lo).all() and (box <= hi).all()
    assert (box.min(axis=0) < lo + 0.05).all() and (box.max(axis=0) > hi - 0.05).all()
    assert len(sdf_samples(tracer, 5, uniform=0.5, seed=1)[0]) == 5


def test_flat_scene_queries_warn_of_nothing(tracers):
    """A scene whose box is flat on an axis: the points' Morton grid (4096 points or
    more) has no overflow to warn of, and the answers are right."""
    v = np.array([[0, 0, 0], [10, 0, 0], [10, 10, 0], [0, 10, 0]], dtype=np.float64)
    tracer = tracers(build(v, np.array([[0, 1, 2], [0, 2, 3]])))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        grid = sdf_grid(tracer, 16, 0.1)
    x = grid.origin[:, None] + grid.spacing * np.arange(16)
    q = np.stack(np.meshgrid(*x, indexing="ij"), axis=-1)
    want = np.linalg.norm(q - np.clip(q, [0, 0, 0], [10, 10, 0]), axis=-1)
    assert np.allclose(np.abs(grid.values), want, rtol=1e-6, atol=1e-6)


def test_sdf_progress_only_on_a_terminal(tmp_path, capsys, monkeypatch):
    """`kdray sdf` shows a large grid's progress as the other steps' (Steps.live: on a
    terminal, without -q; docs/interface.md), not on a file or pipe, with or without
    -q: it printed it whatever stderr was."""
    from kdray import cli
    v, f = icosphere(1)
    mesh = write_obj(tmp_path / "ball.obj", v, f)
    out = tmp_path / "grid.npz"
    # 162^3 points, past SDF_PROGRESS_POINTS; capsys's stderr is no terminal
    code, _, err = run(capsys, "sdf", mesh, "-o", out, "--resolution", 162, "--occupancy")
    assert code == 0 and "% of" not in err, err
    monkeypatch.setattr(cli, "SDF_PROGRESS_POINTS", 8)         # a "large" grid: 3^3 and up
    monkeypatch.setattr(sys.stderr, "isatty", lambda: True)
    code, _, err = run(capsys, "sdf", mesh, "-o", out, "--resolution", 6)
    assert code == 0 and "signed distances: 100% of 216 points" in err


def test_points_command(tmp_path, capsys):
    """`kdray points` writes what the Tracer's point queries give at a file's points,
    the distances matching the float64 brute force, and refuses what does not fit."""
    v, f = icosphere(2)
    mesh = tmp_path / "ball.obj"
    mesh.write_text("".join(f"v {float(a)!r} {float(b)!r} {float(c)!r}\n" for a, b, c in v)
                    + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in f))
    at = np.random.default_rng(4).uniform(-1.5, 1.5, (203, 3))
    np.save(tmp_path / "p.npy", at)
    np.savetxt(tmp_path / "p.txt", at, fmt="%.17g")
    tracer = Tracer(build(v, f))
    out = tmp_path / "q.npz"

    def points(source, query, *more):
        code, said, err = run(capsys, "points", mesh, "--points", tmp_path / source, "-o", out,
                              "--query", query, *more)
        assert code == 0 and said.startswith(f"wrote {out} (203 points, "), err
        with np.load(out) as got:
            return {k: got[k] for k in got.files}

    want_d, _ = reference.closest_points(v[f], at)
    for source in ("p.npy", "p.txt"):
        got, want = points(source, "closest"), tracer.closest_points(at)
        for k in ("point", "distance", "prim", "u", "v", "object"):
            np.testing.assert_array_equal(got[k], getattr(want, k))
        assert np.allclose(got["distance"], want_d, rtol=1e-5, atol=1e-6)
        assert np.array_equal(points(source, "distance")["distance"], tracer.distance(at))
        got = points(source, "signed")["signed_distance"]
        assert np.array_equal(got, tracer.signed_distance(at))
        inside = np.linalg.norm(at, axis=1) < 0.9          # the icosphere's inner radius ~0.95
        assert (got[inside] < 0).all() and np.allclose(np.abs(got), want_d, rtol=1e-5, atol=1e-6)
        assert np.array_equal(points(source, "winding")["winding_number"],
                              tracer.winding_number(at))
        assert np.array_equal(points(source, "occupancy")["occupancy"], tracer.occupancy(at))
    got = points("p.npy", "signed", "--sign", "parity", "--max-distance", "0.3")
    assert np.array_equal(got["signed_distance"],
                          tracer.signed_distance(at, "parity", max_distance=0.3))
    assert np.isinf(got["signed_distance"][want_d > 0.3 * (1 + 1e-6)]).all()
    got = points("p.npy", "closest", "--precision", "double")
    assert got["distance"].dtype == np.float64
    assert np.allclose(got["distance"], want_d, rtol=1e-12, atol=1e-12)
    # the triangle found is a nearest one (several are where the nearest point is a vertex)
    d2 = reference.point_triangle_d2(at, v[f].astype(np.float64))
    assert np.allclose(np.sqrt(d2[np.arange(len(at)), got["prim"]]), want_d, rtol=1e-12,
                       atol=1e-12)

    # double precision's side near the surface, for every query that signs
    tracer64 = Tracer(build(v, f, keep_double=True))
    for query, key in (("winding", "winding_number"), ("occupancy", "occupancy")):
        got = points("p.npy", query, "--precision", "double")[key]
        assert np.array_equal(got, getattr(tracer64, key)(at, precision="double"))
    for more in (("--query", "winding", "--sign", "parity"),
                 ("--query", "occupancy", "--max-distance", "1")):
        code, _, err = run(capsys, "points", mesh, "--points", tmp_path / "p.npy", "-o", out, *more)
        assert code == 2 and "does not go with" in err, more
    np.save(tmp_path / "bad.npy", np.zeros((3, 2)))
    for more in (("--points", tmp_path / "bad.npy", "-o", out),
                 ("--points", tmp_path / "p.npy", "-o", tmp_path / "p.npy"),
                 ("--points", tmp_path / "p.npy", "-o", out, "--max-distance", "-1")):
        code, _, err = run(capsys, "points", mesh, *more)
        assert code == 1 and err.count("\n") == 1 and err.startswith("kdray: error:"), more
    assert np.load(tmp_path / "p.npy").shape == (203, 3)
