"""Rays taken in kdray.ray_order's order against the same rays as they come, in turns:
what the order gains or costs, mesh by mesh and ray kind by ray kind, and where its
thresholds (ORDER_TREE_BYTES, ORDER_FROM, DIRECTION_ORDER_FROM, FOLLOW_ORDER_FROM) lie.

usage: python bench/ab_order.py [--meshes bunny,bunny-x4,bunny-1.6M]
                                [--kinds uniform,centre,ao,aimed,light,sun]
                                [--rays 1048576]
                                [--calls trace] [--rounds 3] [--keys auto]
                                [--presorted] [--against-entry]

Rays: bench_embree.py's `uniform`, `centre` (one (3,) origin), `ao`, `light` and `sun`
(shadow rays from points on the mesh toward a point light, along the sun's direction), and
bench_queries.py's `aimed` (from a sphere around the mesh to points on its surface),
and `spread=S`: random directions from origins uniform in a cube of side S times the
box's longest side about its centre, in (N, 3) rows (where ray_order.CONCENTRATED
lies); `normals`: from points on the mesh (as ao's) into it along their triangle's
normal; `views=K`: from K eyes 1.5 box diagonals from its centre (random directions)
to points on the mesh, the eyes in random turns (where ray_order.FOLLOW_COS lies);
float64. --keys: `auto` (ray_order's choice), or `direction`, `cell` or `entry`
for every kind (ray_order.concentrated and ray_order.follow answering so). Calls:
`trace` (t and prim), and any
of `occluded`, `count`, `intersections`.
Each round times each call once ordered (the order forced for every tree size and
ray count: the keys on the device and their sort included) and once as the rays come
(ray_order answering None), in turns; prints the best of the rounds and their ratio
(ordered / as they come: < 1, the order pays), and checks the two gave the same hits.
With --presorted, also the same rays put in that order on the host beforehand (untimed)
and taken as they come: what the order would gain if its keys, sort and the kernel's
reads out of memory order cost nothing (ms, and / as they come); then where the
difference goes: `order given`, the rays as they come with their order made
beforehand (no keys, no sort), and `identity`, the presorted rays through the order
0, 1, 2, ... (the kernel's way with an order: each lane read and written by itself,
in memory order). With --against-entry, also the rays in the entry keys' order (octant,
then the 16^3 cell where a ray enters the box; ray_order.concentrated and follow
answering False), in the same turns: what the keys ray_order chose gain over those
(ms, and / as they come).
"""
import argparse
import os
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

from bench_embree import rays_of, surface_points  # noqa: E402
from bench_queries import aimed  # noqa: E402
from meshes import mesh as bench_mesh  # noqa: E402

import kdray  # noqa: E402
import kdray.ray_order as ray_order  # noqa: E402
from kdray.host import page_aligned_empty  # noqa: E402
import kdray.query_rays as kquery  # noqa: E402
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


