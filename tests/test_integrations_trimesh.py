"""trimesh's own ray tests with kdray's intersector in place of embree's
(kdray.integrations.trimesh.RayMeshIntersector assigned to `mesh.ray`), and the
intersector's contract against independent oracles.

trimesh's cases are re-implemented here as pytest functions named after theirs
(trimesh's tests/test_ray.py and tests/test_proximity.py at mikedh/trimesh a513c0e),
on the models they load, vendored gzipped in tests/data/trimesh/ (its README.md):

test_ray.py
- test_rays: the same four models and their rays (every 6th of tests/data/ray_data.json:
  200 a model). Theirs asserts that embree and ray_triangle agree on intersects_any;
  here kdray agrees with ray_triangle on intersects_any, and intersects_id /
  intersects_location agree with the float64 brute force (kdray.reference.all_hits),
  except on rays that graze an edge within float32 rounding.
- test_rps: the subdivided unit sphere and 10,000 rays; the rays-per-second figure is
  only logged there and is not asserted here; the hits are, against the sphere's
  inscribed and circumscribed balls.
- test_empty, test_contains, test_on_vertex, test_on_edge (through trimesh's own
  ray_util.contains_points on our intersects_location, and our contains_points),
  test_multiple_hits, test_contain_single, test_box: as theirs.
- test_contains_cavity: theirs makes the box with a cavity with trimesh.boolean (which
  needs manifold3d); here the same solid is the outer box and the inner box turned
  inside out.
- test_embree_duplicate_hits (skipped there without embreex): the same boxes at every
  scale. Theirs starts the ray on the top face and expects two hits; kdray does not
  report a hit at the ray's origin (t > 0, docs/integrations.md), so here a ray from
  the top face has one point (the bottom's) and a ray from above the box two, at every
  scale, each hit once.

test_proximity.py (its contains / signed-distance part)
- test_coplanar_signed_distance, test_noncoplanar_signed_distance, test_edge_case: as
  theirs, through trimesh.proximity.signed_distance, whose ray-decided signs here come
  from our contains_points (checked: it is called).
- Not covered: the nearest-point cases (test_naive, test_helper, test_nearest_naive,
  test_acute_edge_case, test_candidates, test_returns_correct_point_in_ambiguous_cases,
  test_unreferenced_vertex) cast no rays.

trimesh's ray_triangle intersector needs an r-tree (rtree) and signed_distance a
k-d tree of vertices (scipy); where those packages are missing, `brute_trees` puts in
brute-force stand-ins with the same answers (small meshes only).

Besides: pickling and copies, the cache rebuilt after apply_translation, dtypes and
shapes equal to ray_triangle's on the same calls, and rays exactly through the shared
vertices and edges of a closed icosphere (distinct points, fan triangles, contains on
grids through its vertices against the exact convex half-space test).
"""
import copy
import gzip
import io
import json
import pickle
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh
from trimesh.ray import ray_triangle, ray_util

from helpers import edge_distance, graze_tolerance
from kdray.errors import KdrayError
from kdray.integrations.trimesh import RayMeshIntersector
from kdray.rays import contains_directions
from kdray.reference import all_hits

DATA = Path(__file__).resolve().parent / "data" / "trimesh"


def get_mesh(name):
    """A vendored trimesh test model (tests/data/trimesh/<name>.gz), loaded as trimesh's
    tests load it (trimesh.load, processed), with kdray's intersector as `mesh.ray`."""
    with gzip.open(DATA / f"{name}.gz", "rb") as f:
        data = f.read()
    mesh = trimesh.load(file_obj=io.BytesIO(data), file_type=name.rsplit(".", 1)[1].lower())
    mesh.ray = RayMeshIntersector(mesh)
    return mesh


def ours(mesh):
    mesh.ray = RayMeshIntersector(mesh)
    return mesh


def reference_points(mesh, o, d):
    """Per ray, the distinct hit points of the float64 brute force: (ray, prim, t) with a
    ray's hits within 1e-9 of the scene's size of the previous one dropped."""
    ray, prim, t, _, _ = all_hits(mesh.triangles, o, d)
    size = np.abs(mesh.bounds).max() + np.abs(o).max()
    keep = np.ones(len(ray), bool)
    keep[1:] = (ray[1:] != ray[:-1]) | (np.diff(t) > 1e-9 * size)
    return ray, prim, t, keep


def grazing(mesh, tree, tri, o, d, t):
    """(k,) bool: rays passing an edge of their triangle within float32 rounding."""
    tris = mesh.triangles[tri]
    return edge_distance(tris, o, d) <= graze_tolerance(tree, tris, o, d, t, "world")


# -- trimesh's tests/test_ray.py -------------------------------------------------------


