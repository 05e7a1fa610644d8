"""Ray queries (kdray.rays) beside the peers' on the same rays, in turns, and their wrong
answers against exact oracles.

usage: python bench/bench_queries.py [--meshes bunny,bunny-1.6M] [--rays 1048576]
                                     [--repeat 3] [--device intel] [--no-peers]
                                     [--grid 64] [--random-points 1000000]

Speed, for each mesh (numpy in and numpy out, round_robin in turns, best and median):
four ray sets, the framing camera's 1024 x 1024 rays, `--rays` incoherent rays (from
random points in the tree's box in random directions), as many rays that mostly hit
(`aimed`: from a sphere around the mesh to random points on its surface) and as many
from one point (`centre`: the box's centre, random directions, as (N, 3) rows: a
viewpoint's visibility), and as many random points in the box for the inside tests:
- kdray: `trace` (t and prim), `occluded`, `count`, `intersections`, `contains`,
  `trace` and `occluded` with t_max an (N,) array (a range a ray, each inf), and
  `intersections` with max_hits=1 (the nearest hit as a k-nearest list);
- Open3D's RaycastingScene: `cast_rays`, `test_occlusions`, `count_intersections`,
  `list_intersections`, `compute_occupancy` (nsamples 1 and 3);
- trimesh with embreex: `intersects_location(multiple_hits=True)` and `contains`
  (mesh.contains), on a 1/16 sample of the rays (they are slow; rates are per ray);
- Mitsuba 3: `ray_test` (any hit; coherent for the camera's rays).
Each kdray query is checked against trace on the same rays (occluded is its hit,
intersections' first hit its triangle).

Wrong counts: rays from outside through every vertex and edge midpoint of the grid cube
and the icosphere, on through the centre, cross exactly twice: kdray's `count`, Open3D's
`count_intersections`, trimesh+embreex's hits a ray.

Wrong answers (`contains` and the peers' inside tests against an exact oracle: a convex
mesh's half-spaces): points on a grid through every vertex of a grid cube (its vertices
on integer points, the k-d tree's planes through them), on a grid through the centre of
an icosphere of 1280 triangles (its first 12 vertices and their edges lie in the axis
planes; a sphere is Open3D's own failure case, test_sphere_wrong_occupancy), and
`--random-points` random points in each; points within 1e-9 of a face are left out.
"""
import argparse
import os
import sys
import types

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.join(os.path.dirname(HERE), "tests"))
from helpers import edge_midpoints, grid_cube, icosphere  # noqa: E402  (closed meshes of the tests)
from meshes import framed  # noqa: E402
from peers import installed, open3d_scene  # noqa: E402
from timing import round_robin  # noqa: E402

import kdray  # noqa: E402
import kdray.device  # noqa: E402

SAMPLE = 16
"""trimesh's calls take every SAMPLE-th ray or point (their rates are per ray)."""


def incoherent(tree, n, seed=1):
    """(origins, directions) (n, 3) float64: random points in the tree's box, random
    directions."""
    lo, hi = (np.asarray(x, dtype=np.float64) for x in tree.world_box())
    rng = np.random.default_rng(seed)
    return lo + (hi - lo) * rng.random((n, 3)), rng.normal(size=(n, 3))


def aimed(mesh, tree, n, seed=3):
    """(origins, directions) (n, 3) float64: rays that mostly hit, from random points on
    a sphere around the mesh (radius: the box's diagonal) to random points on its
    surface (triangles by area): sensors' and visibility rays."""
    rng = np.random.default_rng(seed)
    v, f = np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces)
    area = np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1)
    tri = v[f[rng.choice(len(f), n, p=area / area.sum())]]
    a, b = rng.random((2, n, 1))
    flip = a + b > 1
    a, b = np.where(flip, 1 - a, a), np.where(flip, 1 - b, b)
    target = tri[:, 0] + a * (tri[:, 1] - tri[:, 0]) + b * (tri[:, 2] - tri[:, 0])
    lo, hi = (np.asarray(x, dtype=np.float64) for x in tree.world_box())
    u = rng.normal(size=(n, 3))
    o = 0.5 * (lo + hi) + np.linalg.norm(hi - lo) * u / np.linalg.norm(u, axis=1, keepdims=True)
    return o, target - o


def centre(tree, n, seed=4):
    """(origins, directions) (n, 3) float64: rays from the centre of the tree's box (one
    origin, repeated in every row) in random directions."""
    lo, hi = (np.asarray(x, dtype=np.float64) for x in tree.world_box())
    rng = np.random.default_rng(seed)
    return np.tile(0.5 * (lo + hi), (n, 1)), rng.normal(size=(n, 3))


def mitsuba_calls(mesh, o, d, coherent):
    """{name: call} of Mitsuba 3's any-hit test, numpy to numpy."""
    from peers import mitsuba_module, mitsuba_rays, mitsuba_scene
    mitsuba_module()
    scene, _ = mitsuba_scene(mesh)
    return {"mitsuba ray_test": lambda: np.asarray(
        scene.ray_test(mitsuba_rays(o, d), coherent=coherent).numpy())}


