"""Point queries (kdray.points) beside the peers' on the same points, in turns, with
their errors against exact float64 answers.

usage: python bench/bench_points.py [--meshes bunny,bunny-1.6M] [--points 1048576]
                                    [--repeat 3] [--device intel] [--no-peers]
                                    [--sample 300] [--grid 256] [--trimesh 4096]

For each mesh, two point sets of `--points` each: uniform in the mesh's box, and near
the surface (uniform by area, moved by Gaussian noise of 1/300 of the box's largest
side: within about 1 % of it). Speed (numpy in and numpy out, round_robin in turns,
best and median):
- kdray: `closest_points`, `distance`, `signed_distance` (sign "parity" and
  "winding"), `winding_number` (beta 5 and 2);
- Open3D's RaycastingScene: `compute_closest_points`, `compute_distance`,
  `compute_signed_distance` (nsamples 1 and its default);
- Warp on its CPU device (when installed): `mesh_query_point_no_sign` and
  `mesh_query_point_sign_winding_number` (accuracy 2) in a kernel that writes the
  distance;
- trimesh's `proximity.closest_point` on the first `--trimesh` points (slow: rates per
  point).
Errors, on `--sample` of each set: distance relative error (p99, max) against the exact
float64 distance to the input's triangles (every triangle whose box may hold a nearer
point than the nearest vertex, exactly), and wrong signs against the exact winding
number (kdray's winding_number with beta=inf: every solid angle summed in double, which
tests/test_points.py checks against numpy), counted where it is farther than 0.1 from
1/2 (the bunny has holes: no sign is right or wrong nearer than that).
Then `--grid`^3 signed distances of the last mesh (kdray.sdf.sdf_grid, winding and
parity signs) beside Open3D's compute_signed_distance on the same points.
"""
import argparse
import os
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from meshes import mesh as load_mesh  # noqa: E402
from peers import installed, open3d_scene  # noqa: E402
from timing import round_robin  # noqa: E402

import kdray  # noqa: E402
import kdray.device  # noqa: E402
from kdray import reference  # noqa: E402
from kdray.sdf import grid_frame, sdf_grid  # noqa: E402


SIGNED = {"kdray signed parity", "kdray signed winding", "open3d signed nsamples=1",
          "open3d signed default", "warp sign_winding_number"}
"""The calls whose answers carry a sign (negative inside), counted for wrong signs."""


