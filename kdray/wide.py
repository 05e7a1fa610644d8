"""Wide nodes: an 8-wide BVH over the tree's triangles, for rays that share no path.

A ray on its own (random origins and directions: inside tests, occlusion, any user's
rays) spends most of its time walking and waiting on memory (BENCHMARKS.md,
"Incoherent rays"). Here one vector step tests a ray against 8 boxes: the nodes of a
binary BVH (kdray/builder/bvh.py, sah_bvh: surface-area splits at multiples of
TRI_BLOCK triangles, leaves of at most TRI_BLOCK) gathered into wide nodes of up to 8
children (wide_children: the gathering of least total node area, which fills a node's
free slots with small subtrees where a node of their own would cost more: fuller
nodes than three binary levels a node, and fewer of them; BENCHMARKS.md, "Incoherent
rays"). A leaf's triangles are copies of their own, TRI_BLOCK or fewer in a run of the
device's triangle buffer (layout.device_triangles' layout,
after the k-d leaves' copies): a ray reads a leaf's triangles in one or two vector
loads a number, and each triangle once, where a k-d walk met several leaves holding
copies of the same triangle and more empty space between them (kernels/wide.cl walks
them). The k-d tree stays for packets, whose shared walk its cells order exactly.

A BVH's boxes overlap, so no order of the children is front to back for every ray;
each node stores, for each of the 8 octants of directions, its slots sorted by their
boxes' centres along the octant's diagonal (nearest first), which a ray takes with no
compare. Any order is exact: the walk skips a child only where it enters its box
beyond the best hit so far.

A record of WIDE_WORDS 32-bit words a node, 256 bytes (four cache lines, each record
on its own: the buffer starts on a page), wide node 0 the root (kernels/wide.cl mirrors
it):

    words  0..47  the children's boxes, 6 rows of 8 float32: min x, min y, min z,
                  max x, max y, max z (+inf and -inf in an empty slot)
    words 48..55  child: a wide node's index (below LEAF), LEAF | (n - 1) << 27 |
                  first / 8 for a leaf of n <= TRI_BLOCK triangle copies from `first`
                  (a multiple of LEAF_ALIGN, as the kernels read them, after the k-d
                  leaves': `wide_nodes`' first_copy), or EMPTY
    words 56..63  per octant o (bit a set: the direction's axis a is negative), the
                  slots in the order of their centres along the octant's diagonal, 3
                  bits a slot, the first in the lowest bits, empty slots last

Every hit is the k-d walk's: kernels/wide.cl tests leaves with the same test, keeps
the nearest hit in (t, input id) order and skips a child only where its box, widened
by more than the tests' roundings, starts beyond that hit; the BVH holds every
triangle the k-d tree lists, each once.
"""
import concurrent.futures
import os

import numpy as np

from . import layout
from .errors import KdrayError
from .builder.bvh import sah_bvh, wide_children

WIDTH = 8                  # children a node
WIDE_WORDS = 8 * WIDTH     # 32-bit words a record
LEAF = 0x80000000
EMPTY = 0xFFFFFFFF
LEAF_ALIGN = 8             # a leaf's first copy is a multiple: first / 8 in its child word
MAX_COPIES = LEAF_ALIGN * ((1 << 27) - 1)   # the child word's reach (an EMPTY's below)
MAX_DEPTH = 48             # the BVH's deepest binary level (kdray/builder/bvh.py)
ONE_AXIS = 4096            # nodes of more triangles split along one axis (sah_bvh)

STACK_GROUPS = (16, MAX_DEPTH + 1)
"""The stack groups (levels of wide nodes, kernels/wide.cl's WIDE_STACK) programs are
compiled for: every tree whose wide nodes are at most 16 levels deep shares its programs
(meshes of 32 to 1.6M triangles have 1 to 9 levels), as kdray.work_sizes' STACK_SIZES
share them among k-d trees; MAX_DEPTH + 1 levels hold any tree's."""


def stack_groups(levels):
    """The fewest of STACK_GROUPS that hold a walk through `levels` levels of wide nodes."""
    return next(g for g in STACK_GROUPS if g >= levels)


