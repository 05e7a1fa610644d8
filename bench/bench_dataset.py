"""Datasets: views per second of a camera orbit, per-scene overhead of many meshes with
and without the tree cache, and Dask workers.

    .venv/bin/python bench/bench_dataset.py                 # everything (a few minutes)
    .venv/bin/python bench/bench_dataset.py --parts orbit --views 100 --rounds 3

orbit    100 views of the bunny at 640 x 480 (depth, normal, id), a scene loaded, its
         tree built and every view's files written: `kdray.dataset.run` (one EXR a
         view, ZIP-compressed) against an Open3D loop doing the same work
         (RaycastingScene, create_rays_pinhole, cast_rays, depth from t_hit), writing
         three uncompressed .npy files a view, or kdray's EXR file (the same channels,
         written by the same function). Timed in turns (bench/timing.py's rule); each
         kdray run makes its Tracer anew (context, upload, programs from the driver's
         disk cache), each Open3D run its RaycastingScene.
scenes   100 different meshes (the four test meshes, each a different random part of
         it, and moved), one 320 x 240 view each, through `kdray batch`'s path: the
         per-scene time of each step (load, tree, device, compile, trace, write) with
         an empty tree cache and then with the trees in it.
workers  the orbit on a local Dask cluster of 1 and of 2 workers (the cluster's start
         timed apart), against the run in this process.
"""
import argparse
import math
import os
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import kdray  # noqa: E402  (before open3d: kdray.runtimes says why)
from kdray.cache import TreeCache  # noqa: E402
from kdray.dataset import Job, local_cluster, run  # noqa: E402
from meshes import MESHES, FILES, mesh as bench_mesh  # noqa: E402
from timing import ROUND_ROBIN_PAUSE  # noqa: E402

AOVS = ("depth", "normal", "id")


def orbit_cameras(tree, n, width, height):
    """n cameras on a circle round the scene box, looking at its centre (kdray.Camera)."""
    lo, hi = tree.world_box()
    centre, radius = (lo + hi) / 2, np.linalg.norm(hi - lo)
    cams = []
    for i in range(n):
        a = 2 * math.pi * i / n
        eye = centre + radius * np.array([math.cos(a), 0.35, math.sin(a)])
        cams.append(kdray.Camera.look_at(eye, centre, fov_deg=40, width=width, height=height))
    return cams


def write_camera_list(path, cameras):
    import json
    items = [{"name": f"view{i:04d}", "width": c.width, "height": c.height, "K": c.K.tolist(),
              "cam_to_world": c.cam_to_world.tolist()} for i, c in enumerate(cameras)]
    path.write_text(json.dumps(items))
    return path


def open3d_orbit(mesh_path, cameras, out, fmt="npy"):
    """The Open3D loop: load, build, and per view rays, cast, depth, and the files:
    fmt "npy" (three uncompressed .npy files) or "exr" (kdray's EXR file, written by the
    same code as kdray's: the same channels, ZIP compression, camera in the header).
    Returns the hit count of the last view (a check that it did the work)."""
    import open3d as o3d
    from kdray.images import compress_on_threads, write_exr
    compress_on_threads()
    m = kdray.load(mesh_path)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(m.vertices.astype(np.float32)),
                        o3d.core.Tensor(m.faces.astype(np.uint32)))
    hits = 0
    for i, cam in enumerate(cameras):
        world_to_cam = np.linalg.inv(cam.cam_to_world)
        rays = scene.create_rays_pinhole(o3d.core.Tensor(cam.K), o3d.core.Tensor(world_to_cam),
                                         cam.width, cam.height)
        ans = scene.cast_rays(rays)
        d = rays.numpy()[..., 3:]
        t = ans["t_hit"].numpy()
        depth = (t * (d @ cam.forward)).astype(np.float32)   # along the optical axis
        normal = ans["primitive_normals"].numpy()
        ids = ans["primitive_ids"].numpy()
        if fmt == "npy":
            np.save(out / f"view{i:04d}.depth.npy", depth)
            np.save(out / f"view{i:04d}.normal.npy", normal)
            np.save(out / f"view{i:04d}.id.npy", ids)
        else:
            write_exr(out / f"view{i:04d}.exr", {"depth": depth, "normal": normal, "id": ids},
                      camera=cam)
        hits = int(np.count_nonzero(ids != o3d.t.geometry.RaycastingScene.INVALID_ID))
    return hits


