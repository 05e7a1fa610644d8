"""kdray behind trimesh's ray queries: a drop-in for trimesh's RayMeshIntersector.

    import trimesh
    from kdray.integrations.trimesh import RayMeshIntersector
    mesh = trimesh.load("part.stl")
    mesh.ray = RayMeshIntersector(mesh)          # device=None: kdray's default device
    index_tri, index_ray = mesh.ray.intersects_id(origins, directions)
    locations, index_ray, index_tri = mesh.ray.intersects_location(origins, directions)
    mesh.ray.intersects_first(origins, directions)   # (n,) int64, -1 on a miss
    mesh.ray.intersects_any(origins, directions)     # (n,) bool
    mesh.contains(points)                            # (n,) bool: contains_points
    trimesh.proximity.signed_distance(mesh, points)  # its ray-decided signs: ours

The methods take the arguments of trimesh's embree intersector
(trimesh.ray.ray_pyembree.RayMeshIntersector), with its names and defaults, and
return what trimesh's intersectors return, for n rays (origins and directions
(n, 3), any float-like dtype; directions of any length, a zero or non-finite one a
miss) and h hits:

    intersects_id(o, d, multiple_hits=True, max_hits=100, return_locations=False)
        -> index_tri (h,) int64, index_ray (h,) int64[, locations (h, 3) float64]
    intersects_location(o, d, multiple_hits=True, max_hits=100)
        -> locations (h, 3) float64, index_ray (h,) int64, index_tri (h,) int64
    intersects_first(o, d) -> (n,) int64 triangle index, -1 on a miss
    intersects_any(o, d)   -> (n,) bool
    contains_points(points (n, 3)) -> (n,) bool

An empty result is (0,) int64 and (0, 3) float64 locations (as embree's; trimesh's
ray_triangle gives (0,) locations there).

Which hits, and the differences from embree's intersector on purpose:

- Every hit of a ray comes from one walk of kdray's tree (Tracer.intersections):
  embree's intersector casts again from each hit moved on by an offset, which loses
  hits closer together than the offset and repeats a hit it gets stuck on at small or
  large scales; kdray lists each triangle once per ray at any scale. `max_hits` keeps
  a ray's nearest hits, as embree's does: its nearest triangles without locations,
  its nearest points with them (None: all; 0: none, as embree's loop of 0 casts).
- kdray's hit test is watertight (docs/conventions.md, "Ray queries"): a ray through
  an edge or a vertex hits every triangle that has it. `intersects_id` without
  locations lists them all: both triangles at a shared edge, the whole fan at a
  vertex. The test decides in float32 along axes sheared by the direction's ratios,
  so directions are traced as given (times a power of two), not made unit (which
  would round them again): a ray through an edge whose origin, direction and ratios
  are exact in float32 hits both triangles; where the shear rounds, the test may see
  it just beside the edge and hit one (watertight still). With locations
  (`intersects_location`, `intersects_id(..., return_locations=True)`) a ray's hits
  at one point are one hit, as trimesh's ray_triangle intersector documents ("unique
  cartesian locations", so that the hits can be counted): the hit of the lowest
  triangle index among them, whatever `max_hits` (the triangle `intersects_first`
  and `multiple_hits=False` give there). Two hits of a ray are one point when their
  distances along it differ by at most SAME_POINT_RTOL times the scene's size, or,
  for triangles that share a vertex (the ray through an edge or a vertex, as kdray's
  float32 test decides it), SAME_TRIANGLE_RTOL times that size.
- A hit counts where the ray meets the hit triangle's plane, in float64 from the
  mesh's vertices, at t > 0, and not where its origin lies on that plane (within
  SAME_POINT_RTOL of the scene's size, _sizes): a ray from a float64 point on the surface
  does not hit the triangles through it, whichever side of them kdray's float32
  triangles put it (embree's may, at t = 0), and a ray in a triangle's plane misses
  it. intersects_any is whether a ray has a hit that counts (_nearest).
- Locations are o + t d in float64 (d the unit direction), t where the ray meets the
  hit triangle's plane, computed in float64 from the triangle's vertices
  (kdray.double.plane_hits: the plane through its first vertex, normal to its edges'
  cross product); where that t is not finite (a ray in the plane to float64
  precision, which the float32 test hit), the float32 test's t. Embree's intersector
  intersects the plane through the first vertex too (trimesh.intersections.
  planes_lines), with `mesh.face_normals` as its normal, which for an STL file can be
  the file's own rounded normals: its points then lie off the triangle by that
  rounding, ours on it to float64 rounding. It also drops a hit whose ray meets the
  plane at less than 1e-5 of a right angle (planes_lines' `valid`); kdray keeps every
  hit its test finds.
- `contains_points` is Tracer.contains: the parity of one ray's exact crossing count
  along a fixed direction (kdray.rays.contains_directions), exact at edges and
  vertices on a closed, consistently oriented mesh, the same every run. trimesh's
  casts two rays a point and, where they disagree, again in a random direction. A
  point on the surface (kdray's float32 triangles: a float64 point within their
  rounding of a face may answer either way) answers as if moved an infinitesimal
  step along that direction (trimesh: undefined); a non-finite point is outside. On a mesh that is not
  closed the answer is that one ray's parity.
- Order: trimesh documents none for several hits (embree's comes from its re-casting:
  all rays' first hits, then their second hits, ...; ray_triangle's from its r-tree).
  Hits here are sorted by ray, then by distance along the ray, ties by triangle index;
  first hits by ray.
- `scale_to_box` is accepted for embree's signature and does nothing: kdray's tree
  stores the triangles relative to their centre, in a power-of-two unit, so its
  accuracy does not depend on where or how large the mesh is.

The tree is built on first use and cached on the mesh's hash (trimesh's Cache with
`mesh.__hash__`, as embree's intersector caches its scene): a mesh that is edited or
transformed is built again on its next query, on the same OpenCL context
(Tracer.with_tree). The intersector pickles and copies without its OpenCL objects,
which it makes again when next used; `copy.deepcopy` copies the mesh too, `copy.copy`
shares it. trimesh's `mesh.copy()` and `copy.deepcopy(mesh)` give a mesh with
trimesh's default intersector: assign this one again.

This is the only kdray module besides kdray.load that imports trimesh.
"""
import copy
import typing

