"""Mesh: validated triangle-mesh arrays.

    vertices : (n, 3) float64
    faces    : (m, 3) int64, indices into vertices; triangle ids are row numbers
"""
import dataclasses

import numpy as np

from .errors import MeshError


def check_arrays(vertices, faces):
    """(vertices (n, 3) float64, faces (m, 3) int64) after checking shapes, that there
    is a face, and that face indices are integers in range; raises MeshError.
    Vertex values are not checked here (see Mesh.from_arrays and the builder)."""
    try:
        v = np.asarray(vertices, dtype=np.float64)
        f = np.asarray(faces)
    except (TypeError, ValueError) as e:
        raise MeshError(f"vertices and faces must be numeric arrays ({e})") from None
    if v.ndim != 2 or v.shape[1] != 3:
        raise MeshError(f"vertices must be an (n, 3) array, got shape {v.shape}")
    if f.ndim != 2 or f.shape[1] != 3:
        raise MeshError(f"faces must be an (m, 3) array of triangles, got shape {f.shape}")
    if len(f) == 0:
        raise MeshError("has no triangles")
    if not np.issubdtype(f.dtype, np.integer):
        if not np.issubdtype(f.dtype, np.number) or not np.all(np.isfinite(f)) or np.any(f != np.round(f)):
            raise MeshError("face indices must be integers")
    f = np.ascontiguousarray(f, dtype=np.int64)         # no copy when it already is
    if f.min() < 0 or f.max() >= len(v):
        bad = int(np.flatnonzero((f < 0).any(axis=1) | (f >= len(v)).any(axis=1))[0])
        raise MeshError(f"face {bad} has a vertex index out of range (the mesh has {len(v)} vertices)")
    return v, f


@dataclasses.dataclass(frozen=True)
class Mesh:
    vertices: np.ndarray
    faces: np.ndarray
    name: str = "mesh"

    @classmethod
    def from_arrays(cls, vertices, faces, name="mesh"):
        """Validate and copy arrays into a Mesh; raises MeshError naming `name`.

        Checks: shapes (n, 3) and (m, 3); at least one face; face indices in range;
        every vertex a face uses is finite. Degenerate (zero-area) triangles are kept
        here; the builder leaves them out of the tree.
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
        return cls(vertices=np.array(v, order="C"), faces=np.array(f, order="C"), name=name)

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
