"""load(path) -> Mesh. The only module that imports trimesh.

OBJ and PLY first, then anything trimesh loads as triangles (STL, OFF, GLB/glTF):
quads and polygons are triangulated by trimesh's loaders, scenes of several meshes
are flattened with their node transforms applied (a mirroring one reverses its
triangles' winding, as glTF 2.0 and trimesh's own flattening do), materials and
textures are skipped (no image library is needed). Triangle ids are the order of the
loaded triangles: meshes are taken in the scene graph's order (a glTF's as the file
lists its nodes, depth first, where trimesh walks them the other way round:
`_gltf_node_ranks`), each mesh's faces in file order (a PLY's put back in it:
`_ply_file_order`; an OBJ of several materials, which trimesh reads as a mesh a
material, is put back in the order of its face lines: `_obj_in_file_order`). A file
whose name ends in .gz is read through gzip ("bunny.obj.gz" as an OBJ named
"bunny.obj"). An OBJ's relative (negative) indices count back from the vertex read
last before their line, as the format has it (trimesh counts from the file's last
vertex): such a file is read with them made absolute first (`_obj_absolute`).

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
import itertools
import logging
import os
import re
import warnings
import zlib

import numpy as np

from .errors import MeshError, one_line
from .mesh import Mesh, check_objects
from .off import Malformed, read_off
from .ply import read_binary_ply

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
    if not os.path.isfile(path):         # a device or a pipe, whose size reads 0
        raise MeshError(f"{path}: is a device or a pipe, not a mesh file (kdray reads a "
                        f"mesh from a file, by its name's format)")
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
        obj = None                  # an OBJ's bytes, read once for both its reads
        header = None               # a glTF's JSON, read once: checked, then its order
        try:
            if ext == "obj":
                obj = _text(_read(path, zipped))
                obj = _obj_plain(obj) or obj
                _obj_zero_index(obj)
                obj = _obj_absolute(obj) or obj
            if ext in ("glb", "gltf"):
                header = _gltf_header(path, zipped, ext)
                _gltf_check(header, path, ext)
            # an ASCII OFF file is read in file order by kdray (kdray.off)
            scene = _polygons_scene(read_off, path, zipped) if ext == "off" else None
            if scene is None and obj is not None:
                scene = trimesh.load(_named_stream(obj, file_name), file_type="obj",
                                     force="scene", process=False, skip_materials=True)
            elif scene is None and zipped:
                with gzip.open(path, "rb") as f:
                    scene = trimesh.load(f, file_type=ext, force="scene", process=False,
                                         skip_materials=True)
            elif scene is None:
                scene = trimesh.load(path, force="scene", process=False, skip_materials=True)
        except MeshError:
            raise
        except Exception as e:  # trimesh raises many kinds for a malformed file
            scene = None
            if isinstance(e, (UnicodeError, ImportError)) and ext in ("ply", "stl"):
                scene = _text_scene(path, zipped, file_name, ext)
            if scene is None and ext == "ply":
                scene = _polygons_scene(read_binary_ply, path, zipped)
            if scene is None and isinstance(e, IndexError):
                raise MeshError(f"{path}: a face refers to a vertex that does not exist "
                                f"({one_line(e)})") from None
            if scene is None:
                raise MeshError(f"{path}: cannot be read as a mesh ({type(e).__name__}: "
                                f"{one_line(e)})") from None
        if ext == "ply":
            _ply_check_counts(scene, path)
            if _ply_sizes_differ(scene):
                # a binary PLY of faces of several sizes that trimesh read as all of the
                # first face's size (their indices in all as many as that): misread
                scene = _polygons_scene(read_binary_ply, path, zipped)
                if scene is None:
                    raise MeshError(f"{path}: its faces are of several sizes, in a PLY "
                                    f"layout kdray cannot read")
        ranks = _gltf_node_ranks(header) if ext in ("glb", "gltf") else None
        vertices, faces, objects, object_names = _scene_arrays(scene, path, ranks)
    if not faces:
        kinds = sorted({type(g).__name__ for g in scene.geometry.values()})
        what = f" (only {', '.join(kinds)})" if kinds else ""
        raise MeshError(f"{path}: contains no triangles{what}")
    mesh = Mesh.from_arrays(np.concatenate(vertices), np.concatenate(faces), name=file_name)
    if ext == "obj" and (len(faces) > 1 or len(mesh.faces) != _obj_face_lines(obj)):
        # a mesh a material, or polygons (a run of quads trimesh splits into every
        # quad's first half, then every second half): put back in the file's order
        mesh = _obj_in_file_order(mesh, obj, path)
    if ext == "obj":
        objects, object_names = _obj_objects(path, zipped, file_name, mesh.triangles, obj)
    if len(object_names) > 1:                   # else one object, named after the file
        objects, object_names = check_objects(objects, object_names, len(mesh.faces))
        mesh = dataclasses.replace(mesh, objects=objects, object_names=object_names)
    return mesh


def _polygons_scene(read, path, zipped):
    """A trimesh Scene of the one mesh that `read` (bytes -> (vertices, polygons):
    kdray.ply.read_binary_ply for a binary PLY of faces of several sizes, which
    trimesh's reader refuses or misreads; kdray.off.read_off) makes of the file, its
    polygons split in file order (`split_polygons`); None where it cannot read it
    (trimesh's reader, or its error, then stands). MeshError for a file `read` knows
    to be malformed (kdray.off.Malformed): trimesh's looser reader would take what it
    could of it without a word."""
    import struct
    import trimesh
    try:
        vertices, polygons = read(_read(path, zipped))
    except Malformed as e:
        raise MeshError(f"{path}: malformed ({one_line(e)})") from None
    except (ValueError, OverflowError, struct.error, OSError, EOFError, zlib.error):
        return None
    faces = split_polygons(polygons) if polygons else None
    if faces is None:
        return None
    return trimesh.Scene(trimesh.Trimesh(vertices=vertices, faces=faces, process=False))


def _scene_arrays(scene, path, ranks=None):
    """The triangles of a trimesh Scene, node by node in the graph's order (or in the
    order of ranks: {object name: rank}, `_gltf_node_ranks`, where it ranks every
    node's object), transforms applied (a mirroring one reverses its triangles'
    winding, so that their normals turn with them): (vertices [(n_i, 3) float64],
    faces [(m_i, 3) int64] indexing the concatenated vertices, objects (m,) uint32,
    object_names tuple): objects numbered in the order of their first triangle. A node
    that trimesh left unreachable from the scene's root (a glTF camera node's
    children) is left out with a warning."""
    import trimesh
    vertices, faces, objects = [], [], []
    names = {}                                  # object name -> index, in order of appearance
    offset = 0
    nodes, lost = [], []
    for node in scene.graph.nodes_geometry:
        try:
            nodes.append((node, *scene.graph[node]))
        except ValueError:                      # "No path from world->node"
            lost.append(str(node))
    if lost:
        log.warning("%s: %s left out: trimesh's reading of the scene does not reach "
                    "them from its root (a camera node's children?)", path, ", ".join(lost))
    if ranks is not None:
        keys = [ranks.get(_object_name(scene, node, scene.geometry[name], ranks))
                for node, _, name in nodes]
        if None in keys:
            log.warning("%s: cannot match its scene's nodes to the file's; meshes in "
                        "trimesh's order", path)
        else:                                   # stable: a node's primitives in turn
            nodes = [nodes[i] for i in sorted(range(len(nodes)), key=keys.__getitem__)]
    for node, transform, name in nodes:
        geom = scene.geometry[name]
        if not isinstance(geom, trimesh.Trimesh) or len(geom.faces) == 0:
            log.info("%s: skipping %s (%s, no triangles)", path, name, type(geom).__name__)
            continue
        v = np.asarray(geom.vertices, dtype=np.float64)
        f = _ply_file_order(geom, np.asarray(geom.faces, dtype=np.int64))
        if not np.array_equal(transform, np.eye(4)):       # any other, however near
            v = v @ transform[:3, :3].T + transform[:3, 3]
            if np.linalg.det(transform[:3, :3]) < 0:
                f = f[:, ::-1]          # a mirror turns the winding (glTF 2.0, as trimesh's dump)
        vertices.append(v)
        faces.append(f + offset)
        offset += len(v)
        index = names.setdefault(_object_name(scene, node, geom, ranks), len(names))
        objects.append(np.full(len(geom.faces), index, dtype=np.uint32))
    objects = np.concatenate(objects) if objects else np.zeros(0, dtype=np.uint32)
    return vertices, faces, objects, tuple(names)


_BOM = b"\xef\xbb\xbf"


def _text(data):
    """A text mesh file's bytes as trimesh's readers take them: a UTF-8 byte-order mark
    taken off (trimesh would read the first line as an unknown keyword, and an OBJ's
    first vertex would be lost) and bytes that are not UTF-8 (a comment or a name in
    another encoding) made U+FFFD, where trimesh would refuse the file or need an
    optional module to guess its encoding."""
    if data.startswith(_BOM):
        data = data[len(_BOM):]
    try:
        data.decode("utf-8")
    except UnicodeDecodeError:
        data = data.decode("utf-8", "replace").encode("utf-8")
    return data


def _text_scene(path, zipped, file_name, ext):
    """trimesh's Scene of an ASCII PLY or STL file read through `_text`, or None where
    the file is binary (its body is not text) or still cannot be read."""
    import trimesh
    data = _read(path, zipped)
    head = data[:data.find(b"end_header")] if ext == "ply" else data[:512]
    if ext == "ply" and b"format ascii" not in head:
        return None
    try:
        return trimesh.load(_named_stream(_text(data), file_name), file_type=ext,
                            force="scene", process=False, skip_materials=True)
    except Exception:  # the caller reports the first read's error
        return None


def _ply_elements(scene):
    """The raw PLY elements trimesh kept of each mesh of the scene: a list of dicts
    {element name: {"length": the header's count, "data": {property: array}}}."""
    raws = [g.metadata.get("_ply_raw") for g in scene.geometry.values()]
    return [raw for raw in raws if isinstance(raw, dict)]


def _ply_check_counts(scene, path):
    """MeshError where a PLY element holds fewer items than its header counts (trimesh
    reads an ASCII file that ends early without a word)."""
    for raw in _ply_elements(scene):
        for name, element in raw.items():
            try:
                count = int(element["length"])
                held = {len(v) for v in element["data"].values()}
            except (KeyError, TypeError, ValueError, AttributeError):
                continue
            if held and min(held) < count:
                raise MeshError(f"{path}: malformed (its header counts {count} {name} "
                                f"elements, the file holds {min(held)})")


def _ply_sizes_differ(scene):
    """Whether trimesh read a binary PLY's faces as all of one size (k) where the file's
    counts say otherwise: the first face of another size is read where it lies, so its
    count, not k, shows it."""
    for raw in _ply_elements(scene):
        rows = _ply_index_lists(raw)
        names = getattr(getattr(rows, "dtype", None), "names", None)
        if names and "f0" in names and "f1" in names:
            width = rows["f1"].reshape(len(rows), -1).shape[1]
            if (rows["f0"] != width).any():
                return True
    return False


def _gltf_header(path, zipped, ext):
    """The JSON of a .glb (its first chunk) or .gltf file, or None where it cannot be
    read so (trimesh's read then says what is wrong)."""
    import json
    import struct
    try:
        with (gzip.open(path, "rb") if zipped else open(path, "rb")) as f:
            if ext == "glb":
                magic, _, _, length, kind = struct.unpack("<4sIIII", f.read(20))
                if magic != b"glTF" or kind != 0x4E4F534A:      # the JSON chunk first
                    return None
                header = json.loads(f.read(length))
            else:
                header = json.loads(f.read())
    except (OSError, EOFError, ValueError, struct.error):
        return None
    return header if isinstance(header, dict) else None


GLTF_FAN = 6
"""glTF's TRIANGLE_FAN primitive mode, which trimesh's reader leaves out."""


def _gltf_check(header, path, ext):
    """MeshError, before trimesh reads the file, for a glTF that trimesh's reader fails
    on with an IndexError, an AssertionError or a FileNotFoundError that name nothing,
    or reads in part or wrong without a word: a .gltf that is not a JSON object; a
    scene, a scene's root, a node's child or mesh, a primitive's accessor, an
    accessor's bufferView or a bufferView's buffer that the file does not have; a node
    that is a child twice or its own ancestor (glTF's nodes are disjoint trees);
    TRIANGLE_FAN primitives (left out) and sparse accessors (read without their sparse
    values) of a triangle primitive's positions or indices. Points and lines (modes
    0-3) hold no triangles and are left out. A .glb whose JSON chunk cannot be read is
    left to trimesh's read."""
    if header is None:
        if ext == "gltf":
            raise MeshError(f"{path}: is not a glTF file (not a JSON object)")
        return

    def items(key):
        value = header.get(key, [])
        if not isinstance(value, list):
            raise MeshError(f"{path}: its {key!r} is not a list")
        return value

    def check(index, key, what):
        count = len(items(key))
        if isinstance(index, bool) or not isinstance(index, int) or not 0 <= index < count:
            noun = "mesh" if key == "meshes" else key[:-1]
            raise MeshError(f"{path}: {what} refers to {noun} {index!r}, and the file "
                            f"has {count}")
    nodes, scenes = items("nodes"), items("scenes")
    if "scene" in header:
        check(header["scene"], "scenes", "its scene")
    for k, scene in enumerate(scenes):
        for root in (scene.get("nodes", []) if isinstance(scene, dict) else []):
            check(root, "nodes", f"scene {k}")
    parent = {}
    for k, node in enumerate(nodes):
        if isinstance(node, dict) and "mesh" in node:
            check(node["mesh"], "meshes", f"node {k}")
        for child in (node.get("children", []) if isinstance(node, dict) else []):
            check(child, "nodes", f"node {k}")
            if child in parent or child == k:
                raise MeshError(f"{path}: node {child} is a child of nodes "
                                f"{parent.get(child, k)} and {k} (glTF's nodes are trees)")
            parent[child] = k
    for k in parent:                            # each node's ancestors: none is itself
        up, seen = parent.get(k), 0
        while up is not None and seen <= len(nodes):
            if up == k:
                raise MeshError(f"{path}: node {k} is its own ancestor (a cycle of "
                                f"nodes; glTF's nodes are trees)")
            up, seen = parent.get(up), seen + 1
    for k, mesh in enumerate(items("meshes")):
        for primitive in (mesh.get("primitives", []) if isinstance(mesh, dict) else []):
            if not isinstance(primitive, dict):
                continue
            used = list((primitive.get("attributes") or {}).values())
            if "indices" in primitive:
                used.append(primitive["indices"])
            for index in used:
                check(index, "accessors", f"a primitive of mesh {k}")
    for k, accessor in enumerate(items("accessors")):
        if isinstance(accessor, dict) and "bufferView" in accessor:
            check(accessor["bufferView"], "bufferViews", f"accessor {k}")
    for k, view in enumerate(items("bufferViews")):
        if isinstance(view, dict) and "buffer" in view:
            check(view["buffer"], "buffers", f"bufferView {k}")
    _gltf_unread_primitives(header, path)


def _gltf_unread_primitives(header, path):
    """_gltf_check's MeshError for TRIANGLE_FAN primitives and sparse accessors of a
    triangle primitive (the references already checked)."""
    try:
        for k, mesh in enumerate(header.get("meshes", [])):
            for primitive in mesh.get("primitives", []):
                mode = primitive.get("mode", 4)
                if mode == GLTF_FAN:
                    named = f" ({mesh['name']!r})" if "name" in mesh else ""
                    raise MeshError(f"{path}: a primitive of mesh {k}{named} is a "
                                    f"TRIANGLE_FAN, which kdray (trimesh) does not read")
                if mode not in (4, 5):
                    continue
                used = [primitive.get("attributes", {}).get("POSITION"), primitive.get("indices")]
                for index in used:
                    if index is not None and "sparse" in header["accessors"][index]:
                        raise MeshError(f"{path}: accessor {index} is sparse, which kdray "
                                        f"(trimesh) does not read")
    except (KeyError, IndexError, TypeError, AttributeError):
        return                                  # malformed: trimesh's read says so


def _gltf_node_ranks(header):
    """{trimesh's name of a glTF node: its rank} from a glTF file's JSON: the nodes of
    the file's scene taken depth first from its roots, each node's children in their
    order (as a viewer walks them; trimesh walks them the other way round), named as
    trimesh names them (a node's name, or its index, made unique in index order; one
    named as the scene's base frame renamed). None where the JSON has no scenes or
    they cannot be walked so."""
    from trimesh.util import unique_name
    import trimesh
    if header is None or "scenes" not in header:   # trimesh adds its meshes as they come
        return None
    try:
        nodes = header.get("nodes", [])
        name_index, counts = {}, {}
        for i, node in enumerate(nodes):
            name_index[unique_name(node.get("name", str(i)), name_index, counts=counts)] = i
        names = {i: name for name, i in name_index.items()}
        base = trimesh.Scene().graph.base_frame
        if base in name_index:                  # trimesh renames it, so as to keep it
            names[name_index[base]] = unique_name(base, set(names.values()))
        scene = header["scenes"][header.get("scene", 0)]
        rank = {}
        stack = list(reversed(scene.get("nodes", [])))
        while stack:
            i = stack.pop()
            if i not in rank:
                rank[i] = len(rank)
                stack.extend(reversed(nodes[i].get("children", [])))
    except (KeyError, IndexError, TypeError, AttributeError):
        return None
    return {names[i]: r for i, r in rank.items() if i in names}


def _ply_file_order(geom, faces):
    """A PLY mesh's triangles (faces (m, 3) int64, trimesh's) in its file's order
    (`split_polygons`), where trimesh puts every file's triangles first, then the
    quads' first halves, then their second halves. faces as they are for other
    meshes, or where the file's polygons (trimesh's raw PLY data) do not give the same
    triangles."""
    polygons = _ply_polygons(geom)
    if polygons is None:
        return faces
    if (isinstance(polygons, np.ndarray) and polygons.dtype != object
            and polygons.reshape(len(polygons), -1).shape[1] == 3):
        return faces                            # triangles only: trimesh's are the file's
    ordered = split_polygons(polygons)
    same = (ordered is not None and len(ordered) == len(faces)
            and np.array_equal(ordered[np.lexsort(ordered.T[::-1])],
                               faces[np.lexsort(faces.T[::-1])]))
    return ordered if same else faces


def split_polygons(polygons):
    """(m, 3) int64 triangles of polygons (an (n, k) array, or a sequence of index
    arrays) in their order, each polygon's in turn, split as trimesh splits them: a
    quad into (0, 1, 2), (2, 3, 0), a larger polygon into a fan from its first vertex;
    polygons of fewer than 3 indices give none. None where polygons are not that."""
    try:
        if isinstance(polygons, np.ndarray) and polygons.dtype != object:
            polygons = polygons.astype(np.int64).reshape(len(polygons), -1)
            groups = [(np.arange(len(polygons)), polygons)]
        else:
            lengths = np.fromiter((len(p) for p in polygons), dtype=np.int64,
                                  count=len(polygons))
            groups = [(i, np.array([polygons[k] for k in i], dtype=np.int64).reshape(len(i), n))
                      for n in np.unique(lengths) for i in [np.flatnonzero(lengths == n)]]
    except (TypeError, ValueError):
        return None
    tris, keys = [np.zeros((0, 3), np.int64)], [np.zeros(0, np.int64)]
    widest = max([rows.shape[1] for _, rows in groups], default=0)
    for source, rows in groups:
        n = rows.shape[1]
        if n < 3:
            continue
        splits = [(0, 1, 2), (2, 3, 0)] if n == 4 else [(0, k, k + 1) for k in range(1, n - 1)]
        for part, corners in enumerate(splits):
            tris.append(rows[:, corners])
            keys.append(source * widest + part)      # part < widest: file order, then part
    tris, keys = np.concatenate(tris), np.concatenate(keys)
    return tris[np.argsort(keys, kind="stable")]


def _ply_polygons(geom):
    """The polygons of a mesh trimesh read from a PLY file (its raw element data): an
    (n, k) array or a sequence of index arrays; None for other meshes."""
    lists = _ply_index_lists(geom.metadata.get("_ply_raw"))
    names = getattr(getattr(lists, "dtype", None), "names", None)
    return lists["f1"] if names and "f1" in names else lists    # binary: (count, indices)


def _ply_index_lists(raw):
    """The face element's index lists in trimesh's raw PLY data (`raw`, a dict of
    elements): an (n, k) array, a sequence of index arrays, or for a binary file a
    structured array of (count "f0", indices "f1"); None where there are none."""
    from .ply import INDEX_NAMES
    try:
        data = raw["face"]["data"]
    except (KeyError, TypeError, IndexError, ValueError):
        return None
    for key in INDEX_NAMES:
        try:
            return data[key]
        except (KeyError, TypeError, IndexError, ValueError):
            continue
    return None


def _object_name(scene, node, geom, ranks=None):
    """The object a scene graph node's triangles belong to: the node, or for one of the
    nodes trimesh makes for the primitives of a glTF mesh (randomly named), its parent:
    the glTF node. ranks: `_gltf_node_ranks`, or None: a node it names is a glTF node,
    its own object, even where trimesh marks its mesh as a primitive's (one of several
    of which only one holds triangles)."""
    if geom.metadata.get("from_gltf_primitive") and not (ranks and node in ranks):
        parent = scene.graph.transforms.parents.get(node)
        if parent is not None and parent != scene.graph.base_frame:
            return parent
    return node


_OBJ_GROUP_LINE = re.compile(rb"^[ \t]*[og][ \t]", re.MULTILINE)


def _read(path, zipped):
    """The file's bytes (through gzip when zipped)."""
    with (gzip.open(path, "rb") if zipped else open(path, "rb")) as f:
        return f.read()


def _named_stream(data, file_name):
    """A stream of data named file_name (trimesh names faces outside any `o` or `g`
    after it)."""
    stream = io.BytesIO(data)
    stream.name = file_name
    return stream


_OBJ_COUNTED = {b"v": 0, b"vt": 1, b"vn": 2}
_OBJ_ELEMENTS = (b"f", b"fo", b"l", b"p")


def _obj_plain(data):
    """An OBJ file's bytes with its lines as trimesh reads them, where some are not:
    a line continued by a backslash joined to the next, blanks before a line's keyword
    taken off, tabs made spaces and a comment after a v, f, l or p line's numbers ("f 1
    2 3 # a face") cut (trimesh leaves out indented lines and "f" and a tab, and refuses
    a comment after numbers); None when no line needs it. Only such files are read
    line by line, and every later read of the bytes (`_obj_absolute`,
    `_obj_file_triangles`) takes them so: a line a line, keywords at its start."""
    ragged = (data.startswith((b" ", b"\t")) or b"\n " in data or b"\t" in data
              or b"\\\n" in data or b"\\\r\n" in data
              or data.count(b"#") > data.count(b"\n#") + data.startswith(b"#"))
    if not ragged:
        return None
    lines = []
    data = data.replace(b"\\\r\n", b"").replace(b"\\\n", b"").replace(b"\t", b" ")
    for line in data.split(b"\n"):
        line = line.lstrip(b" ")
        at = line.find(b"#")
        if at > 0 and line[:1] in (b"v", b"f", b"l", b"p"):   # not in o, g, usemtl names
            line = line[:at].rstrip(b" ")
        lines.append(line)
    return b"\n".join(lines)


def _obj_may_count_back(data):
    """Whether a line of an OBJ file's bytes (made plain: `_obj_plain`) that starts
    with f, l or p holds a '-': where a relative index can be. In numpy (a tenth of a
    second for 60 MB; a regular expression takes seconds)."""
    b = np.frombuffer(data, dtype=np.uint8)
    minus = np.flatnonzero(b == ord("-"))
    if minus.size == 0:
        return False
    _, at = _line_starts(b, minus)
    return bool(np.isin(b[np.minimum(at, len(b) - 1)], list(b"flp")).any())


def _line_starts(b, positions):
    """(line (k,) int64 from 0, start (k,) int64): the line of each of `positions`
    (sorted offsets into the bytes b, a uint8 array) and the offset where it starts."""
    breaks = np.flatnonzero(b == ord("\n"))
    line = np.searchsorted(breaks, positions)
    return line, np.concatenate([[0], breaks + 1])[line]


def _obj_zero_index(data):
    """IndexError for a face, line or point of an OBJ file's bytes (made plain:
    `_obj_plain`) holding an index 0 or -0 (OBJ counts from 1; trimesh would read 0 as
    the last vertex). In numpy, as `_obj_may_count_back`: a '0' between a blank, '/' or
    '-' and a blank, '/' or the line's end, on a line of f, l, p or fo."""
    b = np.frombuffer(data, dtype=np.uint8)

    def peek(i):                        # b[i], and 10 (a line's end) past the end
        return np.where(i < len(b), b[np.minimum(i, len(b) - 1)], 10)

    # a '0' after a separator: from a view of the bytes shifted by one, with no gather
    zero = np.flatnonzero((b[1:] == ord("0"))
                          & ((b[:-1] == ord(" ")) | (b[:-1] == ord("/")) | (b[:-1] == ord("-"))))
    zero += 1
    after = peek(zero + 1)
    zero = zero[(after == ord(" ")) | (after == ord("/")) | (after == ord("\r"))
                | (after == ord("\n"))]
    if zero.size == 0:
        return
    line, at = _line_starts(b, zero)
    # the keyword f, l, p or fo and a blank (not lod, parm, ...)
    first, second = b[at], peek(at + 1)
    bad = np.flatnonzero((np.isin(first, list(b"flp")) & (second == ord(" ")))
                         | ((first == ord("f")) & (second == ord("o"))
                            & (peek(at + 2) == ord(" "))))
    if bad.size:
        raise IndexError(f"line {int(line[bad[0]]) + 1} holds the index 0; OBJ's count from 1")


def _obj_absolute(data):
    """An OBJ file's bytes with its relative (negative) indices made absolute, each
    from the count of its kind (v, vt, vn) read before its line; None when it has none.
    """
    if not _obj_may_count_back(data):
        return None
    counts = [0, 0, 0]
    lines = data.split(b"\n")
    for n, line in enumerate(lines):
        words = line.split()
        if not words:
            continue
        kind = _OBJ_COUNTED.get(words[0])
        if kind is not None:
            counts[kind] += 1
        elif words[0] in _OBJ_ELEMENTS and b"-" in line:
            out = [words[0]]
            for word in words[1:]:
                parts = word.split(b"/")
                for k, part in enumerate(parts[:3]):
                    if part.startswith(b"-") and part[1:].isdigit():
                        index = counts[k] + 1 + int(part)
                        if index < 1:
                            raise IndexError(f"line {n + 1}: {part.decode()} counts back past "
                                             f"the first of {counts[k]} read before it")
                        parts[k] = b"%d" % index
                out.append(b"/".join(parts))
            lines[n] = b" ".join(out)
    return b"\n".join(lines)


def _obj_objects(path, zipped, file_name, triangles, data=None):
    """(objects (m,) uint32, object_names tuple) of an OBJ file: each triangle's `o`/`g`
    group as trimesh's split_objects and split_groups name it (a second read of the
    file, or of `data`, its bytes as read the first time), matched to `triangles` ((m,
    3, 3) float64, the first read's, in triangle id order) by their coordinates. A file
    with no `o` or `g` line, or whose two reads do not hold the same triangles (then
    with a warning), is one object."""
    import trimesh
    one = np.zeros(len(triangles), dtype=np.uint32), (file_name,)
    if data is None:
        data = _read(path, zipped)
    if not _OBJ_GROUP_LINE.search(data):
        return one
    try:
        split = trimesh.load(_named_stream(data, file_name), file_type="obj", force="scene",
                             process=False, skip_materials=True, split_objects=True,
                             split_groups=True, group_material=False)
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
    a, b = _bits(triangles), _bits(np.concatenate(g_vertices)[np.concatenate(g_faces)])
    pairs = _pair_rows(a, b)
    if pairs is None:
        log.warning("%s: its o/g groups hold other triangles than the file (%d, %d); one "
                    "object", path, len(b), len(a))
        return one
    order_a, order_b = pairs
    objects = np.empty(len(a), dtype=np.uint32)
    objects[order_a] = g_objects[order_b]
    # numbered in the order of their first triangle in id order
    used, first = np.unique(objects, return_index=True)
    rank = np.zeros(len(g_names), dtype=np.uint32)
    rank[used[np.argsort(first)]] = np.arange(len(used), dtype=np.uint32)
    return rank[objects], tuple(g_names[i] for i in used[np.argsort(first)])


def _pair_rows(a, b):
    """(order_a, order_b) with a[order_a] equal to b[order_b] bit for bit, a and b (m, k)
    uint64 rows in two orders (equal rows paired in their orders): sorted by a hash of
    their bits, or by the bits themselves should two rows' hashes collide. None where
    a and b do not hold the same rows."""
    if a.shape != b.shape:
        return None
    for sort_key in (_row_hash, _row_bytes):
        order_a = np.argsort(sort_key(a), kind="stable")
        order_b = np.argsort(sort_key(b), kind="stable")
        if np.array_equal(a[order_a], b[order_b]):
            return order_a, order_b
    return None


def _obj_in_file_order(mesh, data, path):
    """An OBJ's Mesh (trimesh's read of data, its bytes: a mesh a material, each
    material's faces in file order, the materials in an order of trimesh's) with its
    triangles in the file's order (`_obj_file_triangles`), matched to them by their
    corners' coordinates, bit for bit. The Mesh as it is, with a warning, where the
    file's face lines cannot be read here or give other triangles."""
    ours = _obj_file_triangles(data)
    pairs = None
    if ours is not None:
        pairs = _pair_rows(_bits(mesh.triangles), _bits(ours))
    if pairs is None:
        log.warning("%s: cannot put its triangles in the file's order (its face lines "
                    "read otherwise than trimesh reads them); triangle ids follow "
                    "trimesh's order", path)
        return mesh
    order_mesh, order_file = pairs
    order = np.empty(len(order_mesh), dtype=np.int64)
    order[order_file] = order_mesh              # the file's triangle i is mesh's order[i]
    return dataclasses.replace(mesh, faces=mesh.faces[order])


def _obj_face_lines(data):
    """The face lines of an OBJ file's bytes (made plain: "f " at a line's start)."""
    return data.count(b"\nf ") + data.startswith(b"f ")


def _obj_file_triangles(data):
    """The triangles of an OBJ file's bytes (made plain, `_obj_plain`, with relative
    indices made absolute), its face lines in the file's order, a polygon of k corners
    split as trimesh splits it: a quad into (0, 1, 2), (2, 3, 0), a larger polygon into
    the fan (0, i, i + 1) for i = 1 .. k - 2. Returns (m, 3, 3) float64 corners, each
    vertex the first three numbers of its line ("v " at a line's start), or None where
    a face line ("f ") has fewer than 3 corners, a corner that is not a vertex of the
    file, or a line does not read as numbers."""
    lines = data.replace(b"\r\n", b"\n").split(b"\n")
    v_lines = [line[2:] for line in lines if line[:2] == b"v "]
    f_lines = [line[2:] for line in lines if line[:2] == b"f "]
    del lines
    v_numbers, v_count = _obj_numbers(v_lines, np.float64)
    corners, k = _obj_numbers(f_lines, np.int64)
    if v_numbers is None or corners is None or len(k) == 0 or k.min() < 3 or v_count.min() < 3:
        return None
    v = v_numbers[(np.cumsum(v_count) - v_count)[:, None] + np.arange(3)]
    corners -= 1
    if corners.min() < 0 or corners.max() >= len(v):
        return None
    first = np.cumsum(k) - k                    # each line's first corner in corners
    polygon = np.repeat(np.arange(len(k)), k - 2)
    i = np.arange(len(polygon)) - np.repeat(np.cumsum(k - 2) - (k - 2), k - 2) + 1
    at = first[polygon]
    faces = np.stack([corners[at], corners[at + i], corners[at + i + 1]], axis=1)
    quad_second = (k[polygon] == 4) & (i == 2)
    faces[quad_second] = np.roll(faces[quad_second], -1, axis=1)
    return v[faces]


def _obj_numbers(lines, dtype):
    """The numbers of lines (bytes each), of each word its part before a "/" (a face's
    vertex index): (numbers (n,) dtype, count (len(lines),) int64 of each line), or
    (None, None) where a word does not read as a number."""
    text = b" ".join(lines)
    # words a line: one more than its spaces where words are single-spaced (checked)
    count = np.fromiter(map(bytes.count, lines, itertools.repeat(b" ")), dtype=np.int64,
                        count=len(lines)) + 1
    if b"  " in text or b"\t" in text or b"\r" in text or b" " in text[:1] + text[-1:]:
        count = np.fromiter(map(len, map(bytes.split, lines)), dtype=np.int64, count=len(lines))
    words = int(count.sum())
    slashes = text.count(b"/")
    try:
        if slashes == 0:
            numbers = np.fromstring(text, dtype=dtype, sep=" ")
        else:
            # words of one form ("1/2/3", "1//3", "1/2"): every p-th number
            form = text.split(None, 1)[0]
            p = form.count(b"/") + 1 - form.count(b"//")
            if slashes == words * form.count(b"/") and text.count(b"//") == words * form.count(b"//"):
                numbers = np.fromstring(text.replace(b"/", b" "), dtype=dtype, sep=" ")[::p]
            else:
                numbers = np.array([w.split(b"/", 1)[0] for w in text.split()],
                                   dtype="S").astype(dtype)
    except ValueError:
        return None, None
    if len(numbers) != words:
        return None, None
    return numbers, count


def _bits(triangles):
    """(m, 9) uint64: the bits of triangles ((m, 3, 3) float64), a row each."""
    return np.ascontiguousarray(triangles, dtype=np.float64).reshape(-1, 9).view(np.uint64)


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