def open3d_calls(mesh, o, d, points):
    """{name: call} of Open3D's queries on the rays and points."""
    import open3d as o3d
    scene, _ = open3d_scene(mesh)
    rays = o3d.core.Tensor(np.concatenate([o, d], axis=1).astype(np.float32))
    p = o3d.core.Tensor(points.astype(np.float32))
    return {"open3d cast_rays": lambda: scene.cast_rays(rays)["t_hit"].numpy(),
            "open3d test_occlusions": lambda: scene.test_occlusions(rays).numpy(),
            "open3d count_intersections": lambda: scene.count_intersections(rays).numpy(),
            "open3d list_intersections": lambda: scene.list_intersections(rays)["t_hit"].numpy(),
            "open3d occupancy n=1": lambda: scene.compute_occupancy(p, nsamples=1).numpy(),
            "open3d occupancy n=3": lambda: scene.compute_occupancy(p, nsamples=3).numpy()}


def trimesh_calls(mesh, o, d, points):
    """{name: call} of trimesh's queries with embreex on every SAMPLE-th ray or point."""
    import trimesh
    from trimesh.ray.ray_pyembree import RayMeshIntersector
    tm = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)
    tm.ray = RayMeshIntersector(tm)
    o, d, points = o[::SAMPLE], d[::SAMPLE], points[::SAMPLE]
    return {"trimesh+embree all hits": lambda: tm.ray.intersects_location(o, d, multiple_hits=True),
            "trimesh+embree contains": lambda: tm.ray.contains_points(points)}


def speed(name, args):
    m, tree, _, co, cd = framed(name, 1024)
    tracer = kdray.Tracer(tree, device=args.device)
    io, idir = incoherent(tree, args.rays)
    print(f"{name}: {len(m.faces):,} triangles; {kdray.device.describe(tracer.device)}")
    for label, (o, d) in (("camera rays, 1024 x 1024", (co, cd)),
                          (f"{args.rays:,} incoherent rays", (io, idir)),
                          (f"{args.rays:,} rays aimed at the surface from around it",
                           aimed(m, tree, args.rays)),
                          (f"{args.rays:,} rays from the box's centre", centre(tree, args.rays))):
        points = io                     # random points in the box
        t_ray = np.full(len(d), np.inf)  # a range a ray
        calls = {"kdray trace": lambda: tracer.trace(o, d, outputs=()),
                 "kdray trace, t a ray": lambda: tracer.trace(o, d, t_max=t_ray, outputs=()),
                 "kdray occluded": lambda: tracer.occluded(o, d),
                 "kdray occluded, t a ray": lambda: tracer.occluded(o, d, t_max=t_ray),
                 "kdray count": lambda: tracer.count(o, d),
                 "kdray intersections": lambda: tracer.intersections(o, d),
                 "kdray intersections, max_hits=1":
                     lambda: tracer.intersections(o, d, max_hits=1),
                 "kdray contains": lambda: tracer.contains(points)}
        if not args.no_peers and installed("open3d"):
            calls.update(open3d_calls(m, o, d, points))
        if not args.no_peers and installed("embreex"):
            calls.update(trimesh_calls(m, o, d, points))
        if not args.no_peers and installed("mitsuba"):
            calls.update(mitsuba_calls(m, o, d, coherent=label.startswith("camera")))
        wall, _, results = round_robin(calls, args.repeat)
        hits = results["kdray trace"]
        assert (results["kdray occluded"] == hits.hit).all()
        assert (results["kdray occluded, t a ray"] == hits.hit).all()
        assert np.array_equal(results["kdray trace, t a ray"].prim, hits.prim)
        assert np.array_equal(results["kdray intersections, max_hits=1"].prim,
                              hits.prim[hits.hit])
        listed = results["kdray intersections"]
        first = listed.offsets[:-1][listed.counts > 0]
        # the list's first hit is trace's but where two hits lie within float32
        # rounding, which the refined t orders (docs/conventions.md, "Ray queries")
        other = listed.prim[first] != hits.prim[hits.hit]
        assert np.allclose(listed.t[first][other], hits.t[hits.hit][other], rtol=1e-6, atol=0)
        base = np.median(wall["kdray trace"])
        print(f"  {label}: {hits.hit.mean():.3f} hit, {listed.counts.mean():.2f} hits a ray, "
              f"{results['kdray count'].mean():.2f} crossings a ray"
              + (f"; Mitsuba's ray_test differs from trace's hit on "
                 f"{int((results['mitsuba ray_test'] != hits.hit).sum())} rays"
                 if "mitsuba ray_test" in results else ""))
        for key, times in wall.items():
            n = len(o) // (SAMPLE if key.startswith("trimesh") else 1)
            print(f"    {key:<32} {n / times.min() / 1e6:8.3f} Mrays/s (best) "
                  f"{n / np.median(times) / 1e6:8.3f} (median)  "
                  f"{np.median(times) / base * len(o) / n:6.2f} x kdray trace's time a ray")


