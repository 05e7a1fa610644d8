"""The first call of each query on a fresh install after `kdray setup`: what compiling
its program costs a user, and the same call again.

    .venv/bin/python bench/bench_first_calls.py [--mesh scenes/cornell.obj] [--turns 2]

Each turn runs, in fresh processes with an empty XDG_CACHE_HOME of its own (pyopencl's
program cache; the builder's numba cache stays as installed): `kdray setup`, timed,
then one process that calls render, trace (1,000 rays in no order, then the camera's
rays), occluded, count, intersections, contains (8,192 points: their order's
program too), closest_points and signed_distance on the mesh, each twice, and prints
the seconds of both calls.
"""
import argparse
import os
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)

CHILD = r"""
import sys, time
import numpy as np
import kdray
mesh = kdray.load(sys.argv[1])
tracer = kdray.Tracer(kdray.build(mesh.vertices, mesh.faces))
lo, hi = tracer.tree.world_box()
rng = np.random.default_rng(0)
o = rng.uniform(lo, hi, (1000, 3))
d = rng.normal(size=(1000, 3))
points = rng.uniform(lo, hi, (8192, 3))     # from 4,096 points contains orders them
camera = kdray.Camera.look_at(hi + (hi - lo), (lo + hi) / 2, width=320, height=240)
calls = [("render", lambda: tracer.render(camera)),
         ("trace, rays in no order", lambda: tracer.trace(o, d)),
         ("trace, the camera's rays", lambda: tracer.trace(*tracer.camera_rays(camera))),
         ("occluded", lambda: tracer.occluded(o, d)),
         ("count", lambda: tracer.count(o, d)),
         ("intersections", lambda: tracer.intersections(o, d)),
         ("contains (8,192 points)", lambda: tracer.contains(points)),
         ("closest_points", lambda: tracer.closest_points(o)),
         ("signed_distance", lambda: tracer.signed_distance(o))]
for name, call in calls:
    t0 = time.perf_counter(); call(); first = time.perf_counter() - t0
    t0 = time.perf_counter(); call(); again = time.perf_counter() - t0
    print(f"{name}\t{first:.2f}\t{again:.3f}", flush=True)
"""


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--mesh", default=os.path.join(ROOT, "scenes", "cornell.obj"))
    parser.add_argument("--turns", type=int, default=2)
    args = parser.parse_args()
    kdray_cli = os.path.join(os.path.dirname(sys.executable), "kdray")
    for turn in range(args.turns):
        with tempfile.TemporaryDirectory(prefix="kdray-first-calls-") as cache:
            env = dict(os.environ, XDG_CACHE_HOME=cache)
            t0 = time.perf_counter()
            subprocess.run([kdray_cli, "setup"], env=env, check=True, capture_output=True)
            print(f"turn {turn + 1}: kdray setup {time.perf_counter() - t0:.2f} s (wall)")
            out = subprocess.run([sys.executable, "-c", CHILD, args.mesh], env=env, check=True,
                                 capture_output=True, text=True).stdout
            for line in out.splitlines():
                name, first, again = line.split("\t")
                print(f"  {name}: first {first} s, again {again} s")


if __name__ == "__main__":
    main()
