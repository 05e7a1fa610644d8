"""A prototype of the next lever for rays that share no path: an 8-wide BVH over small
leaves, walked by kdray's own wide walk (kernels/wide.cl) in place of the k-d tree's
wide nodes, timed against them on the same rays with the same hits required.

usage: python bench/proto_bvh8.py [--meshes bunny,bunny-1.6M] [--rays 1048576]
                                  [--leaf 16] [--split sah] [--repeat 5]

Rays: bench_incoherent.py's (from the box's centre, from random points in it),
bench_embree.py's ambient-occlusion rays and bench_queries.py's rays aimed at the
surface from around it.

The BVH: binary splits of the triangles sorted by centroid along the longest axis of
their centroids' box, at the multiple of 16 triangles (a packet's run) with the least
surface-area cost (--split median: at the median, rounded to a multiple of 16: what a
vectorized builder would find easiest, and --split fastmedian the same split made level by
level in numpy, `median_bvh_arrays`, timed; --split morton: the triangles in the Morton
order of their centroids, 30 bits, split where the highest bit that differs in the
range changes, a linear BVH's radix tree, whose leaves need not fill their runs),
down to leaves of at most --leaf triangles;
three binary levels make
one wide node (kdray/wide.py's record: 8 boxes, children, kinds, and per octant the
children in the order of their boxes' centres along the octant's diagonal, which need
not be front to back: the walk's pruning by entry t makes any order exact). The
leaves' triangles are copied in leaf order, each leaf on a multiple of 16, as
layout.device_triangles does for the k-d leaves.

It is built here in Python, node by node (about 40 s for bunny-1.6M): a measurement,
not a builder. The BVH goes into a second Tracer through its private buffers
(`_tris`, `_tri_ids`, `_wide_nodes`) with every packet traced ray by ray
(`_alone_spread` -1), so that its hits' triangle indices are the BVH's copies; the k-d
Tracer's and the BVH's hits must be the same triangles, and are (the walk's exactness
argument, wide.cl, does not depend on the tree). Not for kdray's users: a Tracer that
adopts the BVH needs its hits mapped back to the k-d copies (packets, refinement,
normals and the queries read those) and a real builder (BENCHMARKS.md, "Incoherent
rays").
"""
import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_embree import AO_OFFSET, ao_rays  # noqa: E402
from bench_incoherent import ray_sets  # noqa: E402
from bench_queries import aimed  # noqa: E402
from meshes import mesh as bench_mesh  # noqa: E402
from timing import round_robin  # noqa: E402

import kdray  # noqa: E402
from kdray.layout import MISS, TRI_BLOCK, triangle_blocks  # noqa: E402
from kdray.wide import EMPTY, LEAF, WIDE_WORDS, WIDTH  # noqa: E402


def _area(lo, hi):
    e = np.maximum(hi - lo, 0).astype(np.float64)
    return e[:, 0] * e[:, 1] + e[:, 1] * e[:, 2] + e[:, 2] * e[:, 0]