def kdray_orbit(mesh_path, cameras_file, out, cache=None, workers=None):
    reports = run([Job(scene=mesh_path, cameras=cameras_file, output=out, aovs=AOVS)],
                  cache=cache, workers=workers)
    assert reports[0].ok, reports[0].errors
    return reports[0]


def prepare_orbit(args, work):
    """(mesh file, cameras, camera file) of the orbit of the bunny."""
    mesh_path = work / "bunny.obj.gz"
    shutil.copy(MESHES / f"{FILES['bunny']}.gz", mesh_path)
    tree = kdray.build(*_arrays(mesh_path))
    cams = orbit_cameras(tree, args.views, *args.size)
    return mesh_path, cams, write_camera_list(work / "orbit.json", cams)


def part_orbit(args, work, mesh_path, cams, cam_file):
    from kdray.images import read_exr
    names = ["kdray"] + (["open3d-npy", "open3d-exr"] if _have("open3d") else [])
    times = {name: [] for name in names}
    last = {}
    for r in range(args.rounds):
        for name in (names if r % 2 == 0 else names[::-1]):
            out = work / f"out-{name}"
            shutil.rmtree(out, ignore_errors=True)
            out.mkdir()
            time.sleep(ROUND_ROBIN_PAUSE)
            t0 = time.perf_counter()
            if name == "kdray":
                last[name] = kdray_orbit(mesh_path, cam_file, out)   # no cache: builds
            else:
                last[name] = open3d_orbit(mesh_path, cams, out, name.rpartition("-")[2])
            times[name].append(time.perf_counter() - t0)
    ids = read_exr(work / "out-kdray" / f"view{args.views - 1:04d}.exr")["id"]
    print(f"orbit: {args.views} views of the bunny at {args.size[0]}x{args.size[1]} "
          f"({', '.join(AOVS)}), {args.rounds} rounds in turns, whole runs (load, build, views, files)")
    rep = last["kdray"]
    print(f"  {'kdray':<10} {args.views / statistics.median(times['kdray']):6.1f} views/s   "
          f"median {statistics.median(times['kdray']):.2f} s  (runs {', '.join(f'{t:.2f}' for t in times['kdray'])}); "
          + ", ".join(f"{k} {v:.2f} s" for k, v in rep.seconds.items())
          + f"; last view {np.count_nonzero(ids != 0xFFFFFFFF)} pixels hit")
    for name in names[1:]:
        what = "three .npy files a view" if name.endswith("npy") else "kdray's EXR file a view"
        print(f"  {name:<10} {args.views / statistics.median(times[name]):6.1f} views/s   "
              f"median {statistics.median(times[name]):.2f} s  (runs {', '.join(f'{t:.2f}' for t in times[name])}); "
              f"{what}; last view {last[name]} pixels hit")
        ratios = [o / k for k, o in zip(times["kdray"], times[name])]
        print(f"    kdray / {name} speed: {statistics.median(ratios):.2f}x (median of per-round "
              f"ratios, {min(ratios):.2f}-{max(ratios):.2f})")
    if len(names) == 1:
        print("  open3d: not installed (make bench-deps)")


def _arrays(path):
    m = kdray.load(path)
    return m.vertices, m.faces


def _have(module):
    try:
        __import__(module)
        return True
    except Exception:
        return False


def make_scenes(folder, n, seed=0):
    """n different meshes as PLY files: each a random 40-100 % of one of the test meshes
    (a contiguous run of its faces), moved by a random offset."""
    import trimesh
    rng = np.random.default_rng(seed)
    bases = [bench_mesh(name) for name in ("bunny", "fandisk", "teapot", "spot")]
    paths = []
    for i in range(n):
        base = bases[i % len(bases)]
        m = len(base.faces)
        keep = int(m * rng.uniform(0.4, 1.0))
        start = int(rng.integers(0, m - keep + 1))
        faces = base.faces[start:start + keep]
        v = base.vertices + rng.normal(size=3) * 10
        path = folder / f"scene{i:03d}.ply"
        trimesh.Trimesh(v, faces, process=False).export(path)
        paths.append(path)
    return paths


