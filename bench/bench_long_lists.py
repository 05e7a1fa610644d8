"""Rays with thousands of hits: `count` and `intersections` through k stacked unit
quads (2k triangles, a layered scan, a stack of sheets), beside Open3D's
count_intersections and list_intersections on the same rays, in turns.

usage: python bench/bench_long_lists.py [--layers 1000,2000,4000,8000] [--rays 1000]
                                        [--repeat 3]

The rays start below the stack at seeded random points of the quads' square (off
their diagonals): "along", all along the stack's axis (each crosses every quad; rays
of one direction walk the k-d tree as packets, whose leaves hold copies of the
quads), and "tilted", each turned a little (by up to 0.02 / k: they still cross every
quad, off the diagonals). A method's time should grow as the hits do, linearly in k;
each answer is checked (every ray's count is k, its list one triangle of each quad,
each once, in t order) and the rays answered wrong are counted. Open3D's list is checked for its length only (its hits come in
its callbacks' order).
"""
import argparse
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import kdray  # noqa: E402
from peers import installed  # noqa: E402
from timing import round_robin  # noqa: E402


def stack(k):
    """(vertices (4k, 3), faces (2k, 3)) of k unit quads at z = 0 .. k - 1."""
    quad = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    v = np.concatenate([quad + [0.0, 0.0, z] for z in range(k)])
    f = (np.arange(k)[:, None, None] * 4 + np.array([[0, 1, 2], [0, 2, 3]])).reshape(-1, 3)
    return v, f


def rays(n, k, tilted, seed=0):
    """(origins, directions) (n, 3) float64: from z = -1 up the stack of k quads."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0.05, 0.95, (n, 2))
    # 0.05 at least off the quads' diagonals (an edge two triangles share)
    near = np.abs(xy[:, 0] - xy[:, 1]) < 0.05
    xy[near, 1] = np.where(xy[near, 0] < 0.8, xy[near, 0] + 0.1, xy[near, 0] - 0.1)
    o = np.column_stack([xy, np.full(n, -1.0)])
    d = np.tile([0.0, 0.0, 1.0], (n, 1))
    if tilted:
        d[:, :2] = rng.uniform(-0.02, 0.02, (n, 2)) / k   # inside the square
    return o, d


def wrong(answer, k):
    """The rays whose answer is not k: a count (an array), or a list (kdray's
    Intersections) whose ray does not hold one triangle of each quad, in t order."""
    if not hasattr(answer, "offsets"):
        return int(np.count_nonzero(answer != k))
    counts = np.diff(answer.offsets)
    ray = np.repeat(np.arange(len(counts)), counts)
    same = ray[1:] == ray[:-1]
    quad = answer.prim.astype(np.int64) // 2          # quad i: triangles 2i, 2i + 1
    bad = same & ((np.diff(answer.t) < 0) | (np.diff(quad) != 1))
    ok = counts == k
    ok[ray[1:][bad]] = False
    return int(np.count_nonzero(~ok))


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--layers", default="1000,2000,4000,8000")
    p.add_argument("--rays", type=int, default=1000)
    p.add_argument("--repeat", type=int, default=3)
    a = p.parse_args()
    o3d = installed("open3d")
    if o3d:
        import open3d
    print(f"{'layers':>6} {'rays':>7} {'method':>22} {'ms':>9} {'Mhits/s':>8} wrong")
    for k in map(int, a.layers.split(",")):
        v, f = stack(k)
        tracer = kdray.Tracer(kdray.build(v, f))
        scene = None
        if o3d:
            scene = open3d.t.geometry.RaycastingScene()
            scene.add_triangles(open3d.core.Tensor(v.astype(np.float32)),
                                open3d.core.Tensor(f.astype(np.uint32)))
        for kind in ("along", "tilted"):
            o, d = rays(a.rays, k, kind == "tilted")
            fns = {"kdray count": lambda: tracer.count(o, d),
                   "kdray intersections": lambda: tracer.intersections(o, d)}
            if scene is not None:
                r = open3d.core.Tensor(np.concatenate([o, d], 1).astype(np.float32))
                fns["Open3D count"] = lambda: scene.count_intersections(r).numpy()
                fns["Open3D list"] = lambda: np.diff(
                    scene.list_intersections(r)["ray_splits"].numpy())
            wall, _, results = round_robin(fns, a.repeat)
            for name, seconds in wall.items():
                s = float(np.median(seconds))
                print(f"{k:>6} {kind:>7} {name:>22} {1e3 * s:>9.1f} "
                      f"{a.rays * k / s / 1e6:>8.2f} {wrong(results[name], k)}", flush=True)


if __name__ == "__main__":
    main()