def point_sets(m, n, seed=0):
    """{label: (n, 3) float64 points}: uniform in the box; near the surface."""
    rng = np.random.default_rng(seed)
    lo, hi = m.vertices.min(axis=0), m.vertices.max(axis=0)
    tri = m.vertices[m.faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    which = rng.choice(len(tri), size=n, p=area / area.sum())
    b = rng.dirichlet([1.0, 1.0, 1.0], n)
    near = np.einsum("ki,kij->kj", b, tri[which])
    near += rng.normal(scale=float((hi - lo).max()) / 300, size=near.shape)
    return {"uniform in the box": lo + (hi - lo) * rng.random((n, 3)),
            "near the surface": near}


def exact_distance(tri, points):
    """(k,) float64 exact distances from points to triangles (m, 3, 3) float64: the
    nearest vertex bounds the answer; every triangle whose box is within that bound is
    measured exactly (kdray.reference.point_triangle_d2)."""
    lo, hi = tri.min(axis=1), tri.max(axis=1)
    verts = np.unique(tri.reshape(-1, 3), axis=0)
    out = np.empty(len(points))
    for i, p in enumerate(points):
        bound2 = float(np.min(((verts - p) ** 2).sum(axis=1)))
        gap = np.maximum(np.maximum(lo - p, p - hi), 0.0)
        near = np.flatnonzero((gap ** 2).sum(axis=1) <= bound2 * (1 + 1e-12))
        out[i] = np.sqrt(reference.point_triangle_d2(p[None], tri[near]).min())
    return out


def warp_calls(m, points):
    """{name: call} of Warp's point queries on its CPU device, or {} without Warp."""
    import warp as wp
    wp.config.quiet = True
    wp.init()
    mesh = wp.Mesh(points=wp.array(m.vertices.astype(np.float32), dtype=wp.vec3, device="cpu"),
                   indices=wp.array(m.faces.astype(np.int32).ravel(), dtype=wp.int32, device="cpu"),
                   support_winding_number=True)
    pts = wp.array(points.astype(np.float32), dtype=wp.vec3, device="cpu")
    out = wp.zeros(len(points), dtype=wp.float32, device="cpu")

    @wp.kernel
    def unsigned(mesh: wp.uint64, pts: wp.array(dtype=wp.vec3), out: wp.array(dtype=wp.float32)):
        i = wp.tid()
        q = wp.mesh_query_point_no_sign(mesh, pts[i], 1.0e30)
        if q.result:
            out[i] = wp.length(wp.mesh_eval_position(mesh, q.face, q.u, q.v) - pts[i])

    @wp.kernel
    def winding(mesh: wp.uint64, pts: wp.array(dtype=wp.vec3), out: wp.array(dtype=wp.float32)):
        i = wp.tid()
        q = wp.mesh_query_point_sign_winding_number(mesh, pts[i], 1.0e30, 2.0, 0.5)
        if q.result:
            out[i] = q.sign * wp.length(wp.mesh_eval_position(mesh, q.face, q.u, q.v) - pts[i])

    def call(kernel):
        def run():
            wp.launch(kernel, dim=len(points), inputs=[mesh.id, pts, out], device="cpu")
            wp.synchronize_device("cpu")
            return out.numpy().copy()
        return run
    return {"warp no_sign": call(unsigned), "warp sign_winding_number": call(winding)}


def open3d_calls(m, points):
    import open3d as o3d
    scene, _ = open3d_scene(m)
    p = o3d.core.Tensor(points.astype(np.float32))
    return {"open3d compute_closest_points":
            lambda: scene.compute_closest_points(p)["points"].numpy(),
            "open3d compute_distance": lambda: scene.compute_distance(p).numpy(),
            "open3d signed nsamples=1":
            lambda: scene.compute_signed_distance(p, nsamples=1).numpy(),
            "open3d signed default": lambda: scene.compute_signed_distance(p).numpy()}


def speed(name, args):
    m = load_mesh(name)
    tree = kdray.build(m.vertices, m.faces)
    tracer = kdray.Tracer(tree, device=args.device)
    print(f"{name}: {len(m.faces):,} triangles; {kdray.device.describe(tracer.device)}")
    tri = m.vertices[m.faces]
    for label, p in point_sets(m, args.points).items():
        calls = {"kdray closest_points": lambda: tracer.closest_points(p).distance,
                 "kdray distance": lambda: tracer.distance(p),
                 "kdray signed parity": lambda: tracer.signed_distance(p, sign="parity"),
                 "kdray signed winding": lambda: tracer.signed_distance(p),
                 "kdray winding_number": lambda: tracer.winding_number(p),
                 "kdray winding beta 2": lambda: tracer.winding_number(p, beta=2.0)}
        if not args.no_peers and installed("open3d"):
            calls.update(open3d_calls(m, p))
        if not args.no_peers and installed("warp"):
            calls.update(warp_calls(m, p))
        import warnings
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")              # parity on an open mesh
            wall, _, results = round_robin(calls, args.repeat)
        tm = {}
        if not args.no_peers and installed("trimesh") and args.trimesh:
            import trimesh
            tmesh = trimesh.Trimesh(m.vertices, m.faces, process=False)
            k = min(args.trimesh, len(p))
            t0 = time.perf_counter()
            _, tm_d, _ = trimesh.proximity.closest_point(tmesh, p[:k])
            tm["trimesh proximity.closest_point"] = (time.perf_counter() - t0, k, tm_d)
        # errors on a sample
        s = np.linspace(0, len(p) - 1, args.sample).astype(np.int64)
        exact = exact_distance(tri, p[s])
        w = tracer.winding_number(p[s], beta=np.inf)
        clear = np.abs(w - 0.5) > 0.1
        inside = w > 0.5
        print(f"  {label}: {len(p):,} points; exact distances of {len(s)}, "
              f"{int(clear.sum())} with a clear sign")
        base = np.median(wall["kdray distance"])
        for key, times in wall.items():
            d = results[key]
            if key == "open3d compute_closest_points":
                d = np.linalg.norm(d - p.astype(np.float32), axis=1)
            err = sign = ""
            if key.startswith("kdray winding"):
                err = f"|w - exact| max {np.abs(d[s] - w).max():.1e}"
                sign = f"{int(((d[s] > 0.5) != inside)[clear].sum())} wrong"
            else:
                dist = np.abs(np.asarray(d, dtype=np.float64)[s])
                rel = np.abs(dist - exact) / np.maximum(exact, 1e-300)
                err = f"rel p99 {np.quantile(rel, 0.99):.1e} max {rel.max():.1e}"
                if key in SIGNED:
                    neg = np.asarray(d)[s] < 0
                    sign = f"{int((neg != inside)[clear].sum())} wrong"
            print(f"    {key:<32} {len(p) / times.min() / 1e6:7.3f} Mpts/s (best) "
                  f"{len(p) / np.median(times) / 1e6:7.3f} (median) "
                  f"{np.median(times) / base:6.2f} x distance  {err:<28} {sign}")
        for key, (secs, k, d) in tm.items():
            j = min(k, args.sample)
            rel = np.abs(d[:j] - exact_distance(tri, p[:j])) / exact_distance(tri, p[:j])
            print(f"    {key:<32} {k / secs / 1e6:7.4f} Mpts/s ({k} points)  "
                  f"{median_x(secs / k, base / len(p)):6.1f} x distance  "
                  f"rel p99 {np.quantile(rel, 0.99):.1e} max {rel.max():.1e}")


def median_x(a, b):
    return a / b


def grid(name, args):
    m = load_mesh(name)
    tracer = kdray.Tracer(kdray.build(m.vertices, m.faces), device=args.device)
    n = args.grid
    print(f"{name}: a {n}^3 signed distance grid ({n ** 3:,} points)")
    import warnings
    for sign in ("winding", "parity"):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            t0 = time.perf_counter()
            g = sdf_grid(tracer, n, sign=sign)
            secs = time.perf_counter() - t0
        print(f"    kdray sdf_grid sign={sign:<8} {secs:8.1f} s  {n ** 3 / secs / 1e6:6.3f} Mpts/s  "
              f"{float((g.values < 0).mean()):.3f} inside")
    if not args.no_peers and installed("open3d"):
        import open3d as o3d
        scene, _ = open3d_scene(m)
        origin, spacing = grid_frame(tracer, n, 0.1)
        t0 = time.perf_counter()
        inside = 0
        for i in range(n):
            j, k = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
            q = origin + spacing * np.stack([np.full(j.size, i), j.ravel(), k.ravel()], axis=1)
            d = scene.compute_signed_distance(o3d.core.Tensor(q.astype(np.float32))).numpy()
            inside += int((d < 0).sum())
        secs = time.perf_counter() - t0
        print(f"    open3d compute_signed_distance {secs:8.1f} s  {n ** 3 / secs / 1e6:6.3f} Mpts/s  "
              f"{inside / n ** 3:.3f} inside")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--meshes", default="bunny,bunny-1.6M")
    ap.add_argument("--points", type=int, default=1 << 20)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--device", default=None)
    ap.add_argument("--no-peers", action="store_true")
    ap.add_argument("--sample", type=int, default=300)
    ap.add_argument("--grid", type=int, default=256)
    ap.add_argument("--trimesh", type=int, default=4096)
    args = ap.parse_args()
    names = args.meshes.split(",")
    for name in names:
        speed(name, args)
    if args.grid:
        grid(names[-1], args)


if __name__ == "__main__":
    main()
