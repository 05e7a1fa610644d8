"""The build loop: nodes in depth-first order from an explicit work stack.

The events of pending nodes live in two uint64 buffers, each used as a stack: a
node's children go to the other buffer than the node's, the above (right) child's
events at its top and the below (left) child's after them, in one pass over the
node's events (`classify.split_merge`: no copy between buffers of its own). The left
child is processed next and so becomes node i + 1 (depth-first, pbrt layout), the
right child waits on the stack with the index of the parent whose `above_child` it
fills in when it is emitted. Taking a node off the work stack frees its buffer's
top down to the node: everything above it belongs to nodes already built.

Parallel build (`build_nodes`): the root is split first; its children are tasks
(their sorted events, box, depth, budget) built on threads (`subdivide` releases the
GIL) down to TASK_DEPTH, where their nodes are handed on as tasks again, the largest
pending task first (`threads.LargestFirst`); at the end every task's subtree is written
once into the whole tree's arrays, in its placeholder's place (`place`). A node's
subtree depends only on its events, box, depth and budget, so the tree is the same,
byte for byte, for any number of threads.

`subdivide` is numba-compiled (`cache=True`; the first call compiles).
"""
import concurrent.futures
import typing

import numpy as np
from numba import njit

from . import scratch
from .classify import classify, clip_straddlers, split_merge, straddler_events
from .clip import polygon_scratch
from .events import END, key_kind, key_prim, position_bits, sorted_copy
from .sah import LEFT, best_split
from .threads import LargestFirst

MAX_REFS_PER_TRI = 32.0
"""Reference budget: a node may hold `budget` leaf references in its subtree (the root
max_refs_per_tri * n); a split whose sides hold more than that is not made, and the
budget is shared between the children in proportion to their triangles. So the tree
never lists more than max_refs_per_tri * n triangles. SAH alone does not bound them:
in a flat node (all triangles in one plane) P_L + P_R = 1, duplicating a triangle is
free, and overlapping coplanar triangles double at every level down to max_depth."""

TASK_DEPTH = 4
"""Depth of the nodes built as separate tasks: up to 2**4 = 16 subtrees, enough to keep
a few threads busy when the subtrees differ in size (with 8, an odd one out runs
alone at the end; a fourth level on one thread costs less than that wait)."""

SMALL_MESH_TRIS = 16000
"""Meshes with fewer triangles hand nodes on as tasks one level higher, at TASK_DEPTH - 1
(up to 8 subtrees): there a task's own cost (its `subdivide` call and arrays, the
hand-over) outweighs the balance that 16 give (measured in turns with depth 3 for
every mesh: 10k 0.93-0.95 of the time, 20k 1.00, bunny 1.07; BENCHMARKS.md)."""

TASK_ROOM = 3
"""A task's slot of keys holds TASK_ROOM times its events (+ 64): room for its two
event stacks (`split_keys`), so that its subtree is built in place."""

STAGE_DEPTHS = (1,)
"""Depths, above TASK_DEPTH, at which the parallel build also hands nodes on as tasks
(`build_nodes`): the root alone is built before a second thread has work."""

MIN_PARALLEL_TRIS = 4000
"""Meshes with fewer triangles are built on one thread, with no thread pool: below it
starting and feeding the pool's threads costs more than they save (measured in
turns, 2 threads against 1: BENCHMARKS.md)."""

_LEAF = np.uint32(3)
_U2 = np.uint32(2)


@njit(cache=True)
def _grow(a, used, need):
    """`a` if it holds `need` rows, else a copy of its first `used` rows in an array of
    at least twice the rows."""
    if need <= len(a):
        return a
    b = np.empty((max(need, 2 * len(a)),) + a.shape[1:], dtype=a.dtype)
    b[:used] = a[:used]
    return b


