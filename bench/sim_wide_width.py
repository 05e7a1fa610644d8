"""How many wide nodes and leaves a lone ray opens in BVHs of other widths: a float64
simulation of the wide walk (kdray/wide.py's binary BVH gathered by wide_children at
each width), to predict what wider nodes would save before building them.

usage: python bench/sim_wide_width.py [--meshes bunny,bunny-1.6M] [--rays 2000]
                                      [--widths 8,16] [--order nearest|octant]
                                      [--splits blocks|any]

Rays: origins uniform in the tree's box, directions uniform on the sphere (bench_embree's
`uniform`), seeded. The walk takes entries nearest first (a heap on where the ray enters
each box) and skips those entered beyond the best hit: an idealised order, the same at
every width, so the widths compare; --order octant takes them as kdray's kernels do (a
stack, each node's slots in the order of their centres along the ray's octant's
diagonal). Steps, not time: 16-wide nodes built as an experiment opened 22 % fewer
and traced in 0.97-1.03 of the time (BENCHMARKS.md, "Incoherent rays"). Leaves are
tested with a float64 Moller-Trumbore test. --splits any builds the binary BVH with
its splits after any triangle (the same cost, a leaf's run of TRI_BLOCK triangles
costing one test however full), not only after whole blocks as kdray/builder/bvh.py
does: numpy, slow (seconds for the bunny), for the simulation only. Prints, per mesh
and width, the wide nodes, their levels, the share of slots filled,
and the nodes opened and leaves tested a ray.
"""
import argparse
import heapq
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from meshes import mesh as bench_mesh  # noqa: E402

import kdray  # noqa: E402
from kdray import wide  # noqa: E402
from kdray.builder.bvh import wide_children  # noqa: E402


def nearest_t(tris, o, d):
    """The nearest t > 0 at which ray o + t d meets one of tris ((k, 3, 3) float64)."""
    v0 = tris[:, 0]
    e1, e2 = tris[:, 1] - v0, tris[:, 2] - v0
    p = np.cross(d, e2)
    det = (e1 * p).sum(1)
    with np.errstate(all="ignore"):
        inv = 1.0 / det
        s = o - v0
        u = (s * p).sum(1) * inv
        q = np.cross(s, e1)
        v = (d * q).sum(1) * inv
        t = (e2 * q).sum(1) * inv
    ok = (det != 0) & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0)
    return t[ok].min() if ok.any() else np.inf


def walk(o, d, kids, wide_of, left, first, count, order, boxes, tris, octant=False):
    """(nodes opened, leaves tested) by ray o + t d, nearest entry first, or with
    `octant` as the kernels take them: a stack, each node's met slots in the order of
    their boxes' centres along the ray's octant's diagonal (kdray/wide.py)."""
    with np.errstate(divide="ignore"):
        inv = 1.0 / d
    diagonal = np.where(d < 0, -1.0, 1.0)
    best, opened, tested = np.inf, 0, 0
    todo = [(0.0, False, 0)]                  # (entry t, is a leaf, wide node or leaf)
    while todo:
        t, is_leaf, i = todo.pop() if octant else heapq.heappop(todo)
        if t > best:
            if octant:
                continue
            break
        if is_leaf:
            tested += 1
            best = min(best, nearest_t(tris[order[first[i]:first[i] + count[i]]], o, d))
            continue
        opened += 1
        slots = kids[i] >= 0
        c = kids[i][slots]
        with np.errstate(invalid="ignore"):
            ta = (boxes[c, :3] - o) * inv
            tb = (boxes[c, 3:] - o) * inv
        enter = np.maximum(np.nanmax(np.minimum(ta, tb), axis=1), 0.0)
        leave = np.minimum(np.nanmin(np.maximum(ta, tb), axis=1), best)
        met = [(k, (a, left[child] < 0, child if left[child] < 0 else w))
               for k, (child, a, b, w) in enumerate(zip(c, enter, leave, wide_of[i][slots]))
               if a <= b]
        if octant:
            # the slots' rank along the diagonal; pushed last first, so popped first first
            rank = np.argsort(np.argsort((boxes[c, :3] + boxes[c, 3:]) @ diagonal,
                                         kind="stable"))
            todo.extend(e for _, e in sorted(met, key=lambda m: -rank[m[0]]))
        else:
            for _, e in met:
                heapq.heappush(todo, e)
    return opened, tested


