"""A binary BVH over triangles for the wide walk (kdray/wide.py): surface-area splits
at multiples of a block of triangles.

Each node's triangles are split in two along one axis, sorted by their boxes' centres,
after a whole number of blocks (`block`, the triangles a wide leaf's run reads at
once): the split of least cost

    C(k) = SA(left box) * ceil(k / block) + SA(right box) * ceil((n - k) / block)

over the three axes and every k = block, 2 block, ... below n (a ray pays a leaf's
tests a run at a time, so a run's cost is the same for 1 or `block` triangles), down to
nodes of at most `block` triangles, the leaves. So every leaf but one (the one holding
n mod block) is full, and there are ceil(n / block) of them.

The three axes' orders are sorted once and each split partitions the other two stably,
which keeps them sorted: O(n) a level. A node that could not reach its leaves within
`max_depth` levels by halving is halved (its blocks split evenly along its centres'
longest axis) instead of costed, so no input, however degenerate (every triangle in
one place: all costs equal), makes the tree deeper than `max_depth`.

Numba-compiled (`cache=True`; the first call compiles).
"""
import numpy as np
from numba import njit


@njit(cache=True)
def _area(lx, ly, lz, hx, hy, hz):
    """Half the surface area of a box, in float64 (0 for an empty one)."""
    ex = max(float(hx) - float(lx), 0.0)
    ey = max(float(hy) - float(ly), 0.0)
    ez = max(float(hz) - float(lz), 0.0)
    return ex * ey + ey * ez + ez * ex


@njit(cache=True)
def _box(ids, a, b, boxes, out):
    """out[0:3], out[3:6] = the box of triangles ids[a:b] (boxes: theirs)."""
    for j in range(3):
        out[j] = np.inf
        out[3 + j] = -np.inf
    for i in range(a, b):
        t = ids[i]
        for j in range(3):
            out[j] = min(out[j], boxes[t, j])
            out[3 + j] = max(out[3 + j], boxes[t, 3 + j])


@njit(cache=True, inline="always")
def _grow(boxes, t, x0, y0, z0, x1, y1, z1):
    """The box (x0, y0, z0, x1, y1, z1) grown by triangle t's."""
    return (min(x0, boxes[t, 0]), min(y0, boxes[t, 1]), min(z0, boxes[t, 2]),
            max(x1, boxes[t, 3]), max(y1, boxes[t, 4]), max(z1, boxes[t, 5]))


@njit(cache=True)
def _sweep(ids, a, n, boxes, block, suffix, best, box_l, box_r):
    """The cheapest split of triangles ids[a:a + n] in their order here (C(k), the
    module's docstring), if cheaper than best[0]: best[0] its cost, best[1] its k, and
    box_l, box_r (6,) its children's boxes. suffix: (n // block + 1, 6) scratch."""
    # the boxes of ids[a + k:a + n] for k = block, 2 block, ..., a block at a time
    # (no division a triangle), the running box in scalars (registers)
    blocks = (n + block - 1) // block
    x0 = y0 = z0 = np.float32(np.inf)
    x1 = y1 = z1 = np.float32(-np.inf)
    for b in range(blocks - 1, 0, -1):
        for i in range(min(n, (b + 1) * block) - 1, b * block - 1, -1):
            x0, y0, z0, x1, y1, z1 = _grow(boxes, ids[a + i], x0, y0, z0, x1, y1, z1)
        suffix[b, 0] = x0
        suffix[b, 1] = y0
        suffix[b, 2] = z0
        suffix[b, 3] = x1
        suffix[b, 4] = y1
        suffix[b, 5] = z1
    x0 = y0 = z0 = np.float32(np.inf)
    x1 = y1 = z1 = np.float32(-np.inf)
    for b in range(1, blocks):
        for i in range((b - 1) * block, b * block):
            x0, y0, z0, x1, y1, z1 = _grow(boxes, ids[a + i], x0, y0, z0, x1, y1, z1)
        r = suffix[b]
        cost = (_area(x0, y0, z0, x1, y1, z1) * b
                + _area(r[0], r[1], r[2], r[3], r[4], r[5]) * (blocks - b))
        if cost < best[0]:
            best[0] = cost
            best[1] = b * block
            box_l[0] = x0
            box_l[1] = y0
            box_l[2] = z0
            box_l[3] = x1
            box_l[4] = y1
            box_l[5] = z1
            box_r[:] = r


