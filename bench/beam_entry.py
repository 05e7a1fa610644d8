"""How deep a shared entry point would start a group of rays: the prediction for beam or
frustum traversal (Reshetov, Soupikov & Hurley 2005, "Multi-Level Ray Tracing
Algorithm"), before building it.

usage: python bench/beam_entry.py [--meshes bunny,bunny-1.6M] [--size 1024]
                                  [--groups 3000] [--shapes row8,row16,row64,blk4x2,blk4x4,blk8x8]

A beam traversal finds, once per group of coherent rays, the deepest node whose region
holds every ray's segment in the scene's box (each node above it sends every ray of the
group to the same child), and starts each packet there. What it saves is the interior
steps above that node, which each packet otherwise takes (one vector step each, all
lanes agreeing). For random groups of the framing camera's rays (row-major pixels,
`Camera.frame`): rows of N consecutive rays (what `trace` gets from a caller's row-major
rays and what a work-item's run holds) and blocks of W x H pixels (`render`'s packets
are 4 x 2 or 4 x 4 blocks; a tile of 8 x 8 would hold several), the script finds that
node in float64 (a group whose rays all miss the box is counted apart) and prints its
mean depth against the interior steps of the packet kernel (STATS: the most any lane of
the group took, a lower bound of the packet's steps). Their ratio bounds the share of
descent steps a beam would save; the descent is about half of a render's time
(BENCHMARKS.md, "Where the time goes").
"""
import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from meshes import framed  # noqa: E402

import kdray  # noqa: E402
from kdray import layout  # noqa: E402


def entry_depth(tree, o, d):
    """Depth of the deepest node whose region holds every segment of the rays o + t d
    (o relative to the tree's origin, (n, 3) float64) inside the tree's box, t >= 0; None
    when every ray misses the box."""
    nodes = tree.nodes
    b = tree.bounds.astype(np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        ta, tb = (b[0] - o) / d, (b[1] - o) / d
        t0 = np.nanmax(np.minimum(ta, tb), axis=1).clip(0.0)
        t1 = np.nanmin(np.maximum(ta, tb), axis=1)
    on = t0 <= t1
    if not on.any():
        return None
    o, d, t0, t1 = o[on], d[on], t0[on], t1[on]
    node, depth = 0, 0
    while not layout.is_leaf(nodes[node:node + 1])[0]:
        k = int(layout.split_axis(nodes[node:node + 1])[0])
        s = float(layout.split(nodes[node:node + 1])[0])
        with np.errstate(divide="ignore", invalid="ignore"):
            t_split = (s - o[:, k]) / d[:, k]
        if np.any((t_split > t0) & (t_split < t1)):
            return depth                 # a segment crosses the plane: both children
        above = o[:, k] + d[:, k] * (0.5 * (t0 + t1)) >= s
        if above.all():
            node = int(layout.above_child(nodes[node:node + 1])[0])
        elif not above.any():
            node += 1
        else:
            return depth                 # rays on both sides
        depth += 1
    return depth


def groups(shape, size, n, rng):
    """n random groups of pixel indices of a size x size row-major image: "rowN" (N
    consecutive pixels, starting at a multiple of N) or "blkWxH"."""
    if shape.startswith("row"):
        width = int(shape[3:])
        for k0 in rng.integers(0, size * size // width, n) * width:
            yield np.arange(k0, k0 + width)
        return
    w, h = (int(v) for v in shape[3:].split("x"))
    for r0, c0 in zip(rng.integers(0, size // h, n) * h, rng.integers(0, size // w, n) * w):
        yield (np.arange(r0, r0 + h)[:, None] * size + np.arange(c0, c0 + w)[None, :]).ravel()


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--meshes", default="bunny,bunny-1.6M")
    ap.add_argument("--size", type=int, default=1024)
    ap.add_argument("--groups", type=int, default=3000)
    ap.add_argument("--shapes", default="row8,row16,row64,blk4x2,blk4x4,blk8x8")
    ap.add_argument("--device", default=None)
    args = ap.parse_args()
    print(f"{'mesh':<12} {'group':<8} {'miss box':>8} {'entry depth':>11} {'steps':>6} {'share':>6}")
    for name in args.meshes.split(","):
        _, tree, _, o, d = framed(name, args.size)
        steps = kdray.Tracer(tree, device=args.device)._trace(o, d, stats=True)[1][:, 0]
        o = o - tree.origin
        for shape in args.shapes.split(","):
            rng = np.random.default_rng(0)
            depths, most, missed = [], [], 0
            for rows in groups(shape, args.size, args.groups, rng):
                depth = entry_depth(tree, o[rows], d[rows])
                if depth is None:
                    missed += 1
                    continue
                depths.append(depth)
                most.append(int(steps[rows].max()))
            depths, most = np.array(depths, float), np.array(most, float)
            print(f"{name:<12} {shape:<8} {missed / args.groups:>8.2f} {depths.mean():>11.2f} "
                  f"{most.mean():>6.1f} {depths.sum() / max(most.sum(), 1):>6.3f}", flush=True)


if __name__ == "__main__":
    main()
