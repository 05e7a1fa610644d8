"""The SAH's traversal cost K_T against build time, tree size and render speed.

usage: python bench/bench_sah.py [--meshes bunny,bunny-1.6M] [--k-t 15,30,60,100,160]
                                 [--size 1024] [--repeat 5]

Only the ratio K_T / K_I shapes the tree (K_I stays 20). For each mesh and K_T: build
time (warm), nodes and leaf references, a 1024 x 1024 depth render of the framing
camera and a numpy-to-numpy trace of the same rays (median of --repeat warm runs),
and per ray the interior nodes, leaves and triangle tests the kernel counted (its
STATS build). The default, K_T = 100, was chosen from this table: on the packet
kernels a node visit costs more than W&H's 15 (mostly cache misses), while a leaf's
triangles are tested 8 lanes at a time.
"""
import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from meshes import mesh as bench_mesh  # noqa: E402

import kdray  # noqa: E402
from kdray.bench import timed  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--meshes", default="bunny,bunny-1.6M")
    ap.add_argument("--k-t", default="15,30,60,100,160")
    ap.add_argument("--size", type=int, default=1024)
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    print(f"{'mesh':<12} {'K_T':>5} {'build s':>8} {'nodes':>10} {'refs':>10} {'render s':>9} "
          f"{'trace s':>8} {'nodes/ray':>9} {'leaves/ray':>10} {'tests/ray':>9}")
    for name in args.meshes.split(","):
        m = bench_mesh(name)
        kdray.build(m.vertices[:3], np.array([[0, 1, 2]]))           # compile the builder
        for k_t in (float(x) for x in args.k_t.split(",")):
            t0 = time.perf_counter()
            tree = kdray.build(m.vertices, m.faces, K_T=k_t)
            build_s = time.perf_counter() - t0
            lo, hi = tree.origin + tree.bounds.astype(np.float64)
            camera = kdray.Camera.frame(lo, hi, args.size, args.size)
            o, d = camera.rays()
            tracer = kdray.Tracer(tree)
            render_s = timed(lambda: tracer.render(camera, aovs=("depth",)), args.repeat)[0]
            trace_s = timed(lambda: tracer.trace(o, d), args.repeat)[0]
            _, stats = tracer._trace(o, d, stats=True)
            per_ray = stats.mean(axis=0)
            print(f"{name:<12} {k_t:>5g} {build_s:>8.3f} {len(tree.nodes):>10} {len(tree.leaf_tris):>10} "
                  f"{render_s:>9.4f} {trace_s:>8.4f} {per_ray[0]:>9.2f} {per_ray[1]:>10.2f} "
                  f"{per_ray[2]:>9.2f}", flush=True)


if __name__ == "__main__":
    main()
