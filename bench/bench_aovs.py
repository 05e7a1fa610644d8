"""What each output set costs a render: the same camera, one AOV set at a time.

usage: python bench/bench_aovs.py [--mesh bunny] [--size 1024] [--repeat 5]

Prints the median of --repeat warm renders per AOV set, all in one process and one
Tracer, so the sets are compared under the same conditions.
"""
import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from meshes import mesh as bench_mesh  # noqa: E402

import kdray  # noqa: E402

SETS = [("depth",), ("id",), ("bary",), ("normal",), ("distance",), ("position",),
        ("depth", "normal", "bary", "id")]


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--mesh", default="bunny")
    ap.add_argument("--size", type=int, default=1024)
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    m = bench_mesh(args.mesh)
    tree = kdray.build(m.vertices, m.faces)
    lo, hi = tree.origin + tree.bounds.astype(np.float64)
    camera = kdray.Camera.frame(lo, hi, args.size, args.size)
    tracer = kdray.Tracer(tree)
    print(f"# {args.mesh}, {args.size}x{args.size}, median of {args.repeat} warm renders")
    for aovs in SETS:
        tracer.render(camera, aovs=aovs)
        times = []
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            tracer.render(camera, aovs=aovs)
            times.append(time.perf_counter() - t0)
        print(f"{','.join(aovs):<24} {np.median(times) * 1000:8.1f} ms", flush=True)


if __name__ == "__main__":
    main()
