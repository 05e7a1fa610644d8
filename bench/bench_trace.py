"""Primary-ray speed and accuracy: kdray beside Open3D (and embreex) on the same rays.

usage: python bench/bench_trace.py [--meshes bunny,teapot-x256] [--size 1024]
                                   [--repeat 5] [--sample 20000] [--device SPEC]

For each mesh: build time, then for 1024 x 1024 primary rays of a framing camera
(warm, median of --repeat rounds; kdray's and Open3D's methods run round-robin, one
call each per round, each 0.1 s after the one before, so that the machine's drift
hits them alike and no call pays for the one before's worker threads):
  kdray render depth   Tracer.render(camera, ["depth"]): rays made on the device
  kdray render default Tracer.render(camera) with depth, normal, bary, id
  kdray trace          Tracer.trace(origins, directions) from numpy to numpy
  open3d pinhole depth create_rays_pinhole(K, pose) + cast_rays + t_hit to numpy
  open3d cast          RaycastingScene.cast_rays on a prepared tensor (cast only)
  open3d numpy         numpy rays -> tensor -> cast_rays -> numpy
  embreex              trimesh's embreex front end, numpy to numpy (if installed)
and the ratios of the two workflows of issue 6: kdray render depth / open3d pinhole
depth and kdray trace / open3d numpy (>= 1: kdray is faster), each the median of the
per-round ratios of Open3D's time to kdray's.
Accuracy on --sample random pixels against a float64 reference (the input mesh in
float64, candidates from kdray's tree): hit/miss disagreements, relative depth error
(99th percentile and max, over rays both hit).
"""
import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from meshes import mesh as bench_mesh  # noqa: E402

import kdray  # noqa: E402
from kdray import reference  # noqa: E402
from kdray.render import DEFAULT_AOVS  # noqa: E402
from peers import embreex_hits, open3d_cast, open3d_scene  # noqa: E402
from timing import median_ratio, round_robin  # noqa: E402


def accuracy(t, prim, ref_t, ref_prim, sample):
    """Errors of (t, prim) on the sampled rays against the reference."""
    t, prim = np.asarray(t)[sample].astype(np.float64), np.asarray(prim)[sample].astype(np.int64)
    hit = np.isfinite(t)
    ref_hit = ref_prim >= 0
    both = hit & ref_hit
    rel = np.abs(t[both] - ref_t[both]) / ref_t[both]
    return {
        "disagree": int(np.count_nonzero(hit != ref_hit)),
        "prim_diff": int(np.count_nonzero(both & (prim != ref_prim))),
        "p99": float(np.percentile(rel, 99)) if len(rel) else float("nan"),
        "max": float(rel.max()) if len(rel) else float("nan"),
    }


def open3d_calls(m, o, d, camera):
    """Open3D's methods as zero-argument calls returning (t, prim or None), and its
    build seconds; ({}, None) without Open3D."""
    try:
        import open3d as o3d
    except ImportError as e:
        print(f"# open3d left out: {e}", flush=True)
        return {}, None
    scene, build = open3d_scene(m)
    rays = o3d.core.Tensor(np.concatenate([o, d], axis=1).astype(np.float32))
    K = o3d.core.Tensor(np.asarray(camera.K, dtype=np.float64))
    w2c = o3d.core.Tensor(np.linalg.inv(np.asarray(camera.cam_to_world, dtype=np.float64)))

    def cast():
        r = scene.cast_rays(rays)
        return r["t_hit"].numpy(), r["primitive_ids"].numpy()

    def pinhole():
        # a depth image from intrinsics and a pose, Open3D making the rays itself; its
        # accuracy is that of its own depths, pixel by pixel (the same pixel centres)
        r = o3d.t.geometry.RaycastingScene.create_rays_pinhole(K, w2c, int(camera.width),
                                                               int(camera.height))
        return scene.cast_rays(r)["t_hit"].numpy().ravel(), None

    return {"open3d pinhole depth": pinhole, "open3d cast": cast,
            "open3d numpy": lambda: open3d_cast(scene, o, d)[:2]}, build


