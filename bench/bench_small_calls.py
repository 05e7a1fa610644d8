"""Small calls: what one call of each query costs when it has few rays or points (a
robot's or a game's few rays a step, picking under a cursor), beside Open3D's.

usage: python bench/bench_small_calls.py [--mesh bunny] [--sizes 1,100,10000]
                                         [--calls 200] [--rounds 3] [--pause 0]
                                         [--device SPEC]

Rays from random points in the mesh's box in random directions (seeded, float64),
points the same origins. Each round times --calls calls of each method back to back
(the methods in turns, a round after another; with --pause S each call S seconds
after the one before: a robot's or a game's loop, whose calls find the machine idle),
and the script prints each one's median over all calls of all rounds, in microseconds
a call, numpy in and numpy out:

  kdray trace          Tracer.trace(o, d, outputs=()): t and prim
  kdray occluded       Tracer.occluded(o, d)
  kdray count          Tracer.count(o, d)
  kdray intersections  Tracer.intersections(o, d)
  kdray contains       Tracer.contains(points)
  kdray distance       Tracer.distance(points)
  open3d cast_rays, test_occlusions, count_intersections, compute_distance
                       RaycastingScene's, rays as one (N, 6) float32 Tensor made in
                       the call, results to numpy

A call's fixed cost (checks, buffers, a kernel launch and its wait) shows at 1 and 100
rays; at 10,000 the rays' own time takes over. Open3D is left out with a note where it
is not installed.
"""
import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_trace import cpu_model, peer_versions  # noqa: E402
from meshes import mesh as bench_mesh  # noqa: E402
from peers import open3d_scene  # noqa: E402

import kdray  # noqa: E402


def kdray_calls(tracer, o, d):
    return {"kdray trace": lambda: tracer.trace(o, d, outputs=()),
            "kdray occluded": lambda: tracer.occluded(o, d),
            "kdray count": lambda: tracer.count(o, d),
            "kdray intersections": lambda: tracer.intersections(o, d),
            "kdray contains": lambda: tracer.contains(o),
            "kdray distance": lambda: tracer.distance(o)}


def open3d_calls(scene, o, d):
    import open3d as o3d

    def rays():
        return o3d.core.Tensor(np.concatenate([o, d], axis=1).astype(np.float32))

    return {"open3d cast_rays": lambda: scene.cast_rays(rays())["t_hit"].numpy(),
            "open3d test_occlusions": lambda: scene.test_occlusions(rays()).numpy(),
            "open3d count_intersections": lambda: scene.count_intersections(rays()).numpy(),
            "open3d compute_distance": lambda: scene.compute_distance(
                o3d.core.Tensor(o.astype(np.float32))).numpy()}


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--mesh", default="bunny")
    ap.add_argument("--sizes", default="1,100,10000")
    ap.add_argument("--calls", type=int, default=200)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--pause", type=float, default=0.0)
    ap.add_argument("--device", default=None)
    args = ap.parse_args()
    m = bench_mesh(args.mesh)
    tracer = kdray.Tracer(kdray.build(m.vertices, m.faces), device=args.device)
    versions, notes = peer_versions()
    scene = open3d_scene(m)[0] if versions["open3d"] else None
    print(f"# CPU {cpu_model()}; kdray on {tracer.device.name.strip()} "
          f"({tracer.device.platform.name.strip()})"
          + (f"; {versions['open3d']}" if scene is not None else ""))
    for note in notes:
        if note.startswith("# open3d"):
            print(note)
    spacing = f"{args.pause} s apart" if args.pause else "back to back"
    print(f"# {args.mesh}, {args.calls} calls {spacing} x {args.rounds} rounds in turns; "
          f"median microseconds a call")
    rng = np.random.default_rng(0)
    lo, hi = m.vertices.min(axis=0), m.vertices.max(axis=0)
    print(f"{'method':<28}" + "".join(f"{n:>12,}" for n in map(int, args.sizes.split(","))))
    table = {}
    for n in map(int, args.sizes.split(",")):
        o = lo + (hi - lo) * rng.random((n, 3))
        d = rng.normal(size=(n, 3))
        calls = kdray_calls(tracer, o, d)
        if scene is not None:
            calls.update(open3d_calls(scene, o, d))
        for f in calls.values():            # programs built, memory touched
            f()
            f()
        times = {name: [] for name in calls}
        for _ in range(args.rounds):
            for name, f in calls.items():
                for _ in range(args.calls):
                    if args.pause:
                        time.sleep(args.pause)
                    t0 = time.perf_counter()
                    f()
                    times[name].append(time.perf_counter() - t0)
        for name, ts in times.items():
            table.setdefault(name, []).append(1e6 * float(np.median(ts)))
    for name, row in table.items():
        print(f"{name:<28}" + "".join(f"{us:12.1f}" for us in row))


if __name__ == "__main__":
    main()
