"""Lidar scans per second: kdray's Tracer.scan beside the same rays through Open3D.

usage: python bench/bench_lidar.py [--mesh bunny-1.6M] [--beams 128] [--columns 2048]
                                   [--repeat 10] [--sample 20000] [--device SPEC]

A 128-beam (elevations 22.5 to -22.5 degrees, as an Ouster OS-128) x 2048-column
scan of the 1.6M-triangle bunny (bench/meshes.py; the tree built once), from two
poses: "inside" (the sensor at the bunny's centre: nearly every beam hits its inner
surface) and "outside" (0.8 box diagonals from its centre at mid-height, x towards
it: about one beam in twenty hits, the rest go out into the void). Timed in turns (bench/timing.py round_robin, each call 0.1 s after
the one before), median of --repeat rounds:

  kdray scan          Tracer.scan(lidar, pose): rays made by the render kernel from the
                      Lidar's direction map, trace, range/id/object images and world
                      points (the whole call)
  kdray rays          Lidar.rays(pose) alone: what making the float64 rays on the
                      host would add (precision="double" scans do)
  kdray trace         Tracer.trace of those float64 rays made beforehand, to max_range
  open3d cast         the same float64 rays -> float32 tensor -> cast_rays -> t as
                      numpy, max_range applied (Open3D has no t_max)

Accuracy on --sample random beams against a float64 reference (kdray.reference.traverse
on the input mesh's float64 triangles, candidates from kdray's tree): beams where the
two disagree on hit or miss, and the relative range error over beams both hit (99th
percentile and max).
"""
import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from meshes import mesh as bench_mesh  # noqa: E402

import kdray  # noqa: E402  (before open3d: kdray.runtimes and TBB)
from kdray import reference  # noqa: E402
from kdray.lidar import Lidar  # noqa: E402
from peers import open3d_scene  # noqa: E402
from timing import median_ratio, round_robin  # noqa: E402


def poses(lo, hi):
    """{name: (4, 4) sensor-to-world pose} of the two scans (see the docstring)."""
    c, size = 0.5 * (lo + hi), float(np.linalg.norm(hi - lo))
    inside = np.eye(4)
    inside[:3, 3] = c
    outside = np.eye(4)
    eye = c + np.array([0.8 * size, 0.3 * size, 0.0])
    yaw = np.arctan2(c[1] - eye[1], c[0] - eye[0])        # x forward towards the bunny
    outside[:3, :3] = [[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]]
    outside[:3, 3] = eye
    return {"inside": inside, "outside": outside}


def accuracy(t, sample, ref):
    t = np.asarray(t, dtype=np.float64)[sample]
    hit, ref_hit = np.isfinite(t), np.isfinite(ref)
    both = hit & ref_hit
    rel = np.abs(t[both] - ref[both]) / ref[both]
    return (int(np.count_nonzero(hit != ref_hit)),
            float(np.percentile(rel, 99)) if rel.size else float("nan"),
            float(rel.max()) if rel.size else float("nan"))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--mesh", default="bunny-1.6M")
    ap.add_argument("--beams", type=int, default=128)
    ap.add_argument("--columns", type=int, default=2048)
    ap.add_argument("--repeat", type=int, default=10)
    ap.add_argument("--sample", type=int, default=20000)
    ap.add_argument("--device", default=None)
    args = ap.parse_args()
    m = bench_mesh(args.mesh)
    kdray.build(m.vertices[:3], np.array([[0, 1, 2]]))               # compile the builder
    t0 = time.perf_counter()
    tree = kdray.build(m.vertices, m.faces)
    build_s = time.perf_counter() - t0
    tracer = kdray.Tracer(tree, device=args.device)
    lo, hi = tree.world_box()
    max_range = 10.0 * float(np.linalg.norm(hi - lo))
    lidar = Lidar.from_dict({"channels": args.beams, "fov_up": 22.5, "fov_down": -22.5,
                             "columns": args.columns, "max_range": max_range})
    n = args.beams * args.columns
    t0 = time.perf_counter()
    Lidar.from_dict(lidar.to_dict()).directions()
    first_dirs = time.perf_counter() - t0
    try:
        import open3d as o3d
        scene, o3d_build = open3d_scene(m)
    except ImportError as e:
        print(f"# open3d left out: {e}")
        o3d, scene, o3d_build = None, None, None
    print(f"# {args.mesh}: {len(m.faces):,} triangles; kdray build {build_s:.2f} s"
          + (f", open3d build {o3d_build:.2f} s" if o3d_build is not None else "")
          + f"; device {tracer.device.name.strip()}")
    print(f"# {args.beams} beams x {args.columns} columns = {n:,} rays a scan, max_range "
          f"{max_range:.3g}; median of {args.repeat} rounds; sensor-frame directions made "
          f"once per Lidar: {first_dirs * 1e3:.1f} ms")
    print(f"{'pose':<8} {'method':<12} {'s/scan':>8} {'scans/s':>8} {'Mrays/s':>8} {'hit %':>6} "
          f"{'disagree':>8} {'range p99':>10} {'range max':>10}")
    rng = np.random.default_rng(0)
    for name, pose in poses(lo, hi).items():
        origin, d = lidar.rays(pose)
        sample = rng.choice(n, size=min(args.sample, n), replace=False)
        ref = reference.traverse(tree, np.broadcast_to(origin, (len(sample), 3)), d[sample],
                                 triangles64=m.triangles)
        ref_t = np.where(ref.t < max_range, ref.t, np.inf)
        calls = {"kdray scan": lambda: tracer.scan(lidar, pose)["range"].reshape(-1),
                 "kdray rays": lambda: lidar.rays(pose) and None,
                 "kdray trace": lambda: tracer.trace(origin, d, t_max=max_range).t}
        if scene is not None:
            def cast(origin=origin, d=d):
                rays = np.empty((len(d), 6), np.float32)
                rays[:, :3], rays[:, 3:] = origin, d
                t = scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()
                return np.where(t < max_range, t, np.inf)
            calls["open3d cast"] = cast
        seconds, _, results = round_robin(calls, args.repeat)
        for method, s in seconds.items():
            s = float(np.median(s))
            t = results[method]
            if t is None:
                acc = ""
                hits = ""
            else:
                disagree, p99, worst = accuracy(t, sample, ref_t)
                hits = f"{100 * np.count_nonzero(np.isfinite(t)) / n:>6.1f}"
                acc = f" {disagree:>8} {p99:>10.2e} {worst:>10.2e}"
            print(f"{name:<8} {method:<12} {s:>8.4f} {1 / s:>8.2f} {n / s / 1e6:>8.2f} {hits:>6}{acc}",
                  flush=True)
        share = median_ratio(seconds["kdray rays"], seconds["kdray scan"])
        print(f"# {name}: float64 rays made on the host would be {100 * share:.1f} % of a scan "
              f"(median of rounds)")
        if "open3d cast" in seconds:
            print(f"# {name}: kdray scan / open3d cast = "
                  f"{median_ratio(seconds['open3d cast'], seconds['kdray scan']):.2f} "
                  f"(>= 1: kdray is faster; median of {args.repeat} rounds)", flush=True)


if __name__ == "__main__":
    main()
