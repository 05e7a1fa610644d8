"""Mesh: validated triangle-mesh arrays.

    vertices     : (n, 3) float64
    faces        : (m, 3) int64, indices into vertices; triangle ids are row numbers
    objects      : (m,) uint32, the object each triangle belongs to: an index into
                   object_names, numbered in the order objects first appear
    object_names : tuple of str, one unique name per object
"""
import dataclasses

import numpy as np

from .errors import MeshError, one_line
from .host import check_host_memory


MESH_ROW_BYTES = 64
"""Host bytes a vertex or face row needs while a mesh is checked and copied (24 of
float64 or int64, the rest temporaries): what `check_arrays` asks the host for."""


def check_arrays(vertices, faces):
    """(vertices (n, 3) float64, faces (m, 3) int64) after checking shapes, that there
    is a face, and that face indices are integers in range; raises MeshError.
    Vertex values are not checked here (see Mesh.from_arrays and the builder)."""
    try:
        v = np.asarray(vertices)
        f = np.asarray(faces)
    except (TypeError, ValueError, OverflowError) as e:     # ragged lists
        raise MeshError(f"vertices and faces must be numeric arrays ({one_line(e)})") from None
    # numbers only: no strings read as numbers, no complex numbers losing their
    # imaginary part, no bools, no objects (types are kept, docs/interface.md)
    for name, a, kinds in (("vertices", v, "fiu"), ("faces", f, "fiu")):
        if a.dtype.kind not in kinds:
            raise MeshError(f"{name} must be an array of numbers, got dtype {a.dtype}")
    try:
        v = v.astype(np.float64, copy=False)
    except (TypeError, ValueError, OverflowError) as e:     # OverflowError: an int beyond float64
        raise MeshError(f"vertices must be numbers ({one_line(e)})") from None
    if v.ndim != 2 or v.shape[1] != 3:
        raise MeshError(f"vertices must be an (n, 3) array, got shape {v.shape}")
    if f.ndim != 2 or f.shape[1] != 3:
        raise MeshError(f"faces must be an (m, 3) array of triangles, got shape {f.shape}")
    # float64 and int64 copies and their checks' temporaries, before any is made (a
    # broadcast array of 2^36 rows costs its caller nothing)
    check_host_memory((len(v) + len(f)) * MESH_ROW_BYTES,
                      f"a mesh of {len(v):,} vertices and {len(f):,} faces",
                      "give fewer vertices and faces", MeshError)
    if len(f) == 0:
        raise MeshError("has no triangles")
    if not np.issubdtype(f.dtype, np.integer):
        if not np.issubdtype(f.dtype, np.number) or not np.all(np.isfinite(f)) or np.any(f != np.round(f)):
            raise MeshError("face indices must be integers")
        if f.min() < 0 or f.max() >= len(v):        # before a cast that cannot hold them
            bad = int(np.flatnonzero((f < 0).any(axis=1) | (f >= len(v)).any(axis=1))[0])
            raise MeshError(f"face {bad} has a vertex index out of range (the mesh has "
                            f"{len(v)} vertices)")
    f = np.ascontiguousarray(f, dtype=np.int64)         # no copy when it already is
    if f.min() < 0 or f.max() >= len(v):
        bad = int(np.flatnonzero((f < 0).any(axis=1) | (f >= len(v)).any(axis=1))[0])
        raise MeshError(f"face {bad} has a vertex index out of range (the mesh has {len(v)} vertices)")
    return v, f


def check_objects(objects, object_names, n_tris):
    """(objects (n_tris,) uint32, object_names tuple of str) after checking them: one
    object index per triangle, each below len(object_names), and unique names. Raises
    MeshError."""
    try:
        names = tuple(object_names) if not isinstance(object_names, (str, bytes)) else None
    except TypeError:
        names = None
    if names is None or not all(isinstance(n, str) for n in names):
        raise MeshError("object_names must be a sequence of strings")
    for n in names:
        try:
            n.encode("utf-8")
        except UnicodeEncodeError:
            raise MeshError(f"object name {n!r} is not valid Unicode (a lone surrogate)") from None
    if not names:
        raise MeshError("object_names must name at least one object")
    if len(set(names)) != len(names):
        dup = next(n for i, n in enumerate(names) if n in names[:i])
        raise MeshError(f"object name {dup!r} is given twice (names must be unique)")
    o = np.asarray(objects)
    if o.shape != (n_tris,):
        raise MeshError(f"objects must be a ({n_tris},) array, one per triangle, got shape {o.shape}")
    if o.size and o.dtype.kind not in "iu":
        raise MeshError(f"objects must be integers, got {o.dtype}")
    if o.size and (o.min() < 0 or o.max() >= len(names)):
        bad = int(np.flatnonzero((o < 0) | (o >= len(names)))[0])
        raise MeshError(f"triangle {bad}'s object {int(o[bad])} is out of range "
                        f"({len(names)} object names)")
    return np.array(o, dtype=np.uint32, order="C"), names