@njit(cache=True, nogil=True)
def subdivide(tri, buf, other, counts, n_tris, bounds, depth0, budget0, K_T, K_I,
              empty_bonus, max_depth, leaf_size, task_depth):
    """Build the nodes of the subtree of one node from its sorted events.

    tri : (m, 3, 3) float32;  buf (>= e,) uint64, counts (3,) int64 : the node's sorted
    event runs in buf[:e], e = counts.sum() (the root's from `events.sorted_root_events`);
    buf is used, and overwritten, as one of the two event stacks, `other` (uint64, any
    contents) as the other: room for about 1.5 e keys in each saves copying them to
    larger ones (untouched room costs no memory);  n_tris : its triangles;
    bounds : (2, 3) float64 its box (float32 values);  depth0 : its depth;  budget0 :
    its reference budget (the root's max_refs_per_tri * m, see MAX_REFS_PER_TRI);
    max_depth : resolved;  task_depth : nodes at this depth (> depth0) are not built
    but handed back as tasks (a placeholder node stands in for each), -1 = none.
    Returns (nodes (n, 2) uint32, leaf_tris (r,) uint32, depth of the deepest leaf,
    tasks), node and leaf indices counted from this subtree's root (nodes and
    leaf_tris are views of larger arrays, not copied here: the caller copies them
    once `buf` is freed); tasks is
    (node (k,) int64 placeholder index, keys (E,) uint64 and key_start (k + 1,) int64
    their slots: task j's events first in keys[key_start[j]:key_start[j + 1]], with
    room to build it there (TASK_ROOM; keys a view of a larger array: a copy would
    page-fault ~100 MB at 1.6M triangles on the one thread; for the root's own
    children, the halves of other when they fit there, see below), counts (k, 3) int64,
    n (k,) int64, box (k, 2, 3) float64,
    depth (k,) int64, budget (k,) float64), in node order.
    """
    m = n_tris

    # Work stack: at most one pending right child per level, plus the node on top.
    cap_stack = max_depth + 4
    st_off = np.empty(cap_stack, dtype=np.int64)
    st_counts = np.empty((cap_stack, 3), dtype=np.int64)
    st_n = np.empty(cap_stack, dtype=np.int64)
    st_box = np.empty((cap_stack, 2, 3), dtype=np.float64)
    st_depth = np.empty(cap_stack, dtype=np.int64)
    st_parent = np.empty(cap_stack, dtype=np.int64)
    st_budget = np.empty(cap_stack, dtype=np.float64)
    st_off[0] = 0
    st_counts[0] = counts
    st_n[0] = m
    for c in range(3):
        st_box[0, 0, c] = bounds[0, c]
        st_box[0, 1, c] = bounds[1, c]
    st_depth[0] = depth0
    st_parent[0] = -1
    st_budget[0] = budget0
    top = 1

    task_node = np.empty(16, dtype=np.int64)
    # Room for the tasks' events and their event stacks (TASK_ROOM; the straddlers add
    # some events) without copying them as they grow; untouched room is never resident.
    # The root's own children as tasks (task_depth = depth0 + 1) are written straight
    # into the halves of `other` when at most 6 events a triangle fit there (in_halves;
    # each half, with the same half of buf, is then a task's two event stacks): those
    # pages are resident already, a new array's would be faulted in on this one thread.
    in_halves = False
    task_keys = np.empty(2 * TASK_ROOM * (counts[0] + counts[1] + counts[2]) + 1024
                         if task_depth >= 0 else 16, dtype=np.uint64)
    task_start = np.zeros(17, dtype=np.int64)
    task_counts = np.empty((16, 3), dtype=np.int64)
    task_n = np.empty(16, dtype=np.int64)
    task_box = np.empty((16, 2, 3), dtype=np.float64)
    task_depth_of = np.empty(16, dtype=np.int64)
    task_budget = np.empty(16, dtype=np.float64)
    n_tasks = 0

    # Room for the nodes and references of typical meshes (8 and 5 per triangle for
    # the bunny); pages never written are never resident, so the room costs nothing.
    nodes = np.empty((16 * m + 16, 2), dtype=np.uint32)
    n_nodes = 0
    leaf_tris = np.empty(16 * m + 16, dtype=np.uint32)
    n_refs = 0
    deepest = 0

    # Scratch, grown on demand.
    poly = polygon_scratch()
    side = np.empty(tri.shape[0], dtype=np.int8)           # `classify` writes before it reads
    strad = np.empty(max(m, 1), dtype=np.int64)
    new_left = np.empty(16, dtype=np.uint64)
    new_right = np.empty(16, dtype=np.uint64)
    new_scratch = np.empty(16, dtype=np.uint64)
    leaf_scratch = np.empty(max(m, 1), dtype=np.uint32)    # a leaf's triangles, unsorted
    left_box = np.empty((16, 2, 3), dtype=np.float32)
    right_box = np.empty((16, 2, 3), dtype=np.float32)
    left_ok = np.empty(16, dtype=np.bool_)
    right_ok = np.empty(16, dtype=np.bool_)
    new_left_runs = np.empty((3, 2), dtype=np.int64)
    new_right_runs = np.empty((3, 2), dtype=np.int64)
    box = np.empty((2, 3), dtype=np.float64)
    node_counts = np.empty(3, dtype=np.int64)
    right_counts = np.empty(3, dtype=np.int64)
    left_counts = np.empty(3, dtype=np.int64)

    # Two event buffers: a node's children go to the other one than the node's (depth
    # parity from depth0: buf0 = buf, buf1 = other), each a stack whose top (top_of)
    # falls back to a node's offset when the node is taken off the work stack.
    buf0 = buf
    buf1 = other
    top_of = np.zeros(2, dtype=np.int64)

    while top > 0:
        top -= 1
        off = st_off[top]
        for k in range(3):
            node_counts[k] = st_counts[top, k]
            box[0, k] = st_box[top, 0, k]
            box[1, k] = st_box[top, 1, k]
        n = st_n[top]
        depth = st_depth[top]
        parent = st_parent[top]
        budget = st_budget[top]
        b = (depth - depth0) & 1
        src = buf0 if b == 0 else buf1
        top_of[b] = off

        idx = n_nodes
        if n_nodes == len(nodes):
            nodes = _grow(nodes, n_nodes, n_nodes + 1)
        n_nodes += 1
        if parent >= 0:
            nodes[parent, 0] |= np.uint32(idx) << _U2

        if depth == task_depth:
            # A task: copy its events out, leave a placeholder node.
            node_total = node_counts[0] + node_counts[1] + node_counts[2]
            k = n_tasks
            task_node = _grow(task_node, k, k + 1)
            task_start = _grow(task_start, k + 1, k + 2)
            task_counts = _grow(task_counts, k, k + 1)
            task_n = _grow(task_n, k, k + 1)
            task_box = _grow(task_box, k, k + 1)
            task_depth_of = _grow(task_depth_of, k, k + 1)
            task_budget = _grow(task_budget, k, k + 1)
            if in_halves:                       # in its half of buf1 already
                task_keys = buf1
                task_start[k] = off
                task_start[k + 1] = len(buf1) // 2 if k == 0 else len(buf1)
            else:
                slot = TASK_ROOM * node_total + 64
                task_keys = _grow(task_keys, task_start[k], task_start[k] + slot)
                task_keys[task_start[k]:task_start[k] + node_total] = src[off:off + node_total]
                task_start[k + 1] = task_start[k] + slot
            task_node[k] = idx
            task_counts[k] = node_counts
            task_n[k] = n
            task_box[k] = box
            task_depth_of[k] = depth
            task_budget[k] = budget
            n_tasks += 1
            nodes[idx, 0] = _LEAF
            nodes[idx, 1] = 0
            continue

        axis = -1
        if n > leaf_size and depth < max_depth:
            # errata 6: no lambda on the leaf; a plane dearer than the leaf is not made
            cost, axis, pos, planar_side, n_below, n_above = best_split(
                src, off, node_counts, n, box, K_T, K_I, empty_bonus, K_I * n)
            if axis >= 0 and n_below + n_above > budget:  # out of references
                axis = -1

        if axis < 0:
            # Leaf: the node's triangles (one START or PLANAR each on x), in index order.
            if n_refs + n > len(leaf_tris):
                leaf_tris = _grow(leaf_tris, n_refs, n_refs + n)
            c = 0
            for i in range(off, off + node_counts[0]):
                if key_kind(src[i]) != END:
                    leaf_scratch[c] = np.uint32(key_prim(src[i]))
                    c += 1
            sorted_copy(leaf_scratch, 0, c, leaf_tris, n_refs)
            nodes[idx, 0] = _LEAF | (np.uint32(c) << _U2)
            nodes[idx, 1] = np.uint32(n_refs)
            n_refs += c
            deepest = max(deepest, depth)
            continue

        # Interior node; its above_child is filled in when the right child is emitted.
        nodes[idx, 0] = np.uint32(axis)
        nodes[idx, 1] = np.float32(pos).view(np.uint32)

        run_start = off
        for k in range(axis):
            run_start += node_counts[k]
        n_strad = classify(src, run_start, node_counts[axis], position_bits(pos),
                           planar_side == LEFT, side, strad)

        if n_strad > len(left_ok):
            size = max(n_strad, 2 * len(left_ok))
            left_box = np.empty((size, 2, 3), dtype=np.float32)
            right_box = np.empty((size, 2, 3), dtype=np.float32)
            left_ok = np.empty(size, dtype=np.bool_)
            right_ok = np.empty(size, dtype=np.bool_)
        clip_straddlers(tri, strad, n_strad, box, axis, pos, poly,
                        left_box, right_box, left_ok, right_ok)

        if 6 * n_strad > len(new_left):
            size = max(6 * n_strad, 2 * len(new_left))
            new_left = np.empty(size, dtype=np.uint64)
            new_right = np.empty(size, dtype=np.uint64)
        if 2 * n_strad > len(new_scratch):
            new_scratch = np.empty(max(2 * n_strad, 2 * len(new_scratch)), dtype=np.uint64)
        straddler_events(strad, n_strad, left_box, left_ok, new_left, new_left_runs, new_scratch)
        straddler_events(strad, n_strad, right_box, right_ok, new_right, new_right_runs,
                         new_scratch)

        # The children in the other buffer: the right one at its top, the left one
        # after room for every event of the node and the right straddlers' (+1: see
        # split_merge).
        node_total = node_counts[0] + node_counts[1] + node_counts[2]
        b_child = 1 - b
        w_right = top_of[b_child]
        w_left = w_right + node_total + new_right_runs[2, 0] + new_right_runs[2, 1] + 1
        need = w_left + node_total + new_left_runs[2, 0] + new_left_runs[2, 1] + 1
        half = len(buf1) // 2
        if (task_depth == depth0 + 1 and depth == depth0 and 6 * n_below + 1 <= half
                and 6 * n_above + 1 <= len(buf1) - half):
            # The root's children are tasks: each straight into its half of buf1 (at
            # most 6 events a triangle), the left one first (node order), no copy.
            in_halves = True
            w_left = 0
            w_right = half
            need = 0
        if b_child == 0:
            if need > len(buf0):
                buf0 = _grow(buf0, w_right, need)
            dst = buf0
        else:
            if need > len(buf1):
                buf1 = _grow(buf1, w_right, need)
            dst = buf1
        n_left, n_right = split_merge(src, off, node_counts, side, new_left, new_left_runs,
                                      new_right, new_right_runs, dst, w_right, w_left,
                                      right_counts, left_counts)

        # Push the right child first, so the left one is emitted next (index idx + 1).
        st_off[top] = w_right
        st_n[top] = n_right
        for k in range(3):
            st_counts[top, k] = right_counts[k]
            st_counts[top + 1, k] = left_counts[k]
            for c in range(2):
                st_box[top, c, k] = box[c, k]
                st_box[top + 1, c, k] = box[c, k]
        st_box[top, 0, axis] = pos
        st_box[top + 1, 1, axis] = pos
        st_depth[top] = depth + 1
        st_parent[top] = idx
        st_budget[top] = budget * n_above / (n_below + n_above)
        top += 1
        st_off[top] = w_left
        st_n[top] = n_left
        st_depth[top] = depth + 1
        st_parent[top] = -1
        st_budget[top] = budget * n_below / (n_below + n_above)
        top += 1

    tasks = (task_node[:n_tasks].copy(), task_keys[:task_start[n_tasks]],
             task_start[:n_tasks + 1].copy(), task_counts[:n_tasks].copy(), task_n[:n_tasks].copy(),
             task_box[:n_tasks].copy(), task_depth_of[:n_tasks].copy(), task_budget[:n_tasks].copy())
    return nodes[:n_nodes], leaf_tris[:n_refs], deepest, tasks


