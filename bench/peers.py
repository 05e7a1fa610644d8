"""Other ray casters on kdray's rays, for the bench/ scripts: Open3D's RaycastingScene,
embreex through trimesh and Mitsuba 3 (the `bench` extra: pip install -e '.[bench]').

Each `*_hits(mesh, o, d, repeat)` returns (build s, median trace s, t, prim (-1 on a
miss), normal or None) on numpy rays, numpy hits out: the method protocol of
`kdray.bench.run`, which `PEERS` wraps (`peer("open3d")`). Open3D, embreex and Mitsuba
are imported only when used.
Mitsuba runs as its variant MITSUBA_VARIANT, llvm_ad_rgb (the CPU: Dr.Jit's LLVM backend
on Mitsuba's Embree BVH), which is set at its first use here (`mitsuba_module`).
"""
import time
from dataclasses import dataclass

import numpy as np

from kdray.bench import timed


def open3d_scene(mesh):
    """Open3D's RaycastingScene of a mesh in float32 world coordinates, its BVH built
    (Open3D builds lazily, at the first cast). Returns (scene, build seconds)."""
    import open3d as o3d
    t0 = time.perf_counter()
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(mesh.vertices.astype(np.float32)),
                        o3d.core.Tensor(mesh.faces.astype(np.uint32)))
    scene.cast_rays(o3d.core.Tensor(np.zeros((1, 6), np.float32)))
    return scene, time.perf_counter() - t0


def open3d_arrays(scene, o, d, keys=("t_hit", "primitive_ids")):
    """numpy rays -> Open3D's cast_rays -> the numpy arrays of its result's `keys` (t_hit
    +inf on a miss, primitive_ids Open3D's invalid id there)."""
    import open3d as o3d
    r = scene.cast_rays(o3d.core.Tensor(np.concatenate([o, d], axis=1).astype(np.float32)))
    return tuple(r[k].numpy() for k in keys)


def hit_prims(t, prim):
    """(N,) int64: prim where t is finite (a hit), else -1."""
    return np.where(np.isfinite(t), prim.astype(np.int64), -1)


def open3d_cast(scene, o, d):
    """numpy rays -> Open3D -> numpy (t, prim with -1 on a miss, normal)."""
    t, prim, normal = open3d_arrays(scene, o, d, ("t_hit", "primitive_ids", "primitive_normals"))
    return t, hit_prims(t, prim), normal


def open3d_hits(mesh, o, d, repeat):
    """Open3D's RaycastingScene, numpy rays to numpy hits (float32 world coordinates).
    Returns (build s, median trace s, t, prim (-1 on a miss), normal)."""
    scene, build_s = open3d_scene(mesh)
    s, (t, prim, normal) = timed(lambda: open3d_cast(scene, o, d), repeat)
    return build_s, s, t, prim, normal


def embreex_hits(mesh, o, d, repeat):
    """trimesh's embreex front end, numpy to numpy (hit points refined in float64 by
    trimesh). Returns (build s, median trace s, t, prim (-1 on a miss), None)."""
    import trimesh
    from trimesh.ray.ray_pyembree import RayMeshIntersector
    t0 = time.perf_counter()
    tm = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)
    rmi = RayMeshIntersector(tm)
    rmi.intersects_first(o[:1], d[:1])
    build_s = time.perf_counter() - t0

    def run():
        tri, ray, loc = rmi.intersects_id(o, d, multiple_hits=False, return_locations=True)
        t = np.full(len(o), np.inf)
        prim = np.full(len(o), -1, dtype=np.int64)
        t[ray] = np.einsum("ij,ij->i", loc - o[ray], d[ray]) / np.einsum("ij,ij->i", d[ray], d[ray])
        prim[ray] = tri
        return t, prim
    s, (t, prim) = timed(run, repeat)
    return build_s, s, t, prim, None


MITSUBA_VARIANT = "llvm_ad_rgb"
"""Mitsuba 3's variant for the peer: its CPU back end (Dr.Jit's LLVM JIT, Embree's BVH),
RGB (the cheapest of the LLVM variants; ray casting does not depend on it)."""


def mitsuba_module():
    """mitsuba, imported and set to MITSUBA_VARIANT at the first call."""
    import mitsuba as mi
    if mi.variant() != MITSUBA_VARIANT:
        mi.set_variant(MITSUBA_VARIANT)
    return mi