def embreex_runs(m, o, d, repeat):
    try:
        import embreex  # noqa: F401
    except ImportError as e:
        print(f"# embreex left out: {e}", flush=True)
        return []
    build, s, t, prim, _ = embreex_hits(m, o, d, max(1, repeat // 2))
    return [("embreex", build, s, t, prim)]


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--meshes", default="bunny,teapot-x256")
    ap.add_argument("--size", type=int, default=1024)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--sample", type=int, default=20000)
    ap.add_argument("--device", default=None)
    args = ap.parse_args()
    n_rays = args.size * args.size
    rng = np.random.default_rng(0)
    print(f"# {n_rays} primary rays ({args.size}x{args.size}), median of {args.repeat} warm rounds")
    header = f"{'mesh':<12} {'tris':>9} {'method':<22} {'build s':>8} {'trace s':>8} {'Mrays/s':>8} " \
             f"{'disagree':>8} {'prim!=':>6} {'depth p99':>10} {'depth max':>10}"
    print(header)
    for name in args.meshes.split(","):
        m = bench_mesh(name)
        kdray.build(m.vertices[:3], np.array([[0, 1, 2]]))           # compile the builder
        t0 = time.perf_counter()
        tree = kdray.build(m.vertices, m.faces)
        build_s = time.perf_counter() - t0
        lo, hi = tree.world_box()
        camera = kdray.Camera.frame(lo, hi, args.size, args.size)
        o, d = camera.rays()
        sample = rng.choice(n_rays, size=min(args.sample, n_rays), replace=False)
        ref = reference.traverse(tree, o[sample], d[sample], triangles64=m.triangles)
        tracer = kdray.Tracer(tree, device=args.device)

        def render(aovs):
            img = tracer.render(camera, aovs=aovs)
            return img["depth"].ravel(), img["id"].ravel() if "id" in img else None

        def trace():
            hits = tracer.trace(o, d)
            return hits.t, hits.prim

        calls = {"kdray render depth": lambda: render(("depth",)),
                 "kdray render default": lambda: render(DEFAULT_AOVS),
                 "kdray trace": trace}
        open3d, o3d_build = open3d_calls(m, o, d, camera)
        seconds, _, results = round_robin({**calls, **open3d}, args.repeat)
        runs = [(method, build_s if method.startswith("kdray") else o3d_build,
                 float(np.median(seconds[method])), *results[method]) for method in seconds]
        runs += embreex_runs(m, o, d, args.repeat)
        for method, b, s, t, prim in runs:
            if prim is None:
                prim = np.where(np.isfinite(t), 0, -1)
                acc = accuracy(t, prim, ref.t, np.where(ref.hit, 0, -1), sample)
            else:
                prim = np.where(np.isfinite(t), np.asarray(prim).astype(np.int64), -1)
                acc = accuracy(t, prim, ref.t, ref.prim, sample)
            print(f"{name:<12} {len(m.faces):>9} {method:<22} {b:>8.3f} {s:>8.4f} {n_rays / s / 1e6:>8.2f} "
                  f"{acc['disagree']:>8} {acc['prim_diff']:>6} {acc['p99']:>10.2e} {acc['max']:>10.2e}",
                  flush=True)
        # the issue's two workflows, kdray against Open3D (>= 1 means kdray is faster)
        for ours, theirs in [("kdray render depth", "open3d pinhole depth"),
                             ("kdray trace", "open3d numpy")]:
            if theirs in seconds:
                print(f"# {name}: {ours} / {theirs} = {median_ratio(seconds[theirs], seconds[ours]):.2f}"
                      f" (median of {len(seconds[ours])} rounds)", flush=True)


if __name__ == "__main__":
    main()
