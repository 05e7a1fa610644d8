"""Ray queries (kdray.rays) against kdray's own nearest hit on the same rays, in turns.

usage: python bench/bench_queries.py [--meshes bunny,bunny-1.6M] [--rays 1048576]
                                     [--repeat 3] [--device intel]

For each mesh, rays from random points in the tree's box in random directions (seeded),
and the same number of points for `contains`. Each round times, in turns
(timing.round_robin): `trace` (t and prim), `occluded`, `count`, `intersections` and
`contains`, numpy in and numpy out. Prints Mrays/s and each query's time against
trace's, and checks that occluded is trace's hit and intersections' first hit its
triangle. The peers (Open3D's test_occlusions, count_intersections,
list_intersections, compute_occupancy; trimesh with embreex) are not in it yet.
"""
import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from meshes import mesh as bench_mesh  # noqa: E402
from timing import round_robin  # noqa: E402

import kdray  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--meshes", default="bunny,bunny-1.6M")
    ap.add_argument("--rays", type=int, default=1 << 20)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--device", default=None)
    args = ap.parse_args()
    for name in args.meshes.split(","):
        m = bench_mesh(name)
        vertices, faces = m.vertices, m.faces
        tree = kdray.build(vertices, faces)
        tracer = kdray.Tracer(tree, device=args.device)
        lo, hi = (np.asarray(x, dtype=np.float64) for x in tree.world_box())
        rng = np.random.default_rng(1)
        o = lo + (hi - lo) * rng.random((args.rays, 3))
        d = rng.normal(size=(args.rays, 3))
        calls = {"trace": lambda: tracer.trace(o, d, outputs=()),
                 "occluded": lambda: tracer.occluded(o, d),
                 "count": lambda: tracer.count(o, d),
                 "intersections": lambda: tracer.intersections(o, d),
                 "contains": lambda: tracer.contains(o)}
        wall, _, results = round_robin(calls, args.repeat)
        hits = results["trace"]
        assert (results["occluded"] == hits.hit).all()
        listed = results["intersections"]
        first = listed.offsets[:-1][listed.counts > 0]
        assert (listed.prim[first] == hits.prim[hits.hit]).all()
        print(f"{name}: {len(faces):,} triangles, {args.rays:,} rays from random points in "
              f"the box, random directions, {kdray.device.describe(tracer.device)}")
        base = np.median(wall["trace"])
        for key, times in wall.items():
            best = float(np.min(times))
            print(f"  {key:<14} {args.rays / best / 1e6:7.2f} Mrays/s  "
                  f"{np.median(times) / base:5.2f} x trace's time")
        print(f"  hits a ray: {listed.counts.mean():.2f} listed, "
              f"{results['count'].mean():.2f} crossings; inside: {results['contains'].mean():.3f}")


if __name__ == "__main__":
    main()
