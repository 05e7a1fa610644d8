"""kdray.offset_origins: rays that leave a surface, against the float64 brute force."""
import numpy as np
import pytest
import trimesh

import kdray
from kdray.errors import ParameterError
from kdray.layout import MISS
from kdray.reference import all_hits


def first_hits(mesh, o, d):
    """(n,) int64 the float64 brute force's nearest triangle of each ray (t > 0; the
    lower index at a tie), MISS on none."""
    ray, prim, _, _, _ = all_hits(mesh.triangles, o, d)
    first = np.full(len(o), int(MISS), dtype=np.int64)
    starts = np.flatnonzero(np.diff(ray, prepend=-1) != 0)
    first[ray[starts]] = prim[starts]
    return first


TORUS = trimesh.creation.torus(1.0, 0.3, major_sections=24, minor_sections=12)


@pytest.mark.parametrize("scale, offset", [(1.0, 0.0), (1e-6, 0.0), (1e30, 0.0),
                                           (1.0, 1e7), (1e-3, 1e4)])
@pytest.mark.parametrize("shape", ["icosphere", "torus"])
def test_rays_leaving_sampled_points_miss_their_triangle(scale, offset, shape):
    """Rays from float64 points on the faces, along and against the face's normal and
    in random directions each way: from the points as given a ray hits its own face
    (about half of them); from offset_origins none does, in single or double precision
    no hit is at t <= 0, occluded agrees, and every hit is the float64 brute force's
    from the same origins. The move is a few float32 roundings of the coordinates."""
    mesh = (trimesh.creation.icosphere(2) if shape == "icosphere" else TORUS).copy()
    mesh.apply_scale(scale)
    mesh.apply_translation([offset, 0.0, 0.0])
    tree = kdray.build(mesh.vertices, mesh.faces, keep_double=True)
    tracer = kdray.Tracer(tree)
    n = 300
    p, face = trimesh.sample.sample_surface(mesh, n, seed=7)
    unit = TORUS if shape == "torus" else trimesh.creation.icosphere(2)
    normal = unit.face_normals[face]          # trimesh zeroes a tiny mesh's normals
    d = np.random.default_rng(7).normal(size=(n, 3))
    size = np.abs(mesh.bounds).max()
    own = 0
    for direction in (normal, -normal, d, -d):
        own += (tracer.trace(p, direction).prim == face).sum()
        o = kdray.offset_origins(tree, p, face, direction)
        assert np.all(np.linalg.norm(o - p, axis=1) <= 1e-6 * size)
        hits = tracer.trace(o, direction)
        assert not (hits.prim == face).any()
        double = tracer.trace(o, direction, precision="double")
        assert np.array_equal(double.prim, hits.prim) and (double.t > 0).all()
        assert np.array_equal(tracer.occluded(o, direction), hits.prim != MISS)
        assert np.array_equal(hits.prim, first_hits(mesh, o, direction))
    assert own > n                          # what the move is for


def test_bounces_from_hits_and_points_left_as_they_are():
    """Hits' points (o + t d in double) as origins of reflected rays inside a closed
    mesh: each bounce hits another face, never the one it left. A MISS, a triangle the
    tree dropped (degenerate), a non-finite point and a zero direction stay as given."""
    mesh = trimesh.creation.icosphere(3)
    tree = kdray.build(mesh.vertices, mesh.faces, keep_double=True)
    tracer = kdray.Tracer(tree)
    rng = np.random.default_rng(3)
    o = rng.normal(size=(2000, 3)) * 0.2
    d = rng.normal(size=(2000, 3))
    for _ in range(4):
        hits = tracer.trace(o, d, precision="double")
        assert (hits.prim != MISS).all()
        p = o + hits.t[:, None] * d
        n = mesh.face_normals[hits.prim]
        reflected = d - 2 * np.einsum("ij,ij->i", d, n)[:, None] * n
        o = kdray.offset_origins(tree, p, hits.prim, reflected)
        again = tracer.trace(o, reflected)
        assert not (again.prim == hits.prim).any()
        d = reflected

    flat = kdray.build(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 0, 0.0]]),
                       np.array([[0, 1, 2], [0, 1, 3]]))        # triangle 1: zero area
    p = np.array([[0.2, 0.2, 0], [0.5, 0, 0], [np.nan, 0, 0], [0.1, 0.1, 0], [0.3, 0.3, 0]])
    d = np.array([[0, 0, 1], [0, 0, 1], [0, 0, 1], [0, 0, 0], [0, 0, -1.0]])
    prim = np.array([int(MISS), 1, 0, 0, 0])
    o = kdray.offset_origins(flat, p, prim, d)
    assert np.array_equal(o[:4], p[:4], equal_nan=True)
    assert o[4, 2] < 0 and np.allclose(o[4, :2], p[4, :2], rtol=1e-15)   # moved along -z
    for bad in (dict(prim=np.array([0, 0])), dict(prim=np.array([2] * 5)),
                dict(prim=np.zeros(5)), dict(directions=d[:4]),
                # numbers only, never converted: strings, bools, objects, complex
                dict(points=p.astype(str)), dict(directions=d.astype(str)),
                dict(directions=d != 0), dict(points=p.astype(object)),
                dict(directions=d + 0j), dict(points=[[0.2, 0.2], [0.5, 0, 0]])):
        args = dict(points=p, prim=prim, directions=d) | bad
        with pytest.raises(ParameterError):
            kdray.offset_origins(flat, **args)