def binary_bvh(tree):
    """The binary BVH of the triangles `tree` lists (kdray/builder/bvh.py, sah_bvh, its
    subtrees on as many threads as the process may run on, as a build's):
    (tris (n,) int64 indices into tree.triangles in leaf order, left, right, first,
    count, depth (m,) int64, box (m, 6) float32), a node's triangles
    tris[first:first + count], its box min then max."""
    listed = np.zeros(len(tree.triangles), bool)
    listed[np.asarray(tree.leaf_tris, np.intp)] = True
    listed = np.flatnonzero(listed)
    if len(listed) == 0:        # a hand-made tree (KdTree.validate refuses it): no BVH
        raise KdrayError("the tree lists no triangle: there is nothing to trace")
    t = np.asarray(tree.triangles, np.float32)[listed]
    boxes = np.concatenate([np.minimum(np.minimum(t[:, 0], t[:, 1]), t[:, 2]),
                            np.maximum(np.maximum(t[:, 0], t[:, 1]), t[:, 2])], axis=1)
    centre = boxes[:, :3] + boxes[:, 3:]          # twice the centre, rounded: any order is valid
    # numpy's sorts release the GIL: the three axes on threads
    with concurrent.futures.ThreadPoolExecutor(3) as pool:
        order = np.stack(list(pool.map(lambda a: np.argsort(centre[:, a]), range(3))))
    order = order.astype(np.int64, copy=False)    # sah_bvh reorders it in place
    threads = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    left, right, first, count, depth, box = sah_bvh(boxes, order, layout.TRI_BLOCK, MAX_DEPTH,
                                                    ONE_AXIS, threads)
    return listed[order[0]], left, right, first, count, depth, box


def wide_nodes(tree, run, first_copy):
    """The tree's wide nodes: (records (m, WIDE_WORDS) uint32, the layout above;
    levels, the most wide nodes a path from the root passes (its stack needs a group a
    level, kernels/wide.cl); copies (k,) int64, the leaves' triangles as indices into
    tree.triangles, each leaf from a multiple of `run` and of LEAF_ALIGN, padded to
    whole runs with -1). A leaf's first copy is first_copy plus its first copy's place
    in `copies`: first_copy, a multiple of both, is where the copies start in the
    device's buffer. KdrayError when the copies reach past MAX_COPIES."""
    tris, left, right, first, count, depth, box = binary_bvh(tree)
    leaf = left < 0
    # the leaves' copies in leaf order, each from a multiple of run and of LEAF_ALIGN
    leaves = np.flatnonzero(leaf)
    leaves = leaves[np.argsort(first[leaves], kind="stable")]
    align = max(run, LEAF_ALIGN)
    size = -(-count[leaves] // align) * align
    copies = layout.padded_entries(tris, first[leaves], count[leaves], size)
    start = np.cumsum(size) - size
    copy_of = np.zeros(len(leaf), np.int64)
    copy_of[leaves] = first_copy + start
    if first_copy % LEAF_ALIGN or first_copy + len(copies) > MAX_COPIES:
        raise KdrayError(f"the wide nodes' triangle copies ({first_copy:,} to "
                         f"{first_copy + len(copies):,}) do not fit their child words (below "
                         f"{MAX_COPIES:,}, from a multiple of {LEAF_ALIGN})")

    # wide nodes: up to WIDTH children each, of least total area (wide_children)
    kid, wide_index, wide_depth = wide_children(left, right, box, WIDTH)
    m = len(kid)
    has = kid >= 0
    safe = np.maximum(kid, 0)
    is_leaf = has & leaf[safe]

    records = np.zeros((m, WIDE_WORDS), np.uint32)
    rows = records[:, :6 * WIDTH].view(np.float32).reshape(m, 6, WIDTH)
    rows[:] = np.where(has[:, None, :], box[safe].transpose(0, 2, 1),
                       np.float32(np.inf) * np.array([1, 1, 1, -1, -1, -1], np.float32)[:, None])
    leaf_word = LEAF | (count[safe] - 1) << 27 | copy_of[safe] // LEAF_ALIGN
    records[:, 6 * WIDTH:7 * WIDTH] = np.where(is_leaf, leaf_word,
                                               np.where(has, wide_index, EMPTY))
    # each octant's order: the centres along its diagonal, empty slots last
    centre = box[safe][:, :, :3].astype(np.float64) + box[safe][:, :, 3:]
    slot = np.arange(WIDTH)
    for octant in range(8):
        sign = np.array([-1.0 if octant >> a & 1 else 1.0 for a in range(3)])
        key = np.where(has, centre @ sign, np.inf)
        order = np.argsort(key, axis=1, kind="stable").astype(np.int64)
        records[:, 7 * WIDTH + octant] = (order << (3 * slot)).sum(axis=1)
    levels = int(wide_depth.max()) + 1
    return records, levels, copies
