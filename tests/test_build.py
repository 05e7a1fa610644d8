"""The SAH k-d tree builder: valid trees on many kinds of input (KdTree.validate),
the same hits as the brute-force oracle, determinism, parameters, and the sweep's
choice checked against a direct evaluation of every candidate plane."""
import os
import threading
import warnings
import time

import numpy as np
import pytest

from kdray import layout, reference
from kdray.builder import build
from kdray.builder.classify import (ON_BOTH, ON_LEFT, ON_RIGHT, classify, clip_straddlers,
                                  split_merge, straddler_events)
from kdray.builder.clip import clip_split, polygon_scratch
from kdray.builder.events import position_bits, position_value, sorted_root_events
from kdray.builder import sah
from kdray.builder.sah import best_split
from kdray.builder.subdivide import MAX_REFS_PER_TRI
from kdray.errors import MeshError, ParameterError
from helpers import real_mesh_arrays



# -- helpers ------------------------------------------------------------------------

def soup(rng, n, size=0.05, flat_axis=None):
    """n random small triangles in the unit cube: (3n, 3) vertices, (n, 3) faces."""
    centre = rng.random((n, 1, 3))
    tri = centre + size * rng.normal(size=(n, 3, 3))
    if flat_axis is not None:
        tri[..., flat_axis] = 0.0
    return tri.reshape(-1, 3), np.arange(3 * n).reshape(-1, 3)


def grid(nx, ny):
    """A flat (nx-1) x (ny-1) grid of unit squares in z = 0, two triangles each."""
    g = np.stack(np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij"), -1).reshape(-1, 2)
    v = np.c_[g, np.zeros(len(g))].astype(np.float64)
    i = (np.arange(nx - 1)[:, None] * ny + np.arange(ny - 1)[None]).ravel()
    return v, np.r_[np.c_[i, i + ny, i + 1], np.c_[i + 1, i + ny, i + ny + 1]]


def cubes(nx, ny, nz):
    """Unit cubes on an integer lattice (12 triangles each): geometry on split planes."""
    corners = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], float)
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    faces = np.array([f for a, b, c, d in quads for f in ((a, b, c), (a, c, d))])
    vs, fs = [], []
    for k, off in enumerate(np.array([[x, y, z] for x in range(nx) for y in range(ny)
                                      for z in range(nz)], float)):
        vs.append(corners + 2 * off)          # a gap of one unit between cubes
        fs.append(faces + 8 * k)
    return np.concatenate(vs), np.concatenate(fs)


load_real = real_mesh_arrays


def leaves(tree):
    """[(node index, leaf triangle array)] of every leaf."""
    out = []
    for i in np.flatnonzero(layout.is_leaf(tree.nodes)):
        start = int(layout.leaf_offset(tree.nodes[i:i + 1])[0])
        count = int(layout.n_prims(tree.nodes[i:i + 1])[0])
        out.append((i, tree.leaf_tris[start:start + count]))
    return out


def check_tree(tree, vertices, faces):
    """validate() plus the builder's own contract: kept triangles, ids, leaf order."""
    tree.validate()
    f = np.asarray(faces, dtype=np.int64)
    expected = (np.asarray(vertices, dtype=np.float64)[f[tree.tri_ids]] - tree.origin).astype(np.float32)
    np.testing.assert_array_equal(tree.triangles, expected)
    assert np.all(np.diff(tree.tri_ids.astype(np.int64)) > 0)          # input order kept
    assert tree.n_input_tris == len(f)
    np.testing.assert_array_equal(tree.bounds[0], tree.triangles.min(axis=(0, 1)))
    np.testing.assert_array_equal(tree.bounds[1], tree.triangles.max(axis=(0, 1)))
    leaf = layout.is_leaf(tree.nodes)
    starts = layout.leaf_offset(tree.nodes[leaf]).astype(np.int64)
    counts = layout.n_prims(tree.nodes[leaf]).astype(np.int64)
    assert np.array_equal(starts, np.r_[0, np.cumsum(counts)[:-1]])    # leaves in node order
    step = np.diff(tree.leaf_tris.astype(np.int64))
    first = np.zeros(len(tree.leaf_tris), dtype=bool)
    first[starts[counts > 0]] = True
    assert np.all(step[~first[1:]] > 0)                                 # increasing per leaf
    assert tree.stats()["refs_per_triangle"] <= MAX_REFS_PER_TRI


