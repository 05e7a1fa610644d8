"""kdray against Embree's own C++ API (bench/embree_anchor.cpp), beside Open3D and
Mitsuba 3, on the same rays in turns: incoherent rays and camera rays.

usage: python bench/bench_embree.py [--meshes bunny,bunny-1.6M] [--rays 1048576]
                                    [--size 1024] [--repeat 5] [--sample 20000]
                                    [--kinds uniform,centre,ao,light,sun,camera]
                                    [--device SPEC]
                                    [--occluded]

Ray kinds (seeded, float64, world coordinates):
  uniform   origins uniform in the mesh's box, directions uniform on the sphere
  centre    from the box's centre, directions uniform on the sphere
  ao        ambient-occlusion rays: points on triangles (uniform by area), directions
            cosine-weighted about the face's normal, origins moved 1e-5 of the box's
            diagonal along the ray (AO_OFFSET): the same rays for every method, Open3D
            and Mitsuba taking no t_min
  aimed     (not in the default kinds) rays that mostly hit, from a sphere around the
            mesh to random points on its surface (bench_queries.py's)
  light     shadow rays: points on triangles (as ao's)
            toward a point light one box diagonal from the box's centre (LIGHT), the
            directions the light's offset, origins moved as ao's
  sun       the same points along one direction (LIGHT's)
  camera    the framing camera's size x size rays (kdray.Camera.frame)
Methods, timed in turns (timing.round_robin, every call 0.1 s after the one before),
each up to its caster's own outputs (t, and prim or the id image, as numpy arrays; in
C++ for Embree): misses are made -1 for the accuracy columns after the timing.
  kdray trace        Tracer.trace(o, d, outputs=()): t and prim, numpy to numpy
  kdray trace32      the same with the rays rounded to float32 beforehand (outside the
                     time, as the anchor's): 24 bytes a ray read instead of 48
  kdray render       (camera) Tracer.render(camera, ["depth", "id"]): rays made on the
                     device
  embree1            rtcIntersect1 over TBB's parallel_for, from C++ (no Python inside)
  embree16           (camera) rtcIntersect16 on 4 x 4 tiles, coherent context
  open3d             RaycastingScene.cast_rays, numpy to numpy (t_hit, primitive_ids)
  mitsuba            ray_intersect_preliminary (coherent only for the camera), numpy
                     to numpy
  kdray occluded,    (--occluded) Tracer.occluded(o, d) and rtcOccluded1 (incoherent
  embree occluded1   context): any hit; then each one's speed against its own nearest
                     hit's (the issue's bar: occluded 1.5x trace on rays that hit)
Printed per mesh and kind: median seconds, Mrays/s, and errors on --sample rays
against the float64 reference (reference.traverse over the input mesh in float64):
hit/miss disagreements, different triangles, relative t error (99th percentile, max);
then kdray's ratios (>= 1: kdray is faster; the median of the rounds' ratios) against
each peer. A peer that is not installed is left out with a note (Embree's C++ anchor
needs g++, libembree-dev and libtbb-dev: `make bench-deps`).
"""
import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_trace import accuracy, cpu_model, peer_versions  # noqa: E402
from embree_anchor import EmbreeAnchor, anchor_missing  # noqa: E402
from meshes import mesh as bench_mesh  # noqa: E402
from peers import hit_prims, mitsuba_cast, mitsuba_scene, open3d_arrays, open3d_scene  # noqa: E402
from timing import median_ratio, round_robin  # noqa: E402

import kdray  # noqa: E402
from kdray import reference  # noqa: E402

KINDS = ("uniform", "centre", "ao", "light", "sun", "camera")


def unit(rng, n):
    d = rng.normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1)[:, None]


AO_OFFSET = 1e-5
"""An ambient-occlusion ray's origin is its surface point moved this much of the box's
diagonal along the ray: a point on a triangle rounded to float32 lies on either side
of it (about 6e-8 of its distance from the tree's origin), and half of such rays would
hit their own triangle at t > 0 in every caster."""


def surface_points(mesh, n, rng):
    """(points, normals) (n, 3) float64: points on the mesh's triangles, uniform by area,
    and their triangles' unit normals."""
    tri = mesh.triangles
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = np.linalg.norm(normal, axis=1)
    pick = rng.choice(len(tri), size=n, p=area / area.sum())
    r1, r2 = rng.random(n), rng.random(n)
    s = np.sqrt(r1)
    p = ((1 - s)[:, None] * tri[pick, 0] + (s * (1 - r2))[:, None] * tri[pick, 1]
         + (s * r2)[:, None] * tri[pick, 2])
    return p, normal[pick] / area[pick][:, None]


