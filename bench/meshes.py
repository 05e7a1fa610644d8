"""Benchmark meshes: the real meshes the tests use (tests/data/meshes, gzipped) and
deterministic subdivisions of them.

`mesh(name)` -> kdray.Mesh for names like "bunny" (69,451 triangles), "bunny-x4"
(each triangle split into 4 once: 277,804), "teapot-x256" (1,617,920), ...
A suffix -x4^k subdivides k times (midpoint subdivision, deterministic); "bunny-1.6M"
is the bunny subdivided twice and its first 162,928 faces a third time (1,600,000),
"bunny-6M" three times and then part of a fourth (5,999,998): PARTIAL. A suffix -<N>k
cuts the mesh by a horizontal plane to its lowest N thousand triangles ("bunny-10k").
"""
import math
from pathlib import Path

import numpy as np

MESHES = Path(__file__).resolve().parents[1] / "tests" / "data" / "meshes"
FILES = {"bunny": "stanford-bunny.obj", "fandisk": "fandisk.obj", "teapot": "teapot.obj",
         "spot": "spot.obj"}


PARTIAL = {"bunny-1.6M": (2, 1_600_000), "bunny-6M": (3, 6_000_000)}
"""name -> (whole subdivisions of the bunny, then its first faces subdivided once more
up to about this many triangles)."""


def subdivide(vertices, faces, times):
    """Midpoint subdivision, `times` rounds: (n,3) float64, (m,3) int -> 4^times * m faces."""
    import trimesh.remesh
    for _ in range(times):
        vertices, faces = trimesh.remesh.subdivide(vertices, faces)
    return np.asarray(vertices, dtype=np.float64), np.asarray(faces, dtype=np.int64)


def mesh(name):
    """'bunny', 'bunny-x4', 'teapot-x256', 'bunny-10k', ... -> kdray.mesh.Mesh."""
    from kdray.load import load
    from kdray.mesh import Mesh
    if name in PARTIAL:
        import trimesh.remesh
        times, target = PARTIAL[name]
        b = mesh("bunny")
        v, f = subdivide(b.vertices, b.faces, times)
        extra = (target - len(f)) // 3                    # each subdivided face adds 3
        v, f = trimesh.remesh.subdivide(v, f, face_index=np.arange(extra))
        return Mesh.from_arrays(np.asarray(v, dtype=np.float64), np.asarray(f, dtype=np.int64),
                                name=name)
    base, _, cut = name.partition("-")
    if cut.endswith("k") and cut[:-1].isdigit():
        # the faces whose centroids are lowest (y), in their order in the file
        m = mesh(base)
        height = m.vertices[m.faces].mean(axis=1)[:, 1]
        keep = np.sort(np.argsort(height, kind="stable")[:int(cut[:-1]) * 1000])
        return Mesh.from_arrays(m.vertices, m.faces[keep], name=name)
    base, _, factor = name.partition("-x")
    m = load(MESHES / f"{FILES[base]}.gz")
    if factor:
        times = round(math.log(int(factor), 4))
        if 4 ** times != int(factor):
            raise ValueError(f"{name}: the factor must be a power of 4")
        v, f = subdivide(m.vertices, m.faces, times)
        m = Mesh.from_arrays(v, f, name=name)
    return m


def framed(name, size):
    """(mesh, tree, camera, o, d) of the mesh `name`: its tree (default parameters), the
    camera framing the tree's box at size x size pixels (`Camera.frame`) and that
    camera's rays (`Camera.rays`: (size * size, 3) float64 origins and directions,
    row-major pixels)."""
    import kdray
    m = mesh(name)
    tree = kdray.build(m.vertices, m.faces)
    lo, hi = tree.world_box()
    camera = kdray.Camera.frame(lo, hi, size, size)
    o, d = camera.rays()
    return m, tree, camera, o, d
