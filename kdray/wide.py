"""Wide nodes: the k-d tree three levels at a time, for rays that share no path.

A ray on its own (random origins and directions: inside tests, occlusion, any user's
rays) spends most of its time in the k-d walk, one dependent load and decision a node
(BENCHMARKS.md, "Incoherent rays"). Here every interior k-d node whose depth is a
multiple of 3 (and the root) stands for a wide node: its children are the k-d nodes
three levels below it, or the leaves met on the way, empty leaves left out, at most
8. Each child carries the box of its triangles clipped to its cell, so one vector
step tests a ray against 8 boxes and skips the empty space around the triangles too
(kernels/wide.cl walks them).

The children's cells are disjoint k-d cells, so the order in which a ray meets them
depends only on the signs of its direction: each node stores, for each of the 8
octants, its slots in that order, and a ray pushes the children it hits with no
compare.

A record of WIDE_WORDS 32-bit words a node, wide node 0 the root (kernels/wide.cl
mirrors it):

    words  0..47  the children's boxes, 6 rows of 8 float32: min x, min y, min z,
                  max x, max y, max z (+inf and -inf in an empty slot)
    words 48..55  child: a wide node's index, or a leaf's first triangle as the
                  kernels read them (layout.device_triangles)
    words 56..63  kind: 0 (a wide node), LEAF | n_prims (a leaf) or EMPTY
    words 64..71  per octant o (bit a set: the direction's axis a is negative), the
                  slots in the order such a ray meets their cells, 3 bits a slot, the
                  nearest in the lowest bits, empty slots last

Every hit is the k-d walk's: kernels/wide.cl tests leaves with the same test, keeps
the nearest hit in (t, input id) order and skips a child only where its box, widened
by more than the tests' roundings, starts beyond that hit.
"""
import numpy as np

from . import layout

WIDTH = 8                  # children a node
LEVELS = 3                 # k-d levels a node spans: WIDTH = 2 ** LEVELS
WIDE_WORDS = 9 * WIDTH     # 32-bit words a record
LEAF = 0x80000000
EMPTY = 0xFFFFFFFF


def content_boxes(tree, depth):
    """(lo, hi) (n_nodes, 3) float32: the box of each node's triangles clipped to its
    cell (tree.node_boxes), relative to the tree's origin; +inf and -inf where a node
    holds no triangle. depth: each node's depth (KdTree._topology)."""
    nodes = tree.nodes
    n = len(nodes)
    leaf = layout.is_leaf(nodes)
    count = layout.n_prims(nodes).astype(np.int64)
    cells = tree.node_boxes()
    lo = np.full((n, 3), np.inf, np.float32)
    hi = np.full((n, 3), -np.inf, np.float32)
    full = np.flatnonzero(leaf & (count > 0))
    if len(full):
        first = layout.leaf_offset(nodes)[full].astype(np.int64)
        cnt = count[full]
        starts = np.cumsum(cnt) - cnt
        entry = np.repeat(first - starts, cnt) + np.arange(int(cnt.sum()))
        tris = np.asarray(tree.triangles, np.float32)[np.asarray(tree.leaf_tris, np.int64)[entry]]
        lo[full] = np.maximum(np.minimum.reduceat(tris.min(axis=1), starts), cells[full, 0])
        hi[full] = np.minimum(np.maximum.reduceat(tris.max(axis=1), starts), cells[full, 1])
    above = layout.above_child(nodes).astype(np.int64)
    inner = np.flatnonzero(~leaf)
    for level in range(int(depth.max(initial=0)) - 1, -1, -1):   # deepest parents first
        at = inner[depth[inner] == level]
        lo[at] = np.minimum(lo[at + 1], lo[above[at]])
        hi[at] = np.maximum(hi[at + 1], hi[above[at]])
    return lo, hi


def stack_groups(levels):
    """A wide walk's stack groups (kernels/wide.cl, WIDE_STACK) for a tree of `levels`
    wide levels: a node's group stays until its last child is taken, so the groups
    belong to nodes on one path from the root, at most one a level."""
    return levels


