"""KdTree: the built tree's arrays, its invariants (`validate`), statistics and file I/O.

Arrays (see `kdray.layout` for the node encoding)::

    nodes      : (n_nodes, 2) uint32      depth-first; below child of i is i + 1
    leaf_tris  : (n_leaf_refs,) uint32    indices into `triangles`
    triangles  : (n_tris, 3, 3) float32   vertices relative to `origin`, in units of `scale`
    tri_ids    : (n_tris,) uint32         index of each triangle in the input
    origin     : (3,) float64             world position the float32 data is relative to
    bounds     : (2, 3) float32           scene box (min, max), relative to `origin`
    scale      : float                    a power of two: world = origin + scale * relative
    triangles64: (n_input_tris, 3, 3) float64 or None: the input's triangles in world
                 coordinates by input id, kept only when asked for (`with_double`,
                 `kdray.build(keep_double=True)`) for Tracer.trace(precision="double");
                 not part of the tree file
    objects    : (n_input_tris,) uint32 or None: the object of each input triangle, an
                 index into `object_names` (`with_objects`); None: one object, 0
    object_names: tuple of str, one unique name per object; () when objects is None

A tree holds an object table only for more than one object (`with_objects` drops a
table of one object), and the tree file holds it then (format version 3).
`object_ids(tri_ids, tree.objects)` looks up the objects of triangle ids.

`scale` is 1 unless the scene's size is outside 2^-28 .. 2^28 (kdray.builder.prepare):
then the float32 data is the scene divided by the power of two nearest its size, so
that the kernels' products of coordinates neither overflow nor underflow. Every
split position and box of the tree is in the same units. `world(x)` converts.
"""
import dataclasses
import math
import os
import stat

import numpy as np

from . import layout
from .files import atomic_write_bytes
from .errors import MeshError, TreeError, TreeFileError
from .mesh import check_objects


@dataclasses.dataclass(frozen=True)
class BuildParams:
    """The SAH builder's parameters (Wald & Havran 2006; names as in the kernels)."""

    K_T: float = 0.0
    """Cost of one traversal step, relative to K_I; 0 = automatic (`auto_K_T`: 400,
    and 600 from 2^20 triangles). W&H's Table 1 has 15 (for 20); on kdray's
    packet kernels a node visit costs more than that, mostly in cache misses, while a
    triangle test of a packet's 8 or 16 lanes is one vector pass. The values are the
    ones that build fastest, with the fewest nodes, among those that trace as fast as
    any (bench/bench_sah.py; the figures are in BENCHMARKS.md)."""
    K_I: float = 20.0
    """Cost of one ray/triangle test (W&H Table 1)."""
    empty_bonus: float = 0.8
    """lambda: the SAH cost of a split with an empty side is multiplied by this (1 = off)."""
    max_depth: int = 0
    """Deepest leaf allowed; 0 = round(8 + 1.3 log2 n) (pbrt), capped at 64."""
    leaf_size: int = 1
    """Nodes with at most this many triangles become leaves without a split search."""

    def resolved(self, n_tris):
        """A copy with `K_T` and `max_depth` resolved for `n_tris` triangles."""
        depth = self.max_depth
        if depth <= 0:
            depth = round(8 + 1.3 * math.log2(max(n_tris, 1)))
        return dataclasses.replace(self, K_T=self.K_T if self.K_T > 0 else auto_K_T(n_tris),
                                   max_depth=int(min(depth, layout.MAX_DEPTH_LIMIT)))


K_T_SMALL = 400.0
K_T_LARGE = 600.0
AUTO_K_T_TRIS = (2 ** 19, 2 ** 20)


