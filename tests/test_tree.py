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