@dataclasses.dataclass(frozen=True, eq=False)
class Mesh:
    vertices: np.ndarray
    faces: np.ndarray
    name: str = "mesh"
    objects: np.ndarray = None
    """(m,) uint32; None when constructed: every triangle object 0."""
    object_names: tuple = None
    """None when constructed: one object, named after the mesh."""

    def __eq__(self, other):
        """Equal arrays (values, dtypes and shapes), name and object names: a Mesh
        compares as its pickled or copied twin does (dataclass equality of numpy
        arrays raised)."""
        if not isinstance(other, Mesh):
            return NotImplemented
        return (self.name == other.name and self.object_names == other.object_names
                and all(a.dtype == b.dtype and np.array_equal(a, b)
                        for a, b in ((self.vertices, other.vertices), (self.faces, other.faces),
                                     (self.objects, other.objects))))

    __hash__ = None                     # arrays: a Mesh is not a dictionary key

    def __post_init__(self):
        if self.objects is None:
            object.__setattr__(self, "objects", np.zeros(len(self.faces), dtype=np.uint32))
        if self.object_names is None:
            object.__setattr__(self, "object_names", (self.name,))

    @classmethod
    def from_arrays(cls, vertices, faces, name="mesh", objects=None, object_names=None):
        """Validate and copy arrays into a Mesh; raises MeshError naming `name`.

        Checks: shapes (n, 3) and (m, 3); at least one face; face indices in range;
        every vertex a face uses is finite. Degenerate (zero-area) triangles are kept
        here; the builder leaves them out of the tree.
        objects : None (one object, 0, named `name`) or (m,) integers, each triangle's
            index into object_names (`check_objects`)
        object_names : the objects' unique names; None with objects given: "object 0",
            "object 1", ... up to the largest index
        """
        try:
            v, f = check_arrays(vertices, faces)
        except MeshError as e:
            raise MeshError(f"{name}: {e}") from None
        used = np.zeros(len(v), dtype=bool)
        used[f.ravel()] = True
        finite = np.isfinite(v).all(axis=1)
        if not finite[used].all():
            bad = int(np.flatnonzero(used & ~finite)[0])
            raise MeshError(f"{name}: vertex {bad} is not finite ({v[bad].tolist()})")
        if objects is None and object_names is None:
            objects, object_names = np.zeros(len(f), dtype=np.uint32), (name,)
        elif objects is None:
            raise MeshError(f"{name}: object_names given without objects")
        elif object_names is None:
            o = np.asarray(objects)
            top = int(o.max()) if o.size and o.dtype.kind in "iu" else 0
            if top >= len(f):
                raise MeshError(f"{name}: object index {top} with no object_names given "
                                f"(without names, objects are numbered below the number "
                                f"of triangles)")
            object_names = tuple(f"object {i}" for i in range(max(top, 0) + 1))
        try:
            objects, object_names = check_objects(objects, object_names, len(f))
        except MeshError as e:
            raise MeshError(f"{name}: {e}") from None
        return cls(vertices=np.array(v, order="C"), faces=np.array(f, order="C"), name=name,
                   objects=objects, object_names=object_names)

    @property
    def triangles(self):
        """(m, 3, 3) float64 world-space triangle vertices."""
        return self.vertices[self.faces]

    @property
    def bounds(self):
        """(2, 3) float64 box of the vertices the faces use."""
        used = self.vertices[np.unique(self.faces)]
        return np.stack([used.min(axis=0), used.max(axis=0)])

    def __len__(self):
        return len(self.faces)