def rays(rng, tree, n):
    """World-space rays: most aimed at points inside the scene box, some axis-parallel."""
    lo, hi = tree.bounds.astype(np.float64) + tree.origin
    size = np.max(hi - lo)
    o = rng.uniform(lo - 0.3 * size, hi + 0.3 * size, (n, 3))
    d = rng.uniform(lo, hi, (n, 3)) - o
    d[: n // 10, :2] = 0.0                                               # along z
    d[n // 10: n // 5, 0] = 0.0                                          # in x planes
    return o, d


def assert_same_hits(tree, rng, n=1500, min_hits=50):
    """reference.traverse through the tree == brute force over the tree's triangles."""
    o, d = rays(rng, tree, n)
    a = reference.traverse(tree, o, d)
    b = reference.brute_force(tree.triangles.astype(np.float64), o - tree.origin, d)
    assert b.hit.sum() >= min_hits
    np.testing.assert_array_equal(a.hit, b.hit)
    np.testing.assert_array_equal(a.t, b.t)
    # Same arithmetic on the same triangles: ties at equal t resolve alike (lowest id).
    np.testing.assert_array_equal(a.prim, np.where(b.hit, tree.tri_ids.astype(np.int64)[np.maximum(b.prim, 0)], -1))


# -- valid trees ----------------------------------------------------------------------

@pytest.mark.parametrize("seed,n,size", [(0, 1, 0.1), (1, 2, 0.1), (2, 7, 0.2), (3, 97, 0.1),
                                         (4, 1013, 0.05), (5, 5003, 0.02), (6, 333, 0.5)])
def test_random_soups(seed, n, size):
    rng = np.random.default_rng(seed)
    v, f = soup(rng, n, size)
    tree = build(v, f)
    check_tree(tree, v, f)
    assert len(tree.triangles) == n
    if n >= 97:
        assert_same_hits(tree, rng, n=800)


@pytest.mark.parametrize("name", ["teapot.obj", "spot.obj", "fandisk.obj", "stanford-bunny.obj"])
def test_real_meshes(name):
    v, f = load_real(name)
    tree = build(v, f)
    check_tree(tree, v, f)
    s = tree.stats()
    # split into many leaves: with K_T / K_I = 20 (the default for small meshes) a
    # split pays when it saves about 20 tests a ray, so leaves hold tens of triangles
    assert s["leaves"] > len(tree.triangles) / 32
    assert 1.0 <= s["refs_per_triangle"] <= 8.0


@pytest.mark.parametrize("name", ["teapot.obj", "fandisk.obj"])
def test_real_meshes_hits_match_brute_force(name):
    v, f = load_real(name)
    tree = build(v, f)
    assert_same_hits(tree, np.random.default_rng(11), n=1000, min_hits=200)


def test_planar_mesh():
    v, f = grid(41, 23)
    v[:, :2] += 0.3 * np.random.default_rng(3).random((len(v), 2))   # irregular, still flat
    tree = build(v, f)
    check_tree(tree, v, f)
    assert tree.bounds[0, 2] == tree.bounds[1, 2] == 0.0
    assert len(tree.nodes) > 100
    assert np.all(layout.split_axis(tree.nodes) != 2)                # no split along z
    assert_same_hits(tree, np.random.default_rng(4), n=1000, min_hits=200)


def test_planar_overlapping_soup_stays_bounded():
    # Coplanar overlapping triangles: in a flat node P_L + P_R = 1, so SAH alone would
    # duplicate them down to max_depth; the reference budget bounds the tree.
    rng = np.random.default_rng(5)
    v, f = soup(rng, 1500, size=0.4, flat_axis=2)
    tree = build(v, f)
    check_tree(tree, v, f)
    assert tree.stats()["refs_per_triangle"] <= MAX_REFS_PER_TRI


def test_cubes_on_the_split_planes():
    v, f = cubes(5, 4, 3)
    tree = build(v, f)
    check_tree(tree, v, f)
    inner = ~layout.is_leaf(tree.nodes)
    splits = layout.split(tree.nodes[inner]).astype(np.float64) + tree.origin[layout.split_axis(tree.nodes[inner])]
    assert np.any(splits == np.round(splits))                      # planes through cube faces
    assert tree.stats()["refs_per_triangle"] == 1.0                # nothing straddles a face plane
    assert_same_hits(tree, np.random.default_rng(6), n=1500, min_hits=300)


def test_degenerate_triangles_are_left_out():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 2, 2], [3, 3, 3], [4, 4, 4],
                  [np.nan, 0, 0], [np.inf, 1, 1], [0, 0, 1], [1e-30, 0, 0], [0, 1e-30, 0]], float)
    f = np.array([
        [0, 1, 2],      # 0 good
        [0, 0, 1],      # 1 repeated vertex: zero area
        [3, 4, 5],      # 2 collinear
        [0, 1, 6],      # 3 NaN vertex
        [0, 2, 7],      # 4 infinite vertex
        [0, 1, 2],      # 5 duplicate of 0: kept
        [1, 2, 8],      # 6 good
        [0, 9, 10],     # 7 cross product underflows to zero in float32
        [2, 1, 0],      # 8 good (reversed)
    ])
    tree = build(v, f)
    np.testing.assert_array_equal(tree.tri_ids, [0, 5, 6, 8])
    check_tree(tree, v, f)
    listed = np.unique(tree.leaf_tris)
    assert set(listed.tolist()) == {0, 1, 2, 3}
    # the origin ignores non-finite vertices
    assert np.all(np.isfinite(tree.origin))


def test_origin_is_centre_of_the_used_vertices():
    rng = np.random.default_rng(9)
    v, f = soup(rng, 50)
    v = np.vstack([v, [[1e6, -1e6, 5e5]]])                            # unused far vertex
    v += [1e5, -2e3, 7.0]
    tree = build(v, f)
    used = v[:-1]
    np.testing.assert_array_equal(tree.origin, 0.5 * (used.min(0) + used.max(0)))
    check_tree(tree, v, f)


def test_an_origin_or_scale_that_puts_coordinates_beyond_2_28_is_refused():
    """build's origin and scale place the stored triangles; where they leave one
    beyond 2^28 in the tree's units the kernels' float32 products overflow (a triangle
    1e30 across at scale 1 was missed by a ray through it), so build refuses them."""
    rng = np.random.default_rng(2)
    v, f = soup(rng, 30)
    with pytest.raises(MeshError, match="at most 2.68e\\+08 \\(2\\^28\\)"):
        build(v * 1e30, f, scale=1.0)
    with pytest.raises(MeshError, match="1e\\+10 from the origin"):
        build(v, f, origin=np.array([0.0, 0.0, 1e10]))
    assert build(v * 1e30, f).scale == 2.0 ** 100
    build(v, f, origin=np.array([0.0, 0.0, 1e8]))       # within 2^28: kept


def test_a_vertex_float32_cannot_hold_leaves_out_its_triangles_only():
    """A vertex beyond float32's range (1e39) neither places nor sizes the tree: its
    triangles are left out, as a non-finite vertex's, and the others kept."""
    rng = np.random.default_rng(4)
    v, f = soup(rng, 40)
    far = np.vstack([v, [[1e39, 0.0, 0.0]]])
    f_far = np.vstack([f, [[0, 1, len(v)]]])
    tree, plain = build(far, f_far), build(v, f)
    assert len(tree.tri_ids) == len(plain.tri_ids) == len(f)
    np.testing.assert_array_equal(tree.origin, plain.origin)
    assert tree.scale == plain.scale
    check_tree(tree, far, f_far)


def test_a_vertex_float32_cannot_hold_is_left_out_at_any_scale():
    """At a scale other than 1 (a scene 1e30 across) a vertex beyond float32's range
    (1e39) is left out as at scale 1, though it divided by the scale would fit."""
    v = np.array([[0, 0, 0], [1e30, 0, 0], [0, 1e30, 0], [1e39, 1e29, 0]], float)
    tree = build(v, np.array([[0, 1, 2], [1, 2, 3]]))
    assert tree.scale != 1.0 and tree.tri_ids.tolist() == [0]
    assert np.abs(tree.world_box()).max() <= 1.0000001e30


def test_build_arguments_keep_their_types():
    """keep_double is a bool, not anything truthy; a scale that is not a power of two
    or an origin that is not 3 finite numbers is a ParameterError (a parameter, as the
    SAH's), float face indices beyond int64 the builder's MeshError, with no numpy
    warning."""
    v, f = np.eye(3), np.array([[0, 1, 2]])
    with pytest.raises(ParameterError, match="keep_double must be True or False"):
        build(v, f, keep_double="no")
    assert build(v, f, keep_double=np.bool_(True)).triangles64 is not None
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for scale in (2 ** 1025, 3.0, "1", -2.0):
            with pytest.raises(ParameterError, match="scale must be a power of two"):
                build(v, f, scale=scale)
        for origin in ((1, 2), (np.nan, 0, 0), "abc"):
            with pytest.raises(ParameterError, match="origin must be 3 finite numbers"):
                build(v, f, origin=origin)
        with pytest.raises(MeshError, match="vertex index out of range"):
            build(v, np.array([[0, 1, 1e20]]))


def numpy_prepare(v, f, origin):
    """The builder's triangles in numpy (the oracle for prepare's numba pass):
    (triangles (k, 3, 3) float32, tri_ids (k,) uint32, bounds (2, 3) float32)."""
    with np.errstate(over="ignore", invalid="ignore"):
        tri = (v[f] - origin).astype(np.float32)
        cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    keep = np.isfinite(tri).all(axis=(1, 2)) & (cross != 0).any(axis=1)
    tri = tri[keep]
    return tri, np.flatnonzero(keep).astype(np.uint32), np.stack([tri.min((0, 1)), tri.max((0, 1))])