def ao_rays(mesh, n, rng, offset):
    """Points on triangles (`surface_points`), cosine-weighted directions about each
    triangle's normal, the points moved `offset` along the ray: (o, d) (n, 3) float64."""
    o, z = surface_points(mesh, n, rng)
    x = np.cross(z, np.where(np.abs(z[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]]))
    x /= np.linalg.norm(x, axis=1)[:, None]
    y = np.cross(z, x)
    phi, r = 2 * np.pi * rng.random(n), np.sqrt(rng.random(n))
    d = (r * np.cos(phi))[:, None] * x + (r * np.sin(phi))[:, None] * y \
        + np.sqrt(1 - r * r)[:, None] * z
    return o + offset * d, d


LIGHT = np.array([0.3, 1.0, 0.6]) / np.linalg.norm([0.3, 1.0, 0.6])
"""Where `light`'s point light lies from the box's centre (times its diagonal), and
`sun`'s direction."""


def shadow_rays(mesh, n, rng, lo, hi, sun=False):
    """Rays from points on triangles (uniform by area, as `ao_rays`') toward a point
    light (LIGHT times the box's diagonal from its centre), or along LIGHT (sun), the
    points moved AO_OFFSET of the diagonal along each ray: (o, d) (n, 3) float64."""
    p, _ = ao_rays(mesh, n, rng, 0.0)
    diag = float(np.linalg.norm(hi - lo))
    d = np.tile(LIGHT, (n, 1)) if sun else 0.5 * (lo + hi) + diag * LIGHT - p
    return p + AO_OFFSET * diag * d / np.linalg.norm(d, axis=1)[:, None], d


