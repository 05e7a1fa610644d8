"""load(path) -> Mesh. The only module that imports trimesh.

OBJ and PLY first, then anything trimesh loads as triangles (STL, OFF, GLB/glTF):
quads and polygons are triangulated by trimesh's loaders, scenes of several meshes
are flattened with their node transforms applied, materials and textures are skipped
(no image library is needed). Triangle ids are the order of the loaded triangles:
meshes are taken in the scene graph's order, each mesh's faces in file order. A file
whose name ends in .gz is read through gzip ("bunny.obj.gz" as an OBJ named
"bunny.obj").

Objects (Mesh.objects, Mesh.object_names), numbered in the order of their first
triangle:

- glTF/GLB and other scenes: a node of the scene graph that has a mesh, each instance
  of a mesh apart, named after the node (trimesh makes the names unique); the
  primitives of a glTF mesh are one object, their node's.
- OBJ: the faces under one `o` name and one `g` name, named as trimesh's
  split_objects/split_groups name them ("o", "g", or "o_g"; faces before any `o` or
  `g` are named after the file). Materials (`usemtl`) do not make objects. They are
  found by a second read of the file with trimesh's splitting, only when it has `o`
  or `g` lines, and matched to the first read's triangles by their coordinates, so
  that triangle ids do not depend on the objects (trimesh's split orders faces by
  object). Exactly equal triangles in different objects may swap objects.
- A file whose triangles all belong to one object (STL, PLY, OFF, an OBJ with no `o`
  or `g`, a scene of one node) has one object, named after the file.
"""
import dataclasses
import gzip
import io
import logging
import os
import re
import warnings

import numpy as np

from .errors import MeshError, one_line
from .mesh import Mesh, check_objects

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
    # trimesh and numpy warn about what a malformed file holds (an index cast from
    # 4294967295, a transform that overflows); Mesh.from_arrays refuses what is left of it
    with warnings.catch_warnings(), np.errstate(all="ignore"):
        warnings.simplefilter("ignore")
        try:
            if zipped:
                with gzip.open(path, "rb") as f:
                    scene = trimesh.load(f, file_type=ext, force="scene", process=False,
                                         skip_materials=True)
            else:
                scene = trimesh.load(path, force="scene", process=False, skip_materials=True)
        except IndexError as e:
            raise MeshError(f"{path}: a face refers to a vertex that does not exist ({one_line(e)})") from None
        except Exception as e:  # trimesh raises many kinds for a malformed file
            raise MeshError(f"{path}: cannot be read as a mesh ({type(e).__name__}: {one_line(e)})") from None
        vertices, faces, objects, object_names = _scene_arrays(scene, path)
    if not faces:
        kinds = sorted({type(g).__name__ for g in scene.geometry.values()})
        what = f" (only {', '.join(kinds)})" if kinds else ""
        raise MeshError(f"{path}: contains no triangles{what}")
    mesh = Mesh.from_arrays(np.concatenate(vertices), np.concatenate(faces), name=file_name)
    if ext == "obj":
        objects, object_names = _obj_objects(path, zipped, file_name, mesh.triangles)
    if len(object_names) > 1:                   # else one object, named after the file
        objects, object_names = check_objects(objects, object_names, len(mesh.faces))
        mesh = dataclasses.replace(mesh, objects=objects, object_names=object_names)
    return mesh


def _scene_arrays(scene, path):
    """The triangles of a trimesh Scene, node by node in the graph's order, transforms
    applied: (vertices [(n_i, 3) float64], faces [(m_i, 3) int64] indexing the
    concatenated vertices, objects (m,) uint32, object_names tuple): objects numbered
    in the order of their first triangle."""
    import trimesh
    vertices, faces, objects = [], [], []
    names = {}                                  # object name -> index, in order of appearance
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
        index = names.setdefault(_object_name(scene, node, geom), len(names))
        objects.append(np.full(len(geom.faces), index, dtype=np.uint32))
    objects = np.concatenate(objects) if objects else np.zeros(0, dtype=np.uint32)
    return vertices, faces, objects, tuple(names)