def _half_area(lo, hi):
    e = np.maximum(hi - lo, 0.0)
    return e[..., 0] * e[..., 1] + e[..., 1] * e[..., 2] + e[..., 2] * e[..., 0]


def any_split_bvh(tree, block):
    """wide.binary_bvh's (order, left, right, first, count, depth, box) with splits after
    any triangle: C(k) = SA(left) ceil(k / block) + SA(right) ceil((n - k) / block)
    over every k and axis (sorted by the boxes' centres), leaves of at most `block`."""
    listed = np.zeros(len(tree.triangles), bool)
    listed[np.asarray(tree.leaf_tris, np.intp)] = True
    listed = np.flatnonzero(listed)
    t = np.asarray(tree.triangles, np.float32)[listed]
    boxes = np.concatenate([t.min(axis=1), t.max(axis=1)], axis=1)
    centre = boxes[:, :3] + boxes[:, 3:]
    order = np.arange(len(t))
    left, right, first, count, depth, box = [-1], [-1], [0], [len(t)], [0], [None]
    stack = [0]
    while stack:
        node = stack.pop()
        a, c = first[node], count[node]
        ids = order[a:a + c]
        box[node] = np.concatenate([boxes[ids, :3].min(axis=0), boxes[ids, 3:].max(axis=0)])
        if c <= block:
            continue
        best = (np.inf, 0, ids)
        k = np.arange(1, c)
        for axis in range(3):
            s = ids[np.argsort(centre[ids, axis], kind="stable")]
            b = boxes[s]
            lo_l, hi_l = np.minimum.accumulate(b[:, :3]), np.maximum.accumulate(b[:, 3:])
            lo_r = np.minimum.accumulate(b[::-1, :3])[::-1]
            hi_r = np.maximum.accumulate(b[::-1, 3:])[::-1]
            cost = (_half_area(lo_l[k - 1], hi_l[k - 1]) * np.ceil(k / block)
                    + _half_area(lo_r[k], hi_r[k]) * np.ceil((c - k) / block))
            j = int(np.argmin(cost))
            if cost[j] < best[0]:
                best = (cost[j], int(k[j]), s)
        _, split, order[a:a + c] = best
        for start, n in ((a, split), (a + split, c - split)):
            left.append(-1); right.append(-1); first.append(start); count.append(n)
            depth.append(depth[node] + 1); box.append(None)
        left[node], right[node] = len(left) - 2, len(left) - 1
        stack += [len(left) - 1, len(left) - 2]
    return (listed[order], np.array(left), np.array(right), np.array(first), np.array(count),
            np.array(depth), np.array(box, np.float32))


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--meshes", default="bunny,bunny-1.6M")
    ap.add_argument("--rays", type=int, default=2000)
    ap.add_argument("--widths", default="8,16")
    ap.add_argument("--order", default="nearest", choices=("nearest", "octant"))
    ap.add_argument("--splits", default="blocks", choices=("blocks", "any"))
    args = ap.parse_args()
    for name in args.meshes.split(","):
        m = bench_mesh(name)
        tree = kdray.build(m.vertices, m.faces)
        if args.splits == "any":
            bvh = any_split_bvh(tree, kdray.layout.TRI_BLOCK)
            order, left, right, first, count, _, box = bvh
        else:
            order, left, right, first, count, _, box = wide.binary_bvh(tree)
        tris = np.asarray(tree.triangles, np.float64).reshape(-1, 3, 3)
        lo, hi = np.asarray(tree.bounds, np.float64).reshape(2, 3)
        rng = np.random.default_rng(5)
        origins = lo + rng.random((args.rays, 3)) * (hi - lo)
        directions = rng.normal(size=(args.rays, 3))
        boxes = box.astype(np.float64)
        for width in (int(w) for w in args.widths.split(",")):
            kids, wide_of, depth = wide_children(left, right, box, width)
            steps = np.array([walk(o, d, kids, wide_of, left, first, count, order, boxes, tris,
                                   args.order == "octant")
                              for o, d in zip(origins, directions)])
            print(f"{name:<11} width {width:>2}, splits {args.splits}: {len(kids):>6} wide "
                  f"nodes, {(left < 0).sum()} leaves, {depth.max() + 1} "
                  f"levels, {np.mean(kids >= 0):.2f} of slots filled; a ray opens "
                  f"{steps[:, 0].mean():.2f} nodes and tests {steps[:, 1].mean():.2f} leaves",
                  flush=True)


if __name__ == "__main__":
    main()