def surface_rays(mesh, tree, kind, n, rng):
    """(o, d) (n, 3) float64: `normals` (from points on the triangles, uniform by area,
    into the mesh along each triangle's normal) or `views=K` (from K eyes around the
    box to such points, each ray's eye at random), origins moved 1e-5 of the box's
    diagonal along the ray."""
    lo, hi = (np.asarray(x, dtype=np.float64) for x in tree.world_box())
    diag = float(np.linalg.norm(hi - lo))
    p, normal = surface_points(mesh, n, rng)
    if kind == "normals":
        o, d = p, -normal
    else:
        eyes = rng.normal(size=(int(kind.split("=")[1]), 3))
        eyes = 0.5 * (lo + hi) + 1.5 * diag * eyes / np.linalg.norm(eyes, axis=1)[:, None]
        o = eyes[rng.integers(0, len(eyes), n)]
        d = p - o
    return o + 1e-5 * diag * d / np.linalg.norm(d, axis=1)[:, None], d


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--meshes", default="bunny,bunny-x4,bunny-1.6M")
    ap.add_argument("--kinds", default="uniform,centre,ao,aimed")
    ap.add_argument("--rays", type=int, default=1 << 20)
    ap.add_argument("--calls", default="trace")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--keys", default="auto", choices=("auto", "direction", "cell", "entry"))
    ap.add_argument("--presorted", action="store_true")
    ap.add_argument("--against-entry", action="store_true")
    args = ap.parse_args()
    if args.keys != "auto":
        ray_order.concentrated = lambda *a, **k: args.keys == "direction"
        ray_order.follow = lambda *a, **k: args.keys == "cell"
    ordered, as_they_come = ray_order.ray_order, (lambda *a: None)

    def entry_order(*a):
        """ray_order with the entry keys whatever the rays."""
        chosen = ray_order.concentrated, ray_order.follow
        ray_order.concentrated = ray_order.follow = lambda *x, **k: False
        try:
            return ordered(*a)
        finally:
            ray_order.concentrated, ray_order.follow = chosen
    ray_order.ORDER_TREE_BYTES, ray_order.ORDER_FROM = 0, 1     # forced: a ray_order per call
    ray_order.DIRECTION_ORDER_FROM = ray_order.FOLLOW_ORDER_FROM = 1
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
            elif kind == "normals" or kind.startswith("views="):
                o, d = surface_rays(m, tree, kind, args.rays, rng)
            elif kind.startswith("spread="):
                lo, hi = (np.asarray(x, dtype=np.float64) for x in tree.world_box())
                side = float(kind.split("=")[1]) * np.max(hi - lo)
                o = 0.5 * (lo + hi) + side * (rng.random((args.rays, 3)) - 0.5)
                d = rng.normal(size=(args.rays, 3))
            else:
                o, d, _ = rays_of(kind, m, tree, Args, rng)
                if kind == "centre":
                    o = o[0]
            ways = [("ordered", ordered, o, d), ("as they come", as_they_come, o, d)]
            if args.against_entry:
                ways.append(("entry keys", entry_order, o, d))
            if args.presorted:
                lo, hi = tracer.tree.world_box()
                order = ordered(tracer, o.reshape(-1, 3), d, lo, hi, int(o.ndim == 2))
                if order is not None:
                    o_sorted = np.ascontiguousarray(o[order]) if o.ndim == 2 else o
                    d_sorted = np.ascontiguousarray(d[order])
                    identity = page_aligned_empty((len(order),), np.uint32)
                    identity[:] = np.arange(len(order))
                    ways += [("presorted", as_they_come, o_sorted, d_sorted),
                             ("order given", lambda *a, **k: order, o, d),
                             ("identity", lambda *a, **k: identity, o_sorted, d_sorted)]
            for call in args.calls.split(","):
                best = {}
                got = {}
                for _ in range(args.rounds):
                    for way, fn, oo, dd in ways:
                        ktrace.ray_order = kquery.ray_order = fn
                        got[way] = answer(tracer, call, oo, dd)      # warm, and kept
                        start = time.perf_counter()
                        answer(tracer, call, oo, dd)
                        best[way] = min(best.get(way, np.inf), time.perf_counter() - start)
                same = all(np.array_equal(a, b, equal_nan=True)
                           for a, b in zip(got["ordered"], got["as they come"]))
                a, b = best["ordered"] * 1e3, best["as they come"] * 1e3
                pre = "".join(f"  {way} {best[way] * 1e3:8.1f} = {best[way] * 1e3 / b:.2f}"
                              for way in ("entry keys", "presorted", "order given", "identity")
                              if way in best)
                print(f"{name:<11} {tracer.device_bytes / 2**20:6.1f} MB {kind:<13} {call:<13} "
                      f"{a:8.1f} / {b:8.1f} = {a / b:.2f}  {'same' if same else 'DIFFERENT'}"
                      + pre, flush=True)
        ktrace.ray_order = kquery.ray_order = ordered


if __name__ == "__main__":
    main()