def rays_of(kind, mesh, tree, args, rng):
    """(o, d, camera or None) for a kind."""
    lo, hi = (np.asarray(x, dtype=np.float64) for x in tree.world_box())
    if kind in ("light", "sun"):
        return (*shadow_rays(mesh, args.rays, rng, lo, hi, sun=kind == "sun"), None)
    if kind == "uniform":
        return lo + (hi - lo) * rng.random((args.rays, 3)), unit(rng, args.rays), None
    if kind == "centre":
        return np.tile(0.5 * (lo + hi), (args.rays, 1)), unit(rng, args.rays), None
    if kind == "ao":
        return (*ao_rays(mesh, args.rays, rng, AO_OFFSET * np.linalg.norm(hi - lo)), None)
    if kind == "aimed":
        from bench_queries import aimed
        return (*aimed(mesh, tree, args.rays), None)
    camera = kdray.Camera.frame(lo, hi, args.size, args.size)
    o, d = camera.rays()
    return o, d, camera


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--meshes", default="bunny,bunny-1.6M")
    ap.add_argument("--rays", type=int, default=1 << 20)
    ap.add_argument("--size", type=int, default=1024)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--sample", type=int, default=20000)
    ap.add_argument("--kinds", default=",".join(KINDS))
    ap.add_argument("--device", default=None)
    ap.add_argument("--occluded", action="store_true",
                    help="also time any-hit queries (kdray occluded, Embree rtcOccluded1)")
    args = ap.parse_args()
    # kdray's device first: Open3D imported before it used to leave Intel's runtime
    # without its TBB (and it costs nothing now)
    first = kdray.build(np.eye(3), np.array([[0, 1, 2]]))
    device = kdray.Tracer(first, device=args.device).device
    versions, notes = peer_versions()
    missing = anchor_missing()
    print(f"# CPU {cpu_model()}; kdray on {device.name.strip()} ({device.platform.name.strip()}); "
          + "; ".join(v for v in versions.values() if v)
          + ("" if missing else "; Embree 3 C++ (libembree-dev)"))
    for note in notes + ([f"# Embree's C++ anchor left out: {missing}"] if missing else []):
        print(note)
    print(f"# {args.rays} rays a kind ({args.size}x{args.size} camera), median of {args.repeat} "
          f"rounds in turns; errors on {args.sample} rays against float64")
    print(f"{'mesh':<11} {'kind':<8} {'method':<13} {'ms':>8} {'Mrays/s':>8} {'hit':>5} "
          f"{'disagree':>8} {'prim!=':>6} {'t p99':>9} {'t max':>9}")
    for name in args.meshes.split(","):
        m = bench_mesh(name)
        tree = kdray.build(m.vertices, m.faces)
        tracer = kdray.Tracer(tree, device=args.device)
        anchor = None if missing else EmbreeAnchor.start(m)
        o3d_scene = open3d_scene(m)[0] if versions["open3d"] else None
        mi_scene = mitsuba_scene(m)[0] if versions["mitsuba"] else None
        try:
            for kind in args.kinds.split(","):
                rng = np.random.default_rng(1)
                o, d, camera = rays_of(kind, m, tree, args, rng)
                n = len(d)
                # each call ends at its caster's numpy outputs (Embree's, in C++, at its
                # t and prim arrays); `finish` makes them (t, prim int64 -1 on a miss)
                # for the accuracy columns after the timing, as the anchor's hits() does
                calls = {"kdray trace": lambda: tracer.trace(o, d, outputs=())}
                finish = {"kdray trace": lambda h: (h.t, hit_prims(h.t, h.prim))}
                # the same rays rounded to float32 beforehand, as Embree's anchor takes
                # them (made outside its time): what reading float64 rays costs kdray
                o32, d32 = o.astype(np.float32), d.astype(np.float32)
                calls["kdray trace32"] = lambda: tracer.trace(o32, d32, outputs=())
                finish["kdray trace32"] = finish["kdray trace"]
                if camera is not None:
                    calls["kdray render"] = lambda: tracer.render(camera, aovs=("depth", "id"))
                    # t: the rays' camera z is 1
                    finish["kdray render"] = lambda img: (img["depth"].ravel(), hit_prims(
                        img["depth"].ravel(), img["id"].ravel()))
                if anchor is not None:
                    anchor.rays(o, d)
                    calls["embree1"] = lambda: anchor.trace1()
                    if camera is not None:
                        calls["embree16"] = lambda: anchor.trace16(args.size, args.size)
                if o3d_scene is not None:
                    calls["open3d"] = lambda: open3d_arrays(o3d_scene, o, d)
                    finish["open3d"] = lambda r: (r[0], hit_prims(*r))
                if mi_scene is not None:
                    calls["mitsuba"] = lambda: mitsuba_cast(mi_scene, o, d, coherent=camera is not None)
                if args.occluded:
                    calls["kdray occluded"] = lambda: tracer.occluded(o, d)
                    if anchor is not None:
                        calls["embree occluded1"] = lambda: anchor.occluded1()
                wall, _, results = round_robin(calls, args.repeat)
                # any-hit answers: a hit fraction (and kdray's against the reference's)
                occluded = {k: results.pop(k) for k in ("kdray occluded", "embree occluded1")
                            if k in results}
                results = {k: finish.get(k, lambda r: r)(r) for k, r in results.items()}
                sample = np.random.default_rng(2).choice(n, size=min(args.sample, n), replace=False)
                ref = reference.traverse(tree, o[sample], d[sample], triangles64=m.triangles)
                ref_prim = np.where(ref.hit, ref.prim, -1)
                if anchor is not None:
                    results["embree1"] = results["embree16"] = anchor.hits()   # the last call's
                for method, s in wall.items():
                    ms = 1e3 * float(np.median(s))
                    if method in occluded:
                        r = occluded[method]
                        hit = r.mean() if method == "kdray occluded" else r[1] / n
                        wrong = (np.count_nonzero(r[sample] != ref.hit)
                                 if method == "kdray occluded" else "-")
                        print(f"{name:<11} {kind:<8} {method:<13} {ms:>8.1f} {n / ms / 1e3:>8.2f} "
                              f"{hit:>5.2f} {wrong:>8}", flush=True)
                        continue
                    t, prim = results[method]
                    acc = accuracy(t, prim, ref.t, ref_prim, sample)
                    print(f"{name:<11} {kind:<8} {method:<13} {ms:>8.1f} {n / ms / 1e3:>8.2f} "
                          f"{np.isfinite(np.asarray(t)).mean():>5.2f} {acc['disagree']:>8} "
                          f"{acc['prim_diff']:>6} {acc['p99']:>9.1e} {acc['max']:>9.1e}", flush=True)
                ours = [k for k in wall if k.startswith("kdray")]
                for peer in [k for k in wall if not k.startswith("kdray")]:
                    print(f"{'':<11} {kind:<8} " + ", ".join(
                        f"{k} / {peer} {median_ratio(wall[peer], wall[k]):.2f}x" for k in ours
                        if (k == "kdray occluded") == (peer == "embree occluded1")))
                for any_hit, nearest in (("kdray occluded", "kdray trace"),
                                         ("embree occluded1", "embree1")):
                    if any_hit in wall and nearest in wall:
                        print(f"{'':<11} {kind:<8} {any_hit} / {nearest}: "
                              f"{median_ratio(wall[nearest], wall[any_hit]):.2f}x its speed")
        finally:
            if anchor is not None:
                anchor.close()


if __name__ == "__main__":
    main()