import numpy as np
from trimesh import caching

from ..builder import build
from ..double import plane_hits
from ..errors import KdrayError, MeshError, ParameterError
from ..host import row_abs_max
from ..layout import MISS
from ..trace import Tracer

__all__ = ["RayMeshIntersector"]

SAME_POINT_RTOL = 2.0 ** -40
"""Two hits of one ray are one point (with locations) when their distances along the
ray differ by at most this times the scene's size (the largest coordinate of the ray's
origin and of the mesh's box, from the box's centre, or WORLD_SHARE of the origin's
world coordinates where that is more): 4096 float64 roundings, the error of t
computed from two planes through the same point."""

WORLD_SHARE = 2.0 ** -8
"""The share of a ray origin's largest world coordinate that counts in the scene's size
(so 2^-48 of it, 32 float64 roundings, in SAME_POINT_RTOL's tolerances): a point
sampled on a face in world coordinates (trimesh.sample) is off its plane by the
rounding of those coordinates, and the planes' offsets carry theirs, which exceed
2^-40 of the mesh's own size where the mesh lies more than some 10^3 of its sizes from
the world's origin."""

SAME_TRIANGLE_RTOL = 2.0 ** -20
"""... and for two triangles that share a vertex, at most this times that size: 16
float32 roundings. kdray decides a hit in float32, so a ray it finds through an edge
or a vertex may pass that far from it in float64, where the two triangles' planes
meet the ray that far apart."""