def test_rays(brute_trees):
    with gzip.open(DATA / "ray_data.json.gz", "rb") as f:
        data = json.load(f)
    for kwargs in data["load_kwargs"]:
        name = kwargs["file_name"]
        mesh = get_mesh(name)
        o = np.array(data["rays"][name]["ray_origins"])
        d = np.array(data["rays"][name]["ray_directions"])
        n = len(o)
        tree = mesh.ray.tracer.tree
        # theirs: the engines agree on intersects_any
        hit_any = mesh.ray.intersects_any(ray_origins=o, ray_directions=d)
        other = ray_triangle.RayMeshIntersector(mesh).intersects_any(o, d)
        assert (hit_any == other).all(), name
        assert 0 < hit_any.sum() < n
        # every triangle hit, against the float64 brute force
        index_tri, index_ray = mesh.ray.intersects_id(o, d)
        ref_ray, ref_prim, ref_t, keep = reference_points(mesh, o, d)
        mine = set(zip(index_ray.tolist(), index_tri.tolist()))
        ref = set(zip(ref_ray.tolist(), ref_prim.tolist()))
        differ = np.array(sorted(mine ^ ref), dtype=np.int64).reshape(-1, 2)
        if len(differ):
            r, p = differ[:, 0], differ[:, 1]
            t = np.einsum("ij,ij->i", mesh.triangles[p][:, 0] - o[r], d[r])
            assert grazing(mesh, tree, p, o[r], d[r], t).all(), (name, differ)
        # distinct points: as many a ray as the brute force's, where no hit grazes
        locations, loc_ray, loc_tri = mesh.ray.intersects_location(o, d)
        counts = np.bincount(loc_ray, minlength=n)
        ref_counts = np.bincount(ref_ray[keep], minlength=n)
        graze = np.zeros(n, bool)
        graze[ref_ray[grazing(mesh, tree, ref_prim, o[ref_ray], d[ref_ray], ref_t)]] = True
        assert (counts[~graze] == ref_counts[~graze]).all(), name
        assert graze.mean() < 0.05
        # each point on its ray and on its triangle's plane
        for r in np.flatnonzero(~graze & (counts > 0)):
            mine_t = np.einsum("ij,j->i", locations[loc_ray == r] - o[r], d[r])
            assert np.allclose(mine_t, ref_t[keep & (ref_ray == r)], rtol=1e-9, atol=1e-12)
        v0 = mesh.triangles[loc_tri, 0]
        normal = np.cross(mesh.triangles[loc_tri, 1] - v0, mesh.triangles[loc_tri, 2] - v0)
        off_plane = np.einsum("ij,ij->i", locations - v0, normal) / np.linalg.norm(normal, axis=1)
        assert np.abs(off_plane).max() < 1e-12 * np.abs(mesh.bounds).max() * 100
        assert (np.diff(loc_ray) >= 0).all()


def test_rps():
    sphere = get_mesh("unit_sphere.STL")
    sphere = ours(sphere.subdivide().subdivide().subdivide())
    rng = np.random.default_rng(1)
    origins = rng.random((10000, 3))
    origins[:, 2] = -5
    directions = np.tile([0.0, 0.0, 1.0], (len(origins), 1))
    a = sphere.ray.intersects_id(origins, directions)
    b = sphere.ray.intersects_location(origins, directions)
    assert all(isinstance(i, np.ndarray) for i in a + b)
    # the faceted sphere holds the ball of its faces' smallest distance from the centre
    # and lies in the unit ball: a line nearer the axis than that crosses it twice
    tri = sphere.triangles
    normal = sphere.face_normals
    inner = np.einsum("ij,ij->i", tri[:, 0], normal).min()
    rho = np.hypot(origins[:, 0], origins[:, 1])
    counts = np.bincount(b[1], minlength=len(origins))
    assert (counts[rho < inner - 1e-9] == 2).all()
    assert (counts[rho > 1 + 1e-9] == 0).all()
    assert (counts <= 2).all()
    # the distinct points' triangles are among intersects_id's
    assert set(zip(b[1].tolist(), b[2].tolist())) <= set(zip(a[1].tolist(), a[0].tolist()))


def test_empty():
    sphere = get_mesh("unit_sphere.STL")
    rng = np.random.default_rng(2)
    origins = rng.random((100, 3))
    origins[:, 2] = -5
    directions = np.tile([0.0, 1.0, 0.0], (len(origins), 1))
    index_tri, index_ray = sphere.ray.intersects_id(origins, directions)
    assert index_tri.shape == index_ray.shape == (0,)
    assert index_tri.dtype == index_ray.dtype == np.int64
    locations, index_ray, index_tri = sphere.ray.intersects_location(origins, directions)
    assert locations.shape == (0, 3) and locations.dtype == np.float64
    assert index_ray.shape == index_tri.shape == (0,)
    assert (sphere.ray.intersects_first(origins, directions) == -1).all()
    assert not sphere.ray.intersects_any(origins, directions).any()


def test_contains():
    scale = 1.5
    mesh = get_mesh("unit_cube.STL")
    mesh.ray.contains_points(mesh.vertices)        # on the surface: defined, not asserted
    assert mesh.ray.contains_points(mesh.vertices * (1.0 / scale)).all()
    assert not mesh.ray.contains_points(mesh.vertices * scale).any()
    rng = np.random.default_rng(3)
    way_out = rng.random((30, 3)) * 100 + 1.0 + mesh.bounds[1]
    assert not mesh.ray.contains_points(way_out).any()
    assert mesh.ray.contains_points([mesh.center_mass]).all()
    # on the surface: as if moved a step along its direction, the same every run
    on = mesh.ray.contains_points(mesh.vertices)
    moved = mesh.vertices + 1e-6 * contains_directions(mesh.ray.tracer, mesh.vertices)
    assert (on == (np.abs(moved) < 0.5).all(axis=1)).all()
    assert (mesh.ray.contains_points(mesh.vertices) == on).all()


