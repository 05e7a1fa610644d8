"""Trees built in plain numpy for the traversal tests, independent of kdray.builder.

    tree = leaf_tree(vertices, faces)                       # one leaf holds everything
    tree = split_tree(vertices, faces, max_depth=20)        # median splits
    tree = split_tree(vertices, faces, split="random", seed=3)   # odd shapes, empty leaves

Every triangle is listed in every child whose closed box its bounding box overlaps
(conservative, so any traversal that visits the right leaves finds every hit). The
tree's triangles are stored in a shuffled order (`seed`) so that `tri_ids` is not the
identity and a kernel that returns tree indices instead of input ids is caught.
Small meshes only: one Python call per node.
"""
import numpy as np

from kdray import layout
from kdray.tree import BuildParams, KdTree


def _prepare(vertices, faces, origin, seed):
    tri64 = np.asarray(vertices, dtype=np.float64)[np.asarray(faces, dtype=np.int64)]
    if origin is None:
        lo, hi = tri64.reshape(-1, 3).min(0), tri64.reshape(-1, 3).max(0)
        origin = 0.5 * (lo + hi)
    origin = np.asarray(origin, dtype=np.float64)
    order = np.random.default_rng(seed).permutation(len(tri64)) if seed is not None \
        else np.arange(len(tri64))
    rel = (tri64[order] - origin).astype(np.float32)
    bounds = np.stack([rel.reshape(-1, 3).min(0), rel.reshape(-1, 3).max(0)])
    return rel, order.astype(np.uint32), origin, bounds


def _kdtree(nodes, leaf_tris, rel, ids, origin, bounds, n_input, depth):
    return KdTree(nodes=np.asarray(nodes, dtype=np.uint32).reshape(-1, 2),
                  leaf_tris=np.asarray(leaf_tris, dtype=np.uint32), triangles=rel, tri_ids=ids,
                  origin=origin, bounds=bounds.astype(np.float32), n_input_tris=n_input,
                  depth=depth, params=BuildParams(max_depth=max(1, depth)).resolved(len(rel)))


def leaf_tree(vertices, faces, origin=None, seed=0):
    """A single leaf listing every triangle."""
    rel, ids, origin, bounds = _prepare(vertices, faces, origin, seed)
    m = len(rel)
    return _kdtree(layout.make_leaf([m], [0]), np.arange(m), rel, ids, origin, bounds, m, 0)


def split_tree(vertices, faces, max_depth=16, leaf_size=4, split="median", origin=None, seed=0):
    """A k-d tree split at the median triangle centroid of the node's longest axis
    (split="median") or at a random position on a random axis (split="random", which
    makes empty leaves, lopsided subtrees and splits through triangles)."""
    rel, ids, origin, bounds = _prepare(vertices, faces, origin, seed)
    lo_t, hi_t = rel.min(axis=1), rel.max(axis=1)
    centroid = rel.mean(axis=1)
    rng = np.random.default_rng(seed)
    nodes, leaf_tris = [], []
    depth_reached = 0

    def make_leaf(index, tris):
        nodes[index] = layout.make_leaf([len(tris)], [len(leaf_tris)])[0]
        leaf_tris.extend(tris.tolist())

    def build(tris, box_lo, box_hi, depth):
        nonlocal depth_reached
        index = len(nodes)
        nodes.append(None)
        depth_reached = max(depth_reached, depth)
        if depth >= max_depth or (len(tris) <= leaf_size and split == "median"):
            return make_leaf(index, tris)
        if split == "median":
            axis = int(np.argmax(box_hi - box_lo))
            pos = np.float32(np.median(centroid[tris, axis])) if len(tris) else np.float32(0)
        else:
            axis = int(rng.integers(3))
            pos = np.float32(box_lo[axis] + rng.random() * (box_hi[axis] - box_lo[axis]))
        if not (box_lo[axis] < pos < box_hi[axis]):
            return make_leaf(index, tris)
        below = tris[lo_t[tris, axis] <= pos]
        above = tris[hi_t[tris, axis] >= pos]
        if split == "median" and len(below) == len(tris) and len(above) == len(tris):
            return make_leaf(index, tris)
        b_hi = box_hi.copy()
        b_hi[axis] = pos
        build(below, box_lo, b_hi, depth + 1)
        a_lo = box_lo.copy()
        a_lo[axis] = pos
        above_index = len(nodes)
        build(above, a_lo, box_hi, depth + 1)
        nodes[index] = layout.make_interior([axis], [pos], [above_index])[0]

    build(np.arange(len(rel)), bounds[0].copy(), bounds[1].copy(), 0)
    return _kdtree(np.stack(nodes), leaf_tris, rel, ids, origin, bounds, len(rel), depth_reached)


def world_triangles(tree):
    """(n_input_tris, 3, 3) float64: the tree's triangles in world coordinates, in input
    order (rows of input ids the tree dropped are NaN): the geometry the tracer sees."""
    out = np.full((tree.n_input_tris, 3, 3), np.nan)
    out[tree.tri_ids] = tree.world(tree.triangles)
    return out
