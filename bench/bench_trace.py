"""Primary-ray speed and accuracy: kdray beside Open3D, Mitsuba 3 (and embreex) on the
same rays.

usage: python bench/bench_trace.py [--meshes bunny,bunny-1.6M] [--size 1024]
                                   [--repeat 5] [--sample 20000] [--device SPEC]

A header names the CPU, kdray's OpenCL device and the peers' versions. For each mesh:
build time (warm builds in turns, as the traces below: kdray.build, and Open3D's and
Mitsuba's scene set-up with their one-ray first cast, `peers.open3d_scene` and
`peers.mitsuba_scene`; the median of --repeat rounds, and the median of the rounds'
ratios kdray / Open3D, which issue 20 wants at most 2), then for 1024 x 1024 primary
rays of a framing camera (warm, median of --repeat rounds; kdray's, Open3D's and
Mitsuba's methods run round-robin, one call each per round, each 0.1 s after the one
before, so that the machine's drift hits them alike and no call pays for the one
before's worker threads):
  kdray render depth      Tracer.render(camera, ["depth"]): rays made on the device
  kdray render default    Tracer.render(camera) with depth, normal, bary, id
  kdray trace             Tracer.trace(origins, directions) from numpy to numpy: t,
                          prim, u, v and normal; the (N, 3) rays are found to be an
                          image in rows (kdray.ray_grid) and traced in its blocks
  kdray trace t,prim      the same with outputs=(): t and prim, as Mitsuba's below
  kdray trace HxW t,prim  the same rays shaped (H, W, 3), as an image's are: traced in
                          packets of 4 x 2 or 4 x 4 pixels (hits (H, W), flattened)
  open3d pinhole depth    create_rays_pinhole(K, pose) + cast_rays + t_hit to numpy
  open3d cast             RaycastingScene.cast_rays on a prepared tensor (cast only)
  open3d numpy            numpy rays -> tensor -> cast_rays -> numpy
  mitsuba prelim coherent numpy rays (kdray trace's) -> Ray3f ->
                          ray_intersect_preliminary(coherent=True) -> numpy t, prim
  mitsuba intersect       the same through ray_intersect(RayFlags.All, coherent=True):
                          the whole SurfaceInteraction evaluated, t and prim to numpy
  mitsuba depth           the pixel rays (numpy) -> ray_intersect_preliminary -> an
                          (H, W) z-depth image in numpy (the rays' camera-z is 1, so t
                          along them is kdray's depth)
  embreex                 trimesh's embreex front end, numpy to numpy (if installed)
and the ratios of the two workflows of issue 6, kdray render depth / open3d pinhole
depth and kdray trace / open3d numpy, and of issue 20 against Mitsuba 3's CPU ray
casting, kdray trace t,prim (and HxW t,prim) / mitsuba prelim coherent and kdray render
depth / mitsuba depth
(>= 1: kdray is faster), each the median of the per-round ratios of the peer's time to
kdray's. Mitsuba runs as bench/peers.py's MITSUBA_VARIANT (llvm_ad_rgb); a peer that
is not installed is left out with a note.
Accuracy on --sample random pixels against a float64 reference (the input mesh in
float64, candidates from kdray's tree): hit/miss disagreements, relative depth error
(99th percentile and max, over rays both hit).
"""
import argparse
import importlib.metadata
import os
import platform
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from meshes import mesh as bench_mesh  # noqa: E402

import kdray  # noqa: E402
from kdray import reference  # noqa: E402
from kdray.render import DEFAULT_AOVS  # noqa: E402
from kdray.trace import TRACE_OUTPUTS  # noqa: E402
from peers import (embreex_hits, mitsuba_cast, mitsuba_module, mitsuba_rays,  # noqa: E402
                   mitsuba_scene, mitsuba_version, open3d_cast, open3d_scene)
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