def split_keys(keys, counts):
    """The two event buffers of `subdivide` from one: (keys' first half, its second
    half) when the events (counts (3,)) fit in the first (`events.sorted_root_events`
    sorts in the second), else (keys, a new array of its size)."""
    half = len(keys) // 2
    if half >= counts.sum():
        return keys[:half], keys[half:]
    return keys, np.empty(len(keys), dtype=np.uint64)


def build_nodes(tri, keys, counts, bounds, K_T, K_I, empty_bonus, max_depth, leaf_size,
                threads=1, max_refs_per_tri=MAX_REFS_PER_TRI, pool=None, reuse=False):
    """The tree's nodes from the root's sorted events, on `threads` threads.

    tri : (m, 3, 3) float32;  keys, counts : from `events.sorted_root_events` (keys
    are overwritten: pass the only reference to them, so that they are freed early);
    bounds : (2, 3) float64 root box (float32 values);  max_depth : resolved.
    pool : None or a concurrent.futures executor of `threads` threads to run on (the
    builder's: `threads.kept_pool`);
    reuse : keys (from `scratch.take`) go back to `scratch` for the next build once
    the build is done with them, when it keeps arrays of their size (else they are
    freed as early as they can be).
    Returns (nodes (n, 2) uint32, leaf_tris (r,) uint32, depth of the deepest leaf),
    the same for any `threads`.

    In stages (`STAGE_DEPTHS`): the calling thread splits the root; each child is a
    task that builds its subtree down to TASK_DEPTH (one level less for meshes under
    SMALL_MESH_TRIS) on a pool thread and there hands its own tasks to the pool, so
    that the second thread starts at depth 1 rather than at TASK_DEPTH (the levels
    above it are a sizeable part of a build). A thread takes the largest task pending
    (`threads.LargestFirst`, by events), so that the build does not end with one
    thread on a large subtree and the other idle.
    Each task's events run in place in its slot of its parent's `tasks` keys; the
    root's two children, when they fit, each in half of the root's two event buffers
    (`subdivide`).
    """
    m = tri.shape[0]
    args = (K_T, K_I, empty_bonus, max_depth, leaf_size)
    budget = max_refs_per_tri * m
    task_depth = max(TASK_DEPTH - 1, 1) if m < SMALL_MESH_TRIS else TASK_DEPTH
    if threads <= 1 or m < MIN_PARALLEL_TRIS or max_depth <= task_depth:
        nodes, leaf_tris, depth, _ = subdivide(tri, *split_keys(keys, counts), counts, m, bounds,
                                               0, budget, *args, -1)
        done = nodes.copy(), leaf_tris.copy(), depth
        if reuse:
            scratch.give(keys)
        return done
    stages = sorted({d for d in STAGE_DEPTHS if d < task_depth} | {task_depth})

    def work(pool, bufs, counts, n, box, depth0, budget, stage):
        """subdivide (bufs: its two event buffers) down to stages[stage]; its tasks
        submitted to `pool` (a LargestFirst; the next stage). Returns (nodes,
        leaf_tris, deepest, placeholders (k,), futures [k])."""
        task_depth = stages[stage] if stage < len(stages) else -1
        nodes, leaf_tris, deepest, tasks = subdivide(tri, *bufs, counts, n, box, depth0, budget,
                                                     *args, task_depth)
        node, task_keys, key_start, task_counts, task_n, task_box, task_depth_of, task_budget = tasks
        futures = [None] * len(node)
        for k in range(len(node)):
            slot = task_keys[key_start[k]:key_start[k + 1]]
            if np.may_share_memory(task_keys, bufs[1]):
                # the root's children, in the halves of its second buffer: the same
                # halves of its first (whose events are spent) are their other stacks
                task_bufs = (slot, bufs[0][key_start[k]:key_start[k + 1]])
            else:
                task_bufs = split_keys(slot, task_counts[k])
            futures[k] = pool.submit(key_start[k + 1] - key_start[k], work, pool, task_bufs,
                                     task_counts[k], task_n[k], task_box[k], task_depth_of[k],
                                     task_budget[k], stage + 1)
        return nodes, leaf_tris, deepest, node, futures

    def gather(result):
        """A `work` result as a Subtree, once its tasks are done."""
        nodes, leaf_tris, deepest, node, futures = result
        subs = [gather(f.result()) for f in futures]
        return Subtree(nodes, leaf_tris, node, subs,
                       n_nodes=len(nodes) - len(node) + sum(s.n_nodes for s in subs),
                       n_refs=len(leaf_tris) + sum(s.n_refs for s in subs),
                       deepest=max([deepest] + [s.deepest for s in subs]))

    if pool is None:
        with concurrent.futures.ThreadPoolExecutor(threads) as own:
            return build_nodes(tri, keys, counts, bounds, *args, threads, max_refs_per_tri, own,
                               reuse)
    pool = LargestFirst(pool)
    try:
        root = work(pool, split_keys(keys, counts), counts, m, bounds, 0, budget, 0)
        held = keys if reuse and scratch.keeps(keys) else None
        del keys
        root = gather(root)
    except BaseException:
        pool.cancel()                       # the executor outlives the build
        raise
    out_nodes = np.empty((root.n_nodes, 2), dtype=np.uint32)
    out_refs = np.empty(root.n_refs, dtype=np.uint32)
    place(root, out_nodes, out_refs, 0, 0)
    if held is not None:
        scratch.give(held)
    return out_nodes, out_refs, root.deepest