def auto_K_T(n_tris):
    """The automatic K_T for a mesh of n_tris triangles: K_T_SMALL up to
    AUTO_K_T_TRIS[0] triangles, K_T_LARGE from AUTO_K_T_TRIS[1], linear in log2(n_tris)
    between. Chosen in turns with bench/bench_sah.py --incoherent (figures in
    BENCHMARKS.md): the largest of the K_T measured that lost nothing, on camera rays
    or on rays in random directions, against smaller ones. Larger leaves, read a packet's run of
    triangles at a time, cost less than the nodes they save and build faster; past
    these values incoherent rays slow down first (more triangle tests a ray)."""
    lo, hi = (math.log2(n) for n in AUTO_K_T_TRIS)
    x = min(max((math.log2(max(n_tris, 1)) - lo) / (hi - lo), 0.0), 1.0)
    return K_T_SMALL + x * (K_T_LARGE - K_T_SMALL)


COVERAGE_LEAVES = 64
"""The leaves a coverage point lies in on average, at most (`validate`'s coverage
check; KdTree.point_leaves' limit)."""

MAX_COORDINATE = 2.0 ** 28
"""The largest |coordinate| of a tree's triangles, in units of its scale
(kdray.builder.prepare.SCALE_FREE): the float32 triangle test's products of three
coordinates overflow from 2^42.7, so a scene is stored within 2^28 of its origin,
where its rays may start 2^14 of its size away."""