def test_contains_cavity():
    outer = trimesh.creation.box(extents=[1, 1, 1])
    inner = trimesh.creation.box(extents=[0.1, 0.1, 0.1])
    inner.invert()
    mesh = ours(trimesh.util.concatenate([outer, inner]))
    assert mesh.is_watertight and mesh.is_winding_consistent
    # the origin sits inside the cavity
    assert not mesh.contains([[0, 0, 0]])[0]
    assert mesh.contains([[0.3, 0.2, 0.1], [0, 0, 0.2]]).all()
    assert not mesh.contains([[0.6, 0, 0], [0.04, -0.04, 0.01]]).any()


def test_on_vertex():
    m = ours(trimesh.creation.box())
    origins = np.zeros_like(m.vertices)
    vectors = m.vertices.copy()
    assert m.ray.intersects_any(ray_origins=origins, ray_directions=vectors).all()
    _, index_ray, index_tri = m.ray.intersects_location(ray_origins=origins,
                                                        ray_directions=vectors)
    assert (np.bincount(index_ray, minlength=len(origins)) == 1).all()
    # every triangle at the vertex is hit, and intersects_id lists them all
    tri, ray = m.ray.intersects_id(origins, vectors)
    for i in range(len(origins)):
        fan = set(np.flatnonzero((m.faces == i).any(axis=1)).tolist())
        assert set(tri[ray == i].tolist()) == fan
        assert index_tri[i] == min(fan) == m.ray.intersects_first(origins, vectors)[i]


def test_on_edge():
    m = get_mesh("7_8ths_cube.stl")
    points = [[4.5, 0, -23], [4.5, 0, -2], [0, -1e-4, 0.0], [0, 0, -1]]
    truth = [False, True, True, True]
    # trimesh's two-way ray test, on our intersects_location
    assert (ray_util.contains_points(m.ray, points) == truth).all()
    assert (m.ray.contains_points(points) == truth).all()
    assert (m.contains(points) == truth).all()


def test_multiple_hits():
    f = np.array([1000.0, 1000.0])
    h, w = 256, 256
    ray_directions = trimesh.util.grid_arange([[-h / 2, -w / 2], [h / 2, w / 2]], step=2.0)
    ray_directions = np.column_stack((ray_directions, np.ones(len(ray_directions)) * f[0]))
    ray_origins = np.tile(np.array([0, 0, -15.0]), (ray_directions.shape[0], 1))
    cube = ours(trimesh.creation.box(extents=[2, 2, 2]))
    index_triangles, index_ray = cube.ray.intersects_id(
        ray_origins=ray_origins, ray_directions=ray_directions, multiple_hits=False)
    assert len(np.unique(index_triangles)) == 2
    assert (np.unique(index_ray) == index_ray).all()
    index_triangles, index_ray = cube.ray.intersects_id(
        ray_origins=ray_origins, ray_directions=ray_directions, multiple_hits=True)
    assert len(np.unique(index_triangles)) > 2
    # a ray that meets the front face (z = -1, 14 / 1000 of the way along its direction
    # from z = -15) enters there and leaves the cube once: two points; the others miss
    front = (np.abs(ray_directions[:, :2]) * 14 / 1000 < 1).all(axis=1)
    _, loc_ray, _ = cube.ray.intersects_location(ray_origins, ray_directions)
    counts = np.bincount(loc_ray, minlength=len(ray_origins))
    assert (counts[front] == 2).all() and (counts[~front] == 0).all()


def test_contain_single():
    mesh = get_mesh("teapot.stl")              # not watertight
    assert not mesh.is_watertight
    points = mesh.bounding_box.sample_grid(step=2.0)
    contained = mesh.ray.contains_points(points)
    assert len(points) == len(contained)
    for point in mesh.bounding_box.vertices:
        assert mesh.ray.contains_points([point]).shape == (1,)


def test_box():
    mesh = get_mesh("unit_cube.STL")
    origins = trimesh.util.grid_linspace(
        mesh.bounds[:, :2] + np.reshape([-0.02, 0.02], (-1, 1)), 100)
    origins = np.column_stack((origins, np.ones(len(origins)) * -100))
    vectors = np.ones((len(origins), 3)) * [0, 0, 1.0]
    pos, ray, _ = mesh.ray.intersects_location(ray_origins=origins, ray_directions=vectors)
    assert len(pos) > 0
    for p, r in zip(pos, ray):
        assert np.allclose(p[:2], origins[r][:2])
        assert np.isclose(p[2], mesh.bounds[:, 2]).any()
    # rays over the top: two points; beside it: none
    inside = (np.abs(origins[:, :2]) < 0.5).all(axis=1)
    counts = np.bincount(ray, minlength=len(origins))
    assert (counts[inside] == 2).all() and (counts[~inside] == 0).all()