def part_scenes(args, work):
    folder = work / "scenes"
    folder.mkdir()
    paths = make_scenes(folder, args.scenes)
    jobs = []
    for p in paths:
        tree_box = kdray.load(p)
        lo, hi = tree_box.bounds
        cam = kdray.Camera.frame(lo, hi, 320, 240)
        cam_file = write_camera_list(folder / f"{p.stem}.json", [cam])
        jobs.append(Job(scene=p, cameras=cam_file, output=work / "scene-out" / p.stem, aovs=AOVS))
    cache = TreeCache(work / "tree-cache")
    n_tris = [len(kdray.load(p).faces) for p in paths]
    print(f"scenes: {len(paths)} meshes of {min(n_tris):,}-{max(n_tris):,} triangles "
          f"(median {int(statistics.median(n_tris)):,}), one 320x240 view each (depth, normal, id)")
    for label in ("empty cache", "trees in the cache"):
        shutil.rmtree(work / "scene-out", ignore_errors=True)
        t0 = time.perf_counter()
        reports = run(jobs, cache=cache)
        wall = time.perf_counter() - t0
        assert all(r.ok for r in reports)
        steps = {k: sum(r.seconds[k] for r in reports) / len(reports) for k in reports[0].seconds}
        overhead = steps["load"] + steps["tree"] + steps["device"] + steps["compile"]
        print(f"  {label:<20} {wall / len(jobs) * 1000:6.0f} ms a scene in all; set-up "
              f"{overhead * 1000:.0f} ms (" + ", ".join(f"{k} {v * 1000:.0f}" for k, v in steps.items())
              + " ms)")


def part_workers(args, work, mesh_path, cam_file):
    import distributed
    cache = TreeCache(work / "worker-cache")
    print(f"workers: the orbit ({args.views} views) with the tree in the cache")
    results = {}
    for workers in (None, 1, 2):
        out = work / f"out-w{workers}"
        shutil.rmtree(out, ignore_errors=True)
        if workers is None:
            t0 = time.perf_counter()
            kdray_orbit(mesh_path, cam_file, out, cache=cache)
            results["in this process"] = (time.perf_counter() - t0, 0.0)
            continue
        # the cluster's start-up timed apart: run() starts and stops its own, so time
        # the same start here once and take it off
        t0 = time.perf_counter()
        cluster = local_cluster(workers)
        client = distributed.Client(cluster)
        client.close()
        cluster.close()
        start = time.perf_counter() - t0
        t0 = time.perf_counter()
        kdray_orbit(mesh_path, cam_file, out, cache=cache, workers=workers)
        results[f"--workers {workers}"] = (time.perf_counter() - t0, start)
    for label, (wall, start) in results.items():
        print(f"  {label:<16} {wall:6.2f} s in all, {args.views / wall:5.1f} views/s"
              + (f"; about {start:.1f} s of it starting and stopping the cluster, "
                 f"{args.views / max(wall - start, 1e-9):.1f} views/s without" if start else ""))


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--parts", default="orbit,scenes,workers")
    parser.add_argument("--views", type=int, default=100)
    parser.add_argument("--scenes", type=int, default=100)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--size", default="640x480")
    args = parser.parse_args()
    args.size = tuple(int(x) for x in args.size.split("x"))
    parts = args.parts.split(",")
    print(f"kdray {kdray.__version__}, {os.cpu_count()} CPUs, device: "
          f"{kdray.Tracer(kdray.build([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])).device.name.strip()}")
    with tempfile.TemporaryDirectory(prefix="kdray-bench-dataset-") as tmp:
        work = Path(tmp)
        mesh_path, cams, cam_file = prepare_orbit(args, work)
        if "orbit" in parts:
            part_orbit(args, work, mesh_path, cams, cam_file)
        if "scenes" in parts:
            part_scenes(args, work)
        if "workers" in parts:
            part_workers(args, work, mesh_path, cam_file)


if __name__ == "__main__":
    main()
