"""Incoherent rays: kdray (packets and single rays) against Open3D on rays in random
directions, in turns.

usage: python bench/bench_incoherent.py [--meshes bunny,bunny-1.6M] [--rays 100000]
                                        [--repeat 5] [--device intel]

For each mesh, two sets of rays in random directions (seeded): all from the centre of
the tree's box, and from random points inside it. Each round times, in turns
(timing.round_robin), `Tracer.trace` with the device's packets, with single rays
(`packet=1`) and Open3D's `cast_rays` (peers.open3d_cast, numpy to numpy). The two
kdray Tracers must give the same triangles. Also prints each ray's mean work (interior
nodes, leaves, triangle tests: `Tracer._trace(stats=True)`). Such rays share no
nodes, so packets cannot help: this is the single-ray kernel's speed.
"""
import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from meshes import mesh as bench_mesh  # noqa: E402
from peers import open3d_cast, open3d_scene  # noqa: E402
from timing import round_robin  # noqa: E402

import kdray  # noqa: E402


def ray_sets(tree, n, seed=1):
    """{name: (origins (n, 3), directions (n, 3))} float64, world coordinates."""
    lo, hi = (np.asarray(x, dtype=np.float64) for x in tree.world_box())
    rng = np.random.default_rng(seed)
    return {"from the centre": (np.tile(0.5 * (lo + hi), (n, 1)), rng.normal(size=(n, 3))),
            "from random points": (lo + (hi - lo) * rng.random((n, 3)), rng.normal(size=(n, 3)))}


def spread_origins(o, lo, hi, spread, seed=0):
    """o (N, 3) moved by normal offsets of spread times the box (lo, hi)'s diagonal: a
    camera's rays from a patch (a lens's or a projector's), packets of several origins."""
    return o + np.random.default_rng(seed).normal(size=o.shape) * spread * np.linalg.norm(hi - lo)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--meshes", default="bunny,bunny-1.6M")
    ap.add_argument("--rays", type=int, default=100_000)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--device", default=None)
    args = ap.parse_args()
    print(f"{'mesh':<12}{'rays':<20}{'packets ms':>11}{'single ms':>10}{'open3d ms':>10}"
          f"{'hit':>6}{'nodes':>7}{'leaves':>7}{'tests':>7}")
    for name in args.meshes.split(","):
        m = bench_mesh(name)
        tree = kdray.build(m.vertices, m.faces)
        packets = kdray.Tracer(tree, device=args.device)
        single = kdray.Tracer(tree, device=args.device, packet=1)
        scene, _ = open3d_scene(m)
        for label, (o, d) in ray_sets(tree, args.rays).items():
            wall, _, res = round_robin({"packets": lambda: packets.trace(o, d),
                                        "single": lambda: single.trace(o, d),
                                        "open3d": lambda: open3d_cast(scene, o, d)}, args.repeat)
            if not np.array_equal(res["packets"].prim, res["single"].prim):
                raise SystemExit(f"{name} {label}: packets and single rays disagree")
            _, stats = single._trace(o, d, stats=True)
            work = stats[:, :3].mean(axis=0)
            ms = {k: 1e3 * np.median(v) for k, v in wall.items()}
            print(f"{name:<12}{label:<20}{ms['packets']:>11.2f}{ms['single']:>10.2f}"
                  f"{ms['open3d']:>10.2f}{np.mean(res['single'].hit):>6.2f}"
                  f"{work[0]:>7.1f}{work[1]:>7.1f}{work[2]:>7.1f}", flush=True)


if __name__ == "__main__":
    main()