def test_embree_duplicate_hits():
    for scale in [1e-4, 0.1, 1.0, 10, 1e4, 1e8]:
        mesh = trimesh.creation.box().subdivide().subdivide()
        mesh.apply_scale(scale)
        mesh.ray = RayMeshIntersector(mesh, scale_to_box=False)
        down = np.array([[0.0, 0.0, -1.0]])
        bottom = np.flatnonzero((mesh.vertices == [0, 0, -scale / 2]).all(axis=1))
        fan = set(np.flatnonzero(np.isin(mesh.faces, bottom).any(axis=1)).tolist())
        # from the top face (the centre's vertex): the hit at the origin is not reported
        index_tri, _ = mesh.ray.intersects_id(np.array([[0.0, 0.0, scale / 2.0]]), down,
                                              multiple_hits=True)
        assert set(index_tri.tolist()) == fan, scale
        assert len(index_tri) == len(fan)
        locations, _, _ = mesh.ray.intersects_location(np.array([[0.0, 0.0, scale / 2]]), down)
        assert len(locations) == 1 and np.allclose(locations, [0, 0, -scale / 2], rtol=0,
                                                     atol=1e-12 * scale)
        # from above: the two faces, once each
        locations, _, _ = mesh.ray.intersects_location(np.array([[0.0, 0.0, scale]]), down)
        assert len(locations) == 2, scale
        assert np.allclose(locations[:, 2], [scale / 2, -scale / 2], rtol=1e-12)


# -- trimesh's tests/test_proximity.py: the signs of signed_distance -------------------


def spy_contains(mesh):
    """mesh.ray with contains_points counting its calls: [calls]."""
    calls = []
    contains = mesh.ray.contains_points

    def counted(points):
        calls.append(len(points))
        return contains(points)
    mesh.ray.contains_points = counted
    return calls


def test_coplanar_signed_distance(brute_trees):
    mesh = ours(trimesh.primitives.Box())
    calls = spy_contains(mesh)
    # well outside the box, coplanar with a face: negative
    distance = mesh.nearest.signed_distance([mesh.bounds[0] + [100, 0, 0]])
    assert distance[0] < 0.0
    assert calls
    # origin inside, coplanar with its nearest face: positive
    mesh = get_mesh("origin_inside.STL")
    calls = spy_contains(mesh)
    distance = mesh.nearest.signed_distance([[0, 0, 0]])
    assert distance[0] > 0.0
    assert calls


def test_noncoplanar_signed_distance(brute_trees):
    mesh = ours(trimesh.primitives.Box())
    distance = mesh.nearest.signed_distance([mesh.bounds[0] + [100, 100, 100]])
    assert distance[0] < 0.0


def test_edge_case(brute_trees):
    mesh = get_mesh("20mm-xyz-cube.stl")
    assert (mesh.nearest.signed_distance([[-51, 4.7, -20.6]]) < 0.0).all()


def test_signed_distance_signs_on_a_sphere(brute_trees):
    """Points whose nearest triangle does not decide the sign (its projection falls
    outside it) are signed by our contains_points: against the convex half-space test."""
    mesh = ours(trimesh.creation.icosphere(subdivisions=1))
    rng = np.random.default_rng(9)
    points = rng.normal(size=(300, 3)) * 0.6
    side = halfspace(mesh, points)
    clear = np.abs(side).min(axis=1) > 1e-6
    calls = spy_contains(mesh)
    distance = trimesh.proximity.signed_distance(mesh, points[clear])
    assert ((distance > 0) == (side[clear] < 0).all(axis=1)).all()
    assert sum(calls) > 0


# -- the intersector's own contract ----------------------------------------------------


def halfspace(mesh, points):
    """(n, faces) signed distances of points to a convex mesh's face planes: inside is
    all < 0."""
    tri = mesh.triangles
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    return np.einsum("pfk,fk->pf", np.asarray(points)[:, None, :] - tri[None, :, 0], normal)


def test_through_icosphere_vertices_and_edges():
    """Rays exactly through the shared vertices and edges of a closed icosphere: one
    point at each (the fan's lowest triangle), every listed triangle one that has it."""
    mesh = ours(trimesh.creation.icosphere(subdivisions=2))
    v, f = mesh.vertices, mesh.faces
    edges = mesh.edges_unique
    targets = np.concatenate([v, 0.5 * (v[edges[:, 0]] + v[edges[:, 1]])])
    # the triangles at each target: a vertex's fan, an edge's two
    at_vertex = [set(np.flatnonzero((f == i).any(axis=1)).tolist()) for i in range(len(v))]
    at_edge = [set(np.flatnonzero(np.isin(f, e).sum(axis=1) == 2).tolist()) for e in edges]
    owners = at_vertex + at_edge
    # the antipode of each target is a target too (the icosphere is centrally symmetric)
    anti = np.array([np.argmin(np.abs(targets + p).max(axis=1)) for p in targets])
    assert np.abs(targets[anti] + targets).max() < 1e-12
    o, d = 3 * targets, -targets
    tri, ray = mesh.ray.intersects_id(o, d)
    for i in range(len(targets)):
        got = set(tri[ray == i].tolist())
        assert got <= owners[i] | owners[anti[i]]
        assert got & owners[i] and got & owners[anti[i]]
    locations, loc_ray, loc_tri = mesh.ray.intersects_location(o, d)
    assert (np.bincount(loc_ray, minlength=len(targets)) == 2).all()
    assert np.allclose(locations[0::2], targets, rtol=0, atol=1e-12)
    assert np.allclose(locations[1::2], -targets, rtol=0, atol=1e-12)
    first = mesh.ray.intersects_first(o, d)
    assert (loc_tri[0::2] == first).all()
    assert all(first[i] in owners[i] for i in range(len(targets)))
    # max_hits counts points with locations: a cut at the fan's first triangles lists
    # the ray again, and its first two points are the two targets
    two, two_ray, _ = mesh.ray.intersects_location(o, d, max_hits=2)
    assert (np.bincount(two_ray) == 2).all() and np.allclose(two, locations)
    one, one_ray, one_tri = mesh.ray.intersects_location(o, d, max_hits=1)
    assert (one_ray == np.arange(len(targets))).all() and (one_tri == first).all()
    few_tri, few_ray = mesh.ray.intersects_id(o, d, max_hits=1)
    assert (few_tri == first).all() and (few_ray == np.arange(len(targets))).all()