def convex_inside(v, f, p, chunk=1 << 16):
    """(inside (k,) bool, clear (k,) bool): p behind every face's plane of a convex
    mesh, exactly in float64; clear where no plane is within 1e-9 of the point."""
    tri = v[f]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    inside = np.empty(len(p), bool)
    clear = np.empty(len(p), bool)
    for a in range(0, len(p), chunk):
        side = np.einsum("pfk,fk->pf", p[a:a + chunk, None, :] - tri[None, :, 0], normal)
        inside[a:a + chunk] = (side < 0).all(axis=1)
        clear[a:a + chunk] = np.abs(side).min(axis=1) > 1e-9
    return inside, clear


def wrong_answers(args):
    print("wrong inside answers against the exact half-space test (points within 1e-9 "
          "of a face left out)")
    rng = np.random.default_rng(2)
    for label, (v, f), g, about in (
            ("grid cube [-2, 2]^3", grid_cube(2), np.arange(-3, 3.25, 0.25), "the vertices"),
            ("icosphere, 1280 triangles", icosphere(3), np.linspace(-1.5, 1.5, args.grid + 1),
             "the centre")):
        grid = np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3)
        lo, hi = v.min(axis=0) * 1.2, v.max(axis=0) * 1.2
        rand = lo + (hi - lo) * rng.random((args.random_points, 3))
        tracer = kdray.Tracer(kdray.build(v, f), device=args.device)
        m = types.SimpleNamespace(vertices=v, faces=f)
        for which, p in ((f"grid through {about}", grid), ("random points", rand)):
            inside, clear = convex_inside(v, f, p)
            answers = {"kdray contains": tracer.contains(p)}
            if not args.no_peers and installed("open3d"):
                import open3d as o3d
                scene, _ = open3d_scene(m)
                pt = o3d.core.Tensor(p.astype(np.float32))
                for k in (1, 3):
                    answers[f"open3d occupancy n={k}"] = scene.compute_occupancy(
                        pt, nsamples=k).numpy().astype(bool)
            if not args.no_peers and installed("embreex"):
                import trimesh
                from trimesh.ray.ray_pyembree import RayMeshIntersector
                tm = trimesh.Trimesh(v, f, process=False)
                tm.ray = RayMeshIntersector(tm)
                answers["trimesh+embree contains"] = tm.ray.contains_points(p)
            print(f"  {label}, {which}: {int(clear.sum()):,} points ({int((~clear).sum())} "
                  f"on a face left out)")
            for key, a in answers.items():
                print(f"    {key:<28} {int((a[clear] != inside[clear]).sum()):>8} wrong")


def wrong_counts(args):
    """Crossing counts of rays from outside through every vertex and edge midpoint of
    the closed convex test meshes, on through the centre: exactly 2 each."""
    print("wrong crossing counts of rays through every vertex and edge midpoint, from "
          "outside through the centre (each crosses exactly twice)")
    for label, (v, f) in (("grid cube [-2, 2]^3", grid_cube(2)),
                          ("icosphere, 1280 triangles", icosphere(3))):
        targets = np.concatenate([v, edge_midpoints(v, f)])
        o, d = 3 * targets, -targets
        counts = {"kdray count": kdray.Tracer(kdray.build(v, f), device=args.device).count(o, d)}
        if not args.no_peers and installed("open3d"):
            import open3d as o3d
            scene, _ = open3d_scene(types.SimpleNamespace(vertices=v, faces=f))
            rays = o3d.core.Tensor(np.concatenate([o, d], axis=1).astype(np.float32))
            counts["open3d count_intersections"] = scene.count_intersections(rays).numpy()
        if not args.no_peers and installed("embreex"):
            import trimesh
            from trimesh.ray.ray_pyembree import RayMeshIntersector
            tm = trimesh.Trimesh(v, f, process=False)
            _, ray = RayMeshIntersector(tm).intersects_id(o, d, multiple_hits=True)
            counts["trimesh+embree hits"] = np.bincount(ray, minlength=len(o))
        print(f"  {label}: {len(targets):,} rays")
        for key, c in counts.items():
            print(f"    {key:<28} {int((c != 2).sum()):>8} wrong  (counts seen: "
                  f"{sorted(set(np.asarray(c).tolist()))})")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--meshes", default="bunny,bunny-1.6M")
    ap.add_argument("--rays", type=int, default=1 << 20)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--device", default=None)
    ap.add_argument("--no-peers", action="store_true")
    ap.add_argument("--grid", type=int, default=64)
    ap.add_argument("--random-points", type=int, default=1_000_000)
    args = ap.parse_args()
    for name in filter(None, args.meshes.split(",")):
        speed(name, args)
    wrong_counts(args)
    wrong_answers(args)


if __name__ == "__main__":
    main()
