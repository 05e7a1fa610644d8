"""The packet kernels' KD_LANE_RATIO and KD_CULL_LANE_RATIO against trace speed.

usage: python bench/sweep_lane_ratio.py [--meshes bunny,bunny-1.6M] [--size 1024]
                                        [--ratios 0.5,0.25,0.35,0.75]
                                        [--cull-ratios 0.25,0,0.125,0.5]
                                        [--repeat 9] [--spread 1e-4]

A packet reaching a leaf of n triangles with a of its lanes active tests the leaf ray
by ray, 16 (or 8) triangles at a time, when a * ceil(n / 16) < ratio * n, and else
with all lanes at once (packet.cl, kd_packet_leaf); the hits are the same either way.
The ratio is KD_CULL_LANE_RATIO for a packet of one origin and shear, which culls the
leaf's triangles before its lanes test them, and KD_LANE_RATIO for the others.

--cull-ratios: KD_CULL_LANE_RATIO, on the framing camera's depth render and on a
trace of its rays numpy to numpy (t and prim). --ratios: KD_LANE_RATIO (0 compiles
the ray-by-ray path out for such packets), on a trace of the camera's rays from
origins spread over a patch --spread times the scene box's diagonal wide (a lens's or
a projector's): coherent packets of several origins. For each mesh (its tree built
once, default parameters) one Tracer per value (`Tracer._cull_lane_ratio`,
`Tracer._lane_ratio`), each sweep in one round robin (`timing.round_robin`, --repeat
rounds); "x r0" is the median of the rounds' time ratios to the first value listed
(< 1: faster). An empty list skips its sweep.
"""
import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_incoherent import spread_origins  # noqa: E402
from meshes import framed  # noqa: E402
from timing import median_ratio, round_robin  # noqa: E402

import kdray  # noqa: E402


def sweep(label, name, values, calls_of, repeat):
    """Time calls_of(value) -> {what: call} for each value in one round robin and print
    each call's median and its ratio to the first value's."""
    calls = {(what, v): call for v in values for what, call in calls_of(v).items()}
    seconds, _, _ = round_robin(calls, repeat)
    for v in values:
        row = [f"{name:<12} {label:<5} {v:>6g}"]
        for what in calls_of(values[0]):
            t = seconds[what, v]
            row.append(f"{what} {np.median(t):.4f} s x r0 {median_ratio(t, seconds[what, values[0]]):.3f}")
        print("  ".join(row), flush=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--meshes", default="bunny,bunny-1.6M")
    ap.add_argument("--ratios", default="0.5,0.25,0.35,0.75")
    ap.add_argument("--cull-ratios", default="0.25,0,0.125,0.5")
    ap.add_argument("--size", type=int, default=1024)
    ap.add_argument("--repeat", type=int, default=9)
    ap.add_argument("--spread", type=float, default=1e-4)
    args = ap.parse_args()
    ratios = [float(x) for x in args.ratios.split(",") if x]
    cull_ratios = [float(x) for x in args.cull_ratios.split(",") if x]
    for name in args.meshes.split(","):
        _, tree, camera, o, d = framed(name, args.size)
        if kdray.Tracer(tree).packet == 1:
            sys.exit("this device traces one ray a work-item: no packets")

        def one_origin(ratio):
            tracer = kdray.Tracer(tree)
            tracer._cull_lane_ratio = ratio
            return {"render": lambda: tracer.render(camera, aovs=("depth",)),
                    "trace": lambda: tracer.trace(o, d, outputs=())}

        spread = spread_origins(o, *tree.world_box(), args.spread)

        def origins(ratio):
            tracer = kdray.Tracer(tree)
            tracer._lane_ratio = ratio
            return {"trace": lambda: tracer.trace(spread, d, outputs=())}

        if cull_ratios:
            sweep("cull", name, cull_ratios, one_origin, args.repeat)
        if ratios:
            sweep("lane", name, ratios, origins, args.repeat)


if __name__ == "__main__":
    main()