def binary_bvh(tris, leaf, split_at="sah"):
    """(root, leaves): a binary BVH over tris (n, 3, 3) float32 as nested tuples
    ("node", left, right) / ("leaf", i), and each leaf's triangle indices."""
    cent = tris.mean(axis=1).astype(np.float64)
    lo_t, hi_t = tris.min(axis=1), tris.max(axis=1)
    leaves = []

    def split(idx):
        if len(idx) <= leaf:
            leaves.append(idx)
            return ("leaf", len(leaves) - 1)
        c = cent[idx]
        axis = int(np.argmax(c.max(axis=0) - c.min(axis=0)))
        o = idx[np.argsort(c[:, axis], kind="stable")]
        n = len(o)
        if split_at == "median":
            k = max(TRI_BLOCK, n // 2 // TRI_BLOCK * TRI_BLOCK) if n > 2 * TRI_BLOCK else n // 2
            return ("node", split(o[:k]), split(o[k:]))
        cand = np.arange(TRI_BLOCK, n, TRI_BLOCK)
        if len(cand) == 0:
            cand = np.array([n // 2])
        lo_pre = np.minimum.accumulate(lo_t[o], axis=0)
        hi_pre = np.maximum.accumulate(hi_t[o], axis=0)
        lo_suf = np.minimum.accumulate(lo_t[o][::-1], axis=0)[::-1]
        hi_suf = np.maximum.accumulate(hi_t[o][::-1], axis=0)[::-1]
        cost = (_area(lo_pre[cand - 1], hi_pre[cand - 1]) * np.ceil(cand / TRI_BLOCK)
                + _area(lo_suf[cand], hi_suf[cand]) * np.ceil((n - cand) / TRI_BLOCK))
        k = int(cand[np.argmin(cost)])
        return ("node", split(o[:k]), split(o[k:]))

    sys.setrecursionlimit(max(10000, sys.getrecursionlimit()))
    if split_at == "morton":
        lo, hi = cent.min(axis=0), cent.max(axis=0)
        q = np.clip(((cent - lo) / np.maximum(hi - lo, 1e-300) * 1023).astype(np.int64), 0, 1023)
        code = np.zeros(len(q), np.int64)
        for b in range(10):
            for a in range(3):
                code |= ((q[:, a] >> b) & 1) << (3 * b + a)
        order = np.argsort(code, kind="stable")
        code = code[order]

        def radix(a, b):
            if b - a <= leaf:
                leaves.append(order[a:b])
                return ("leaf", len(leaves) - 1)
            diff = int(code[a] ^ code[b - 1])
            if diff == 0:
                k = a + (b - a) // 2
            else:
                bit = 1 << (diff.bit_length() - 1)
                k = a + int(np.searchsorted(code[a:b] & bit, bit))
            return ("node", radix(a, k), radix(k, b))
        return radix(0, len(tris)), leaves
    return split(np.arange(len(tris))), leaves


def median_bvh_arrays(tris, leaf):
    """A median-split binary BVH built level by level with numpy (the split that
    `binary_bvh(split_at="median")` makes, each level's segments sorted at once):
    (perm (n,) the triangles in leaf order, left, right (k,) int64 children or -1,
    first, count (k,) each node's range of perm, depth (k,))."""
    n = len(tris)
    cent = tris.mean(axis=1)
    perm = np.arange(n)
    left, right, first, count, depth = [np.array([-1])], [np.array([-1])], [np.array([0])], \
        [np.array([n])], [np.array([0])]
    seg = np.array([0]) if n > leaf else np.zeros(0, np.int64)   # active nodes
    s_first, s_count = np.array([0]), np.array([n])
    n_nodes, level = 1, 0
    left_all = np.full(4 * (n // max(leaf // 2, 1) + 2), -1, np.int64)
    right_all = left_all.copy()
    while len(seg):
        starts = np.cumsum(s_count) - s_count
        pos = np.repeat(s_first - starts, s_count) + np.arange(int(s_count.sum()))
        c = cent[perm[pos]]
        extent = np.maximum.reduceat(c, starts) - np.minimum.reduceat(c, starts)
        axis = np.argmax(extent, axis=1)
        seg_of = np.repeat(np.arange(len(seg)), s_count)
        key = c[np.arange(len(pos)), axis[seg_of]]
        perm[pos] = perm[pos][np.lexsort((key, seg_of))]
        k = np.where(s_count > 2 * leaf, np.maximum(leaf, s_count // 2 // leaf * leaf), leaf)
        ids = n_nodes + np.arange(2 * len(seg))
        left_all[seg], right_all[seg] = ids[0::2], ids[1::2]
        c_first = np.stack([s_first, s_first + k], axis=1).reshape(-1)
        c_count = np.stack([k, s_count - k], axis=1).reshape(-1)
        first.append(c_first)
        count.append(c_count)
        depth.append(np.full(len(ids), level + 1))
        n_nodes += len(ids)
        go = c_count > leaf
        seg, s_first, s_count = ids[go], c_first[go], c_count[go]
        level += 1
    return (perm, left_all[:n_nodes], right_all[:n_nodes], np.concatenate(first),
            np.concatenate(count), np.concatenate(depth))


def wide_bvh_fast(tree, leaf):
    """wide_bvh's outputs for median_bvh_arrays' tree, every step vectorized."""
    tris = np.asarray(tree.triangles, np.float32).reshape(-1, 3, 3)
    ids = np.asarray(tree.tri_ids, np.uint32)
    perm, left, right, first, count, depth = median_bvh_arrays(tris, leaf)
    is_leaf = left < 0
    # the leaves in perm order, each from a multiple of TRI_BLOCK
    leaves = np.flatnonzero(is_leaf)
    leaves = leaves[np.argsort(first[leaves])]
    size = -(-count[leaves] // TRI_BLOCK) * TRI_BLOCK
    start = np.cumsum(size) - size
    copy_of = np.full(len(first), -1, np.int64)
    copy_of[leaves] = start
    k = np.arange(int(size.sum())) - np.repeat(start, size)
    src = np.repeat(first[leaves], size) + k
    real = k < np.repeat(count[leaves], size)
    dev = np.zeros((int(size.sum()), 3, 3), np.float32)
    dev_ids = np.full(int(size.sum()), MISS, np.uint32)
    dev[real] = tris[perm[src[real]]]
    dev_ids[real] = ids[perm[src[real]]]
    # boxes: leaves from their triangles, then parents deepest first
    lo = np.zeros((len(first), 3), np.float32)
    hi = np.zeros((len(first), 3), np.float32)
    t_lo, t_hi = tris.min(axis=1)[perm], tris.max(axis=1)[perm]
    lo[leaves] = np.minimum.reduceat(t_lo, first[leaves])
    hi[leaves] = np.maximum.reduceat(t_hi, first[leaves])
    for d in range(int(depth.max()), -1, -1):
        at = np.flatnonzero((depth == d) & ~is_leaf)
        lo[at] = np.minimum(lo[left[at]], lo[right[at]])
        hi[at] = np.maximum(hi[left[at]], hi[right[at]])
    # wide nodes: the binary nodes at depths 0, 3, 6, ..., three levels each
    roots = np.flatnonzero(~is_leaf & (depth % 3 == 0)) if not is_leaf[0] else np.array([0])
    wide_index = np.full(len(first), -1, np.int64)
    wide_index[roots] = np.arange(len(roots))
    kid = roots[:, None]
    for _ in range(3):
        safe = np.maximum(kid, 0)
        inner = (kid >= 0) & ~is_leaf[safe]
        kid = np.stack([np.where(inner, left[safe], kid), np.where(inner, right[safe], -1)],
                       axis=2).reshape(len(roots), -1)
    kid = np.take_along_axis(kid, np.argsort(kid < 0, axis=1, kind="stable"), axis=1)
    has = kid >= 0
    safe = np.maximum(kid, 0)
    records = np.zeros((len(roots), WIDE_WORDS), np.uint32)
    rows = records[:, :6 * WIDTH].view(np.float32).reshape(len(roots), 6, WIDTH)
    rows[:, :3] = np.where(has[:, None, :], lo[safe].transpose(0, 2, 1), np.inf)
    rows[:, 3:] = np.where(has[:, None, :], hi[safe].transpose(0, 2, 1), -np.inf)
    leafy = has & is_leaf[safe]
    records[:, 6 * WIDTH:7 * WIDTH] = np.where(leafy, copy_of[safe], np.where(has, wide_index[safe], 0))
    records[:, 7 * WIDTH:8 * WIDTH] = np.where(leafy, LEAF | count[safe], np.where(has, 0, EMPTY))
    centre = 0.5 * (lo[safe].astype(np.float64) + hi[safe])
    for octant in range(8):
        sign = np.array([-1.0 if (octant >> a) & 1 else 1.0 for a in range(3)])
        key = np.where(has, centre @ sign, np.inf)
        order = np.argsort(key, axis=1, kind="stable").astype(np.int64)
        records[:, 8 * WIDTH + octant] = (order << (3 * np.arange(WIDTH))).sum(axis=1)
    return records, int(depth[roots].max()) // 3 + 1, dev, dev_ids


def wide_bvh(tree, leaf, split_at="sah"):
    """(records (m, WIDE_WORDS) uint32, levels, tris (k, 3, 3) float32, ids (k,)
    uint32): the BVH's wide nodes and its leaves' triangle copies (MISS padding)."""
    tris = np.asarray(tree.triangles, np.float32).reshape(-1, 3, 3)
    ids = np.asarray(tree.tri_ids, np.uint32)
    root, leaves = binary_bvh(tris, leaf, split_at)
    sizes = np.array([-(-len(x) // TRI_BLOCK) * TRI_BLOCK for x in leaves])
    starts = np.cumsum(sizes) - sizes
    dev = np.zeros((int(sizes.sum()), 3, 3), np.float32)
    dev_ids = np.full(int(sizes.sum()), MISS, np.uint32)
    box = {}
    for i, x in enumerate(leaves):
        dev[starts[i]:starts[i] + len(x)] = tris[x]
        dev_ids[starts[i]:starts[i] + len(x)] = ids[x]
        box[("leaf", i)] = (tris[x].min(axis=(0, 1)), tris[x].max(axis=(0, 1)))

    def bounds(nd):
        if nd[0] == "leaf":
            return box[nd]
        (a0, a1), (b0, b1) = bounds(nd[1]), bounds(nd[2])
        return np.minimum(a0, b0), np.maximum(a1, b1)

    records, deepest = [], [0]
    sign = np.array([[-1.0 if (o >> a) & 1 else 1.0 for a in range(3)] for o in range(8)])

    def wide(nd, depth):
        at = len(records)
        records.append(None)
        deepest[0] = max(deepest[0], depth)
        kids = [nd]
        for _ in range(3):
            kids = [c for k in kids for c in ((k[1], k[2]) if k[0] == "node" else (k,))]
        rec = np.zeros(WIDE_WORDS, np.uint32)
        rows = rec[:6 * WIDTH].view(np.float32).reshape(6, WIDTH)
        rows[:3], rows[3:] = np.inf, -np.inf
        rec[7 * WIDTH:8 * WIDTH] = EMPTY
        centre = np.zeros((WIDTH, 3))
        for s, k in enumerate(kids):
            lo, hi = bounds(k)
            rows[:3, s], rows[3:, s] = lo, hi
            centre[s] = 0.5 * (lo.astype(np.float64) + hi)
            if k[0] == "leaf":
                rec[6 * WIDTH + s] = starts[k[1]]
                rec[7 * WIDTH + s] = LEAF | len(leaves[k[1]])
            else:
                rec[6 * WIDTH + s] = wide(k, depth + 1)
                rec[7 * WIDTH + s] = 0
        for octant in range(8):
            key = np.where(np.arange(WIDTH) < len(kids), centre @ sign[octant], np.inf)
            order = np.argsort(key, kind="stable").astype(np.int64)
            rec[8 * WIDTH + octant] = int((order << (3 * np.arange(WIDTH))).sum())
        records[at] = rec
        return at

    wide(root, 0)
    return np.array(records), deepest[0] + 1, dev, dev_ids


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--meshes", default="bunny,bunny-1.6M")
    ap.add_argument("--rays", type=int, default=1 << 20)
    ap.add_argument("--leaf", type=int, default=16)
    ap.add_argument("--split", choices=("sah", "median", "morton", "fastmedian"), default="sah")
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    for name in args.meshes.split(","):
        m = bench_mesh(name)
        tree = kdray.build(m.vertices, m.faces)
        kd = kdray.Tracer(tree)
        bvh = kdray.Tracer(tree)
        bvh._alone_spread = -1.0
        import time
        t0 = time.perf_counter()
        if args.split == "fastmedian":
            records, levels, dev, dev_ids = wide_bvh_fast(tree, args.leaf)
        else:
            records, levels, dev, dev_ids = wide_bvh(tree, args.leaf, args.split)
        print(f"{name}: built in {time.perf_counter() - t0:.2f} s", flush=True)
        bvh._tris = bvh._tree_buffer(triangle_blocks(dev))
        bvh._tri_ids = bvh._tree_buffer(dev_ids)
        bvh._wide_nodes = (bvh._tree_buffer(records), levels)
        print(f"{name}: BVH {len(records)} wide nodes, {levels} levels, "
              f"{(records.nbytes + dev.nbytes) / 2**20:.1f} MiB; k-d wide nodes "
              f"{kd._wide()[1]} levels", flush=True)
        sets = ray_sets(tree, args.rays)
        lo, hi = (np.asarray(x, dtype=np.float64) for x in tree.world_box())
        sets["ambient occlusion"] = ao_rays(m, args.rays, np.random.default_rng(2),
                                            AO_OFFSET * np.linalg.norm(hi - lo))
        sets["aimed at the surface"] = aimed(m, tree, args.rays)
        for label, (o, d) in sets.items():
            wall, _, res = round_robin({"kd": lambda: kd.trace(o, d),
                                        "bvh": lambda: bvh.trace(o, d)}, args.repeat)
            ms = {k: float(np.median(v)) * 1e3 for k, v in wall.items()}
            same = np.array_equal(res["kd"].prim, res["bvh"].prim)
            print(f"  {label:<20} k-d {ms['kd']:7.1f} ms  BVH {ms['bvh']:7.1f} ms  "
                  f"BVH / k-d {ms['bvh'] / ms['kd']:.3f}  same triangles {same}", flush=True)
            if not same:
                raise SystemExit("the BVH's hits differ from the k-d tree's")


if __name__ == "__main__":
    main()