@pytest.mark.parametrize("seed, threads", [(0, 1), (1, 1), (2, 2), (3, 3)])
def test_prepare_matches_numpy(seed, threads, monkeypatch):
    # Degenerate, non-finite, float32-overflowing and tiny triangles among ordinary ones;
    # on threads, in pieces (each leaves out its own) put back together.
    import concurrent.futures
    import kdray.builder.prepare as prepare_module
    monkeypatch.setattr(prepare_module, "PARALLEL_FACES", 0)
    pool = concurrent.futures.ThreadPoolExecutor(threads)

    def prepare(v, f, origin):
        return prepare_module.prepare(v, f, origin, pool=pool, threads=threads)
    rng = np.random.default_rng(seed)
    v, f = soup(rng, 3000, 0.02)
    v[:900, 2] = 0.5                        # triangles flat on z, and on x
    v[900:1200, 0] = -0.25
    v = np.vstack([v, [[np.nan, 0, 0], [np.inf, 1, 1], [1e39, 0, 0], [1e-30, 0, 0], [0, 1e-30, 0]]])
    n = len(v)
    f = np.vstack([f, rng.integers(0, n, size=(500, 3)), rng.integers(n - 5, n, size=(50, 3)),
                   np.repeat(rng.integers(0, n, size=(50, 1)), 3, axis=1)])
    f = f[rng.permutation(len(f))]
    for origin in (np.array([0.3, -7.0, 1e38]), None):
        # the default origin: the box of what float32 holds (not the 1e39 vertex's)
        pts = v[np.unique(f)]
        pts = pts[(np.abs(pts) <= np.finfo(np.float32).max).all(axis=1)]
        p = prepare(v, f, origin)
        o = 0.5 * (pts.min(0) + pts.max(0)) if origin is None else origin
        np.testing.assert_array_equal(p.origin, o)
        tri, ids, bounds = numpy_prepare(v, f, o)
        assert 0 < len(ids) < len(f)
        assert p.triangles.dtype == np.float32 and p.tri_ids.dtype == np.uint32
        assert p.triangles.tobytes() == tri.tobytes()
        assert p.tri_ids.tobytes() == ids.tobytes()
        assert p.bounds.dtype == np.float32 and p.bounds.tobytes() == bounds.tobytes()
        assert p.n_input_tris == len(f)
        flat = (tri.min(axis=1) == tri.max(axis=1)).sum(axis=0)
        assert flat.any()
        np.testing.assert_array_equal(p.flat, flat)


@pytest.mark.parametrize("v,f,match", [
    (np.zeros((3, 3)), np.array([[0, 1, 2]]), "no triangles left"),
    (np.array([[0, 0, 0], [1, 1, 1], [2, 2, 2.0]]), np.array([[0, 1, 2]]), "no triangles left"),
    (np.full((3, 3), np.nan), np.array([[0, 1, 2]]), "no triangles left"),
    (np.eye(3), np.zeros((0, 3), int), "has no triangles"),
    (np.eye(3), np.array([[0, 1, 3]]), "out of range"),
    (np.eye(3), np.array([[0, -1, 2]]), "out of range"),
    (np.eye(3)[:, :2], np.array([[0, 1, 2]]), "vertices must be"),
    (np.eye(3), np.array([[0, 1]]), "faces must be"),
    (np.eye(3), np.array([[0, 1, 2.5]]), "integers"),
])
def test_bad_meshes_raise(v, f, match):
    with pytest.raises(MeshError, match=match):
        build(v, f)


def test_dense_cluster_in_a_huge_scene():
    rng = np.random.default_rng(10)
    v1, f1 = soup(rng, 40, size=0.05)
    v1 = v1 * 1e4 - 5e3                                               # a few huge triangles
    v2, f2 = soup(rng, 2000, size=0.03)
    v2 = v2 * 0.1 + 1234.5                                            # a dense tiny cluster
    v = np.vstack([v1, v2])
    f = np.vstack([f1, f2 + len(v1)])
    tree = build(v, f)
    check_tree(tree, v, f)
    # rays at the cluster
    o = 1234.5 + rng.uniform(-1, 1, (800, 3))
    d = 1234.5 + 0.1 * rng.random((800, 3)) - o
    a = reference.traverse(tree, o, d)
    b = reference.brute_force(tree.triangles.astype(np.float64), o - tree.origin, d)
    assert b.hit.sum() > 100
    np.testing.assert_array_equal(a.prim, np.where(b.hit, tree.tri_ids.astype(np.int64)[np.maximum(b.prim, 0)], -1))


@pytest.mark.parametrize("flat", [False, True])
def test_long_thin_overlapping_slivers(flat):
    rng = np.random.default_rng(12)
    n = 3000
    x0 = 0.1 * rng.random(n)
    y = rng.random(n)
    z = 0.0 if flat else rng.random(n)
    a = np.stack([x0, y, np.broadcast_to(z, n)], 1)
    b = np.stack([x0 + 1 + rng.random(n), y + 1e-3, np.broadcast_to(z, n) + (0 if flat else 1e-3)], 1)
    c = np.stack([x0 + 0.5, y + 2e-3 * rng.random(n), np.broadcast_to(z, n)], 1)
    v = np.stack([a, b, c], 1).reshape(-1, 3)
    f = np.arange(3 * n).reshape(-1, 3)
    tree = build(v, f)
    check_tree(tree, v, f)
    assert tree.stats()["refs_per_triangle"] <= MAX_REFS_PER_TRI


# -- determinism and parameters ------------------------------------------------------

def test_deterministic():
    v, f = load_real("teapot.obj")
    a = build(v, f)
    b = build(v.copy(), f.copy())
    assert a == b
    assert a.to_bytes() == b.to_bytes()


def test_parameters_change_the_tree():
    rng = np.random.default_rng(13)
    v, f = soup(rng, 2000, 0.03)
    base = build(v, f)
    assert base.params.max_depth == round(8 + 1.3 * np.log2(2000))
    no_bonus = build(v, f, empty_bonus=1.0)
    assert no_bonus.params.empty_bonus == 1.0
    assert no_bonus != base
    assert no_bonus.stats()["empty_leaves"] < base.stats()["empty_leaves"]
    shallow = build(v, f, max_depth=3)
    check_tree(shallow, v, f)
    assert shallow.depth == 3 and shallow.params.max_depth == 3
    cheap_tests = build(v, f, K_I=1.0)                                # splitting rarely pays
    assert len(cheap_tests.nodes) < len(base.nodes)
    one_leaf = build(v, f, leaf_size=10 ** 6)
    assert len(one_leaf.nodes) == 1 and len(one_leaf.leaf_tris) == 2000
    big_leaves = build(v, f, leaf_size=128)
    check_tree(big_leaves, v, f)
    assert len(big_leaves.nodes) < len(base.nodes)
    assert base.params.K_T == 400.0 and build(v, f, K_T=320).params.K_T == 320.0
    assert build(v, f, K_T=320) == build(v, f, K_T=320) != base


