"""What precision="double" costs each ray query, and what it changes: `trace`,
`occluded`, `count` and `intersections` in single and double precision on the same
rays, in turns.

usage: python bench/bench_double.py [--meshes bunny] [--rays 1048576] [--repeat 3]

Rays, two kinds a mesh: "uniform", from random points in the tree's box in random
directions (no origin near the surface: double precision should change no answer),
and "surface", from float64 points sampled on the triangles by area, given as they
are (no `offset_origins`), leaving in random directions of the face's front
hemisphere: about half of them hit their own face in float32, which double precision
does not count (docs/conventions.md, "Float64 answers"). For each call: the median
milliseconds of --repeat rounds (`timing.round_robin`), the double call's median
ratio to the single one, and the rays whose answers differ (for intersections, whose
list length differs); then the rays whose double answers break a documented rule
(docs/interface.md, "Tracer"; 0 expected): occluded is `trace`'s double `hit`,
`intersections(..., max_hits=1)`'s hit is `trace`'s double hit, a double count is at
most the single count and the double list's length. (The float64 brute force of
tests/test_double.py is too slow for 2^20 rays.)
"""
import argparse
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import kdray  # noqa: E402
from kdray.layout import MISS  # noqa: E402
from meshes import mesh  # noqa: E402
from timing import median_ratio, round_robin  # noqa: E402

CALLS = ("trace", "occluded", "count", "intersections")


def first_prim(listed, n):
    """(n,) uint32: each ray's first listed hit (an Intersections), MISS where none."""
    first = np.full(n, MISS, dtype=np.uint32)
    rows = np.flatnonzero(np.diff(listed.offsets) > 0)
    first[rows] = listed.prim[listed.offsets[rows]]
    return first


def ray_kinds(m, tree, n, seed):
    """{kind: (origins, directions, prim or None)}: (n, 3) float64 rays of each kind
    (module docstring); prim: the face each surface ray's origin lies on."""
    import trimesh
    rng = np.random.default_rng(seed)
    lo, hi = tree.world_box()
    uniform = (lo + rng.random((n, 3)) * (hi - lo), rng.normal(size=(n, 3)), None)
    tm = trimesh.Trimesh(m.vertices, m.faces, process=False)
    points, face = trimesh.sample.sample_surface(tm, n, seed=seed)
    d = rng.normal(size=(n, 3))
    d *= np.where((d * tm.face_normals[face]).sum(axis=1) < 0, -1.0, 1.0)[:, None]
    return {"uniform": uniform, "surface": (points, d, face)}


def answer(name, result):
    """The (N,) array two calls' answers are compared by."""
    if name == "trace":
        return result.prim
    if name == "intersections":
        return np.diff(result.offsets)
    return result


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--meshes", default="bunny")
    ap.add_argument("--rays", type=int, default=1 << 20)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    print(f"kdray {kdray.__version__}, {args.rays:,} rays, median of {args.repeat} rounds in "
          f"turns, ms")
    for name in args.meshes.split(","):
        m = mesh(name)
        tree = kdray.build(m.vertices, m.faces, keep_double=True)
        tracer = kdray.Tracer(tree)
        print(f"\n{name} ({len(m.faces):,} triangles, {tracer.device.name.strip()})")
        print(f"{'rays':8} {'call':14} {'single':>8} {'double':>8} {'x':>6} {'differ':>9} "
              f"{'wrong':>6}")
        for kind, (o, d, _) in ray_kinds(m, tree, args.rays, args.seed).items():
            fns = {}
            for call in CALLS:
                for precision in ("single", "double"):
                    kw = {"outputs": ()} if call == "trace" else {}
                    fns[call, precision] = (lambda f=getattr(tracer, call), p=precision, kw=kw:
                                            f(o, d, precision=p, **kw))
            wall, _, results = round_robin(fns, args.repeat)
            truth = results["trace", "double"]
            nearest = first_prim(tracer.intersections(o, d, max_hits=1, precision="double"),
                                 len(d))
            for call in CALLS:
                single, double = results[call, "single"], results[call, "double"]
                differ = int((answer(call, single) != answer(call, double)).sum())
                if call == "occluded":
                    wrong = int((double != truth.hit).sum())
                elif call == "intersections":
                    wrong = int((nearest != truth.prim).sum())
                elif call == "count":
                    listed = np.diff(results["intersections", "double"].offsets)
                    wrong = int(((double > single) | (double > listed)).sum())
                else:
                    wrong = "-"
                a, b = wall[call, "single"], wall[call, "double"]
                print(f"{kind:8} {call:14} {np.median(a) * 1e3:8.1f} {np.median(b) * 1e3:8.1f} "
                      f"{median_ratio(b, a):6.2f} {differ:9,} {wrong:>6}")


if __name__ == "__main__":
    main()