def sah_bvh(boxes, order, block, max_depth, one_axis, threads=1):
    """A binary BVH over n triangles (the module's docstring).

    boxes  : (n, 6) float32, each triangle's box, min x y z then max x y z (one row
             one read: the sweeps read them in the axes' orders, at random).
    order  : (3, n) int64, the triangles sorted by their boxes' centres along x, y, z;
             reordered in place, so that each node's triangles are
             order[0][first:first + count] (every row holds the same sets).
    block  : the leaves' largest size, and what the splits are multiples of.
    max_depth : the deepest a node may lie (the root at 0); at least ceil(log2(
             ceil(n / block))).
    one_axis : nodes of more triangles are split along their centres' longest axis
             only (the three sweeps cost 3 times one).
    threads : the subtrees below the top split on this many threads. From
             PARALLEL_FROM triangles the top is split first, down to nodes of at most
             n / SUBTREES triangles, then each of those nodes' subtrees is built into
             its own range of node indices (2 ceil(count / block) - 2 of them, in the
             order the top found them), so the result does not depend on threads.

    Returns (left, right, first, count, depth (m,) int64, box (m, 6) float32 its
    triangles' box, min then max), m = 2 ceil(n / block) - 1 nodes (0 when n is 0), the
    root 0 and children after their parent; left and right are -1 at a leaf."""
    n = order.shape[1]
    nodes, side, tmp = _start(boxes, order, block)
    if len(nodes[0]) == 0:
        return nodes
    args = (boxes, order, block, max_depth, one_axis, *nodes, side, tmp)
    if n < PARALLEL_FROM:
        _split_subtree(0, 1, 0, np.empty(0, np.int64), *args)
        return nodes
    pending = np.empty(2 * ((n + block - 1) // block), np.int64)
    made, n_pending = _split_subtree(0, 1, n // SUBTREES, pending, *args)
    roots = pending[:n_pending]
    count = nodes[3]
    size = 2 * ((count[roots] + block - 1) // block) - 2
    base = made + np.cumsum(size) - size
    from .threads import kept_pool
    pool = kept_pool(threads)
    none = np.empty(0, np.int64)
    # the largest first, so that the threads end together
    jobs = [(int(roots[i]), int(base[i])) for i in np.argsort(-count[roots], kind="stable")]
    if pool is None:
        for root, at in jobs:
            _split_subtree(root, at, 0, none, *args)
    else:
        for job in [pool.submit(_split_subtree, root, at, 0, none, *args) for root, at in jobs]:
            job.result()
    return nodes


PARALLEL_FROM = 1 << 18
"""Triangles from which `sah_bvh` builds its top first and the subtrees below it on
threads: below, a build takes milliseconds."""

SUBTREES = 16
"""The top's split ends at nodes of n / SUBTREES triangles or fewer: about as many
subtrees, enough for the threads to end together."""


@njit(cache=True)
def _start(boxes, order, block):
    """(nodes, side, tmp): sah_bvh's node arrays (left, right, first, count, depth,
    box) for n triangles with the root (node 0, all of them, their box) set, and the
    partition's scratch (n,) arrays."""
    n = order.shape[1]
    leaves = (n + block - 1) // block
    m = max(2 * leaves - 1, 0)
    left = np.full(m, -1, np.int64)
    right = np.full(m, -1, np.int64)
    first = np.zeros(m, np.int64)
    count = np.zeros(m, np.int64)
    depth = np.zeros(m, np.int64)
    box = np.zeros((m, 6), np.float32)
    if m:
        whole = np.empty(6)
        _box(order[0], 0, n, boxes, whole)
        box[0, :] = whole
        count[0] = n
    return (left, right, first, count, depth, box), np.zeros(n, np.uint8), np.empty(n, np.int64)


@njit(cache=True, nogil=True)
def _split_subtree(root, made, stop, pending, boxes, order, block, max_depth, one_axis,
                   left, right, first, count, depth, box, side, tmp):
    """Split the subtree of node `root` depth-first, numbering new nodes from `made`;
    nodes of more than `block` and at most `stop` triangles are left unsplit and listed
    in `pending`. Writes only the subtree's nodes and its triangles' places in order,
    side and tmp, so that disjoint subtrees may grow on threads at once (no GIL).
    Returns (the next free node index, the number of pending nodes)."""
    c0 = count[root]
    suffix = np.empty(((c0 + block - 1) // block + 1, 6), np.float32)
    stack = np.empty(2 * ((c0 + block - 1) // block) + 1, np.int64)
    best = np.empty(2)
    box_l = np.empty(6)
    box_r = np.empty(6)
    top = 1
    stack[0] = root
    n_pending = 0
    while top > 0:
        top -= 1
        node = stack[top]
        a = first[node]
        c = count[node]
        if c <= block:
            continue
        if c <= stop:
            pending[n_pending] = node
            n_pending += 1
            continue
        blocks = (c + block - 1) // block
        halvings = 0
        while (1 << halvings) < blocks:
            halvings += 1
        best[0] = np.inf
        # the centres' longest axis
        longest = 0
        spread = -1.0
        for ax in range(3):
            p, q = order[ax, a], order[ax, a + c - 1]
            s = ((float(boxes[q, ax]) + float(boxes[q, 3 + ax]))
                 - (float(boxes[p, ax]) + float(boxes[p, 3 + ax])))
            if s > spread:
                spread = s
                longest = ax
        axis = longest
        if depth[node] + halvings < max_depth:
            for ax in range(3):
                if c > one_axis and ax != longest:
                    continue
                before = best[0]
                _sweep(order[ax], a, c, boxes, block, suffix, best, box_l, box_r)
                if best[0] < before:
                    axis = ax
        if best[0] == np.inf:
            # halve: the blocks split evenly along the centres' longest axis (also
            # where no cost is finite)
            best[1] = (blocks + 1) // 2 * block
            k = int(best[1])
            _box(order[axis], a, a + k, boxes, box_l)
            _box(order[axis], a + k, a + c, boxes, box_r)
        k = int(best[1])
        # the other axes' orders partitioned stably by side: still sorted in each half
        ids = order[axis]
        for i in range(a, a + k):
            side[ids[i]] = 0
        for i in range(a + k, a + c):
            side[ids[i]] = 1
        for ax in range(3):
            if ax == axis:
                continue
            row = order[ax]
            lft = a
            rgt = a
            for i in range(a, a + c):
                t = row[i]
                if side[t] == 0:
                    row[lft] = t
                    lft += 1
                else:
                    tmp[rgt] = t
                    rgt += 1
            for i in range(a, rgt):
                row[lft + i - a] = tmp[i]
        l_node = made
        r_node = made + 1
        made += 2
        left[node] = l_node
        right[node] = r_node
        first[l_node] = a
        count[l_node] = k
        first[r_node] = a + k
        count[r_node] = c - k
        depth[l_node] = depth[node] + 1
        depth[r_node] = depth[node] + 1
        box[l_node, :] = box_l
        box[r_node, :] = box_r
        stack[top] = r_node
        stack[top + 1] = l_node
        top += 2
    return made, n_pending


@njit(cache=True)
def wide_children(left, right, box, width):
    """The binary BVH (sah_bvh's left, right, box) gathered into wide nodes of up to
    `width` children, at the least total surface area of the wide nodes (after Ylitie
    et al. 2017): a ray meets a node's box with a chance in proportion to its area and
    then pays the node's box tests; every leaf is some node's child whatever the
    gathering, so only the nodes' areas differ. forest[n, k] is the least area of n's
    subtree's wide nodes when the subtree is at most k children of one node (n itself,
    a wide node's root: A(n) + its children's best split into at most `width`; or a
    split of n's children's forests), so a small subtree fills its parent's free slots
    where a node of its own would cost more.

    Returns (kids (w, width) int64: each wide node's children, binary node indices,
    -1 past its last; wide (w, width) int64: where a child is inner, the wide node it
    starts, else -1; depth (w,) int64: each wide node's depth, the root's 0), wide node
    0 from the root (holding the root alone if it is a leaf), in breadth-first order:
    children after their parent."""
    m = len(left)
    forest = np.empty((m, width + 1))    # forest[n, k]: n's subtree as <= k children
    cut = np.zeros((m, width + 1), np.int64)   # the k that left takes (0: n alone)
    split = np.ones(m, np.int64)         # n a wide node: the children left's part takes
    for n in range(m - 1, -1, -1):       # children after their parent: theirs first
        l, r = left[n], right[n]
        if l < 0:
            forest[n, :] = 0.0
            continue
        alone = np.inf
        for j in range(1, width):
            c = forest[l, j] + forest[r, width - j]
            if c < alone:
                alone = c
                split[n] = j
        alone += _area(box[n, 0], box[n, 1], box[n, 2], box[n, 3], box[n, 4], box[n, 5])
        forest[n, 1] = alone
        for k in range(2, width + 1):
            forest[n, k] = alone
            cut[n, k] = 0
            for j in range(1, k):
                c = forest[l, j] + forest[r, k - j]
                if c < forest[n, k]:
                    forest[n, k] = c
                    cut[n, k] = j
    kids = np.full((m, width), -1, np.int64)
    wide = np.full((m, width), -1, np.int64)
    depth = np.zeros(m, np.int64)
    queue = np.empty(m, np.int64)
    todo_n = np.empty(2 * width, np.int64)
    todo_k = np.empty(2 * width, np.int64)
    queue[0] = 0
    tail = 1
    head = 0
    while head < tail:
        w = head
        b = queue[head]
        head += 1
        if left[b] < 0:
            kids[w, 0] = b
            continue
        # b's own split into at most `width`, each part unfolded by its cut
        top = 2
        todo_n[0], todo_k[0] = left[b], split[b]
        todo_n[1], todo_k[1] = right[b], width - split[b]
        count = 0
        while top > 0:
            top -= 1
            n, k = todo_n[top], todo_k[top]
            j = cut[n, k] if left[n] >= 0 else 0
            if j == 0:
                kids[w, count] = n
                if left[n] >= 0:
                    queue[tail] = n
                    wide[w, count] = tail
                    depth[tail] = depth[w] + 1
                    tail += 1
                count += 1
            else:
                todo_n[top], todo_k[top] = right[n], k - j
                todo_n[top + 1], todo_k[top + 1] = left[n], j
                top += 2
    return kids[:tail], wide[:tail], depth[:tail]