def cpu_model():
    """The CPU's model name (/proc/cpuinfo), or what the platform module says."""
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.partition(":")[2].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def peer_versions():
    """({peer: its version text, or None when it is left out}, ["# peer left out: why"]).
    Imports the peers: call after kdray's first Tracer (see main)."""
    def open3d():
        import open3d as o3d
        return f"Open3D {o3d.__version__}"

    def embreex():
        import embreex
        try:
            return f"embreex {importlib.metadata.version('embreex')}"
        except importlib.metadata.PackageNotFoundError:
            return f"embreex {getattr(embreex, '__version__', '(version unknown)')}"

    versions, notes = {}, []
    for name, version in (("open3d", open3d), ("mitsuba", mitsuba_version), ("embreex", embreex)):
        try:
            versions[name] = version()
        except Exception as e:          # ImportError; OSError: Open3D without libusb-1.0
            versions[name] = None
            notes.append(f"# {name} left out: {e}")
    return versions, notes


def open3d_calls(m, o, d, camera):
    """Open3D's methods as zero-argument calls returning (t, prim or None) (its build is
    timed by `build_seconds`)."""
    import open3d as o3d
    scene, _ = open3d_scene(m)
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
            "open3d numpy": lambda: open3d_cast(scene, o, d)[:2]}


def mitsuba_calls(m, o, d, camera):
    """Mitsuba 3's methods as zero-argument calls returning (t, prim or None) (its build
    is timed by `build_seconds`). Each starts from kdray trace's numpy rays and ends in numpy arrays,
    which waits for Dr.Jit's asynchronous kernels."""
    mi = mitsuba_module()
    import drjit as dr
    scene, _ = mitsuba_scene(m)
    shape = (int(camera.height), int(camera.width))

    def prelim():
        return mitsuba_cast(scene, o, d, coherent=True)

    def intersect():
        si = scene.ray_intersect(mitsuba_rays(o, d), mi.RayFlags.All, True)
        prim = dr.select(si.is_valid(), mi.Int64(si.prim_index), -1)
        dr.eval(si, prim)       # all of it (p, n, uv, frames, partials), as its caller has it
        return si.t.numpy(), prim.numpy()

    def depth():
        # an (H, W) image: t along the camera's rays, whose camera-z is 1, is the z-depth
        # kdray renders (+inf on a miss)
        pi = scene.ray_intersect_preliminary(mitsuba_rays(o, d), coherent=True)
        return pi.t.numpy().reshape(shape)

    return {"mitsuba prelim coherent": prelim, "mitsuba intersect": intersect,
            "mitsuba depth": lambda: (depth().ravel(), None)}


def build_seconds(m, versions, repeat):
    """{"kdray", "open3d", "mitsuba" (those installed): (repeat,) wall seconds} of warm
    builds of mesh m, in turns (`timing.round_robin`: one untimed build each first)."""
    calls = {"kdray": lambda: kdray.build(m.vertices, m.faces)}
    if versions["open3d"]:
        calls["open3d"] = lambda: open3d_scene(m)
    if versions["mitsuba"]:
        calls["mitsuba"] = lambda: mitsuba_scene(m)
    wall, _, _ = round_robin(calls, repeat)
    return wall