def mitsuba_version():
    """Mitsuba's version and what it runs on, for a bench's header:
    'Mitsuba 3.9.1 (llvm_ad_rgb, Dr.Jit 1.5.0, 2 threads)'."""
    mi = mitsuba_module()
    import drjit as dr
    return f"Mitsuba {mi.__version__} ({mi.variant()}, Dr.Jit {dr.__version__}, " \
           f"{dr.thread_count()} threads)"


def mitsuba_rays(o, d):
    """numpy (N, 3) origins and directions -> mi.Ray3f (float32, maxt +inf).

    Each array is made float32 in numpy (one pass over a contiguous array), copied flat
    into Dr.Jit and split into x, y, z by dr.unravel, a gather that runs in Dr.Jit's
    threads: the fastest of the conversions tried, faster than a (3, N) array or three
    mi.Float columns, whose transpose in numpy costs more (commit 4aeee7e has the
    figures)."""
    mi = mitsuba_module()
    import drjit as dr
    return mi.Ray3f(dr.unravel(mi.Point3f, mi.Float(np.ascontiguousarray(o, np.float32).ravel())),
                    dr.unravel(mi.Vector3f, mi.Float(np.ascontiguousarray(d, np.float32).ravel())))


def mitsuba_scene(mesh):
    """Mitsuba 3's scene of one mesh in float32 world coordinates (no vertex normals:
    face normals), its BVH built (Embree's, when the scene is loaded) and a first
    one-ray cast made, as `open3d_scene` does (it compiles the cast's kernel, or loads
    it from Dr.Jit's kernel cache). Returns (scene, build seconds)."""
    mi = mitsuba_module()
    t0 = time.perf_counter()
    shape = mi.Mesh("mesh", vertex_count=len(mesh.vertices), face_count=len(mesh.faces),
                    has_vertex_normals=False, has_vertex_texcoords=False)
    params = mi.traverse(shape)
    params["vertex_positions"] = mi.Float(np.ascontiguousarray(mesh.vertices, np.float32).ravel())
    params["faces"] = mi.UInt32(np.ascontiguousarray(mesh.faces, np.uint32).ravel())
    params.update()
    scene = mi.load_dict({"type": "scene", "mesh": shape})
    mitsuba_cast(scene, np.zeros((1, 3)), np.array([[0.0, 0.0, 1.0]]))
    return scene, time.perf_counter() - t0


def mitsuba_cast(scene, o, d, coherent=True):
    """numpy rays -> Mitsuba's ray_intersect_preliminary -> numpy (t float32 +inf on a
    miss, prim int64 -1 on a miss). coherent: Mitsuba's hint to Embree that neighbouring
    rays are alike (a camera's are).

    Dr.Jit is lazy and asynchronous: t and prim are evaluated together, in one kernel
    with the cast, and .numpy() waits for it. (Calling .numpy() on each alone would
    run the cast twice.)"""
    mi = mitsuba_module()
    import drjit as dr
    pi = scene.ray_intersect_preliminary(mitsuba_rays(o, d), coherent=coherent)
    prim = dr.select(dr.isfinite(pi.t), mi.Int64(pi.prim_index), -1)
    dr.eval(pi.t, prim)
    return pi.t.numpy(), prim.numpy()


def mitsuba_hits(mesh, o, d, repeat):
    """Mitsuba 3 (MITSUBA_VARIANT), numpy rays to numpy hits through
    ray_intersect_preliminary (coherent; float32 world coordinates). Returns (build s,
    median trace s, t, prim (-1 on a miss), None)."""
    scene, build_s = mitsuba_scene(mesh)
    s, (t, prim) = timed(lambda: mitsuba_cast(scene, o, d), repeat)
    return build_s, s, t, prim, None


PEERS = {"open3d": open3d_hits, "embreex": embreex_hits, "mitsuba": mitsuba_hits}
"""name -> method; the module each needs has the same name."""


@dataclass(frozen=True)
class Peer:
    """A peer as a `kdray.bench.run` setting: `name` and `hits(mesh, o, d, repeat)`."""
    name: str

    def hits(self, mesh, o, d, repeat):
        return PEERS[self.name](mesh, o, d, repeat)


def installed(name):
    """Whether the peer's module imports (Open3D also needs the system's libusb-1.0) and,
    for Mitsuba, its variant can be set (the LLVM back end needs a libLLVM shared library
    on the system, or DRJIT_LIBLLVM_PATH)."""
    try:
        if name == "mitsuba":
            mitsuba_module()
        else:
            __import__(name)
        return True
    except Exception:
        return False