def test_automatic_K_T_follows_the_triangle_count():
    from kdray.tree import AUTO_K_T_TRIS, K_T_LARGE, K_T_SMALL, BuildParams, auto_K_T
    lo, hi = AUTO_K_T_TRIS
    assert auto_K_T(0) == auto_K_T(1) == auto_K_T(lo) == K_T_SMALL
    assert auto_K_T(hi) == auto_K_T(10 ** 8) == K_T_LARGE
    middle = auto_K_T(int(np.sqrt(lo * hi)))
    assert middle == pytest.approx((K_T_SMALL + K_T_LARGE) / 2)
    steps = [auto_K_T(n) for n in range(lo, hi + 1, 4096)]
    assert np.all(np.diff(steps) > 0)
    assert BuildParams().resolved(hi).K_T == K_T_LARGE
    assert BuildParams(K_T=15.0).resolved(hi).K_T == 15.0          # given: kept


@pytest.mark.parametrize("task_depth, stages", [(1, (1,)), (3, (1,)), (6, (1, 2)), (4, ()),
                                               (None, None)])
def test_threads_give_the_same_tree(monkeypatch, task_depth, stages):
    # Subtrees built as tasks on threads and spliced in == the one-thread build.
    # (None: the defaults, which for this mesh of 12,946 triangles, under
    # SMALL_MESH_TRIS, hand tasks on one level higher than TASK_DEPTH.)
    import kdray.builder.subdivide as subdivide
    v, f = load_real("fandisk.obj")
    one = build(v, f, threads=1)
    monkeypatch.setattr(subdivide, "MIN_PARALLEL_TRIS", 0)
    if task_depth is not None:
        monkeypatch.setattr(subdivide, "SMALL_MESH_TRIS", 0)
        monkeypatch.setattr(subdivide, "TASK_DEPTH", task_depth)
        monkeypatch.setattr(subdivide, "STAGE_DEPTHS", stages)
    else:
        assert len(f) < subdivide.SMALL_MESH_TRIS
    many = build(v, f, threads=3)
    assert many.to_bytes() == one.to_bytes()
    assert many.depth == one.depth


@pytest.mark.parametrize("room_per_tri, room", [(0, 0), (0, 64), (6, 64), (12, 256)])
def test_event_room_does_not_change_the_tree(monkeypatch, room_per_tri, room):
    # However much room the root's events have (none: the two event buffers grow, and
    # the root's children are copied out; a little: they do not fit in halves), the
    # nodes are those of the one-thread build with the default room.
    from kdray.builder.prepare import prepare
    import kdray.builder.subdivide as subdivide
    v, f = load_real("fandisk.obj")
    mesh = prepare(v, f)
    m = len(mesh.triangles)
    params = (140.0, 20.0, 0.8, 24, 1)
    box = mesh.bounds.astype(np.float64)
    want = subdivide.build_nodes(mesh.triangles, *sorted_root_events(mesh.triangles, room=12 * m),
                                 box, *params, threads=1)
    monkeypatch.setattr(subdivide, "MIN_PARALLEL_TRIS", 0)
    keys, counts = sorted_root_events(mesh.triangles, room=room_per_tri * m + room)
    got = subdivide.build_nodes(mesh.triangles, keys, counts, box, *params, threads=2)
    for a, b in zip(got, want):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("kw", [dict(K_T=-1), dict(K_I=-1), dict(empty_bonus=0), dict(empty_bonus=1.5),
                                dict(max_depth=-1), dict(leaf_size=-1), dict(K_T=float("nan")),
                                dict(threads=0)])
def test_bad_parameters_raise(kw):
    with pytest.raises(ValueError):
        build(np.eye(3), np.array([[0, 1, 2]]), **kw)


# -- the sweep -----------------------------------------------------------------------

def test_two_separated_triangles_are_split_apart():
    # A spans x in [0, 1], B x in [3, 4]; both span [0, 1] in y and z. Candidates
    # strictly inside the root box [0, 4] x [0, 1]^2: x = 1 and x = 3, each with one
    # triangle per side: C = 15 + 20 (P_L + P_R) = 15 + 20 (6/18 + 14/18) < 40 = 20 * 2.
    v = np.array([[0, 0, 0], [1, 1, 0], [0, 1, 1], [3, 0, 0], [4, 1, 0], [3, 1, 1]], float)
    f = np.array([[0, 1, 2], [3, 4, 5]])
    tree = build(v, f, K_T=15.0, K_I=20.0)                # W&H's costs (the default K_T is larger)
    tree.validate()
    assert len(tree.nodes) == 3
    assert layout.split_axis(tree.nodes)[0] == 0
    split = layout.split(tree.nodes[:1])[0] + tree.origin[0]
    assert split == 1.0                                   # tie with x = 3: lower plane first
    assert [t.tolist() for _, t in leaves(tree)] == [[0], [1]]
    keys, counts = sorted_root_events(tree.triangles)
    cost, axis, pos, side, n_l, n_r = best_split(keys, 0, counts, 2, tree.bounds.astype(np.float64),
                                                 15.0, 20.0, 0.8)
    assert (axis, n_l, n_r) == (0, 1, 1)
    assert cost == pytest.approx(15 + 20 * (6 + 14) / 18)


def brute_force_sah(boxes, box, K_T, K_I, lam):
    """Min SAH cost over every candidate plane, straight from the definition."""
    ext = box[1] - box[0]
    area = 2 * (ext[0] * ext[1] + ext[1] * ext[2] + ext[2] * ext[0])
    best = np.inf
    for k in range(3):
        lo, hi = boxes[:, 0, k], boxes[:, 1, k]
        for p in np.unique(np.r_[lo, hi]):
            if not box[0, k] < p < box[1, k]:
                continue
            e = ext.copy()
            e[k] = p - box[0, k]
            p_l = 2 * (e[0] * e[1] + e[1] * e[2] + e[2] * e[0]) / area
            e[k] = box[1, k] - p
            p_r = 2 * (e[0] * e[1] + e[1] * e[2] + e[2] * e[0]) / area
            planar = (lo == p) & (hi == p)
            n_l = np.sum(lo < p)
            n_r = np.sum(hi > p)
            for nl, nr in ((n_l + planar.sum(), n_r), (n_l, n_r + planar.sum())):
                c = K_T + K_I * (p_l * nl + p_r * nr)
                best = min(best, c * (lam if nl == 0 or nr == 0 else 1.0))
    return best