@njit(cache=True, nogil=True)
def _place_top(nodes, leaf_tris, node, sub_nodes, sub_refs, out, out_refs, base, ref_base,
               sub_base, sub_ref_base):
    """Write a subtree whose placeholders stand for subtrees of their own into the
    whole tree's arrays, its root at out[base] and its first leaf reference at
    out_refs[ref_base], renumbering children and leaf offsets.

    nodes (n, 2) uint32, leaf_tris (r,) uint32 : the subtree, indices from its root;
    node (k,) int64 increasing : its placeholders; sub_nodes, sub_refs (k,) int64 : the
    nodes and leaf references of the subtree each stands for (its own placeholders
    filled in);  out (N, 2), out_refs (R,) uint32 : the tree's arrays.
    Writes sub_base, sub_ref_base (k,) int64: where each placeholder's subtree goes.
    Depth-first layout: a placeholder's subtree takes its place, so every later node
    moves down by that subtree's nodes less one, and leaves list their references
    in node order.
    """
    n = nodes.shape[0]
    k = len(node)
    if k == 0:                  # a task's own subtree: shift every index, copy the references
        _relocate(nodes, out, base, ref_base)
        out_refs[ref_base:ref_base + len(leaf_tris)] = leaf_tris
        return
    new_index = np.empty(n, dtype=np.int64)
    j = 0
    shift = base
    for i in range(n):
        new_index[i] = i + shift
        if j < k and node[j] == i:
            shift += sub_nodes[j] - 1
            j += 1
    j = 0
    r = ref_base
    for i in range(n):
        w = new_index[i]
        flags = nodes[i, 0]
        if j < k and node[j] == i:
            sub_base[j] = w
            sub_ref_base[j] = r
            r += sub_refs[j]
            j += 1
        elif flags & _LEAF == _LEAF:
            count = flags >> _U2
            first = nodes[i, 1]
            for c in range(count):
                out_refs[r + c] = leaf_tris[first + c]
            out[w, 0] = flags
            out[w, 1] = np.uint32(r)
            r += count
        else:
            out[w, 0] = (flags & _LEAF) | (np.uint32(new_index[flags >> _U2]) << _U2)
            out[w, 1] = nodes[i, 1]


