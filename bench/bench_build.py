"""SAH k-d tree build speed, memory and tree statistics from ~10k to 1.6M triangles.

usage: python bench/bench_build.py [--max-tris N] [--repeat 3]

Meshes (deterministic): the Stanford bunny cut by a horizontal plane into its lowest
10k / 20k / 40k triangles, the whole bunny (69,451), the bunny subdivided once
(277,804) and twice (1,111,216), and twice plus a third time on its first 162,928
faces (1,600,000).

Each size runs in its own subprocess: it loads the mesh, builds a tiny mesh first so
the numba kernels are compiled (or loaded from the on-disk cache), resets the peak
RSS counter (/proc/self/clear_refs), then builds `--repeat` times (1 for sizes over
500k) and reports the fastest. Columns:

  build s      wall time of kdray.build (warm)
  peak MiB     the process's peak resident memory during the builds (VmHWM), mesh
               and Python included; base MiB is the resident memory before them
  t/(n lg n)   build time / (n log2 n), relative to the smallest size: flat = O(n log n)
  ns/node      build time per tree node: the work per node does not grow with n; the
               tree has relatively more nodes on small meshes (max_depth = 8 + 1.3 log2 n)
"""
import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

SIZES = ["bunny-10k", "bunny-20k", "bunny-40k", "bunny", "bunny-x4", "bunny-x16", "bunny-1.6M"]


def make_mesh(name):
    """name -> (vertices (n,3) float64, faces (m,3) int64)."""
    from meshes import mesh as bench_mesh, subdivide
    if name.startswith("bunny-") and name.endswith("k"):
        m = bench_mesh("bunny")
        keep = int(name[len("bunny-"):-1]) * 1000
        height = m.vertices[m.faces].mean(axis=1)[:, 1]
        faces = m.faces[np.sort(np.argsort(height, kind="stable")[:keep])]
        return m.vertices, faces
    if name == "bunny-1.6M":
        import trimesh.remesh
        v, f = subdivide(bench_mesh("bunny").vertices, bench_mesh("bunny").faces, 2)
        extra = (1_600_000 - len(f)) // 3
        v, f = trimesh.remesh.subdivide(v, f, face_index=np.arange(extra))
        return np.asarray(v, dtype=np.float64), np.asarray(f, dtype=np.int64)
    m = bench_mesh(name)
    return m.vertices, m.faces


def proc_status(field):
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith(field + ":"):
                return int(line.split()[1]) / 1024.0            # kB -> MiB
    return float("nan")


def child(path, repeat):
    """Build one mesh; print one JSON line."""
    import kdray
    data = np.load(path)
    vertices, faces = data["vertices"], data["faces"]
    kdray.build(np.eye(3), np.array([[0, 1, 2]]))              # compile / load the kernels
    base = proc_status("VmRSS")
    try:
        with open("/proc/self/clear_refs", "w") as f:           # reset VmHWM
            f.write("5")
    except OSError:
        pass
    best = math.inf
    tree = None
    for _ in range(repeat):
        del tree
        t0 = time.perf_counter()
        tree = kdray.build(vertices, faces)
        best = min(best, time.perf_counter() - t0)
    peak = proc_status("VmHWM")                                  # before stats() allocates
    s = tree.stats()
    print(json.dumps(dict(n=len(tree.triangles), seconds=best, peak_mib=peak,
                          base_mib=base, nodes=s["nodes"], leaves=s["leaves"],
                          empty=s["empty_leaves"], depth=s["max_leaf_depth"],
                          refs=s["refs_per_triangle"], sah=s["sah_cost"])))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--max-tris", type=int, default=2_000_000, help="skip meshes larger than this")
    ap.add_argument("--repeat", type=int, default=3, help="builds per size (the fastest counts)")
    ap.add_argument("--child", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        child(args.child, args.repeat)
        return

    # compile once up front so that no size pays for it
    subprocess.run([sys.executable, "-c", "import numpy as np, kdray; "
                    "kdray.build(np.eye(3), np.array([[0, 1, 2]]))"], check=True)
    rows = []
    print(f"{'mesh':<12}{'n':>10}{'build s':>9}{'peak MiB':>10}{'base MiB':>10}{'nodes':>11}"
          f"{'leaves':>10}{'empty':>10}{'depth':>6}{'refs/tri':>9}{'SAH':>8}{'t/(n lg n)':>11}{'ns/node':>9}")
    with tempfile.TemporaryDirectory() as tmp:
        for name in SIZES:
            vertices, faces = make_mesh(name)
            if len(faces) > args.max_tris:
                continue
            path = os.path.join(tmp, "mesh.npz")
            np.savez(path, vertices=vertices, faces=faces)
            del vertices, faces
            repeat = args.repeat if os.path.getsize(path) < 40e6 else 1
            out = subprocess.run([sys.executable, __file__, "--child", path, "--repeat", str(repeat)],
                                 check=True, capture_output=True, text=True).stdout
            r = json.loads(out.strip().splitlines()[-1])
            r["norm"] = r["seconds"] / (r["n"] * math.log2(r["n"]))
            rows.append(r)
            print(f"{name:<12}{r['n']:>10,}{r['seconds']:>9.3f}{r['peak_mib']:>10.0f}{r['base_mib']:>10.0f}"
                  f"{r['nodes']:>11,}{r['leaves']:>10,}{r['empty']:>10,}{r['depth']:>6}{r['refs']:>9.2f}"
                  f"{r['sah']:>8.0f}{r['norm'] / rows[0]['norm']:>11.2f}{1e9 * r['seconds'] / r['nodes']:>9.0f}",
                  flush=True)


if __name__ == "__main__":
    main()