@pytest.mark.parametrize("dtype", [np.uint64, np.uint32, np.int64])
def test_sorted_copy_equals_numpy(dtype):
    # Every length around the block size and its merges (1, 2 and 3 merge passes,
    # uneven last blocks), distinct keys (as the builder's are) far apart and next to
    # each other, at offsets in both arrays; nothing outside dst[at:at + n] written.
    from kdray.builder.events import RANK_SORT_MAX, sorted_copy
    rng = np.random.default_rng(5)
    b = RANK_SORT_MAX
    for n in [0, 1, 2, 3, 7, 31, 32, 33, b - 1, b, b + 1, 2 * b + 5, 4 * b, 5 * b + 3, 9 * b]:
        for spread in (2 ** 20, 1):
            keys = (rng.permutation(n) * spread + rng.integers(0, spread, size=n)).astype(dtype)
            start, at = int(rng.integers(0, 5)), int(rng.integers(0, 5))
            src = np.concatenate([np.full(start, 9, dtype), keys, np.full(3, 9, dtype)])
            dst = np.full(at + n + 3, 7, dtype=dtype)
            sorted_copy(src, start, start + n, dst, at)
            assert np.array_equal(dst[at:at + n], np.sort(keys)), (n, spread)
            assert (dst[:at] == 7).all() and (dst[at + n:] == 7).all()
            assert (src[:start] == 9).all() and (src[start + n:] == 9).all()


def test_part_axis_events_split_the_run_at_any_pivot():
    # Below the pivot forward, at or above it backward to the run's end, both in
    # triangle order: sorted, the two parts are the whole sorted run, whatever the
    # pivot (an event's position, -0.0 against 0.0 events, beyond every event).
    from kdray.builder.events import axis_events, part_axis_events, radix_sort_events
    rng = np.random.default_rng(5)
    n = 3000
    tri = (np.round(rng.normal(size=(n, 3, 3)) * 4) / 4).astype(np.float32)
    tri[:300, :, 2] = np.float32(-0.0)
    tri[300:600, :, 2] = np.float32(0.0)
    full = np.empty(2 * n, dtype=np.uint64)
    e = axis_events(tri, 2, full, 0)
    tmp = np.empty(2 * n, dtype=np.uint64)
    radix_sort_events(full, 0, e, tmp, 0)
    for pivot in (-0.0, 0.0, tri[7, 1, 2], -1e9, 1e9, 0.25):
        keys = np.full(e + 10, 7, dtype=np.uint64)
        end = part_axis_events(tri, 2, np.float32(pivot), True, keys, 0)
        first = part_axis_events(tri, 2, np.float32(pivot), False, keys, e)
        assert end == first and (keys[e:] == 7).all()
        radix_sort_events(keys, 0, end, tmp, 0)
        radix_sort_events(keys, first, e, tmp, 0)
        assert keys[:e].tobytes() == full[:e].tobytes(), pivot


@pytest.mark.parametrize("threads,room,given_flat", [
    (1, 0, False), (1, 100000, False), (2, 0, False), (3, 100000, False),
    (2, 100000, True), (1, 0, True)])