@dataclasses.dataclass(eq=False)
class KdTree:
    nodes: np.ndarray
    leaf_tris: np.ndarray
    triangles: np.ndarray
    tri_ids: np.ndarray
    origin: np.ndarray
    bounds: np.ndarray
    n_input_tris: int
    depth: int
    params: BuildParams
    scale: float = 1.0
    triangles64: np.ndarray = None
    objects: np.ndarray = None
    object_names: tuple = ()

    def __eq__(self, other):
        if not isinstance(other, KdTree):
            return NotImplemented
        arrays = ("nodes", "leaf_tris", "triangles", "tri_ids", "origin", "bounds")
        return (all(np.array_equal(getattr(self, a), getattr(other, a)) for a in arrays)
                and self.n_input_tris == other.n_input_tris and self.depth == other.depth
                and self.params == other.params and self.scale == other.scale
                and (self.objects is None) == (other.objects is None)
                and (self.objects is None or np.array_equal(self.objects, other.objects))
                and tuple(self.object_names) == tuple(other.object_names))

    @property
    def n_objects(self):
        """The number of objects: len(object_names), 1 for a tree with no table."""
        return len(self.object_names) if self.objects is not None else 1

    def with_objects(self, objects, object_names):
        """A copy of the tree that keeps the object of each input triangle: objects
        (n_input_tris,) integers, indices into object_names (unique strings), as
        kdray.Mesh has them (Mesh.objects, Mesh.object_names). A table of one object is
        dropped (every triangle is object 0 anyway). Raises TreeError when the table
        does not fit the tree's input or is not valid."""
        try:
            objects, object_names = check_objects(objects, object_names, self.n_input_tris)
        except MeshError as e:
            raise TreeError(f"with_objects: {e}") from None
        if len(object_names) == 1:
            return dataclasses.replace(self, objects=None, object_names=())
        return dataclasses.replace(self, objects=objects, object_names=object_names)

    def with_double(self, vertices, faces, built=False):
        """A copy of the tree that keeps the float64 triangles of the mesh it was built
        from (vertices (n, 3), faces (n_input_tris, 3)): the geometry
        precision="double" computes t, u, v from. Raises TreeError when the faces do not
        match the tree's input, or the triangles it holds are not theirs rounded as the
        builder rounds them (another mesh of as many faces). built: the caller has just
        built the tree from this mesh (kdray.build, cull), whose rounding is not checked
        again (a tenth of a 1.6M-triangle build)."""
        try:
            v, f = np.asarray(vertices), np.asarray(faces)
        except (TypeError, ValueError) as e:        # ragged lists
            raise TreeError(f"with_double needs numeric arrays ({e})") from None
        if v.dtype.kind not in "fiu":               # numbers only: no strings read as them
            raise TreeError(f"with_double needs numeric vertices, got dtype {v.dtype}")
        v = v.astype(np.float64, copy=False)
        if v.ndim != 2 or v.shape[1] != 3 or f.shape != (self.n_input_tris, 3) or f.dtype.kind not in "iu":
            raise TreeError(f"with_double needs the mesh the tree was built from: (n, 3) vertices "
                            f"and ({self.n_input_tris}, 3) integer faces, got {v.shape} and {f.shape}")
        if f.size and (f.min() < 0 or f.max() >= len(v)):
            raise TreeError("with_double: a face's vertex index is out of range")
        t64 = v[f]
        if built:
            return dataclasses.replace(self, triangles64=t64)
        # the builder's rounding (builder.prepare): the difference times 1 / scale (a
        # power of two: exact), to float32
        with np.errstate(over="ignore", invalid="ignore"):
            t32 = ((t64[np.asarray(self.tri_ids, np.intp)] - self.origin)
                   * (1.0 / self.scale)).astype(np.float32)
        differ = np.flatnonzero((t32 != np.asarray(self.triangles)).any(axis=(1, 2)))
        if differ.size:
            i = int(self.tri_ids[differ[0]])
            raise TreeError(f"with_double needs the mesh the tree was built from: its "
                            f"triangle {i} is not the tree's ({differ.size:,} of "
                            f"{len(self.tri_ids):,} differ)")
        return dataclasses.replace(self, triangles64=t64)

    def stored_index(self):
        """(n_input_tris,) int64: the row of `triangles` holding each input triangle,
        -1 for one the tree left out (degenerate or not finite)."""
        stored = np.full(self.n_input_tris, -1, dtype=np.int64)
        stored[np.asarray(self.tri_ids, dtype=np.int64)] = np.arange(len(self.tri_ids))
        return stored

    def world(self, relative):
        """float64 world coordinates of points relative to the tree: origin + scale * x
        (any shape ending in 3)."""
        return self.origin + self.scale * np.asarray(relative, dtype=np.float64)

    def world_box(self):
        """(lo, hi) (3,) float64: the scene box in world coordinates."""
        return self.world(self.bounds[0]), self.world(self.bounds[1])

    # -- files -------------------------------------------------------------------

    def to_bytes(self):
        return layout.encode(self)

    @classmethod
    def from_bytes(cls, data, name="tree file"):
        """Decode and validate; raises TreeFileError for any bad input."""
        fields = layout.decode(data, name)
        fields["params"] = BuildParams(**fields["params"])
        tree = cls(**fields)
        try:
            tree.validate(coverage_samples=None)
        except TreeError as e:
            raise TreeFileError(f"{name}: {e}") from None
        return tree

    def save(self, path):
        """Write the tree file atomically (temporary file + rename)."""
        atomic_write_bytes(path, self.to_bytes())

    @classmethod
    def load(cls, path):
        """Read a tree file (or a pipe). The header is read first: a bad magic, an
        unknown version or a short header is refused from it, and its counts are checked
        against a file's size before the body is read (a pipe's body is read up to them
        and one byte more)."""
        from .validate import check_not_device
        path = os.fspath(path)
        check_not_device(path, path, TreeFileError)
        try:
            with open(path, "rb") as f:
                head = f.read(layout.HEADER_SIZE)
                need = None
                if len(head) == layout.HEADER_SIZE and head[:8] == layout.MAGIC:
                    need = layout.header_file_size(head)
                if need is None:
                    # refused by the header alone: a short file, a bad magic or version
                    # (the checksum's room added, so that decode reads them)
                    room = layout.CHECKSUM_SIZE if len(head) == layout.HEADER_SIZE else 0
                    cls.from_bytes(head + bytes(room), name=path)
                    raise TreeFileError(f"{path}: not a kdray tree file")
                info = os.fstat(f.fileno())
                if stat.S_ISREG(info.st_mode):
                    size = info.st_size
                    body = f.read() if size == need else b""
                else:
                    body = f.read(need - len(head) + 1)
                    size = len(head) + len(body)
                if size != need:
                    raise TreeFileError(f"{path}: {size} bytes, but its counts need {need} "
                                        f"(truncated or corrupt)")
                data = head + body
        except OSError as e:
            raise TreeFileError(f"{path}: cannot read ({e.strerror or e})") from None
        except ValueError:                      # a NUL byte in the path
            raise TreeFileError(f"{path!r}: cannot read (a path cannot hold a NUL byte)") from None
        return cls.from_bytes(data, name=path)

    # -- structure ---------------------------------------------------------------

    def _topology(self):
        """Parent links and depths of every node, checking that the nodes form one tree.

        Returns (depth (n,) int32, parent (n,) int64, is_above (n,) bool). Raises TreeError.
        """
        nodes = self.nodes
        n = len(nodes)
        leaf = layout.is_leaf(nodes)
        inner = np.flatnonzero(~leaf)
        above = layout.above_child(nodes)[inner].astype(np.int64)
        if np.any(above <= inner + 1) or np.any(above >= n) or np.any(inner + 1 >= n):
            raise TreeError("an interior node's child index is out of range")
        children = np.concatenate([inner + 1, above])
        if len(children) != n - 1 or np.any(np.bincount(children, minlength=n)[1:] != 1):
            raise TreeError("the nodes do not form a single tree (a node has no parent or two)")
        parent = np.full(n, -1, dtype=np.int64)
        parent[inner + 1] = inner
        parent[above] = inner
        is_above = np.zeros(n, dtype=bool)
        is_above[above] = True
        # children have larger indices than parents, so one ordered pass sets depths;
        # do it level by level, vectorized.
        depth = np.full(n, -1, dtype=np.int32)
        depth[0] = 0
        frontier = np.array([0])
        level = 0
        while len(frontier):
            level += 1
            if level > layout.MAX_DEPTH_LIMIT + 1:
                raise TreeError(f"tree deeper than {layout.MAX_DEPTH_LIMIT}")
            f_inner = frontier[~leaf[frontier]]
            frontier = np.concatenate([f_inner + 1, layout.above_child(nodes)[f_inner].astype(np.int64)])
            depth[frontier] = level
        return depth, parent, is_above

    def node_boxes(self):
        """(n_nodes, 2, 3) float32 box of every node, relative to `origin`."""
        depth, parent, is_above = self._topology()
        n = len(self.nodes)
        boxes = np.empty((n, 2, 3), dtype=np.float32)
        boxes[0] = self.bounds
        axis = layout.split_axis(self.nodes).astype(np.int64)
        split = layout.split(self.nodes)
        order = np.argsort(depth, kind="stable")
        levels = np.split(order, np.flatnonzero(np.diff(depth[order])) + 1)
        for nodes_at in levels[1:]:
            p = parent[nodes_at]
            boxes[nodes_at] = boxes[p]
            side = np.where(is_above[nodes_at], 0, 1)       # above child: raise min
            boxes[nodes_at, side, axis[p]] = split[p]
        return boxes

    def validate(self, coverage_samples=4, seed=0):
        """Check the structural invariants; raise TreeError naming the first broken one.

        coverage_samples=None skips the (slower) coverage check; the file loader does.
        Else an integer >= 0 (TreeError otherwise), as seed.

        - array shapes and dtypes; indices in range (children, leaf ranges, leaf
          triangle indices, tri_ids < n_input_tris); finite splits and triangles;
        - the nodes form one tree with depth-first below children, no deeper than
          `params.max_depth` and exactly `depth` deep;
        - split planes lie inside their node's box;
        - coverage: points sampled on every triangle (vertices, edge midpoints,
          centroid and `coverage_samples` random points, clipped to the scene box)
          lie in a leaf that lists the triangle.
        """
        for value, name in ((coverage_samples, "coverage_samples"), (seed, "seed")):
            if value is not None and (isinstance(value, bool)
                                      or not isinstance(value, (int, np.integer)) or value < 0):
                raise TreeError(f"{name} must be an integer >= 0, got {value!r:.40}")
        t = self
        if t.nodes.ndim != 2 or t.nodes.shape[1] != 2 or t.nodes.dtype != np.uint32 or len(t.nodes) < 1:
            raise TreeError("nodes must be a non-empty (n, 2) uint32 array")
        if t.leaf_tris.ndim != 1 or t.leaf_tris.dtype != np.uint32:
            raise TreeError("leaf_tris must be a (k,) uint32 array")
        if t.triangles.ndim != 3 or t.triangles.shape[1:] != (3, 3) or t.triangles.dtype != np.float32:
            raise TreeError("triangles must be an (m, 3, 3) float32 array")
        if t.tri_ids.shape != (len(t.triangles),) or t.tri_ids.dtype != np.uint32:
            raise TreeError("tri_ids must be an (m,) uint32 array matching triangles")
        if len(t.nodes) >= layout.MAX_NODES or len(t.triangles) >= layout.MAX_NODES:
            raise TreeError("too many nodes or triangles for the node encoding")
        if t.origin.shape != (3,) or not np.all(np.isfinite(t.origin)):
            raise TreeError("origin must be 3 finite float64 values")
        if not layout.is_scale(t.scale):
            raise TreeError(f"scale must be a power of two from 2^-126 to 2^127, got {t.scale!r}")
        if t.bounds.shape != (2, 3) or not np.all(np.isfinite(t.bounds)) or np.any(t.bounds[0] > t.bounds[1]):
            raise TreeError("bounds must be a finite (2, 3) box with min <= max")
        if not np.all(np.isfinite(t.triangles)):
            raise TreeError("a triangle has a non-finite coordinate")
        if len(t.tri_ids) and int(t.tri_ids.max()) >= t.n_input_tris:
            raise TreeError("a triangle id is out of range of the input's triangles")
        if len(t.leaf_tris) and int(t.leaf_tris.max()) >= len(t.triangles):
            raise TreeError("a leaf refers to a triangle out of range")
        if t.objects is not None or len(t.object_names):
            self._check_objects()
        p = t.params
        # finite costs, as the builder takes them (builder.check_params)
        if not (0 < p.K_T < np.inf and 0 < p.K_I < np.inf and 0 < p.empty_bonus <= 1
                and 1 <= p.max_depth <= layout.MAX_DEPTH_LIMIT):
            raise TreeError("build parameters out of range")
        leaf = layout.is_leaf(t.nodes)
        counts = layout.n_prims(t.nodes[leaf]).astype(np.int64)
        starts = layout.leaf_offset(t.nodes[leaf]).astype(np.int64)
        ends = starts + counts
        if len(ends) and int(ends.max()) > len(t.leaf_tris):
            raise TreeError("a leaf's triangle range runs past leaf_tris")
        # the leaves' ranges split leaf_tris in node order, as the builder lays them
        # out: no range shared (a file whose leaves all list one range would make
        # a device copy a reference, gigabytes from a small file)
        full = counts > 0
        if (int(counts.sum()) != len(t.leaf_tris)
                or np.any(starts[full] != (np.cumsum(counts) - counts)[full])):
            raise TreeError("the leaves' triangle ranges do not split leaf_tris in node order")
        if len(t.triangles) == 0 or np.any(
                np.bincount(t.leaf_tris, minlength=len(t.triangles)) == 0):
            raise TreeError("a triangle is listed in no leaf (or the tree has none)")
        if np.abs(t.bounds).max() > MAX_COORDINATE:
            raise TreeError(f"the scene lies {float(np.abs(t.bounds).max()):.3g} from its origin "
                            f"in units of its scale; at most {MAX_COORDINATE:.3g} (2^28): "
                            f"the kernels' products of coordinates would overflow")
        if not np.all(np.isfinite(layout.split(t.nodes[~leaf]))):
            raise TreeError("a split position is not finite")
        depth, _, _ = self._topology()
        leaf_depth = int(depth[leaf].max())
        if leaf_depth != t.depth:
            raise TreeError(f"tree depth is {leaf_depth} but the header says {t.depth}")
        if t.depth > p.max_depth:
            raise TreeError(f"tree depth {t.depth} exceeds max_depth {p.max_depth}")
        boxes = self.node_boxes()
        inner = np.flatnonzero(~leaf)
        ax = layout.split_axis(t.nodes[inner]).astype(np.int64)
        s = layout.split(t.nodes[inner])
        if np.any(s < boxes[inner, 0, ax]) or np.any(s > boxes[inner, 1, ax]):
            raise TreeError("a split plane lies outside its node's box")
        if np.any(t.triangles.min(axis=1) < t.bounds[0]) or np.any(t.triangles.max(axis=1) > t.bounds[1]):
            raise TreeError("a triangle lies outside the scene bounds")
        if coverage_samples is not None and coverage_samples >= 0 and len(t.triangles):
            self._check_coverage(coverage_samples, seed)

    def _check_objects(self):
        """The object table: (n_input_tris,) uint32 indices below the number of
        objects, more than one object, unique string names."""
        o, names = self.objects, self.object_names
        if o is None:
            raise TreeError("object_names given without an objects table")
        if o.shape != (self.n_input_tris,) or o.dtype != np.uint32:
            raise TreeError(f"objects must be an ({self.n_input_tris},) uint32 array, one per "
                            f"input triangle")
        if not isinstance(names, tuple) or not all(isinstance(n, str) for n in names):
            raise TreeError("object_names must be a tuple of strings")
        if len(names) < 2:
            raise TreeError("an object table has at least two objects")
        if len(set(names)) != len(names):
            raise TreeError("object names must be unique")
        if len(o) and int(o.max()) >= len(names):
            raise TreeError(f"an object index is out of range ({len(names)} objects)")

    def _check_coverage(self, n_random, seed):
        tri = self.triangles.astype(np.float64)
        m = len(tri)
        rng = np.random.default_rng(seed)
        fixed = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [.5, .5, 0], [0, .5, .5],
                          [.5, 0, .5], [1 / 3, 1 / 3, 1 / 3]])
        w = rng.random((m, n_random, 3)) ** 2
        w /= w.sum(axis=2, keepdims=True)
        weights = np.concatenate([np.broadcast_to(fixed, (m, 7, 3)), w], axis=1)
        pts = np.einsum("mkj,mjc->mkc", weights, tri)
        # a triangle lying flat in a plane must be sampled exactly in it (the weighted
        # sum can round one ulp off, onto the side of a split it is not listed on)
        flat = tri.min(axis=1) == tri.max(axis=1)
        pts = np.where(flat[:, None, :], tri[:, None, 0, :], pts).reshape(-1, 3)
        pts = np.clip(pts, self.bounds[0], self.bounds[1])
        owner = np.repeat(np.arange(m), weights.shape[1])
        # a point lies in one leaf, or a few where split planes meet: a bound far
        # above any builder's tree, far below the memory of a hostile one's
        leaves = point_leaves(self.nodes, pts, limit=COVERAGE_LEAVES * len(pts) + 2 ** 20)
        pt_idx, leaf_idx = leaves
        # (leaf node, triangle) pairs that the tree lists
        is_leaf = layout.is_leaf(self.nodes)
        leaf_nodes = np.flatnonzero(is_leaf)
        counts = layout.n_prims(self.nodes[leaf_nodes]).astype(np.int64)
        starts = layout.leaf_offset(self.nodes[leaf_nodes]).astype(np.int64)
        ref_node = np.repeat(leaf_nodes, counts)
        ref_pos = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts) + np.repeat(starts, counts)
        listed = np.unique(ref_node * m + self.leaf_tris[ref_pos].astype(np.int64))
        ok = np.isin(leaf_idx.astype(np.int64) * m + owner[pt_idx], listed)
        covered = np.zeros(len(pts), dtype=bool)
        covered[pt_idx[ok]] = True
        if not covered.all():
            bad = owner[np.flatnonzero(~covered)[0]]
            raise TreeError(f"triangle {bad} (input id {self.tri_ids[bad]}) is not listed in a "
                            f"leaf that contains part of it")

    # -- statistics ----------------------------------------------------------------

    def stats(self):
        """Dict of tree statistics: nodes, leaves, empty leaves, max and mean leaf depth,
        references per triangle, SAH cost (in units of K_I-weighted tests) and bytes."""
        leaf = layout.is_leaf(self.nodes)
        depth, _, _ = self._topology()
        boxes = self.node_boxes().astype(np.float64)
        ext = boxes[:, 1] - boxes[:, 0]
        area = 2 * (ext[:, 0] * ext[:, 1] + ext[:, 1] * ext[:, 2] + ext[:, 2] * ext[:, 0])
        root_area = area[0] if area[0] > 0 else 1.0
        n_in_leaf = layout.n_prims(self.nodes[leaf]).astype(np.float64)
        p = self.params
        with np.errstate(over="ignore"):      # K_T or K_I near float64's largest: inf
            sah = (p.K_T * area[~leaf].sum() + p.K_I * (area[leaf] * n_in_leaf).sum()) / root_area
        n_tris = len(self.triangles)
        return {
            "triangles": n_tris,
            "input_triangles": self.n_input_tris,
            "nodes": len(self.nodes),
            "leaves": int(leaf.sum()),
            "empty_leaves": int((n_in_leaf == 0).sum()),
            "max_leaf_depth": int(depth[leaf].max()),
            "mean_leaf_depth": float(depth[leaf].mean()),
            "refs_per_triangle": float(len(self.leaf_tris) / max(n_tris, 1)),
            "mean_leaf_size": float(n_in_leaf[n_in_leaf > 0].mean()) if np.any(n_in_leaf > 0) else 0.0,
            "sah_cost": float(sah),
            "bytes": int(self.nodes.nbytes + self.leaf_tris.nbytes + self.triangles.nbytes + self.tri_ids.nbytes),
            "double_bytes": int(self.triangles64.nbytes) if self.triangles64 is not None else 0,
        }


