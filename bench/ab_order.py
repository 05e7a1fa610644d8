"""Rays taken in kdray.ray_order's order against the same rays as they come, in turns:
what the order gains or costs, mesh by mesh and ray kind by ray kind, and where its
thresholds (ORDER_TREE_BYTES, ORDER_FROM, DIRECTION_ORDER_FROM) lie.

usage: python bench/ab_order.py [--meshes bunny,bunny-x4,bunny-1.6M]
                                [--kinds uniform,centre,ao,aimed] [--rays 1048576]
                                [--calls trace] [--rounds 3]

Rays: bench_embree.py's `uniform`, `centre` (one (3,) origin) and `ao`, and
bench_queries.py's `aimed` (from a sphere around the mesh to points on its surface),
float64. Calls: `trace` (t and prim), and any of `occluded`, `count`, `intersections`.
Each round times each call once ordered (the order forced for every tree size and
ray count: the keys on the device and their sort included) and once as the rays come
(ray_order answering None), in turns; prints the best of the rounds and their ratio
(ordered / as they come: < 1, the order pays), and checks the two gave the same hits.
"""
import argparse
import os
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

from bench_embree import rays_of  # noqa: E402
from bench_queries import aimed  # noqa: E402
from meshes import mesh as bench_mesh  # noqa: E402

import kdray  # noqa: E402
import kdray.ray_order as ray_order  # noqa: E402
import kdray.rays as krays  # noqa: E402
import kdray.trace as ktrace  # noqa: E402


def answer(tracer, call, o, d):
    """The call's answer, as arrays to compare."""
    if call == "trace":
        hits = tracer.trace(o, d, outputs=())
        return hits.t, hits.prim
    if call == "intersections":
        hits = tracer.intersections(o, d)
        return hits.offsets, hits.t, hits.prim
    return (getattr(tracer, call)(o, d),)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--meshes", default="bunny,bunny-x4,bunny-1.6M")
    ap.add_argument("--kinds", default="uniform,centre,ao,aimed")
    ap.add_argument("--rays", type=int, default=1 << 20)
    ap.add_argument("--calls", default="trace")
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args()
    ordered, as_they_come = ray_order.ray_order, (lambda *a: None)
    ray_order.ORDER_TREE_BYTES, ray_order.ORDER_FROM = 0, 1     # forced: a ray_order per call
    ray_order.DIRECTION_ORDER_FROM = 1
    print(f"# {args.rays} rays, best of {args.rounds} rounds in turns; ms ordered / as they come")
    for name in args.meshes.split(","):
        m = bench_mesh(name)
        tree = kdray.build(m.vertices, m.faces)
        tracer = kdray.Tracer(tree)

        class Args:
            rays, size = args.rays, 1024

        rng = np.random.default_rng(5)
        for kind in args.kinds.split(","):
            if kind == "aimed":
                o, d = aimed(m, tree, args.rays)
            else:
                o, d, _ = rays_of(kind, m, tree, Args, rng)
                if kind == "centre":
                    o = o[0]
            for call in args.calls.split(","):
                best = {}
                got = {}
                for _ in range(args.rounds):
                    for way, fn in (("ordered", ordered), ("as they come", as_they_come)):
                        ktrace.ray_order = krays.ray_order = fn
                        got[way] = answer(tracer, call, o, d)        # warm, and kept
                        start = time.perf_counter()
                        answer(tracer, call, o, d)
                        best[way] = min(best.get(way, np.inf), time.perf_counter() - start)
                same = all(np.array_equal(a, b, equal_nan=True)
                           for a, b in zip(got["ordered"], got["as they come"]))
                a, b = best["ordered"] * 1e3, best["as they come"] * 1e3
                print(f"{name:<11} {tracer.device_bytes / 2**20:6.1f} MB {kind:<8} {call:<13} "
                      f"{a:8.1f} / {b:8.1f} = {a / b:.2f}  {'same' if same else 'DIFFERENT'}",
                      flush=True)
        ktrace.ray_order = krays.ray_order = ordered


if __name__ == "__main__":
    main()
