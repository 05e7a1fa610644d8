"""The SAH's traversal cost K_T against build time, tree size and render speed.

usage: python bench/bench_sah.py [--meshes bunny,bunny-1.6M] [--k-t 140,170,200,240]
                                 [--size 1024] [--repeat 9] [--incoherent]

Only the ratio K_T / K_I shapes the tree (K_I stays 20). For each mesh, the trees of
every K_T are built in turns (--repeat rounds, a third of them from 1M triangles
up, at least 2; median build time), then a
1024 x 1024 depth render of the framing camera and a numpy-to-numpy trace of the same
rays run in turns over all the trees (--repeat rounds, median), so that the machine's
drift in speed hits every K_T alike; x K_T0 is the median of the rounds' time ratios
to the first K_T listed (< 1: faster). Per ray, the interior nodes, leaves and triangle
tests the kernel counted (its STATS build). With --incoherent, two more calls in the
same turns: traces of bench_incoherent.py's 100,000 rays in random directions from
the box's centre and from random points in it (x K_T0 each). The defaults (kdray.tree.auto_K_T) were chosen from
this table: on the packet kernels a node visit costs more than W&H's 15 (mostly cache
misses), while a leaf's triangles are tested a packet's 8 or 16 lanes at a time.
"""
import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_incoherent import ray_sets  # noqa: E402
from meshes import mesh as bench_mesh  # noqa: E402

import kdray  # noqa: E402
from timing import median_ratio, round_robin  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--meshes", default="bunny,bunny-1.6M")
    ap.add_argument("--k-t", default="140,170,200,240")
    ap.add_argument("--size", type=int, default=1024)
    ap.add_argument("--repeat", type=int, default=9)
    ap.add_argument("--incoherent", action="store_true",
                    help="also time 100,000 rays in random directions (two sets)")
    args = ap.parse_args()
    k_ts = [float(x) for x in args.k_t.split(",")]
    print(f"{'mesh':<12} {'K_T':>5} {'build s':>8} {'x K_T0':>7} {'nodes':>10} {'refs':>10} "
          f"{'render s':>9} {'x K_T0':>7} {'trace s':>8} {'x K_T0':>7} {'nodes/ray':>9} "
          f"{'leaves/ray':>10} {'tests/ray':>9}"
          + (f" {'centre x K_T0':>13} {'points x K_T0':>13}" if args.incoherent else ""))
    for name in args.meshes.split(","):
        m = bench_mesh(name)
        kdray.build(np.eye(3), np.array([[0, 1, 2]]))                  # compile the builder
        build_s, _, trees = round_robin(
            {k_t: (lambda k_t=k_t: kdray.build(m.vertices, m.faces, K_T=k_t)) for k_t in k_ts},
            max(2, args.repeat if len(m.faces) < 1_000_000 else args.repeat // 3))
        lo, hi = trees[k_ts[0]].world_box()
        camera = kdray.Camera.frame(lo, hi, args.size, args.size)
        o, d = camera.rays()
        incoherent = ray_sets(trees[k_ts[0]], 100_000) if args.incoherent else {}
        tracers = {k_t: kdray.Tracer(tree) for k_t, tree in trees.items()}
        calls = {}
        for k_t, tracer in tracers.items():
            calls["render", k_t] = lambda t=tracer: t.render(camera, aovs=("depth",))
            calls["trace", k_t] = lambda t=tracer: t.trace(o, d)
            for label, (oi, di) in incoherent.items():
                calls[label, k_t] = lambda t=tracer, oi=oi, di=di: t.trace(oi, di)
        seconds, _, _ = round_robin(calls, args.repeat)
        for k_t, tracer in tracers.items():
            tree = trees[k_t]
            per_ray = tracer._trace(o, d, stats=True)[1].mean(axis=0)
            row = [f"{name:<12} {k_t:>5g}",
                   f"{np.median(build_s[k_t]):>8.3f} {median_ratio(build_s[k_t], build_s[k_ts[0]]):>7.3f}",
                   f"{len(tree.nodes):>10} {len(tree.leaf_tris):>10}"]
            for what, width in (("render", 9), ("trace", 8)):
                t = seconds[what, k_t]
                row.append(f"{np.median(t):>{width}.4f} {median_ratio(t, seconds[what, k_ts[0]]):>7.3f}")
            row.append(f"{per_ray[0]:>9.2f} {per_ray[1]:>10.2f} {per_ray[2]:>9.2f}")
            for label in incoherent:
                row.append(f"{median_ratio(seconds[label, k_t], seconds[label, k_ts[0]]):>13.3f}")
            print(" ".join(row), flush=True)


if __name__ == "__main__":
    main()