def test_root_events_are_sorted_keys(threads, room, given_flat):
    # The radix sort on position and type == numpy's sort of the whole keys, whatever
    # the threads and scratch: shared positions, planar triangles, +-0, negative values.
    # On two threads z is made and sorted in two parts about a pivot (n is above
    # events.SPLIT_TRIS); given the flat triangles' counts (prepare's), the function
    # does not count them.
    from kdray.builder.events import END, PLANAR, SPLIT_TRIS, START

    def key(x, kind, t):                     # the key layout of events.py, in numpy
        b = (x + np.float32(0.0)).view(np.uint32).astype(np.uint64)
        b = np.where(b >= 2 ** 31, np.uint64(2 ** 32 - 1) - b, b + np.uint64(2 ** 31))
        return (b << np.uint64(32)) | (np.uint64(kind) << np.uint64(30)) | t.astype(np.uint64)

    rng = np.random.default_rng(21)
    n = SPLIT_TRIS + 1
    tri = (np.round(rng.normal(size=(n, 3, 3)) * 50) / 8).astype(np.float32)
    tri[: n // 5, :, 1] = np.float32(-0.25)
    tri[n // 5: n // 4, :, 2] = np.float32(-0.0)
    tri[n // 4: n // 3, :, 0] = np.float32(0.0)
    tri[-100:] *= np.float32(1e30)
    flat = (tri.min(axis=1) == tri.max(axis=1)).sum(axis=0) if given_flat else None
    keys, counts = sorted_root_events(tri, room=room, threads=threads, flat=flat)
    assert len(keys) == counts.sum() + room
    start = 0
    t = np.arange(n)
    for k in range(3):
        lo, hi = tri[:, :, k].min(axis=1), tri[:, :, k].max(axis=1)
        flat = lo == hi
        expected = np.concatenate([key(lo[flat], PLANAR, t[flat]), key(lo[~flat], START, t[~flat]),
                                   key(hi[~flat], END, t[~flat])])
        assert counts[k] == len(expected)
        np.testing.assert_array_equal(keys[start:start + counts[k]], np.sort(expected))
        start += counts[k]


def plain_sweep(keys, counts, n, box, K_T, K_I, lam):
    """Every plane evaluated in turn, in Python floats (IEEE double, as numba's): the
    sweep without the block bounds. Returns best_split's tuple."""
    area = 2.0 * sum((box[1, k] - box[0, k]) * (box[1, (k + 1) % 3] - box[0, (k + 1) % 3])
                     for k in range(3))
    best = (np.inf, -1, np.float32(0.0), 0, 0, 0)
    start = 0
    for k in range(3):
        run = keys[start:start + counts[k]].astype(np.uint64)
        start += counts[k]
        pos = (run >> np.uint64(32)).astype(np.int64)
        kind = ((run >> np.uint64(30)) & np.uint64(3)).astype(np.int64)
        lo, hi = float(box[0, k]), float(box[1, k])
        e1 = box[1, (k + 1) % 3] - box[0, (k + 1) % 3]
        e2 = box[1, (k + 2) % 3] - box[0, (k + 2) % 3]
        cap = 2.0 * e1 * e2 * (1.0 / area)
        perim = 2.0 * (e1 + e2) * (1.0 / area)
        n_left, n_right = 0, n
        for p in np.unique(pos):
            at = kind[pos == p]
            p_end, p_planar, p_start = (at == 0).sum(), (at == 1).sum(), (at == 2).sum()
            n_right -= p_end + p_planar
            x = float(position_value(np.uint64(p)))
            if lo < x < hi:
                pl, pr = cap + (x - lo) * perim, cap + (hi - x) * perim
                for side, nl, nr in ((0, n_left + p_planar, n_right), (1, n_left, n_right + p_planar)):
                    if side == 1 and p_planar == 0:
                        continue
                    c = K_T + K_I * (pl * nl + pr * nr)
                    if nl == 0 or nr == 0:
                        c *= lam
                    if c < best[0]:
                        best = (c, k, np.float32(x), side, nl, nr)
            n_left += p_start + p_planar
    return best


@pytest.mark.parametrize("seed", range(24))
def test_sweep_equals_plain_sweep(seed):
    # The block bounds only skip planes that cannot win: the same choice, to the bit.
    rng = np.random.default_rng(100 + seed)
    n = int(rng.integers(2, 700))
    tri = rng.random((n, 3, 3)) * rng.random(3)
    tri = (np.round(tri * rng.choice([8, 64, 4096])) / 8).astype(np.float32)
    tri[: n // 5, :, int(rng.integers(3))] = tri[0, 0, 0]
    keys, counts = sorted_root_events(tri)
    box = np.stack([tri.min(axis=(0, 1)), tri.max(axis=(0, 1))]).astype(np.float64)
    K_T, K_I, lam = [(100.0, 20.0, 0.8), (15.0, 20.0, 1.0), (1.0, 80.0, 0.5)][seed % 3]
    got = best_split(keys, 0, counts, n, box, K_T, K_I, lam)
    want = plain_sweep(keys, counts, n, box, K_T, K_I, lam)
    assert got[0] == want[0] and tuple(got[1:]) == tuple(want[1:])
    if want[1] >= 0:
        # max_cost: a plane that costs exactly that is still found, none below it is
        capped = best_split(keys, 0, counts, n, box, K_T, K_I, lam, want[0])
        assert capped[0] == want[0] and tuple(capped[1:]) == tuple(want[1:])
        none = best_split(keys, 0, counts, n, box, K_T, K_I, lam, np.nextafter(want[0], 0))
        assert none[1] == -1 and none[0] == np.inf


@pytest.mark.parametrize("seed", range(8))
def test_small_runs_equal_plain_sweep(seed):
    # Runs of at most sah.SMALL_RUN events take a path of their own: many small nodes
    # (either side of the threshold) with shared positions, planar triangles and flat
    # boxes, at an offset in a buffer with other keys around, and max_cost.
    rng = np.random.default_rng(300 + seed)
    for trial in range(60):
        n = int(rng.integers(1, sah.SMALL_RUN // 2 + 8))      # runs either side of SMALL_RUN
        tri = rng.random((n, 3, 3))
        tri = (np.round(tri * rng.choice([2, 4, 16, 1024])) / 8).astype(np.float32)
        if trial % 3 == 0:
            tri[: int(rng.integers(0, n + 1)), :, int(rng.integers(3))] = tri[0, 0, 0]
        if trial % 7 == 0:
            tri[..., int(rng.integers(3))] = np.float32(0.25)      # a flat box
        keys, counts = sorted_root_events(tri)
        pad = int(rng.integers(0, 5))
        buf = np.concatenate([keys[::-1][:pad], keys, keys[:pad]])
        box = np.stack([tri.min(axis=(0, 1)), tri.max(axis=(0, 1))]).astype(np.float64)
        K_T, K_I, lam = [(100.0, 20.0, 0.8), (15.0, 20.0, 1.0), (1.0, 80.0, 0.5)][trial % 3]
        want = plain_sweep(keys, counts, n, box, K_T, K_I, lam)
        for max_cost in (np.inf, want[0], np.nextafter(want[0], 0), K_I * n):
            got = best_split(buf, pad, counts, n, box, K_T, K_I, lam, max_cost)
            if want[0] <= max_cost:
                assert got[0] == want[0] and tuple(got[1:]) == tuple(want[1:])
            else:
                assert got[1] == -1 and got[0] == np.inf


@pytest.mark.parametrize("n", [20, 400])
def test_sweep_ties_across_axes_go_to_the_lower_axis(n):
    # best_split sweeps the longest axis first; a plane on a lower axis swept later
    # that costs exactly as much must still win. Triangles with their x <-> z mirror
    # images in a box longest in y, each spanning all of y: x's and z's costs are
    # equal to the bit (the formula is symmetric), y is swept first and loses, then
    # z, then x, which must win.
    rng = np.random.default_rng(n)
    tri = (np.round(rng.random((n, 3, 3)) * [4, 8, 4]) / 8).astype(np.float32)
    tri[:, 0, 1], tri[:, 1, 1] = 0.0, 1.0
    tri = np.concatenate([tri, tri[:, :, ::-1]])
    keys, counts = sorted_root_events(tri)
    box = np.stack([tri.min(axis=(0, 1)), tri.max(axis=(0, 1))]).astype(np.float64)
    assert box[1, 1] - box[0, 1] > box[1, 0] - box[0, 0] == box[1, 2] - box[0, 2]
    for K_T, K_I, lam in [(100.0, 20.0, 0.8), (15.0, 20.0, 1.0), (1.0, 80.0, 0.5)]:
        want = plain_sweep(keys, counts, len(tri), box, K_T, K_I, lam)
        got = best_split(keys, 0, counts, len(tri), box, K_T, K_I, lam)
        assert want[1] == 0 and got[0] == want[0] and tuple(got[1:]) == tuple(want[1:])


def snapped_soup(rng, n, scales, flat_share):
    """(n, 3, 3) float32 random triangles on a grid of 1/8 steps (a scale from
    `scales`), so that positions repeat; up to 1/flat_share of them flat on one axis
    at one value (planar events)."""
    tri = (np.round(rng.random((n, 3, 3)) * rng.choice(scales)) / 8).astype(np.float32)
    tri[: int(rng.integers(0, n + 1)) // flat_share, :, int(rng.integers(3))] = tri[0, 0, 0]
    return tri


@pytest.mark.parametrize("seed", range(6))
def test_classify_follows_the_event_rules(seed):
    # Each triangle's side from its own extent on the split axis (errata 4): the end
    # at or before the plane -> left, the start at or after it -> right, flat at the
    # plane -> the chosen side, else both; straddlers listed in the run's order.
    # Planes at event positions, between them and outside, runs at an offset.
    rng = np.random.default_rng(500 + seed)
    for trial in range(40):
        n = int(rng.integers(1, 300))
        tri = snapped_soup(rng, n, [4, 16, 1024], flat_share=3)
        keys, counts = sorted_root_events(tri)
        axis = int(rng.integers(3))
        start = int(counts[:axis].sum())
        lo = tri[:, :, axis].min(axis=1)
        hi = tri[:, :, axis].max(axis=1)
        plane = np.float32(rng.choice([rng.choice(lo), rng.choice(hi), rng.random() * 1.2 - 0.1]))
        planar_left = bool(rng.integers(2))
        side = np.zeros(n + 5, dtype=np.int8)
        strad = np.full(n + 1, -1, dtype=np.int64)
        pad = int(rng.integers(0, 4))
        buf = np.concatenate([keys[::-1][:pad], keys])
        n_strad = classify(buf, pad + start, int(counts[axis]), position_bits(plane),
                           planar_left, side, strad)
        want = np.where(hi <= plane, ON_LEFT, np.where(lo >= plane, ON_RIGHT, ON_BOTH))
        flat_at = (lo == plane) & (hi == plane)
        want[flat_at] = ON_LEFT if planar_left else ON_RIGHT
        np.testing.assert_array_equal(side[:n], want)
        order = np.argsort(lo, kind="stable")           # START keys: position, then index
        np.testing.assert_array_equal(strad[:n_strad], order[want[order] == ON_BOTH])


@pytest.mark.parametrize("seed", range(6))
def test_split_merge_gives_each_child_its_sorted_events(seed):
    # Each child's run on each axis: the one-sided triangles' events and the clipped
    # straddlers' new ones, sorted; the counts of triangles per side; nothing written
    # outside the two children's ranges but the one slot past each.
    rng = np.random.default_rng(700 + seed)
    for trial in range(30):
        n = int(rng.integers(2, 400))
        tri = snapped_soup(rng, n, [4, 64, 4096], flat_share=4)
        keys, counts = sorted_root_events(tri)
        box = np.stack([tri.min(axis=(0, 1)), tri.max(axis=(0, 1))]).astype(np.float64)
        axis = int(np.argmax(box[1] - box[0]))
        pos = np.float32(box[0, axis] + (box[1, axis] - box[0, axis]) * rng.uniform(0.2, 0.8))
        side = np.zeros(n, dtype=np.int8)
        strad = np.zeros(n, dtype=np.int64)
        start = int(counts[:axis].sum())
        n_strad = classify(keys, start, int(counts[axis]), position_bits(pos), True, side, strad)
        boxes = [np.zeros((n_strad + 1, 2, 3), np.float32) for _ in range(2)]
        ok = [np.zeros(n_strad + 1, bool) for _ in range(2)]
        clip_straddlers(tri, strad, n_strad, box, axis, pos, polygon_scratch(),
                        boxes[0], boxes[1], ok[0], ok[1])
        new = [np.zeros(6 * n_strad + 1, np.uint64) for _ in range(2)]
        runs = [np.zeros((3, 2), np.int64) for _ in range(2)]
        for c in range(2):
            straddler_events(strad, n_strad, boxes[c], ok[c], new[c], runs[c],
                             np.zeros(2 * n_strad + 1, np.uint64))
        total = int(counts.sum())
        pad = int(rng.integers(0, 3))
        w_right = pad
        w_left = w_right + total + int(runs[1][2].sum()) + 1
        dst = np.full(w_left + total + int(runs[0][2].sum()) + 1 + pad, 7, dtype=np.uint64)
        right_counts, left_counts = np.zeros(3, np.int64), np.zeros(3, np.int64)
        n_left, n_right = split_merge(keys, 0, counts, side, new[0], runs[0], new[1], runs[1],
                                      dst, w_right, w_left, right_counts, left_counts)
        run_starts = np.r_[0, np.cumsum(counts)]
        for c, (w, got_counts, on) in enumerate([(w_left, left_counts, ON_LEFT),
                                                  (w_right, right_counts, ON_RIGHT)]):
            for k in range(3):
                run = keys[run_starts[k]:run_starts[k + 1]]
                mine = run[side[(run & np.uint64((1 << 30) - 1)).astype(np.intp)] == on]
                added = new[c][runs[c][k, 0]:runs[c][k].sum()]
                want = np.sort(np.concatenate([mine, added]))
                got = dst[w:w + got_counts[k]]
                np.testing.assert_array_equal(got, want)
                w += got_counts[k]
            x_run = dst[w - got_counts.sum():w - got_counts[1:].sum()]
            assert (n_left, n_right)[c] == np.count_nonzero((x_run >> np.uint64(30)) & np.uint64(3))
        assert (dst[:pad] == 7).all() and (dst[len(dst) - pad:] == 7).all()


@pytest.mark.parametrize("seed", range(6))
def test_sweep_finds_the_cheapest_plane(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(2, 60))
    tri = rng.random((n, 3, 3))
    tri = (np.round(tri * 6) / 6).astype(np.float32)    # shared positions, planar triangles
    tri[: n // 4, :, int(rng.integers(3))] = np.float32(0.5)
    boxes = np.stack([tri.min(axis=1), tri.max(axis=1)], axis=1).astype(np.float64)
    box = np.stack([boxes[:, 0].min(0), boxes[:, 1].max(0)])
    keys, counts = sorted_root_events(tri)
    lam = [0.8, 1.0, 0.5][seed % 3]
    cost, axis, pos, side, _, _ = best_split(keys, 0, counts, n, box, 15.0, 20.0, lam)
    expected = brute_force_sah(boxes, box, 15.0, 20.0, lam)
    if np.isinf(expected):
        assert axis == -1
    else:
        assert cost == pytest.approx(expected, rel=1e-12)
        assert box[0, axis] < pos < box[1, axis]


# -- events and clipping ---------------------------------------------------------------

def test_event_positions_keep_float_order():
    rng = np.random.default_rng(14)
    x = np.r_[rng.normal(size=200) * 10.0 ** rng.integers(-30, 30, 200), 0.0, -0.0,
              np.finfo(np.float32).max, -np.finfo(np.float32).max, 1e-45, -1e-45].astype(np.float32)
    bits = np.array([position_bits(v) for v in x], dtype=np.uint64)
    order = np.argsort(bits, kind="stable")
    assert np.all(np.diff(x[order].astype(np.float64)) >= 0)
    assert position_bits(np.float32(0.0)) == position_bits(np.float32(-0.0))
    back = np.array([position_value(b) for b in bits], dtype=np.float32)
    np.testing.assert_array_equal(back, x)


def test_clipped_boxes_are_conservative():
    rng = np.random.default_rng(15)
    poly = polygon_scratch()
    w = rng.random((300, 3)) ** 2
    w /= w.sum(1, keepdims=True)
    out_l = np.empty((2, 3), np.float32)
    out_r = np.empty((2, 3), np.float32)
    seen_empty = 0
    for trial in range(300):
        tri = rng.normal(size=(1, 3, 3)).astype(np.float32)
        box = np.sort(rng.normal(size=(2, 3)), axis=0).astype(np.float32).astype(np.float64)
        axis = int(rng.integers(3))
        pos = np.float32(rng.uniform(box[0, axis], box[1, axis]))
        ok_l, ok_r = clip_split(tri, 0, box, axis, pos, poly, out_l, out_r)
        pts = w @ tri[0].astype(np.float64)
        for ok, out, lo_k, hi_k in ((ok_l, out_l, box[0, axis], pos), (ok_r, out_r, pos, box[1, axis])):
            child = box.copy()
            child[0, axis], child[1, axis] = lo_k, hi_k
            inside = np.all((pts >= child[0]) & (pts <= child[1]), axis=1)
            if not ok:
                seen_empty += 1
                assert not inside.any()
                continue
            assert np.all(out[0] <= out[1])
            assert np.all(out[0] >= child[0]) and np.all(out[1] <= child[1])
            assert np.all(pts[inside] >= out[0]) and np.all(pts[inside] <= out[1])
    assert seen_empty > 0


def test_kept_scratch_never_changes_a_tree(monkeypatch):
    # The events' array kept between builds (builder.scratch) holds whatever the last
    # build left: poisoned with every byte set, or left by a larger or smaller mesh, the
    # trees are those of builds on fresh arrays; two builds on two threads at once
    # take it one at a time.
    import concurrent.futures
    from kdray.builder import scratch
    rng = np.random.default_rng(31)
    meshes = [soup(rng, n, 0.05) for n in (300, 6000, 9000)]
    scratch.release()
    fresh = []
    for v, f in meshes:
        fresh.append(build(v, f))
        scratch.release()
    for v, f in meshes[::-1] + meshes:
        kept = scratch._kept
        if kept is not None:
            kept[:] = np.uint64(2 ** 64 - 1)
        assert build(v, f) == fresh[[m[1] is f for m in meshes].index(True)]
    assert scratch._kept is not None
    with concurrent.futures.ThreadPoolExecutor(2) as pool:
        trees = list(pool.map(lambda vf: build(*vf), meshes * 2))
    assert trees == fresh * 2
    monkeypatch.setattr(scratch, "KEEP_BYTES", 0)        # nothing kept: fresh arrays
    scratch.release()
    assert build(*meshes[1]) == fresh[1] and scratch._kept is None


def test_scratch_keeps_one_array_up_to_its_limit(monkeypatch):
    from kdray.builder import scratch
    scratch.release()
    a = scratch.take(100)
    assert a.dtype == np.uint64 and a.shape == (100,)
    scratch.give(a)
    b = scratch.take(50)                                  # the kept array, a view of it
    assert np.shares_memory(a, b) and len(b) == 50
    assert not np.shares_memory(a, scratch.take(10))      # taken: a new one
    scratch.give(b)                                       # the whole array comes back
    assert scratch._kept is a
    assert not np.shares_memory(a, scratch.take(101))     # too short: a new one
    scratch.give(np.empty(10, np.uint64))                 # shorter than the kept one
    assert scratch._kept is a
    monkeypatch.setattr(scratch, "KEEP_BYTES", 1000)
    scratch.give(np.empty(126, np.uint64))                # 1008 bytes: not kept
    assert scratch._kept is a
    scratch.release()
    assert scratch._kept is None


def test_builds_keep_one_pool_of_bound_threads(monkeypatch):
    # Builds on threads reuse one executor; its threads are bound one to a CPU in turn
    # (Linux), or left unbound with KDRAY_BIND_THREADS=0; the trees are the same.
    from kdray.builder import threads as bthreads
    monkeypatch.delenv("KDRAY_BIND_THREADS", raising=False)
    monkeypatch.setattr(bthreads, "_POOLS", {})
    v, f = soup(np.random.default_rng(41), 6000, 0.05)
    one = build(v, f, threads=1)
    assert build(v, f, threads=2) == one
    pool = bthreads.kept_pool(2)
    assert bthreads.kept_pool(2) is pool and bthreads.kept_pool(1) is None
    assert build(v, f, threads=2) == one and bthreads.kept_pool(2) is pool
    workers = [t for t in threading.enumerate() if t.name.startswith("kdray-build")]
    assert workers
    if hasattr(os, "sched_setaffinity"):
        cpus = sorted(os.sched_getaffinity(0))
        bound = [os.sched_getaffinity(t.native_id) for t in workers]
        assert all(len(b) == 1 and b <= set(cpus) for b in bound), bound
        assert bthreads.bound_cpus({}) == cpus
    assert bthreads.bound_cpus({"KDRAY_BIND_THREADS": "0"}) is None
    monkeypatch.setenv("KDRAY_BIND_THREADS", "0")
    monkeypatch.setattr(bthreads, "_POOLS", {})
    assert build(v, f, threads=3) == one
    if hasattr(os, "sched_setaffinity"):
        unbound = [t for t in threading.enumerate() if t.name.startswith("kdray-build")
                   and t not in workers]
        assert unbound and all(os.sched_getaffinity(t.native_id) == os.sched_getaffinity(0)
                               for t in unbound)


def test_a_failed_build_cancels_its_tasks_and_the_pool_lives_on(monkeypatch):
    # A task that raises fails the build; its pending tasks are cancelled, and so are
    # the tasks that running ones hand on afterwards; the next build uses the same pool.
    from kdray.builder import subdivide as bsub
    from kdray.builder import threads as bthreads
    v, f = soup(np.random.default_rng(43), 6000, 0.05)
    good = build(v, f, threads=2)
    real, calls = bsub.subdivide, []

    def failing(*args):
        calls.append(args[6])                   # depth0: 0 at the root
        if len(calls) == 3:
            raise MemoryError("planted")
        return real(*args)
    monkeypatch.setattr(bsub, "subdivide", failing)
    with pytest.raises(MemoryError, match="planted"):
        build(v, f, threads=2)
    monkeypatch.setattr(bsub, "subdivide", real)
    assert build(v, f, threads=2) == good

    tasks, ran = bthreads.LargestFirst(bthreads.kept_pool(2)), []
    gate = threading.Event()
    first = tasks.submit(1, gate.wait)
    second = tasks.submit(2, gate.wait)            # both threads blocked on the gate
    while not (first.running() and second.running()):
        time.sleep(0.001)
    later = [tasks.submit(n, ran.append, n) for n in (3, 4)]
    tasks.cancel()
    gate.set()
    assert first.result(timeout=10) and second.result(timeout=10)
    assert all(f.cancelled() for f in later) and ran == []
    assert tasks.submit(5, ran.append, 5).cancelled() and ran == []


@pytest.mark.skipif(not hasattr(os, "fork"), reason="no fork")
def test_a_forked_child_builds_on_threads():
    # The parent's kept pool has no threads in a forked child: the child makes its own.
    import multiprocessing
    v, f = soup(np.random.default_rng(47), 6000, 0.05)
    want = build(v, f, threads=2)
    with multiprocessing.get_context("fork").Pool(1) as child:
        got = child.apply_async(build, (v, f), {"threads": 2}).get(timeout=120)
    assert got == want


def test_a_tree_larger_than_its_format_holds_is_refused(monkeypatch):
    """The builder stores child indices in 30 bits and leaf offsets in 32: a build that
    makes more nodes or leaf references (K_T=15 on about 2*10^8 triangles) is refused
    with a ParameterError, not returned with indices that wrapped. Shown with the
    bounds made small."""
    import kdray.builder
    from helpers import icosphere
    v, f = icosphere(3)
    tree = kdray.builder.build(v, f)
    n_nodes, n_refs = len(tree.nodes), len(tree.leaf_tris)
    monkeypatch.setattr(kdray.builder, "MAX_NODES", n_nodes)
    with pytest.raises(ParameterError, match="more than the tree format holds"):
        kdray.builder.build(v, f)
    monkeypatch.setattr(kdray.builder, "MAX_NODES", n_nodes + 1)
    assert len(kdray.builder.build(v, f).nodes) == n_nodes
    monkeypatch.setattr(kdray.builder, "MAX_LEAF_REFS", n_refs)
    with pytest.raises(ParameterError, match="2\\^32 references"):
        kdray.builder.build(v, f)
