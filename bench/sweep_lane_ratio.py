"""The packet kernels' KD_LANE_RATIO against render and trace speed.

usage: python bench/sweep_lane_ratio.py [--meshes bunny,bunny-1.6M]
                                        [--ratios 0.5,0.25,0.35,0.75] [--size 1024]
                                        [--repeat 9]

A packet reaching a leaf of n triangles with a of its lanes active tests the leaf ray
by ray, 16 (or 8) triangles at a time, when a * ceil(n / 16) < KD_LANE_RATIO * n, and
else triangle by triangle for all lanes at once (packet.cl, kd_packet_leaf); the hits
are the same either way. A ratio of 0 compiles the ray-by-ray path out. For each mesh
(its tree built once, default parameters) one Tracer per ratio (`Tracer._lane_ratio`)
renders the framing camera's depth image and traces its rays numpy to numpy (t and
prim), all in one round robin (`timing.round_robin`, --repeat rounds); "x r0" is the
median of the rounds' time ratios to the first ratio listed (< 1: faster).
"""
import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from meshes import framed  # noqa: E402
from timing import median_ratio, round_robin  # noqa: E402

import kdray  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--meshes", default="bunny,bunny-1.6M")
    ap.add_argument("--ratios", default="0.5,0.25,0.35,0.75")
    ap.add_argument("--size", type=int, default=1024)
    ap.add_argument("--repeat", type=int, default=9)
    args = ap.parse_args()
    ratios = [float(x) for x in args.ratios.split(",")]
    print(f"{'mesh':<12} {'ratio':>6} {'render s':>9} {'x r0':>6} {'trace s':>8} {'x r0':>6}")
    for name in args.meshes.split(","):
        _, tree, camera, o, d = framed(name, args.size)
        calls = {}
        for ratio in ratios:
            tracer = kdray.Tracer(tree)
            if tracer.packet == 1:
                sys.exit(f"{tracer.device.name.strip()} traces one ray a work-item: no packets")
            tracer._lane_ratio = ratio
            calls["render", ratio] = lambda t=tracer: t.render(camera, aovs=("depth",))
            calls["trace", ratio] = lambda t=tracer: t.trace(o, d, outputs=())
        seconds, _, _ = round_robin(calls, args.repeat)
        for ratio in ratios:
            row = [f"{name:<12} {ratio:>6g}"]
            for what, width in (("render", 9), ("trace", 8)):
                t = seconds[what, ratio]
                row.append(f"{np.median(t):>{width}.4f} {median_ratio(t, seconds[what, ratios[0]]):>6.3f}")
            print(" ".join(row), flush=True)


if __name__ == "__main__":
    main()
