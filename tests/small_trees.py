"""Hand-made trees, independent of the builder, for layout and oracle tests."""
import numpy as np

from kdray import layout
from kdray.tree import BuildParams, KdTree


def two_leaf_tree():
    """Two triangles split by the plane x = 0: node 0 splits, 1 and 2 are leaves.

    Triangle 0 lies at x < 0, triangle 1 at x > 0; input had 3 triangles, the middle
    one (id 1) was dropped, so tri_ids = [0, 2]."""
    tris = np.array([[[-2, -1, 0], [-1, -1, 0], [-1.5, 1, 0]],
                     [[1, -1, 0.5], [2, -1, 0.5], [1.5, 1, 0.5]]], dtype=np.float32)
    nodes = np.concatenate([layout.make_interior([0], [0.0], [2]),
                            layout.make_leaf([1], [0]),
                            layout.make_leaf([1], [1])])
    return KdTree(nodes=nodes, leaf_tris=np.array([0, 1], dtype=np.uint32), triangles=tris,
                  tri_ids=np.array([0, 2], dtype=np.uint32),
                  origin=np.array([1e6, -2.5, 0.125]),
                  bounds=np.array([[-2, -1, 0], [2, 1, 0.5]], dtype=np.float32),
                  n_input_tris=3, depth=1, params=BuildParams(K_T=15.0, max_depth=4))


def single_leaf_tree(triangles, origin=(0.0, 0.0, 0.0)):
    """Every triangle in one leaf. triangles : (m, 3, 3) float64 world coordinates."""
    origin = np.asarray(origin, dtype=np.float64)
    rel = (np.asarray(triangles, dtype=np.float64) - origin).astype(np.float32)
    m = len(rel)
    return KdTree(nodes=layout.make_leaf([m], [0]).reshape(1, 2),
                  leaf_tris=np.arange(m, dtype=np.uint32), triangles=rel,
                  tri_ids=np.arange(m, dtype=np.uint32), origin=origin,
                  bounds=np.stack([rel.reshape(-1, 3).min(0), rel.reshape(-1, 3).max(0)]),
                  n_input_tris=m, depth=0, params=BuildParams(max_depth=1).resolved(m))