def embreex_runs(m, o, d, repeat):
    build, s, t, prim, _ = embreex_hits(m, o, d, max(1, repeat // 2))
    return [("embreex", build, s, t, prim)]


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--meshes", default="bunny,bunny-1.6M")
    ap.add_argument("--size", type=int, default=1024)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--sample", type=int, default=20000)
    ap.add_argument("--device", default=None)
    args = ap.parse_args()
    n_rays = args.size * args.size
    rng = np.random.default_rng(0)
    # kdray's OpenCL device before any peer: Intel's CPU runtime fails to load in a
    # process that has imported Open3D (which bundles an older TBB). Mitsuba imported
    # first does no harm (checked with 3.9.1), but it comes after kdray too.
    first = kdray.build(np.eye(3), np.array([[0, 1, 2]]))         # compiles the builder
    device = kdray.Tracer(first, device=args.device).device
    versions, notes = peer_versions()
    print(f"# CPU {cpu_model()}; kdray on {device.name.strip()} ({device.platform.name.strip()}); "
          + "; ".join(v for v in versions.values() if v))
    for note in notes:
        print(note)
    print(f"# {n_rays} primary rays ({args.size}x{args.size}), median of {args.repeat} warm rounds")
    header = f"{'mesh':<12} {'tris':>9} {'method':<23} {'build s':>8} {'trace s':>8} {'Mrays/s':>8} " \
             f"{'disagree':>8} {'prim!=':>6} {'depth p99':>10} {'depth max':>10}"
    print(header)
    for name in args.meshes.split(","):
        m = bench_mesh(name)
        tree = kdray.build(m.vertices, m.faces)
        lo, hi = tree.world_box()
        camera = kdray.Camera.frame(lo, hi, args.size, args.size)
        o, d = camera.rays()
        sample = rng.choice(n_rays, size=min(args.sample, n_rays), replace=False)
        ref = reference.traverse(tree, o[sample], d[sample], triangles64=m.triangles)
        tracer = kdray.Tracer(tree, device=args.device)

        def render(aovs):
            img = tracer.render(camera, aovs=aovs)
            return img["depth"].ravel(), img["id"].ravel() if "id" in img else None

        def trace(outputs, shape=(-1,)):
            hits = tracer.trace(o.reshape(shape + (3,)), d.reshape(shape + (3,)), outputs=outputs)
            return hits.t.ravel(), hits.prim.ravel()

        calls = {"kdray render depth": lambda: render(("depth",)),
                 "kdray render default": lambda: render(DEFAULT_AOVS),
                 "kdray trace": lambda: trace(TRACE_OUTPUTS),
                 "kdray trace t,prim": lambda: trace(()),
                 "kdray trace HxW t,prim": lambda: trace((), (args.size, args.size))}
        for peer, peer_calls in (("open3d", open3d_calls), ("mitsuba", mitsuba_calls)):
            if versions[peer]:
                calls.update(peer_calls(m, o, d, camera))
        build_s = build_seconds(m, versions, args.repeat)
        builds = {peer: float(np.median(s)) for peer, s in build_s.items()}
        seconds, _, results = round_robin(calls, args.repeat)
        runs = [(method, builds[method.split()[0]], float(np.median(seconds[method])),
                 *results[method]) for method in seconds]
        if versions["embreex"]:
            runs += embreex_runs(m, o, d, args.repeat)
        for method, b, s, t, prim in runs:
            if prim is None:
                prim = np.where(np.isfinite(t), 0, -1)
                acc = accuracy(t, prim, ref.t, np.where(ref.hit, 0, -1), sample)
            else:
                prim = np.where(np.isfinite(t), np.asarray(prim).astype(np.int64), -1)
                acc = accuracy(t, prim, ref.t, ref.prim, sample)
            print(f"{name:<12} {len(m.faces):>9} {method:<23} {b:>8.3f} {s:>8.4f} {n_rays / s / 1e6:>8.2f} "
                  f"{acc['disagree']:>8} {acc['prim_diff']:>6} {acc['p99']:>10.2e} {acc['max']:>10.2e}",
                  flush=True)
        # issue 6's two workflows, kdray against Open3D, and issue 20's against Mitsuba 3
        # (>= 1 means kdray is faster)
        for ours, theirs in [("kdray render depth", "open3d pinhole depth"),
                             ("kdray trace", "open3d numpy"),
                             ("kdray trace t,prim", "mitsuba prelim coherent"),
                             ("kdray trace HxW t,prim", "mitsuba prelim coherent"),
                             ("kdray render depth", "mitsuba depth")]:
            if theirs in seconds:
                print(f"# {name}: {ours} / {theirs} = {median_ratio(seconds[theirs], seconds[ours]):.2f}"
                      f" (median of {len(seconds[ours])} rounds)", flush=True)
        if "open3d" in build_s:
            print(f"# {name}: build time kdray / open3d = "
                  f"{median_ratio(build_s['kdray'], build_s['open3d']):.2f} (median of "
                  f"{len(build_s['kdray'])} rounds; <= 1 means kdray builds faster)", flush=True)


if __name__ == "__main__":
    main()