def _object_name(scene, node, geom):
    """The object a scene graph node's triangles belong to: the node, or for one of the
    nodes trimesh makes for the primitives of a glTF mesh (randomly named), its parent:
    the glTF node."""
    if geom.metadata.get("from_gltf_primitive"):
        parent = scene.graph.transforms.parents.get(node)
        if parent is not None and parent != scene.graph.base_frame:
            return parent
    return node


_OBJ_GROUP_LINE = re.compile(rb"^[ \t]*[og][ \t]", re.MULTILINE)


def _obj_objects(path, zipped, file_name, triangles):
    """(objects (m,) uint32, object_names tuple) of an OBJ file: each triangle's `o`/`g`
    group as trimesh's split_objects and split_groups name it (a second read of the
    file), matched to `triangles` ((m, 3, 3) float64, the first read's, in triangle id
    order) by their coordinates. A file with no `o` or `g` line, or whose two reads do
    not hold the same triangles (then with a warning), is one object."""
    import trimesh
    one = np.zeros(len(triangles), dtype=np.uint32), (file_name,)
    with (gzip.open(path, "rb") if zipped else open(path, "rb")) as f:
        data = f.read()
    if not _OBJ_GROUP_LINE.search(data):
        return one
    stream = io.BytesIO(data)
    stream.name = file_name         # trimesh's name for faces outside any `o` and `g`
    try:
        split = trimesh.load(stream, file_type="obj", force="scene", process=False,
                             skip_materials=True, split_objects=True, split_groups=True,
                             group_material=False)
    except Exception as e:  # trimesh read the file once already: not expected
        log.warning("%s: cannot read its o/g groups (%s: %s); one object", path,
                    type(e).__name__, e)
        return one
    g_vertices, g_faces, g_objects, g_names = _scene_arrays(split, path)
    if len(g_names) <= 1:
        return one
    # the same triangles, bit for bit, in two orders: sort both and pair them up
    # (equal triangles pair in the order of their ids and of the groups); by a hash of
    # their bits, and by the bits themselves should two triangles' hashes collide
    a = np.ascontiguousarray(triangles, dtype=np.float64).reshape(-1, 9).view(np.uint64)
    b = np.ascontiguousarray(np.concatenate(g_vertices)[np.concatenate(g_faces)])
    b = b.reshape(-1, 9).view(np.uint64)
    different = (f"{path}: its o/g groups hold other triangles than the file ({len(b)}, "
                 f"{len(a)}); one object")
    if len(a) != len(b):
        log.warning("%s", different)
        return one
    for sort_key in (_row_hash, _row_bytes):
        order_a = np.argsort(sort_key(a), kind="stable")
        order_b = np.argsort(sort_key(b), kind="stable")
        if np.array_equal(a[order_a], b[order_b]):
            break
    else:
        log.warning("%s", different)
        return one
    objects = np.empty(len(a), dtype=np.uint32)
    objects[order_a] = g_objects[order_b]
    # numbered in the order of their first triangle in id order
    used, first = np.unique(objects, return_index=True)
    rank = np.zeros(len(g_names), dtype=np.uint32)
    rank[used[np.argsort(first)]] = np.arange(len(used), dtype=np.uint32)
    return rank[objects], tuple(g_names[i] for i in used[np.argsort(first)])


def _row_hash(rows):
    """(m,) uint64 hash of the bits of each row of an (m, k) uint64 array."""
    h = np.full(len(rows), 0x9E3779B97F4A7C15, dtype=np.uint64)
    for column in rows.T:
        h ^= column
        h *= np.uint64(0xBF58476D1CE4E5B9)
        h ^= h >> np.uint64(31)
    return h


def _row_bytes(rows):
    """(m,) the bytes of each row of a C-contiguous (m, k) array, as one sortable value."""
    return rows.view(np.dtype((np.void, rows.shape[1] * rows.itemsize))).ravel()