def test_contains_on_grids_through_icosphere_vertices():
    """contains_points exact against the convex half-space test: on a regular grid, on
    rays through every vertex and edge midpoint from the centre, and along
    each point's own direction through them (contains_directions: the one ray a point
    casts passes through a vertex or an edge)."""
    mesh = ours(trimesh.creation.icosphere(subdivisions=2))
    v = mesh.vertices
    mid = 0.5 * (v[mesh.edges_unique[:, 0]] + v[mesh.edges_unique[:, 1]])
    targets = np.concatenate([v, mid])
    g = np.arange(-1.2, 1.21, 0.1)
    grid = np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3)
    radial = (targets[:, None, :] * np.array([0.0, 0.5, 0.9, 0.999, 1.001, 1.5])[None, :, None])
    tracer = mesh.ray.tracer
    s = np.array([-1.0, -0.01, 0.01, 0.3, 1.0, 2.5])[None, :, None]
    along = (targets[:, None, :] - s * contains_directions(tracer, targets)[:, None, :]).reshape(-1, 3)
    # the points whose own ray is the one through the vertex or edge midpoint
    through = (contains_directions(tracer, along).reshape(-1, len(s[0]), 3)
               == contains_directions(tracer, targets)[:, None, :]).all(axis=2).ravel()
    assert through.mean() > 0.5
    points = np.concatenate([grid, radial.reshape(-1, 3), along[through]])
    side = halfspace(mesh, points)
    clear = (np.abs(side).min(axis=1) > 1e-9) | (side.max(axis=1) < 0)
    expected = (side < 0).all(axis=1)
    got = mesh.ray.contains_points(points)
    assert clear.mean() > 0.95
    assert (got[clear] == expected[clear]).all()
    assert (mesh.contains(points) == got).all()
    assert (mesh.ray.contains_points(points) == got).all()       # the same every run


def test_dtypes_and_shapes_match_ray_triangle(brute_trees):
    mesh = ours(trimesh.creation.icosphere(subdivisions=1))
    other = ray_triangle.RayMeshIntersector(mesh)
    rng = np.random.default_rng(10)
    o = rng.normal(size=(40, 3)) * 3
    d = rng.normal(size=(40, 3)) * 0.5 - o * 0.2      # most toward the sphere, not all
    miss_o, miss_d = o + [10.0, 0, 0], np.tile([1.0, 0, 0], (40, 1))
    calls = [("intersects_id", {}), ("intersects_id", {"multiple_hits": False}),
             ("intersects_id", {"return_locations": True}),
             ("intersects_id", {"multiple_hits": False, "return_locations": True}),
             ("intersects_location", {}), ("intersects_first", {}), ("intersects_any", {})]
    for name, kwargs in calls:
        for rays in ((o, d), (miss_o, miss_d)):
            mine = getattr(mesh.ray, name)(*rays, **kwargs)
            theirs = getattr(other, name)(*rays, **kwargs)
            if isinstance(theirs, np.ndarray):
                mine, theirs = (mine,), (theirs,)
            assert len(mine) == len(theirs), name
            for a, b in zip(mine, theirs):
                assert a.dtype == b.dtype, (name, kwargs)
                # an empty location list is (0, 3) here (embree's), (0,) in ray_triangle
                assert a.shape == b.shape or (a.shape == (0, 3) and b.shape == (0,)), name
    for points in (o, np.zeros((0, 3))):
        mine, theirs = mesh.ray.contains_points(points), other.contains_points(points)
        assert mine.dtype == theirs.dtype and mine.shape == theirs.shape
    # and the same hits where no ray grazes an edge
    tri, ray = mesh.ray.intersects_id(o, d)
    tri2, ray2 = other.intersects_id(o, d)
    assert set(zip(ray.tolist(), tri.tolist())) == set(zip(ray2.tolist(), tri2.tolist()))
    assert (mesh.ray.intersects_first(o, d) == other.intersects_first(o, d)).all()


def test_pickle_and_copies():
    mesh = ours(trimesh.creation.icosphere(subdivisions=2))
    rng = np.random.default_rng(11)
    o = rng.normal(size=(50, 3)) * 3
    d = -o + rng.normal(size=(50, 3)) * 0.3
    want = mesh.ray.intersects_location(o, d)
    assert mesh.ray.tracer is not None                    # built
    for other in (pickle.loads(pickle.dumps(mesh.ray)), copy.deepcopy(mesh.ray),
                  copy.copy(mesh.ray)):
        assert isinstance(other, RayMeshIntersector)
        assert other._kept is None and not other._cache.cache   # no OpenCL objects
        got = other.intersects_location(o, d)
        assert all(np.array_equal(a, b) for a, b in zip(got, want))
        assert other.tracer is not mesh.ray.tracer
    assert copy.copy(mesh.ray).mesh is mesh
    deep = copy.deepcopy(mesh.ray)
    assert deep.mesh is not mesh and np.array_equal(deep.mesh.vertices, mesh.vertices)
    # a pickled mesh keeps its intersector, pointing at the unpickled mesh
    back = pickle.loads(pickle.dumps(mesh))
    assert isinstance(back.ray, RayMeshIntersector) and back.ray.mesh is back
    assert (back.ray.intersects_first(o, d) == mesh.ray.intersects_first(o, d)).all()


