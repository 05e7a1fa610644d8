"""load(path) -> Mesh. The only module that imports trimesh.

OBJ and PLY first, then anything trimesh loads as triangles (STL, OFF, GLB/glTF):
quads and polygons are triangulated by trimesh's loaders, scenes of several meshes
are flattened with their node transforms applied, materials and textures are skipped
(no image library is needed). Triangle ids are the order of the loaded triangles:
meshes are taken in the scene graph's order, each mesh's faces in file order. A file
whose name ends in .gz is read through gzip ("bunny.obj.gz" as an OBJ named
"bunny.obj").
"""
import gzip
import logging
import os

import numpy as np

from .errors import MeshError
from .mesh import Mesh

log = logging.getLogger(__name__)


def load(path):
    """Load a mesh file as triangles. Returns Mesh; raises MeshError naming the file."""
    path = os.fspath(path)
    if not os.path.exists(path):
        raise MeshError(f"{path}: no such file")
    if os.path.isdir(path):
        raise MeshError(f"{path}: is a folder, not a mesh file")
    if not os.access(path, os.R_OK):
        raise MeshError(f"{path}: cannot be read (permission denied)")
    if os.path.getsize(path) == 0:
        raise MeshError(f"{path}: is empty")
    import trimesh

    file_name = os.path.basename(path)
    zipped = file_name.lower().endswith(".gz")
    if zipped:
        file_name = file_name[:-3]
    ext = os.path.splitext(file_name)[1].lower().lstrip(".")
    if ext not in trimesh.available_formats():
        raise MeshError(f"{path}: unknown mesh format {'.' + ext if ext else '(no extension)'} "
                        f"(kdray reads OBJ, PLY, STL, OFF, GLB/glTF and what else trimesh loads)")
    try:
        if zipped:
            with gzip.open(path, "rb") as f:
                scene = trimesh.load(f, file_type=ext, force="scene", process=False,
                                     skip_materials=True)
        else:
            scene = trimesh.load(path, force="scene", process=False, skip_materials=True)
    except IndexError as e:
        raise MeshError(f"{path}: a face refers to a vertex that does not exist ({e})") from None
    except Exception as e:  # trimesh raises many kinds for a malformed file
        raise MeshError(f"{path}: cannot be read as a mesh ({type(e).__name__}: {e})") from None
    vertices, faces = [], []
    offset = 0
    for node in scene.graph.nodes_geometry:
        transform, name = scene.graph[node]
        geom = scene.geometry[name]
        if not isinstance(geom, trimesh.Trimesh) or len(geom.faces) == 0:
            log.info("%s: skipping %s (%s, no triangles)", path, name, type(geom).__name__)
            continue
        v = np.asarray(geom.vertices, dtype=np.float64)
        if not np.allclose(transform, np.eye(4)):
            v = v @ transform[:3, :3].T + transform[:3, 3]
        vertices.append(v)
        faces.append(np.asarray(geom.faces, dtype=np.int64) + offset)
        offset += len(v)
    if not faces:
        kinds = sorted({type(g).__name__ for g in scene.geometry.values()})
        what = f" (only {', '.join(kinds)})" if kinds else ""
        raise MeshError(f"{path}: contains no triangles{what}")
    return Mesh.from_arrays(np.concatenate(vertices), np.concatenate(faces), name=file_name)