class Subtree(typing.NamedTuple):
    """A task's result with the subtrees of its own tasks (`build_nodes`)."""
    nodes: np.ndarray           # (n, 2) uint32, indices from its root, placeholders as leaves
    leaf_tris: np.ndarray       # (r,) uint32
    placeholders: np.ndarray    # (k,) int64 increasing: nodes that stand for subs[j]
    subs: list                  # [k] Subtree
    n_nodes: int                # nodes of the whole subtree, placeholders filled in
    n_refs: int                 # leaf references of the whole subtree
    deepest: int                # depth of its deepest leaf


def place(sub, out, out_refs, base, ref_base):
    """Write Subtree `sub` and its tasks' subtrees, recursively, into the whole tree's
    arrays at out[base], out_refs[ref_base] (each node and reference written once,
    where the one-thread build puts it)."""
    k = len(sub.subs)
    sub_base = np.empty(k, dtype=np.int64)
    sub_ref_base = np.empty(k, dtype=np.int64)
    _place_top(sub.nodes, sub.leaf_tris, sub.placeholders,
               np.array([s.n_nodes for s in sub.subs], dtype=np.int64),
               np.array([s.n_refs for s in sub.subs], dtype=np.int64),
               out, out_refs, base, ref_base, sub_base, sub_ref_base)
    for s, b, rb in zip(sub.subs, sub_base, sub_ref_base):
        place(s, out, out_refs, int(b), int(rb))


@njit(cache=True, nogil=True, inline="always")
def _relocate(sub, out, base, ref_shift):
    """out[base:base + len(sub)] = sub with above_child + base and leaf_offset + ref_shift.

    sub, out : (n, 2) uint32 nodes;  base, ref_shift : int."""
    above_shift = np.uint32(base) << _U2
    for i in range(sub.shape[0]):
        if sub[i, 0] & _LEAF == _LEAF:
            out[base + i, 0] = sub[i, 0]
            out[base + i, 1] = sub[i, 1] + np.uint32(ref_shift)
        else:
            out[base + i, 0] = sub[i, 0] + above_shift
            out[base + i, 1] = sub[i, 1]
