"""KdTree.validate() catches broken trees; stats() reports what a tree is."""
import dataclasses
import warnings

import numpy as np
import pytest

from kdray import layout
from kdray.errors import TreeError
from small_trees import single_leaf_tree, two_leaf_tree


def test_valid_trees_pass():
    two_leaf_tree().validate()
    rng = np.random.default_rng(3)
    single_leaf_tree(rng.random((37, 3, 3))).validate()


def broken(**changes):
    return dataclasses.replace(two_leaf_tree(), **changes)


@pytest.mark.parametrize("name, tree", [
    ("leaf lists wrong triangle", broken(leaf_tris=np.array([1, 0], dtype=np.uint32))),
    ("leaf index out of range", broken(leaf_tris=np.array([0, 2], dtype=np.uint32))),
    ("tri id out of range", broken(tri_ids=np.array([0, 3], dtype=np.uint32))),
    ("depth mismatch", broken(depth=2)),
    ("deeper than max_depth", broken(params=dataclasses.replace(two_leaf_tree().params, max_depth=0))),
    ("infinite K_T", broken(params=dataclasses.replace(two_leaf_tree().params, K_T=np.inf))),
    ("infinite K_I", broken(params=dataclasses.replace(two_leaf_tree().params, K_I=np.inf))),
    ("triangle outside bounds", broken(bounds=np.array([[-1, -1, 0], [2, 1, .5]], dtype=np.float32))),
    ("split outside the box", broken(nodes=np.concatenate([layout.make_interior([0], [9.0], [2]),
                                                            two_leaf_tree().nodes[1:]]))),
    ("not a tree", broken(nodes=np.concatenate([layout.make_interior([0], [0.0], [1]),
                                                 two_leaf_tree().nodes[1:]]))),
    ("nan triangle", broken(triangles=np.full((2, 3, 3), np.nan, dtype=np.float32))),
])
def test_broken_trees_are_caught(name, tree):
    with pytest.raises(TreeError):
        tree.validate()


@pytest.mark.parametrize("name, tree", [
    ("no triangle", broken(nodes=layout.make_leaf([0], [0]), leaf_tris=np.zeros(0, np.uint32),
                           triangles=np.zeros((0, 3, 3), np.float32),
                           tri_ids=np.zeros(0, np.uint32), depth=0)),
    ("a triangle in no leaf", broken(leaf_tris=np.array([0, 0], dtype=np.uint32))),
    ("leaves share a range", broken(nodes=np.concatenate([
        two_leaf_tree().nodes[:1], layout.make_leaf([2], [0]), layout.make_leaf([2], [0])]))),
    ("ranges out of node order", broken(nodes=np.concatenate([
        two_leaf_tree().nodes[:1], layout.make_leaf([1], [1]), layout.make_leaf([1], [0])]),
        leaf_tris=np.array([1, 0], dtype=np.uint32))),
    ("coordinates beyond 2^28", broken(
        triangles=two_leaf_tree().triangles * np.float32(1e9),
        bounds=two_leaf_tree().bounds * np.float32(1e9),
        nodes=two_leaf_tree().nodes)),
])
def test_broken_trees_are_caught_without_the_coverage_check(name, tree):
    """What a hostile tree file held that KdTree.load (validate without the coverage
    check) passed, and a Tracer then crashed on (no triangle listed: wide.py), or made
    gigabytes of device copies of (shared ranges), or traced wrong (coordinates whose
    products overflow float32)."""
    with pytest.raises(TreeError):
        tree.validate(coverage_samples=None)


def test_stats_of_a_known_tree():
    s = two_leaf_tree().stats()
    assert s["nodes"] == 3 and s["leaves"] == 2 and s["empty_leaves"] == 0
    assert s["max_leaf_depth"] == 1 and s["mean_leaf_depth"] == 1.0
    assert s["refs_per_triangle"] == 1.0
    assert s["bytes"] == 3 * 8 + 2 * 4 + 2 * 36 + 2 * 4
    # box 4 x 2 x 0.5 split in half at x = 0: each child has area 2(2*2 + 2*.5 + .5*2) = 12
    root = 2 * (4 * 2 + 2 * .5 + .5 * 4)
    assert s["sah_cost"] == pytest.approx((15 * root + 20 * 12 + 20 * 12) / root)
    # costs near float64's largest (a tree file may hold them): inf, and no warning
    huge = broken(params=dataclasses.replace(two_leaf_tree().params, K_T=1e308, K_I=1e308))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert huge.stats()["sah_cost"] == np.inf


def comb_tree(depth, m):
    """A complete tree of `depth` levels whose every split is x = 0, over m triangles
    lying in that plane, listed in its first and last leaves: a point on the plane
    lies in every leaf (2^depth of them)."""
    n = 2 ** (depth + 1) - 1
    nodes = np.zeros((n, 2), np.uint32)
    leaves = []

    def make(i, d):
        if d == depth:
            leaves.append(i)
            return i + 1
        above = make(i + 1, d + 1)
        nodes[i] = layout.make_interior([0], [0.0], [above])[0]
        return make(above, d + 1)
    make(0, 0)
    for leaf in leaves:
        count, first = (m, 0) if leaf == leaves[0] else (m, m) if leaf == leaves[-1] else (0, 0)
        nodes[leaf] = layout.make_leaf([count], [first])[0]
    tris = np.zeros((m, 3, 3), np.float32)
    tris[:, :, 1:] = np.random.default_rng(0).random((m, 3, 2))
    return dataclasses.replace(
        two_leaf_tree(), nodes=nodes, leaf_tris=np.tile(np.arange(m, dtype=np.uint32), 2),
        triangles=tris, tri_ids=np.arange(m, dtype=np.uint32), n_input_tris=m,
        bounds=np.array([[-1, 0, 0], [1, 1, 1]], np.float32), depth=depth,
        params=dataclasses.replace(two_leaf_tree().params, max_depth=64))


def test_coverage_of_splits_that_repeat_a_plane_is_bounded():
    """validate's coverage check walks its points to every leaf that holds them: a tree
    whose splits repeat one plane (which no build makes, and a small file can) sends a
    point on it to every leaf. Past COVERAGE_LEAVES a point on average it is refused,
    before its pairs take the memory (depth 17 over 5,000 triangles: 7e9 pairs)."""
    comb_tree(3, 20).validate()                     # 8 leaves a point: within the bound
    with pytest.raises(TreeError, match="splits repeat a plane"):
        comb_tree(12, 50).validate()


def test_wide_nodes_of_a_tree_that_lists_no_triangle_are_refused():
    """A hand-made tree whose leaves list no triangle (validate refuses it; the
    constructor does not check): its wide nodes are a KdrayError, not a crash (the
    BVH builder wrote past an empty queue)."""
    from kdray.errors import KdrayError
    from kdray.wide import wide_nodes
    tree = dataclasses.replace(two_leaf_tree(), nodes=layout.make_leaf([0], [0]),
                               leaf_tris=np.zeros(0, np.uint32), depth=0)
    with pytest.raises(KdrayError, match="lists no triangle"):
        wide_nodes(tree, 16, 0)