class RayMeshIntersector:
    """Ray queries on a trimesh.Trimesh through a kdray tree; assign it to `mesh.ray`.

    geometry : trimesh.Trimesh (kept as `self.mesh`; read at each query).
    scale_to_box : accepted for embree's signature; does nothing (module docstring).
    device : None (kdray's default device) or a device string as kdray.Tracer takes it
        ("pocl", "intel", "0:1").
    """

    def __init__(self, geometry, scale_to_box=True, device=None):
        self.mesh = geometry
        self._scale_to_box = bool(scale_to_box)
        self.device = device
        self._kept = None   # the last Tracer: its context and programs serve the next tree
        self._cache = caching.Cache(id_function=self.mesh.__hash__)

    # -- the tree and its Tracer ---------------------------------------------------------

    @property
    def tracer(self):
        """kdray.Tracer of the mesh as it is now (built on first use, and again after the
        mesh changed), or None for a mesh with no triangle a ray can hit. Its richer
        queries (Tracer.count, intersections with t ranges, trace's barycentrics) take
        the mesh's face indices as triangle ids."""
        return self._tracer

    @caching.cache_decorator
    def _tracer(self):
        vertices = np.asarray(self.mesh.vertices, dtype=np.float64).reshape(-1, 3)
        faces = np.asarray(self.mesh.faces, dtype=np.int64).reshape(-1, 3)
        if len(faces) == 0:
            return None
        try:
            tree = build(vertices, faces)
        except MeshError:
            # only a mesh none of whose triangles kdray keeps is one a ray misses
            if _usable(vertices, faces).any():
                raise
            return None
        tracer = None
        if self._kept is not None:
            try:
                tracer = self._kept.with_tree(tree)
            except KdrayError:          # a tree too deep for the kept work sizes
                tracer = None
        if tracer is None:
            tracer = Tracer(tree, device=self.device)
        self._kept = tracer
        return tracer

    # -- queries -------------------------------------------------------------------------

    def intersects_id(self, ray_origins, ray_directions, multiple_hits=True, max_hits=100,
                      return_locations=False):
        """The triangles the rays hit.

        ray_origins, ray_directions : (n, 3) float-like, the same shape.
        multiple_hits : every hit of each ray (sorted by distance), else the first.
        max_hits : the most hits a ray keeps, its nearest (an int >= 0, or None: all).
        return_locations : also the hit points; a ray's hits at one point are then one.
        Returns index_tri (h,) int64 (rows of mesh.faces), index_ray (h,) int64, and
        with return_locations locations (h, 3) float64; sorted by ray, then distance.
        ParameterError (a ValueError) for arrays of other shapes or a bad max_hits."""
        rays = _rays(ray_origins, ray_directions)
        limit = _max_hits(max_hits)
        tracer = self._tracer
        if tracer is None or len(rays.o) == 0 or limit == 0:
            return _empty(return_locations)
        if not multiple_hits:
            ray, tri, t = self._first_points(tracer, rays)
        elif not return_locations:
            hits, _ = self._list(tracer, rays, np.arange(len(rays.o)), limit, plane=False)
            return hits.tri, hits.ray
        else:
            ray, tri, t = self._points(tracer, rays, limit)
        if not return_locations:
            return tri, ray
        return tri, ray, rays.o[ray] + t[:, None] * rays.d[ray]

    def intersects_location(self, ray_origins, ray_directions, multiple_hits=True,
                            max_hits=100):
        """The points where the rays hit, each once per ray.

        Returns locations (h, 3) float64, index_ray (h,) int64, index_tri (h,) int64:
        intersects_id(..., return_locations=True) in trimesh's order of the three."""
        index_tri, index_ray, locations = self.intersects_id(
            ray_origins, ray_directions, multiple_hits=multiple_hits, max_hits=max_hits,
            return_locations=True)
        return locations, index_ray, index_tri

    def intersects_first(self, ray_origins, ray_directions):
        """(n,) int64: the index of the triangle each ray hits first, -1 on a miss (at an
        edge or a vertex the lowest index that kdray's test hits there: the first point's
        as intersects_location gives it, _first_points)."""
        rays = _rays(ray_origins, ray_directions)
        first = np.full(len(rays.o), -1, dtype=np.int64)
        tracer = self._tracer
        if tracer is None or len(rays.o) == 0:
            return first
        ray, tri, _ = self._first_points(tracer, rays)
        first[ray] = tri
        return first

    def intersects_any(self, ray_origins, ray_directions):
        """(n,) bool: whether each ray hits the mesh (a hit that counts: _nearest; the
        same answers as intersects_first != -1)."""
        rays = _rays(ray_origins, ray_directions)
        hit = np.zeros(len(rays.o), dtype=bool)
        tracer = self._tracer
        if tracer is not None and len(rays.o):
            hit[self._nearest(tracer, rays, plane=False).ray] = True
        return hit

    def contains_points(self, points):
        """(n,) bool: whether each point is inside the mesh (Tracer.contains: one ray's
        exact crossing parity; module docstring). points : (n, 3) float-like; a
        non-finite point is outside. ParameterError (a ValueError) for other shapes."""
        p = np.asarray(points, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 3:
            raise ParameterError(f"points must be an (n, 3) array, got shape {p.shape}")
        inside = np.zeros(len(p), dtype=bool)
        finite = np.isfinite(p).all(axis=1)
        tracer = self._tracer
        if tracer is not None and finite.any():
            inside[finite] = tracer.contains(p[finite])
        return inside

    # -- hits that count, and hit points -------------------------------------------------

    def _counts(self, rays, ray, tri, t32):
        """(h,) bool: whether each of kdray's hits (ray, tri (h,) int64; t32 (h,)
        float64 its distance at kdray's float32 t, _dist) counts. Not where the ray's
        origin lies on the triangle's plane (within SAME_POINT_RTOL times the scene's
        size: the ray meets it only there, at t = 0), nor where the ray meets that
        plane behind its origin (t <= 0; where the ray is parallel to it, t32 decides),
        the plane in float64 from the mesh's vertices. So a ray from a point on the
        surface, given in float64, does not hit the triangles through that point, which
        kdray's float32 triangles, moved by their rounding, may put just ahead of it."""
        normal, offset = self._planes
        o = rays.o[ray]
        ahead = offset[tri] - np.einsum("ij,ij->i", normal[tri], o)   # plane - origin
        with np.errstate(divide="ignore", invalid="ignore"):
            t = ahead / np.einsum("ij,ij->i", normal[tri], rays.d[ray])
        t = np.where(np.isfinite(t), t, t32)
        return ~(np.abs(ahead) <= SAME_POINT_RTOL * self._sizes(o)) & ~(t <= 0.0)

    @caching.cache_decorator
    def _planes(self):
        """The faces' planes, float64: unit normals (m, 3) and offsets (m,), n . v0 (NaN
        for a degenerate face, whose hits then count)."""
        p = self._triangles
        n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
        with np.errstate(divide="ignore", invalid="ignore"):
            n = n / np.linalg.norm(n, axis=1)[:, None]
        return n, np.einsum("ij,ij->i", n, p[:, 0])

    def _hits(self, rays, ray, tri, t32, u32, v32, plane=True):
        """_Hits of kdray's hits (ray, tri, t32 as _counts takes them; u32, v32 (h,)
        its barycentrics) with, where `plane`, where each unit ray meets its triangle's
        plane in float64 from the mesh's vertices (kdray.double.plane_hits: t a
        distance, u, v; the float32 test's t where that is not finite: a ray in the
        plane to float64 precision that float32 found a hit for); else NaN there."""
        if not plane:
            nan = np.full(len(ray), np.nan)
            return _Hits(ray, tri, t32, u32, v32, nan, nan, nan)
        t, u, v = plane_hits(self._triangles[tri], rays.o[ray], rays.d[ray])
        bad = ~np.isfinite(t)
        t[bad] = t32[bad]
        return _Hits(ray, tri, t32, u32, v32, t, u, v)

    @caching.cache_decorator
    def _triangles(self):
        """(m, 3, 3) float64: the mesh's triangles."""
        return np.asarray(self.mesh.vertices, dtype=np.float64)[np.asarray(self.mesh.faces)]

    def _list(self, tracer, rays, rows, limit, plane=True):
        """The hits that count (_counts) of the rays `rows` ((r,) int64, ascending), at
        most `limit` a ray (None: all), the nearest as Tracer.intersections lists them
        (by t, ties by index), with their planes' hits where `plane` (_hits): (_Hits
        sorted by ray, more (r,) bool: whether a ray's list was cut at `limit`). A ray
        whose list was cut and had hits that do not count is listed again with room for
        as many more."""
        parts, more = [], np.zeros(len(rows), dtype=bool)
        pending, k = np.arange(len(rows)), limit
        while pending.size:
            r = rows[pending]
            found = tracer.intersections(rays.o[r], rays.kd[r], max_hits=k)
            ray, tri = r[found.ray], found.prim.astype(np.int64)
            t32 = _dist(rays, ray, found.t)
            counts = self._counts(rays, ray, tri, t32)
            cut = found.counts == k if k is not None else np.zeros(len(r), dtype=bool)
            dropped = np.bincount(found.ray[~counts], minlength=len(r))
            again = cut & (dropped > 0)
            keep = counts & ~again[found.ray]
            parts.append(self._hits(rays, ray[keep], tri[keep], t32[keep], found.u[keep],
                                    found.v[keep], plane))
            more[pending[cut & ~again]] = True
            if again.any():
                k += int(dropped[again].max())
            pending = pending[again]
        hits = _Hits(*(np.concatenate(c) for c in zip(*parts)))
        hits = hits.take(np.argsort(hits.ray, kind="stable"))
        if limit is not None:
            # rays listed again may have more than `limit` that count: their nearest
            rank = np.arange(len(hits.ray)) - np.searchsorted(hits.ray, hits.ray)
            more[np.searchsorted(rows, hits.ray[rank >= limit])] = True
            hits = hits.take(rank < limit)
        return hits, more

    def _nearest(self, tracer, rays, plane=True):
        """_Hits of each ray's nearest hit that counts (_counts), by ray, with its
        plane's hit where `plane` (_hits): Tracer.trace's, or where that does not count
        the nearest of the ray's list (_list)."""
        found = tracer.trace(rays.o, rays.kd, outputs=("uv",) if plane else ())
        hit = np.flatnonzero(found.prim != MISS)
        tri, t32 = found.prim[hit].astype(np.int64), _dist(rays, hit, found.t[hit])
        counts = self._counts(rays, hit, tri, t32)
        ray, tri, t32 = hit[counts], tri[counts], t32[counts]
        # trace's barycentrics where they are wanted (_near_edges), else none
        u32, v32 = (found.u[ray], found.v[ray]) if plane else (t32 * np.nan,) * 2
        hits = self._hits(rays, ray, tri, t32, u32, v32, plane)
        if counts.all():
            return hits
        again, _ = self._list(tracer, rays, hit[~counts], 1, plane)
        hits = _Hits(*(np.concatenate(c) for c in zip(hits, again)))
        return hits.take(np.argsort(hits.ray, kind="stable"))

    def _first_points(self, tracer, rays):
        """(ray, tri, t) of the rays that hit, by ray: the first point each hits
        (_distinct) and there its lowest triangle index; (h,) int64, int64, float64 (t
        the distance to the triangle's plane: _hits). _nearest's triangle is that one
        but where the ray passes through an edge or a vertex: kdray's float32 test
        orders the triangles there by their t's roundings, not by index. So rays whose
        hit is that near an edge of its triangle (_near_edges) list all their hits
        again: the triangles through that point may lie anywhere in the list, as their
        float32 t may round far from it where the ray grazes them (and pass a t_max
        their float64 t is within)."""
        hits = self._nearest(tracer, rays)
        ray, tri, t = hits.ray, hits.tri.copy(), hits.t.copy()
        near = np.flatnonzero(self._near_edges(rays, hits))
        if near.size == 0:
            return ray, tri, t
        again, _ = self._list(tracer, rays, ray[near], None)
        ray2, tri2, t2 = self._distinct(rays, again.ray, again.tri, again.t)
        first = np.flatnonzero(np.diff(ray2, prepend=-1) != 0)
        at = np.searchsorted(ray, ray2[first])
        tri[at] = tri2[first]
        t[at] = t2[first]
        return ray, tri, t

    def _near_edges(self, rays, hits):
        """(h,) bool: whether each of `hits` (_Hits) lies within SAME_TRIANGLE_RTOL times
        the scene's size of an edge of its triangle, where another triangle may share
        the point: by its float64 barycentrics or kdray's (these allowed 2^-20 for
        float32's rounding; the float64 ones hold where a ray meets the triangle at a
        grazing angle, at which kdray's triangles, moved by their rounding, move the hit
        far along the plane)."""
        u, v = hits.u32.astype(np.float64), hits.v32.astype(np.float64)
        weights = np.stack([1.0 - u - v, u, v], axis=1) - 2.0 ** -20       # (h, 3)
        weights = np.fmin(weights, np.stack([1.0 - hits.u - hits.v, hits.u, hits.v], axis=1))
        tol = SAME_TRIANGLE_RTOL * self._sizes(rays.o[hits.ray])
        return (weights <= tol[:, None] * self._inverse_altitudes[hits.tri]).any(axis=1)

    @caching.cache_decorator
    def _inverse_altitudes(self):
        """(m, 3) float64: 1 / each face's altitude from vertex k to the opposite edge
        (a barycentric weight k over a distance from that edge); inf for a degenerate
        face."""
        p = self._triangles
        # the altitude: twice the area over the edge's length
        area2 = np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
        edges = np.linalg.norm(p[:, [2, 0, 1]] - p[:, [1, 2, 0]], axis=2)
        with np.errstate(divide="ignore", invalid="ignore"):
            inverse = edges / area2[:, None]
        return np.where(np.isnan(inverse), np.inf, inverse)

    def _points(self, tracer, rays, limit):
        """(ray, tri, t) of every distinct hit point of each ray, at most `limit` (None:
        all) a ray, sorted by ray then t: (h,) int64, int64, float64."""
        o = rays.o
        hits, more = self._list(tracer, rays, np.arange(len(o)), limit)
        ray, tri, t = self._distinct(rays, hits.ray, hits.tri, hits.t)
        cut = np.flatnonzero(more)
        if limit is None or cut.size == 0:
            return ray, tri, t
        # A ray cut at `limit` triangles is listed again, every hit, to keep its first
        # `limit` points: with fewer than `limit` points (its triangles shared points),
        # and with `limit` when its last hit is near an edge (_near_edges): its point's
        # other triangles (ordered by their float32 t's roundings) may lie past the cut
        # and have a lower index.
        points = np.bincount(ray, minlength=len(o))
        end = np.searchsorted(hits.ray, cut, side="right") - 1     # each cut ray's last
        relist = (points[cut] < limit) | self._near_edges(rays, hits.take(end))
        redo = cut[relist]
        if redo.size == 0:
            return ray, tri, t
        again, _ = self._list(tracer, rays, redo, None)
        ray2, tri2, t2 = self._distinct(rays, again.ray, again.tri, again.t)
        starts = np.searchsorted(ray2, ray2, side="left")
        keep = np.arange(len(ray2)) - starts < limit
        old = ~np.isin(ray, redo)
        ray = np.concatenate([ray[old], ray2[keep]])
        tri = np.concatenate([tri[old], tri2[keep]])
        t = np.concatenate([t[old], t2[keep]])
        order = np.lexsort((t, ray))
        return ray[order], tri[order], t[order]

    def _distinct(self, rays, ray, tri, t):
        """The hits (ray, tri, t: (h,) each; t the float64 distance to the triangle's
        plane, _hits) merged to one a point: sorted by (ray, t, tri), a hit is the
        previous one's point when their t differ by at most SAME_POINT_RTOL * size, or
        SAME_TRIANGLE_RTOL * size for triangles sharing a vertex; a point keeps its
        lowest triangle index. Returns (ray, tri, t) sorted by ray then t."""
        order = np.lexsort((tri, t, ray))
        ray, tri, t = ray[order], tri[order], t[order]
        if len(ray) < 2:
            return ray, tri, t
        size = self._sizes(rays.o[ray[1:]])
        step = np.diff(t)
        same_ray = ray[1:] == ray[:-1]
        same = same_ray & (step <= SAME_POINT_RTOL * size)
        near = np.flatnonzero(same_ray & ~same & (step <= SAME_TRIANGLE_RTOL * size))
        if near.size:
            a = self._triangles[tri[near]]
            b = self._triangles[tri[near + 1]]
            # a shared vertex: equal coordinates (a mesh whose vertices are not merged
            # shares none by index)
            shared = (a[:, :, None, :] == b[:, None, :, :]).all(axis=3).any(axis=(1, 2))
            same[near[shared]] = True
        group = np.cumsum(np.concatenate([[True], ~same])) - 1
        pick = np.lexsort((tri, group))
        first = pick[np.concatenate([[True], np.diff(group[pick]) != 0])]
        return ray[first], tri[first], t[first]

    def _sizes(self, o):
        """(h,) float64 the scene's size a ray (origins o (h, 3)) sees: the largest
        coordinate of its origin and of the mesh's box, from the box's centre, or
        WORLD_SHARE of its origin's largest world coordinate where that is more."""
        bounds = np.asarray(self.mesh.bounds, dtype=np.float64)
        centre = bounds.mean(axis=0)
        box = np.abs(bounds - centre).max()
        return np.fmax(np.fmax(row_abs_max(o - centre), box), WORLD_SHARE * row_abs_max(o))

    # -- pickling and copies: without OpenCL objects --------------------------------------

    def __getstate__(self):
        state = self.__dict__.copy()
        state.pop("_cache", None)
        state["_kept"] = None
        return state

    def __setstate__(self, state):
        self.__dict__.update(state)
        self._kept = None
        self._cache = caching.Cache(id_function=self.mesh.__hash__)

    def __copy__(self):
        return type(self)(self.mesh, scale_to_box=self._scale_to_box, device=self.device)

    def __deepcopy__(self, memo):
        other = type(self).__new__(type(self))
        memo[id(self)] = other
        other.__setstate__(copy.deepcopy(self.__getstate__(), memo))
        return other

    def __repr__(self):
        return (f"<kdray.integrations.trimesh.RayMeshIntersector of {len(self.mesh.faces)} "
                f"faces, device={self.device!r}>")


def _rays(ray_origins, ray_directions):
    """_Rays of the arguments: o (n, 3) float64; d (n, 3) float64 unit directions; kd,
    the directions as given times a power of two (so that the largest component's
    magnitude is in [0.5, 1)), which kdray traces: as exact as the caller's in float32,
    where a unit direction would round again (a ray through an edge then passes beside
    it); length (n,) float64 kd's norm, t along kd times which is the distance; zero
    where a direction is zero or not finite, which kdray takes as a miss.
    ParameterError for shapes that differ or are not (n, 3) (a single (3,) ray is one
    ray)."""
    # C order: the lengths' sums (einsum) then round alike whatever the caller's layout
    o = np.array(ray_origins, dtype=np.float64, order="C")
    d = np.array(ray_directions, dtype=np.float64, order="C")
    if o.shape != d.shape:
        raise ParameterError(f"ray origins {o.shape} and directions {d.shape} must have "
                             f"the same shape")
    if o.ndim not in (1, 2) or o.shape[-1] != 3:
        raise ParameterError(f"rays must be (n, 3) arrays, got shape {o.shape}")
    o, d = o.reshape(-1, 3), d.reshape(-1, 3)
    # scaled by a power of two first: a finite direction of any size has a norm
    big = row_abs_max(d)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        kd = np.ldexp(d, -np.frexp(big)[1][:, None])
        length = np.sqrt(np.einsum("ij,ij->i", kd, kd))
        unit = kd / length[:, None]
    ok = np.isfinite(unit).all(axis=1)
    unit[~ok], kd[~ok], length[~ok] = 0.0, 0.0, 1.0
    return _Rays(o, unit, kd, length)


class _Rays(typing.NamedTuple):
    """The rays of a query (_rays): origins, unit directions, the directions kdray
    traces and their lengths."""
    o: np.ndarray
    d: np.ndarray
    kd: np.ndarray
    length: np.ndarray


class _Hits(typing.NamedTuple):
    """Hits of the rays of a query, (h,) each (RayMeshIntersector._hits): the ray
    (int64), the triangle (int64, a row of mesh.faces), the distance at kdray's float32
    t (float64) and kdray's barycentrics (float32), and where the unit ray meets the
    triangle's plane in float64: the distance t and barycentrics u, v."""
    ray: np.ndarray
    tri: np.ndarray
    t32: np.ndarray
    u32: np.ndarray
    v32: np.ndarray
    t: np.ndarray
    u: np.ndarray
    v: np.ndarray

    def take(self, index):
        """The hits at `index` (a bool mask or indices)."""
        return _Hits(*(a[index] for a in self))


def _dist(rays, ray, t):
    """(h,) float64 distances of the hits at kdray's t (h,) along rays.kd[ray]."""
    return t.astype(np.float64) * rays.length[ray]


def _max_hits(max_hits):
    """max_hits as an int >= 0, or None (all hits); ParameterError otherwise."""
    if max_hits is None:
        return None
    if isinstance(max_hits, bool) or not isinstance(max_hits, (int, np.integer)):
        raise ParameterError(f"max_hits must be an integer >= 0 or None, got {max_hits!r}")
    if max_hits < 0:
        raise ParameterError(f"max_hits must be >= 0, got {max_hits}")
    return int(max_hits)


def _empty(locations):
    """intersects_id's result with no hits."""
    none = np.zeros(0, dtype=np.int64)
    if locations:
        return none, none.copy(), np.zeros((0, 3), dtype=np.float64)
    return none, none.copy()


def _usable(vertices, faces):
    """(m,) bool: triangles with finite vertices and a nonzero float32 cross product of
    their edges, about the triangles kdray.build keeps (it raises MeshError when it
    keeps none; asked only then)."""
    tri = vertices[faces]
    finite = np.isfinite(tri).all(axis=(1, 2))
    with np.errstate(invalid="ignore", over="ignore"):
        e1 = (tri[:, 1] - tri[:, 0]).astype(np.float32)
        e2 = (tri[:, 2] - tri[:, 0]).astype(np.float32)
        cross = np.cross(e1, e2)
    return finite & (cross != 0).any(axis=1)

