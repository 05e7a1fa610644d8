"""Other ray casters on kdray's rays, for the bench/ scripts: Open3D's RaycastingScene
and embreex through trimesh (the `bench` extra: pip install -e '.[bench]').

Each `*_hits(mesh, o, d, repeat)` returns (build s, median trace s, t, prim (-1 on a
miss), normal or None) on numpy rays, numpy hits out: the method protocol of
`kdray.bench.run`, which `PEERS` wraps (`peer("open3d")`). Open3D and embreex are
imported only when used.
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


def open3d_cast(scene, o, d):
    """numpy rays -> Open3D -> numpy (t, prim with -1 on a miss, normal)."""
    import open3d as o3d
    r = scene.cast_rays(o3d.core.Tensor(np.concatenate([o, d], axis=1).astype(np.float32)))
    t = r["t_hit"].numpy()
    prim = np.where(np.isfinite(t), r["primitive_ids"].numpy().astype(np.int64), -1)
    return t, prim, r["primitive_normals"].numpy()


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


PEERS = {"open3d": open3d_hits, "embreex": embreex_hits}
"""name -> method; the module each needs has the same name."""


@dataclass(frozen=True)
class Peer:
    """A peer as a `kdray.bench.run` setting: `name` and `hits(mesh, o, d, repeat)`."""
    name: str

    def hits(self, mesh, o, d, repeat):
        return PEERS[self.name](mesh, o, d, repeat)


def installed(name):
    """Whether the peer's module imports (Open3D also needs the system's libusb-1.0)."""
    try:
        __import__(name)
        return True
    except Exception:
        return False
