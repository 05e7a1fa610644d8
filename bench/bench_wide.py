"""The wide nodes' build (kdray/wide.py: the 8-wide BVH that rays sharing no path walk)
beside the k-d tree's: its time, size and depth, made as a Tracer makes them at its
first trace of such rays.

usage: python bench/bench_wide.py [--meshes bunny,bunny-1.6M] [--repeat 3]

Prints per mesh the k-d build's time, the wide nodes' (`Tracer._wide`: the binary BVH,
its wide records and the triangle copies appended to the device buffers), the least
of --repeat runs each, and the wide nodes' count, levels and bytes on the device.
"""
import argparse
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from meshes import mesh as bench_mesh  # noqa: E402

import kdray  # noqa: E402
from kdray.wide import WIDE_WORDS  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--meshes", default="bunny,bunny-1.6M")
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    for name in args.meshes.split(","):
        m = bench_mesh(name)
        builds, wides = [], []
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            tree = kdray.build(m.vertices, m.faces)
            builds.append(time.perf_counter() - t0)
            tracer = kdray.Tracer(tree)
            if tracer.packet == 1:
                raise SystemExit("no packets on this device: no wide nodes")
            before = tracer.device_bytes
            t0 = time.perf_counter()
            records, levels = tracer._wide()
            wides.append(time.perf_counter() - t0)
        n = records.size // (WIDE_WORDS * 4)      # a device buffer's bytes
        print(f"{name}: {len(tree.triangles):,} triangles, k-d build {min(builds):.2f} s, "
              f"wide nodes {min(wides):.2f} s ({min(wides) / min(builds):.2f} of the build): "
              f"{n:,} wide nodes, {levels} levels, "
              f"+{(tracer.device_bytes - before) / 2**20:.1f} MiB on the device", flush=True)


if __name__ == "__main__":
    main()