def test_tree_rebuilt_when_the_mesh_changes():
    mesh = ours(trimesh.creation.box())
    o, d = np.array([[0.0, 0.0, -5.0]]), np.array([[0.0, 0.0, 1.0]])
    before = mesh.ray.intersects_location(o, d)[0]
    tracer = mesh.ray.tracer
    assert mesh.ray.tracer is tracer                       # cached
    mesh.apply_translation([0.0, 0.0, 2.0])
    after = mesh.ray.intersects_location(o, d)[0]
    assert np.allclose(after, before + [0, 0, 2], rtol=0, atol=1e-12)
    assert mesh.ray.tracer is not tracer
    assert mesh.ray.tracer.context is tracer.context       # the same context (with_tree)
    # moved out of the ray's way: no hit
    mesh.apply_translation([5.0, 0.0, 0.0])
    assert not mesh.ray.intersects_any(o, d).any()
    assert not mesh.contains([[0.0, 0.0, 2.0]]).any() and mesh.contains([[5.0, 0.0, 2.0]]).all()
    # edited vertices
    mesh.vertices = mesh.vertices * 3
    assert mesh.contains([[15.0, 0.0, 6.0]]).all()


def test_rays_of_any_length_and_bad_input():
    mesh = ours(trimesh.creation.icosphere(subdivisions=1))
    o = np.array([[0, 0, -3.0], [0, 0, -3.0], [0, 0, -3.0], [0, 0, -3.0], [np.nan, 0, -3]])
    d = np.array([[0, 0, 1.0], [0, 0, 1e-200], [0, 0, 1e200], [0, 0, 0.0], [0, 0, 1.0]])
    first = mesh.ray.intersects_first(o, d)
    assert first[0] == first[1] == first[2] != -1 and first[3] == first[4] == -1
    loc, ray, _ = mesh.ray.intersects_location(o, d)
    assert (np.bincount(ray, minlength=5) == [2, 2, 2, 0, 0]).all()
    assert np.allclose(loc[ray == 1], loc[ray == 0]) and np.allclose(loc[ray == 2], loc[ray == 0])
    # one (3,) ray is one ray
    assert mesh.ray.intersects_first(o[0], d[0]).shape == (1,)
    # the caller's memory layout changes no number (the rays' lengths summed in C order)
    rng = np.random.default_rng(3)
    ro, rd = rng.normal(size=(1000, 3)) * 3, rng.normal(size=(1000, 3))
    want = mesh.ray.intersects_location(ro, rd)
    for layout in (np.asfortranarray, lambda a: a.T.copy().T, lambda a: a[::-1].copy()[::-1]):
        got = mesh.ray.intersects_location(layout(ro), layout(rd))
        for a, b in zip(got, want):
            np.testing.assert_array_equal(a, b)
    assert (mesh.ray.intersects_id(o, d, max_hits=0)[0].shape == (0,))
    assert not mesh.ray.contains_points([[np.nan, 0, 0], [0, 0, 0]])[0]
    for bad in (lambda: mesh.ray.intersects_id(o, d[:2]),
                lambda: mesh.ray.intersects_any(o[:, :2], d[:, :2]),
                lambda: mesh.ray.intersects_id(o, d, max_hits=-1),
                lambda: mesh.ray.intersects_id(o, d, max_hits=2.5),
                lambda: mesh.ray.contains_points([0.0, 0.0, 0.0])):
        with pytest.raises(ValueError) as info:
            bad()
        assert isinstance(info.value, KdrayError)


def test_meshes_with_nothing_to_hit():
    empty = trimesh.Trimesh(vertices=np.zeros((0, 3)), faces=np.zeros((0, 3), dtype=np.int64))
    flat = trimesh.Trimesh(vertices=[[0, 0, 0], [1, 0, 0], [2, 0, 0]], faces=[[0, 1, 2]],
                           process=False)
    o, d = np.zeros((3, 3)), np.tile([1.0, 0, 0], (3, 1))
    for mesh in (empty, flat):
        ray = RayMeshIntersector(mesh)
        assert ray.tracer is None
        assert (ray.intersects_first(o, d) == -1).all()
        assert not ray.intersects_any(o, d).any()
        assert ray.intersects_location(o, d)[0].shape == (0, 3)
        assert ray.intersects_id(o, d)[0].shape == (0,)
        assert not ray.contains_points(o).any()


def test_trimesh_imported_only_by_the_adapter():
    code = ("import sys, kdray, kdray.integrations; assert 'trimesh' not in sys.modules; "
            "import kdray.integrations.trimesh; assert 'trimesh' in sys.modules")
    subprocess.run([sys.executable, "-c", code], check=True)


