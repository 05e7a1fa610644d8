"""Depth accuracy on the stiff cases, kdray (float32 default, refinement off, double)
beside Open3D and embreex on the same rays: small objects on huge ground planes and
beside walls, a huge triangle before the eye, long slivers, the same far from the
origin, and a mesh scaled to 1e15 and 1e-20.

usage: python bench/bench_stiff.py [--device pocl]

The scenes are tests/test_refine.py's (their large triangles float32-exact) and the
fandisk mesh scaled; the rays are each scene's float64 camera rays (Camera.rays). The
reference is kdray.reference.brute_force in float64 for the triangle, and that
triangle's plane in float64 for t. Per method: rays whose hit or miss differs from the
reference, rays naming another triangle, and the relative depth error (p99, max) on
rays that hit the reference's triangle. Open3D casts float32 world coordinates (its
API); embreex takes float64 rays and trimesh recomputes its hit points in float64.
"""
import argparse
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.join(os.path.dirname(HERE), "tests"))
import kdray  # noqa: E402
from kdray.reference import brute_force  # noqa: E402
from peers import installed  # noqa: E402
import test_refine  # noqa: E402  (the scenes)


def scaled_fandisk(s):
    import helpers
    from kdray.camera import Camera
    v, f = helpers.real_mesh_arrays("fandisk.obj")
    v = v * s
    lo, hi = v[np.unique(f)].min(0), v[np.unique(f)].max(0)
    return (v, f), Camera.frame(lo, hi, 48, 32)


def cases():
    """{name: ((vertices, faces), camera)}."""
    out = {}
    for name, make in test_refine.CASES.items():
        (v, f), camera = make()
        out[name] = ((v, f), camera)
        offset = np.array([3e6, -2e6, 1e6])
        pose = np.array(camera.cam_to_world)
        pose[:3, 3] += offset
        out[name + "-far"] = ((v + offset, f), kdray.Camera.from_intrinsics(
            camera.K, pose, camera.width, camera.height))
    out["fandisk-1e15"] = scaled_fandisk(1e15)
    out["fandisk-1e-20"] = scaled_fandisk(1e-20)
    return out


def kdray_hits(v, f, o, d, device, **options):
    precision = options.pop("precision", "single")
    tree = kdray.build(v, f, keep_double=precision == "double")
    hits = kdray.Tracer(tree, device=device, **options).trace(o, d, precision=precision)
    return hits.t.astype(np.float64), np.where(hits.hit, hits.prim.astype(np.int64), -1)


def open3d_hits(v, f, o, d):
    from peers import open3d_cast, open3d_scene
    scene, _ = open3d_scene(kdray.Mesh.from_arrays(v, f))
    t, prim, _ = open3d_cast(scene, o, d)
    return t.astype(np.float64), prim


def embreex_hits(v, f, o, d):
    import trimesh
    from trimesh.ray.ray_pyembree import RayMeshIntersector
    mesh = trimesh.Trimesh(v, f, process=False)
    tri, ray, loc = RayMeshIntersector(mesh).intersects_id(o, d, multiple_hits=False,
                                                           return_locations=True)
    t = np.full(len(o), np.inf)
    prim = np.full(len(o), -1, dtype=np.int64)
    t[ray] = np.einsum("ij,ij->i", loc - o[ray], d[ray]) / np.einsum("ij,ij->i", d[ray], d[ray])
    prim[ray] = tri
    return t, prim


def row(name, method, t, prim, ref_t, ref_prim):
    same = (prim >= 0) & (prim == ref_prim)
    rel = np.abs(t[same] - ref_t[same]) / ref_t[same]
    p99 = np.percentile(rel, 99) if len(rel) else float("nan")
    mx = rel.max() if len(rel) else float("nan")
    return (f"| {name} | {method} | {np.count_nonzero((prim >= 0) != (ref_prim >= 0))} "
            f"| {np.count_nonzero((prim >= 0) & (ref_prim >= 0) & (prim != ref_prim))} "
            f"| {p99:.2e} | {mx:.2e} |")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--device", default=None)
    args = ap.parse_args()
    methods = {"kdray": dict(), "kdray refine=0": dict(refine=False),
               "kdray double": dict(precision="double")}
    print(f"# rays per case: 48 x 32 camera rays; device {args.device or 'default'}")
    print("| case | method | hit/miss differ | other triangle | depth p99 | depth max |")
    print("|---|---|---:|---:|---:|---:|")
    for name, ((v, f), camera) in cases().items():
        o, d = camera.rays()
        ref = brute_force(v[f], o, d)
        hit = ref.prim >= 0
        ref_t = np.full(len(o), np.inf)
        ref_t[hit] = test_refine.plane_hits(v[f][ref.prim[hit]], o[hit], d[hit])[0]
        for method, options in methods.items():
            t, prim = kdray_hits(v, f, o, d, args.device, **options)
            print(row(name, method, t, prim, ref_t, ref.prim))
        for method, fn in (("open3d", open3d_hits), ("embreex", embreex_hits)):
            if installed(method):
                t, prim = fn(v, f, o, d)
                print(row(name, method, t, prim, ref_t, ref.prim))


if __name__ == "__main__":
    main()
