"""The float64 oracles against each other and against hand-computed hits."""
import numpy as np
import pytest

from kdray import reference as ref
from small_trees import single_leaf_tree, two_leaf_tree


def test_hand_computed_hit():
    tri = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]]], dtype=float)
    h = ref.brute_force(tri, [[0.25, 0.5, 2.0]], [[0, 0, -4.0]])
    assert h.prim[0] == 0 and h.t[0] == pytest.approx(0.5)
    assert (h.u[0], h.v[0]) == pytest.approx((0.25, 0.5))     # P = (1-u-v) v0 + u v1 + v v2


def test_t_strictly_positive_and_edge_on():
    tri = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]]], dtype=float)
    on_surface = ref.brute_force(tri, [[0.2, 0.2, 0.0]], [[0, 0, -1.0]])
    assert not on_surface.hit[0]                                # t = 0 is not a hit
    edge_on = ref.brute_force(tri, [[-1, 0.2, 0.0]], [[1, 0, 0.0]])
    assert not edge_on.hit[0]                                   # ray in the triangle's plane
    behind = ref.brute_force(tri, [[0.2, 0.2, 1.0]], [[0, 0, 1.0]])
    assert not behind.hit[0]


def test_watertight_shared_edge_and_vertex():
    # a square of two triangles; rays exactly through the diagonal and the shared vertices
    tri = np.array([[[0, 0, 0], [1, 0, 0], [1, 1, 0]], [[0, 0, 0], [1, 1, 0], [0, 1, 0]]], dtype=float)
    s = np.linspace(0, 1, 41)
    o = np.stack([s, s, np.full_like(s, 3.0)], axis=1)
    h = ref.brute_force(tri, o, np.tile([0, 0, -1.0], (len(s), 1)))
    assert h.hit.all()
    assert np.all(h.prim[h.hit] == 0)                           # ties: lowest index wins


def test_traverse_equals_brute_force_on_hand_trees():
    rng = np.random.default_rng(7)
    tree = two_leaf_tree()
    tri_world = tree.triangles.astype(np.float64) + tree.origin
    o = tree.origin + rng.uniform(-3, 3, (1001, 3))
    d = rng.normal(size=(1001, 3))
    aim = tree.origin + rng.uniform(tree.bounds[0], tree.bounds[1], (1001, 3))
    d[200:] = aim[200:] - o[200:]                               # most rays aimed into the box
    d[:100, :2] = 0.0                                           # axis-parallel rays
    d[100:200, 0] = -0.0
    a = ref.traverse(tree, o, d)
    b = ref.brute_force(tri_world, o, d)
    assert a.hit.sum() > 100
    assert np.array_equal(a.prim, np.where(b.hit, tree.tri_ids.astype(np.int64)[np.maximum(b.prim, 0)], -1))
    np.testing.assert_allclose(a.t[a.hit], b.t[b.hit], rtol=1e-9)


def test_traverse_single_leaf_far_from_origin():
    rng = np.random.default_rng(8)
    tris = rng.random((200, 3, 3)) + 1e5
    tree = single_leaf_tree(tris, origin=(1e5 + .5,) * 3)
    o = 1e5 + rng.uniform(-1, 2, (513, 3))
    d = 1e5 + rng.random((513, 3)) - o                          # aimed into the cluster
    a = ref.traverse(tree, o, d)
    b = ref.brute_force(tree.triangles.astype(np.float64), o - tree.origin, d)
    assert a.hit.sum() > 200
    assert np.array_equal(a.prim, b.prim)


def test_empty_inputs():
    tri = np.zeros((1, 3, 3))
    assert len(ref.brute_force(tri, np.zeros((0, 3)), np.zeros((0, 3))).t) == 0


def test_traverse_rays_that_all_miss_the_box():
    """A chunk of rays none of which meets the tree's box: all misses, and hits in
    the next chunk still found."""
    tree = two_leaf_tree()
    far = tree.origin + 10.0 * (tree.bounds[1] - tree.bounds[0])
    o = np.tile(far, (5, 1))
    d = np.tile(far - tree.origin, (5, 1))                     # pointing away
    a = ref.traverse(tree, o, d)
    assert not a.hit.any() and np.all(a.prim == -1) and np.all(np.isinf(a.t))
    aim = tree.origin + tree.triangles[0].astype(np.float64).mean(axis=0)   # a triangle's centroid
    o2 = np.concatenate([o, [far]])
    d2 = np.concatenate([d, [aim - far]])
    b = ref.traverse(tree, o2, d2, chunk=5)
    c = ref.brute_force(tree.triangles.astype(np.float64) + tree.origin, o2, d2)
    assert not b.hit[:5].any() and b.hit[5] and c.hit[5]
    assert b.prim[5] == tree.tri_ids[c.prim[5]] and b.t[5] == pytest.approx(c.t[5])


def test_closest_points_tie_on_a_shared_edge_goes_to_the_lower_id():
    """Two triangles share an edge, listed a-b in one and b-a in the other, and a point
    lies beyond it: both are exactly as near (exact rational arithmetic says so), and
    the oracle, like the kernels, gives the lower id. Its segment distance was taken
    from each triangle's own end of the edge, so the two rounded apart and the higher
    id won in 385 of 3000 such random cases."""
    from fractions import Fraction
    p, q = [-0.02281679847634721, 0.8660369607481395, -0.9608350501344631], \
        [0.9302816221731605, -0.663237591721139, 0.6790455967856273]
    tris = np.array([[p, q, [0.5079230475850469, 1.2396465412423725, -0.11559842886110896]],
                     [q, p, [0.00986401597901096, 0.9084506220013231, 0.05196316532962289]]])
    point = np.array([0.70918416684448, -0.6192726539779826, -0.09980618118602552])

    def exact(a, b):                     # squared distance to segment a-b, exactly
        pe, ae, be = ([Fraction(float(x)) for x in v] for v in (point, a, b))
        ab = [be[k] - ae[k] for k in range(3)]
        s = min(max(sum((pe[k] - ae[k]) * ab[k] for k in range(3))
                    / sum(x * x for x in ab), Fraction(0)), Fraction(1))
        return sum((pe[k] - ae[k] - s * ab[k]) ** 2 for k in range(3))

    assert exact(p, q) == exact(q, p)
    d2 = ref.point_triangle_d2(point[None], tris)[0]
    assert d2[0] == d2[1]
    _, prim = ref.closest_points(tris, point[None])
    assert prim.tolist() == [0]
    rng = np.random.default_rng(5)
    for _ in range(200):                 # random shared edges, points beyond them
        a, b, c, e = rng.normal(size=(4, 3))
        pair = np.array([[a, b, c], [b, a, e]])
        x = (a + b) / 2 - 0.5 * (np.cross(b - a, c - a) + np.cross(a - b, e - b))
        d2 = ref.point_triangle_d2(x[None], pair)[0]
        if abs(d2[0] - d2[1]) <= 1e-12 * d2.max():
            assert d2[0] == d2[1]