def voxel_surface(occupied):
    """(vertices (n, 3) float64, faces (m, 3) int64): the boundary of the union of the
    unit cubes [i, i + 1] x [j, j + 1] x [k, k + 1] where occupied[i, j, k] (bool (X, Y,
    Z)), two triangles a square face, outward, vertices shared by their integer
    coordinates."""
    index, faces = {}, []
    pad = np.pad(occupied, 1)
    for axis in range(3):
        u, w = (axis + 1) % 3, (axis + 2) % 3
        for cell in np.argwhere(pad):
            for side in (-1, 1):
                beside = cell.copy()
                beside[axis] += side
                if pad[tuple(beside)]:
                    continue
                corner = cell - 1
                corner[axis] += side == 1
                square = []
                for a, b in ((0, 0), (1, 0), (1, 1), (0, 1)):
                    p = corner.copy()
                    p[u] += a
                    p[w] += b
                    square.append(index.setdefault(tuple(p.tolist()), len(index)))
                if side == -1:
                    square = square[::-1]
                faces += [square[:3], [square[0], square[2], square[3]]]
    return np.array(list(index), dtype=np.float64), np.array(faces, dtype=np.int64)


def exact_first(vertices, faces, o, d):
    """(n,) int64 the lowest index among the triangles each ray o + t d (t > 0) hits at
    its least t, -1 on a miss, in exact arithmetic: 2 o, the vertices and d integers
    (Cramer's rule in int64, edges and vertices inside)."""
    tri = (2 * vertices[faces]).astype(np.int64)
    o2, d = (2 * o).astype(np.int64), d.astype(np.int64)
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    first = np.full(len(o), -1, dtype=np.int64)
    for i in range(len(o)):
        s = o2[i] - tri[:, 0]
        nd = np.broadcast_to(-d[i], s.shape)
        det = np.linalg.det(np.stack([e1, e2, nd], axis=2)).round().astype(np.int64)
        u = np.linalg.det(np.stack([s, e2, nd], axis=2)).round().astype(np.int64)
        v = np.linalg.det(np.stack([e1, s, nd], axis=2)).round().astype(np.int64)
        t = np.linalg.det(np.stack([e1, e2, s], axis=2)).round().astype(np.int64)
        sign = np.sign(det)
        hit = (det != 0) & (u * sign >= 0) & (v * sign >= 0) & ((u + v) * sign <= det * sign) \
            & (t * sign > 0)
        if hit.any():
            # t / det exact in float64's division: equal ratios, equal numbers
            at = np.where(hit, t / np.where(det == 0, 1, det), np.inf)
            first[i] = np.flatnonzero(at == at.min())[0]
    return first


def test_first_hit_at_edges_and_vertices_is_the_lowest_index():
    """Rays between the centres of a voxel solid's cells pass exactly through its edges
    and vertices (the squares' diagonals included). intersects_first, multiple_hits=False
    and the first point of intersects_location, whatever max_hits, give the same
    triangle: the lowest index that kdray's test hits there. In directions whose ratios
    are exact in float32 (components 0, 1, 2, 4) the test is exact, and that is the exact
    oracle's lowest index at the least t."""
    rng = np.random.default_rng(5)
    v, f = voxel_surface(rng.random((5, 5, 5)) < 0.5)
    mesh = ours(trimesh.Trimesh(v, f, process=False))
    n = 4000
    o = rng.integers(-1, 6, size=(2 * n, 3)) + 0.5
    d = np.concatenate([rng.choice([-4, -2, -1, 0, 0, 1, 2, 4], size=(n, 3)),
                        rng.integers(-1, 6, size=(n, 3)) + 0.5 - o[n:]])
    d[(d == 0).all(axis=1)] = (1, 1, 1)
    first = mesh.ray.intersects_first(o, d)
    assert (first[:n] >= 0).sum() > n // 3 and (first[n:] >= 0).sum() > n // 3
    assert (first[:n] == exact_first(v, f, o[:n], d[:n])).all()
    tri, ray = mesh.ray.intersects_id(o, d, multiple_hits=False)
    assert (ray == np.flatnonzero(first >= 0)).all() and (tri == first[ray]).all()
    for max_hits in (None, 1, 2):
        _, ray, tri = mesh.ray.intersects_location(o, d, max_hits=max_hits)
        starts = np.flatnonzero(np.diff(ray, prepend=-1) != 0)
        assert (ray[starts] == np.flatnonzero(first >= 0)).all()
        assert (tri[starts] == first[ray[starts]]).all()
    # two faces at a right angle sharing an edge, and a ray through it (the audit's
    # case: its unit direction rounded, the first hit was 1)
    two = ours(trimesh.Trimesh([[1, 3, 0], [1, 4, 0], [1, 4, 1], [0, 4, 0]],
                               [[0, 1, 2], [3, 2, 1]], process=False))
    through = ([[0.5, 5.5, -0.5]], [[1.0, -3.0, 2.0]])    # (1, 4, 0.5) at t = 0.5
    assert two.ray.intersects_first(*through).tolist() == [0]
    assert two.ray.intersects_location(*through, max_hits=1)[2].tolist() == [0]



