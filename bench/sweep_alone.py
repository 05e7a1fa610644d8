"""Packets traversed together against their rays traced alone (packet.cl, kd_alone), in
turns, over how far apart a packet's origins and directions lie: the measurements
behind KD_ALONE_SPREAD.

usage: python bench/sweep_alone.py [--mesh bunny] [--spreads 0.01,0.03,0.1,0.3,1]
                                   [--angles 1,30,180] [--rays 100000] [--repeat 5]

Each packet's 16 consecutive rays (the Tracer's packet width; 8 on AVX2) leave points
in a cube of side `spread` times the tree's box around a random centre inside the box,
in directions uniform in a cone of half-angle `angle` degrees around a random axis.
Times `Tracer.trace` with the kernel's rule off (`_alone_spread` inf: every packet
traversed as a packet) and with every packet traced alone (`_alone_spread` -1), in
turns (timing.round_robin), and checks that both give the same hits.
"""
import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from meshes import mesh as bench_mesh  # noqa: E402
from timing import round_robin  # noqa: E402

import kdray  # noqa: E402


def cone_rays(lo, hi, n, group, spread, angle, rng):
    """(origins, directions) (n, 3) float64: groups of `group` rays, each from a cube of
    side spread * (hi - lo) around a random point of the box, in a cone of half-angle
    `angle` degrees around a random axis."""
    k = n // group
    axis = rng.normal(size=(k, 3))
    axis = np.repeat(axis / np.linalg.norm(axis, axis=1)[:, None], group, axis=0)
    c = 1.0 - rng.random(k * group) * (1.0 - np.cos(np.radians(angle)))
    phi = 2.0 * np.pi * rng.random(k * group)
    other = np.where(np.abs(axis[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    u = np.cross(axis, other)
    u /= np.linalg.norm(u, axis=1)[:, None]
    v = np.cross(axis, u)
    s = np.sqrt(1.0 - c * c)[:, None]
    d = c[:, None] * axis + s * (np.cos(phi)[:, None] * u + np.sin(phi)[:, None] * v)
    centre = np.repeat(lo + (hi - lo) * rng.random((k, 3)), group, axis=0)
    o = centre + spread * (hi - lo) * (rng.random((k * group, 3)) - 0.5)
    return o, d


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mesh", default="bunny")
    ap.add_argument("--spreads", default="0.01,0.03,0.1,0.3,1")
    ap.add_argument("--angles", default="1,30,180")
    ap.add_argument("--rays", type=int, default=100_000)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--device", default=None)
    args = ap.parse_args()
    m = bench_mesh(args.mesh)
    tree = kdray.build(m.vertices, m.faces)
    packets = kdray.Tracer(tree, device=args.device)
    packets._alone_spread = np.inf
    alone = kdray.Tracer(tree, device=args.device)
    alone._alone_spread = -1.0
    lo, hi = (np.asarray(x, dtype=np.float64) for x in tree.world_box())
    rng = np.random.default_rng(3)
    print(f"{args.mesh}, packets of {packets.packet}")
    print(f"{'spread':>7}{'angle':>6}{'packets ms':>11}{'alone ms':>9}{'alone / packets':>16}{'hit':>6}")
    for spread in (float(x) for x in args.spreads.split(",")):
        for angle in (float(x) for x in args.angles.split(",")):
            o, d = cone_rays(lo, hi, args.rays, packets.packet, spread, angle, rng)
            wall, _, res = round_robin({"packets": lambda: packets.trace(o, d),
                                        "alone": lambda: alone.trace(o, d)}, args.repeat)
            if not (np.array_equal(res["packets"].prim, res["alone"].prim)
                    and np.array_equal(res["packets"].t, res["alone"].t)):
                raise SystemExit(f"spread {spread}, angle {angle}: the two disagree")
            ms = {k: 1e3 * np.median(v) for k, v in wall.items()}
            print(f"{spread:>7g}{angle:>6g}{ms['packets']:>11.1f}{ms['alone']:>9.1f}"
                  f"{ms['alone'] / ms['packets']:>16.3f}{np.mean(res['alone'].hit):>6.2f}",
                  flush=True)


if __name__ == "__main__":
    main()