def wide_nodes(tree, device_nodes):
    """The wide nodes of `tree`: (records (m, WIDE_WORDS) uint32, levels), the layout
    above; device_nodes: the nodes as the kernels read them (layout.device_triangles),
    whose leaves' offsets the records take. levels: the most wide nodes a path from the
    root passes (its stack needs a group a level, kernels/wide.cl)."""
    nodes = tree.nodes
    n = len(nodes)
    leaf = layout.is_leaf(nodes)
    count = layout.n_prims(nodes).astype(np.int64)
    above = layout.above_child(nodes).astype(np.int64)
    axis = layout.split_axis(nodes).astype(np.int64)
    depth = tree._topology()[0]
    lo, hi = content_boxes(tree, depth)

    roots = np.flatnonzero(~leaf & (depth % LEVELS == 0))
    if leaf[0]:
        roots = np.array([0], np.int64)               # a tree of one leaf
    m = len(roots)
    wide_index = np.full(n, -1, np.int64)
    wide_index[roots] = np.arange(m)

    # each root's subtree LEVELS levels down: a leaf stays at the first (lowest) of the
    # positions below it; axes[:, p, l]: the split axis at level l above position p
    ids = roots[:, None]
    axes = np.zeros((m, 1, 0), np.int64)
    for _ in range(LEVELS):
        safe = np.where(ids >= 0, ids, 0)
        inner = (ids >= 0) & ~leaf[safe]
        below = np.where(inner, ids + 1, ids)
        up = np.where(inner, above[safe], -1)
        ax = np.where(inner, axis[safe], -1)
        ids = np.stack([below, up], axis=2).reshape(m, -1)
        axes = np.concatenate([np.repeat(axes, 2, axis=1), np.repeat(ax, 2, axis=1)[..., None]],
                              axis=2)
    safe = np.where(ids >= 0, ids, 0)
    ids = np.where((ids >= 0) & ~(leaf[safe] & (count[safe] == 0)), ids, -1)
    valid = ids >= 0

    # slots: the valid positions first, in position order
    slot_pos = np.argsort(~valid, axis=1, kind="stable")
    kid = np.take_along_axis(ids, slot_pos, axis=1)
    has = kid >= 0
    safe = np.where(has, kid, 0)
    is_leaf = has & leaf[safe]

    records = np.zeros((m, WIDE_WORDS), np.uint32)
    boxes = records[:, :6 * WIDTH].view(np.float32).reshape(m, 6, WIDTH)
    boxes[:, :3] = np.where(has[:, None, :], lo[safe].transpose(0, 2, 1), np.inf)
    boxes[:, 3:] = np.where(has[:, None, :], hi[safe].transpose(0, 2, 1), -np.inf)
    first = layout.leaf_offset(device_nodes).astype(np.int64)
    records[:, 6 * WIDTH:7 * WIDTH] = np.where(is_leaf, first[safe],
                                               np.where(has, wide_index[safe], 0))
    records[:, 7 * WIDTH:8 * WIDTH] = np.where(is_leaf, LEAF | count[safe],
                                               np.where(has, 0, EMPTY))

    # the octants' orders: position p's bit at level l (the most significant first),
    # flipped where the octant goes down that level's axis, orders the cells front to
    # back; invalid positions after every valid one
    pos = np.arange(WIDTH)
    bits = (pos[:, None] >> (LEVELS - 1 - np.arange(LEVELS))) & 1          # (8, 3)
    weight = 1 << (LEVELS - 1 - np.arange(LEVELS))
    slot_of_pos = np.argsort(slot_pos, axis=1)
    for octant in range(8):
        flip = np.where(axes >= 0, (octant >> np.maximum(axes, 0)) & 1, 0)
        key = ((bits[None] ^ flip) * weight).sum(axis=2)
        key = np.where(valid, key, WIDTH + pos)
        order = np.take_along_axis(slot_of_pos, np.argsort(key, axis=1, kind="stable"), axis=1)
        records[:, 8 * WIDTH + octant] = (order << (3 * pos)).sum(axis=1)
    levels = int(depth[roots].max(initial=0)) // LEVELS + 1
    return records, levels
