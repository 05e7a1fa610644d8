"""SAH k-d tree build speed, memory and tree statistics from ~10k to 6M triangles,
beside Open3D's build (Embree's BVH) of the same mesh.

usage: python bench/bench_build.py [--max-tris N] [--repeat 3] [--threads T] [--no-open3d]

Meshes (deterministic): the Stanford bunny cut by a horizontal plane into its lowest
10k / 20k / 40k triangles, the whole bunny (69,451), the bunny subdivided once
(277,804) and twice (1,111,216), twice plus a third time on its first 162,928 faces
(1,600,000), three times (4,444,864), and three times plus a fourth time on its first
518,378 faces (5,999,998).

Each size runs in its own subprocess: it loads the mesh, builds a tiny mesh first so
the numba kernels are compiled (or loaded from the on-disk cache), resets the peak
RSS counter (/proc/self/clear_refs) and builds once for the memory columns; then,
after a warm-up build with each, `--repeat` rounds each build the mesh with kdray and
with Open3D, in turns (the order reversed every other round, each build 0.1 s after
the one before; `timing.round_robin`), so that the machine's drift in speed
(+-20 % over minutes here) hits both alike and neither pays for the other's idle
worker threads. The whole run takes about 6 minutes on 2 cores and
needs ~3 GiB at 6M. Columns:

  build s      wall time of kdray.build (warm: fastest of the rounds), `--threads`
               threads (default: all CPUs)
  cpu s        CPU time of that build, all threads together
  peak MiB     the process's peak resident memory during the first build (VmHWM), mesh
               and Python included; base MiB is the resident memory before it
  B/tri        (peak - base) / triangles: the build's memory per triangle in bytes
  t/(n lg n)   build time / (n log2 n), relative to the smallest size: flat = O(n log n)
  ns/node      build time per tree node: the work per node does not grow with n; the
               tree has relatively more nodes on small meshes (max_depth = 8 + 1.3 log2 n)
  O3D s        Open3D's RaycastingScene on the same mesh, in the same process, in turns
               with kdray's builds: add_triangles plus a cast of one ray (Open3D builds
               its Embree BVH at the first cast; `peers.open3d_scene`), fastest of
               the rounds; n/a when Open3D is not installed. Embree's build is multi-threaded.
  x O3D        kdray's build time / Open3D's: the median of the rounds' ratios
"""
import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
from types import SimpleNamespace

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from meshes import mesh as bench_mesh  # noqa: E402

SIZES = ["bunny-10k", "bunny-20k", "bunny-40k", "bunny", "bunny-x4", "bunny-x16", "bunny-1.6M",
         "bunny-x64", "bunny-6M"]


def proc_status(field):
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith(field + ":"):
                return int(line.split()[1]) / 1024.0            # kB -> MiB
    return float("nan")


def child(path, repeat, threads, with_open3d):
    """Build one mesh; print one JSON line."""
    import kdray
    from peers import open3d_scene
    from timing import median_ratio, round_robin
    data = np.load(path)
    vertices, faces = data["vertices"], data["faces"]
    kdray.build(np.eye(3), np.array([[0, 1, 2]]))              # compile / load the kernels
    kw = {} if threads is None else dict(threads=threads)
    # Memory: the first build, alone (Open3D's scene would count towards the peak).
    base = proc_status("VmRSS")
    try:
        with open("/proc/self/clear_refs", "w") as f:           # reset VmHWM
            f.write("5")
    except OSError:
        pass
    tree = kdray.build(vertices, faces, **kw)
    peak = proc_status("VmHWM")                                  # before stats() allocates
    s = tree.stats()
    n = len(tree.triangles)
    del tree

    # Time: kdray and Open3D in turns, so that the machine's drift hits both alike;
    # neither result is kept while the other builds.
    def kdray_build():
        kdray.build(vertices, faces, **kw)

    calls = {"kdray": kdray_build}
    if with_open3d:
        try:
            import open3d  # noqa: F401
        except ImportError:
            pass
        else:
            mesh = SimpleNamespace(vertices=vertices, faces=faces)

            def open3d_build():
                open3d_scene(mesh)

            calls["open3d"] = open3d_build
    wall, cpu, _ = round_robin(calls, repeat)
    kd = wall["kdray"]
    o3d = wall.get("open3d")
    best = int(np.argmin(kd))
    print(json.dumps(dict(n=n, seconds=float(kd[best]), cpu=float(cpu["kdray"][best]), peak_mib=peak,
                          base_mib=base, nodes=s["nodes"], leaves=s["leaves"],
                          empty=s["empty_leaves"], depth=s["max_leaf_depth"],
                          refs=s["refs_per_triangle"], sah=s["sah_cost"],
                          open3d=float(o3d.min()) if o3d is not None else None,
                          ratio=median_ratio(kd, o3d) if o3d is not None else None)))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--max-tris", type=int, default=7_000_000, help="skip meshes larger than this")
    ap.add_argument("--repeat", type=int, default=3, help="builds per size (the fastest counts)")
    ap.add_argument("--threads", type=int, default=None, help="kdray.build threads (default: all CPUs)")
    ap.add_argument("--no-open3d", action="store_true", help="leave out Open3D's build")
    ap.add_argument("--child", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        child(args.child, args.repeat, args.threads, not args.no_open3d)
        return

    # compile once up front so that no size pays for it
    subprocess.run([sys.executable, "-c", "import numpy as np, kdray; "
                    "kdray.build(np.eye(3), np.array([[0, 1, 2]]))"], check=True)
    rows = []
    print(f"{'mesh':<12}{'n':>10}{'build s':>9}{'cpu s':>8}{'peak MiB':>10}{'base MiB':>10}{'B/tri':>7}"
          f"{'nodes':>12}{'leaves':>11}{'empty':>11}{'depth':>6}{'refs/tri':>9}{'SAH':>8}"
          f"{'t/(n lg n)':>11}{'ns/node':>9}{'O3D s':>8}{'x O3D':>7}")
    with tempfile.TemporaryDirectory() as tmp:
        for name in SIZES:
            m = bench_mesh(name)
            vertices, faces = m.vertices, m.faces
            if len(faces) > args.max_tris:
                continue
            path = os.path.join(tmp, "mesh.npz")
            np.savez(path, vertices=vertices, faces=faces)
            del m, vertices, faces
            cmd = [sys.executable, __file__, "--child", path, "--repeat", str(args.repeat)]
            if args.threads is not None:
                cmd += ["--threads", str(args.threads)]
            if args.no_open3d:
                cmd.append("--no-open3d")
            out = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout
            r = json.loads(out.strip().splitlines()[-1])
            r["norm"] = r["seconds"] / (r["n"] * math.log2(r["n"]))
            rows.append(r)
            per_tri = (r["peak_mib"] - r["base_mib"]) * 2 ** 20 / r["n"]
            o3d = f"{r['open3d']:>8.3f}{r['ratio']:>7.2f}" if r["open3d"] else f"{'n/a':>8}{'n/a':>7}"
            print(f"{name:<12}{r['n']:>10,}{r['seconds']:>9.3f}{r['cpu']:>8.2f}{r['peak_mib']:>10.0f}"
                  f"{r['base_mib']:>10.0f}{per_tri:>7.0f}{r['nodes']:>12,}{r['leaves']:>11,}{r['empty']:>11,}"
                  f"{r['depth']:>6}{r['refs']:>9.2f}{r['sah']:>8.0f}{r['norm'] / rows[0]['norm']:>11.2f}"
                  f"{1e9 * r['seconds'] / r['nodes']:>9.0f}{o3d}", flush=True)


if __name__ == "__main__":
    main()