def first_clear_of_origin(mesh, o, d):
    """(n,) int64 the float64 brute force's first triangle each ray hits farther than
    1e-9 from its origin, and than 2^-40 of its world coordinates (their rounding, far
    from the world's origin), the lower index where two hit within 1e-12 of each
    other; -1 on none."""
    length = np.linalg.norm(d, axis=1)
    clear = 1e-9 + 2.0 ** -40 * np.abs(o).max(axis=1)
    ray, prim, t, _, _ = all_hits(mesh.triangles, o, d, t_min=clear / length)
    first = np.full(len(o), -1, dtype=np.int64)
    for r in np.unique(ray):
        k = np.flatnonzero(ray == r)
        first[r] = prim[k][t[k] - t[k[0]] <= 1e-12 * t[k[0]]].min()
    return first


def test_rays_from_surface_points_do_not_hit_where_they_start():
    """Rays from float64 points on a closed mesh's faces (trimesh.sample, as visibility
    and ambient-occlusion rays start) do not hit the face they start on: on a convex
    mesh rays leaving it hit nothing and rays entering it one point, the far side; on
    a torus each ray's first hit is the float64 brute force's first clear of the
    origin. kdray's float32 triangles, moved by their rounding, put about half of such
    origins just behind their face (docs/integrations.md, "No hit at the origin").
    Also far from the world's origin (1e5 and 1e6 of the mesh's size), where a point's
    world coordinates round by more than 2^-40 of the mesh (the own face had been hit
    by 1 ray in 10 there)."""
    torus = trimesh.creation.torus(1.0, 0.3, major_sections=24, minor_sections=12)
    for mesh, seed, shift in ((trimesh.creation.icosphere(2), 1, 0.0), (torus, 2, 0.0),
                              (trimesh.creation.icosphere(2), 3, 1e6), (torus, 4, 1e5)):
        mesh = trimesh.Trimesh(mesh.vertices + shift, mesh.faces, process=False)
        m = ours(mesh)
        n = 600
        o, face = trimesh.sample.sample_surface(m, n, seed=seed)
        normal = m.face_normals[face]
        d = np.random.default_rng(seed).normal(size=(n, 3))
        d *= np.sign(np.einsum("ij,ij->i", d, normal))[:, None]          # outward
        for rays in ((o, normal), (o, -normal), (o, d), (o, -d)):
            got = m.ray.intersects_first(*rays)
            assert (got == first_clear_of_origin(m, *rays)).all()
            assert (got != face).all()
            assert (m.ray.intersects_any(*rays) == (got >= 0)).all()
            tri, ray = m.ray.intersects_id(*rays, multiple_hits=False)
            assert (ray == np.flatnonzero(got >= 0)).all() and (tri == got[ray]).all()
            _, ray, tri = m.ray.intersects_location(*rays)
            starts = np.flatnonzero(np.diff(ray, prepend=-1) != 0)
            assert (ray[starts] == np.flatnonzero(got >= 0)).all()
            assert (tri[starts] == got[ray[starts]]).all()
            tri, ray = m.ray.intersects_id(*rays)
            assert not (tri == face[ray]).any()
            if seed in (1, 3):                          # the icospheres: convex
                leaving = rays[1] is normal or rays[1] is d
                assert (np.bincount(ray, minlength=n) == (0 if leaving else 1)).all()


def test_first_points_agree_where_rays_graze_edges():
    """Rays aimed at points of random edges, half from origins beside the surface (so
    that many graze a triangle of the edge): intersects_first, multiple_hits=False and
    the first point of intersects_location, whatever max_hits, name the same triangle.
    Where a ray grazes, kdray's float32 barycentrics can put its hit 1e-6 off an edge
    that float64's puts it on, and a float32 t can round past another triangle's; and
    a ray that lies in a triangle's plane (to float64 precision) misses it, as a
    float32 hit does not show."""
    rng = np.random.default_rng(11)
    meshes = (trimesh.creation.icosphere(2), trimesh.creation.annulus(0.3, 0.8, 1.0, sections=8),
              trimesh.creation.cylinder(0.5, 1, sections=8),
              trimesh.creation.torus(1.0, 0.3, major_sections=12, minor_sections=8))
    for mesh in meshes:
        m = ours(mesh)
        n = 3000
        edges = m.edges_unique[rng.integers(0, len(m.edges_unique), n)]
        s = rng.random((n, 1))
        target = m.vertices[edges[:, 0]] * (1 - s) + m.vertices[edges[:, 1]] * s
        o = rng.normal(size=(n, 3)) * 2
        k = n // 2
        along = m.vertices[edges[:k, 1]] - m.vertices[edges[:k, 0]]
        o[:k] = target[:k] + 3 * np.cross(along, rng.normal(size=(k, 3))) \
            + 0.05 * rng.normal(size=(k, 3))
        d = target - o
        first = m.ray.intersects_first(o, d)
        assert (first >= 0).sum() > n // 2
        tri, ray = m.ray.intersects_id(o, d, multiple_hits=False)
        assert (ray == np.flatnonzero(first >= 0)).all() and (tri == first[ray]).all()
        for max_hits in (None, 1, 2):
            _, ray, tri = m.ray.intersects_location(o, d, max_hits=max_hits)
            starts = np.flatnonzero(np.diff(ray, prepend=-1) != 0)
            assert (ray[starts] == np.flatnonzero(first >= 0)).all()
            assert (tri[starts] == first[ray[starts]]).all()
            # at most max_hits points a ray
            if max_hits:
                assert np.bincount(ray).max() <= max_hits