def point_leaves(nodes, points, limit=None):
    """Locate points in the tree; a point on a split plane goes to both sides.

    nodes : (n, 2) uint32;  points : (k, 3) float64 relative to the origin.
    limit : None, or the most (point, node) pairs the walk may hold at once: TreeError
        beyond it (splits that repeat one plane send a point on it down every path).
    Returns (point_index, leaf_node) : two (j,) int64 arrays, every pair of a point
    and a leaf whose closed box holds it.
    """
    pi = np.arange(len(points))
    node = np.zeros(len(points), dtype=np.int64)
    out_p, out_n = [], []
    axis_all = layout.split_axis(nodes).astype(np.int64)
    split_all = layout.split(nodes).astype(np.float64)
    above_all = layout.above_child(nodes).astype(np.int64)
    while len(pi):
        ax = axis_all[node]
        at_leaf = ax == layout.LEAF
        out_p.append(pi[at_leaf])
        out_n.append(node[at_leaf])
        pi, node, ax = pi[~at_leaf], node[~at_leaf], ax[~at_leaf]
        c = points[pi, ax]
        s = split_all[node]
        go_below = c <= s
        go_above = c >= s
        pi = np.concatenate([pi[go_below], pi[go_above]])
        node = np.concatenate([node[go_below] + 1, above_all[node[go_above]]])
        if limit is not None and len(pi) + sum(map(len, out_p)) > limit:
            raise TreeError(f"points on split planes lie in more than {limit:,} leaves in "
                            f"all ({len(points):,} points): splits repeat a plane")
    return np.concatenate(out_p), np.concatenate(out_n)


def object_ids(tri_ids, objects):
    """(N,) uint32: the object of each input triangle id, objects[tri_ids], and MISS
    where tri_ids is MISS (a miss).

    tri_ids : (N,) uint32 input triangle ids or MISS (Hits.prim, the `id` AOV)
    objects : (n_input_tris,) uint32 (KdTree.objects) or None: every triangle object 0
    """
    tri_ids = np.asarray(tri_ids, dtype=np.uint32)
    if objects is None:
        return np.where(tri_ids == layout.MISS, layout.MISS, np.uint32(0)).astype(np.uint32)
    # the table with MISS appended, indexed by min(id, n): a miss takes the last entry
    table = np.append(np.asarray(objects, dtype=np.uint32), layout.MISS)
    return table[np.minimum(tri_ids, np.uint32(len(table) - 1))]
