"""Float64 answers on request (precision="double"): the same hits as the default, t, u,
v (and a render's depth, distance, position, bary) in float64 from the input's float64
triangles, within 1e-12 of the exact answer: an oracle in rational arithmetic
(fractions.Fraction) on the float64 input, independent of kdray."""
from fractions import Fraction

import numpy as np
import pytest

from helpers import SCENES, real_mesh, real_mesh_arrays, run
from kdray.builder import build
from kdray.camera import Camera
from kdray.errors import KdrayError, TreeError
from kdray.layout import MISS
from kdray.trace import Tracer


def exact_hit(tri, o, d):
    """(t, u, v) as Fractions: ray o + t d on the plane of tri (3, 3), exactly."""
    P = [[Fraction(float(x)) for x in p] for p in tri]
    O, D = [Fraction(float(x)) for x in o], [Fraction(float(x)) for x in d]
    e1 = [P[1][k] - P[0][k] for k in range(3)]
    e2 = [P[2][k] - P[0][k] for k in range(3)]

    def cross(a, b):
        return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]

    def dot(a, b):
        return sum(x * y for x, y in zip(a, b))
    n = cross(e1, e2)
    t = dot(n, [P[0][k] - O[k] for k in range(3)]) / dot(n, D)
    h = [O[k] + t * D[k] - P[0][k] for k in range(3)]
    nn = dot(n, n)
    return t, dot(cross(h, e2), n) / nn, dot(cross(e1, h), n) / nn


def rays(tree, n, seed):
    rng = np.random.default_rng(seed)
    lo, hi = tree.world_box()
    target = lo + rng.random((n, 3)) * (hi - lo)
    o = target + rng.normal(size=(n, 3)) * np.linalg.norm(hi - lo)
    return o, target - o


CASES = {"teapot": (1.0, 0.0), "teapot-far": (1.0, 1e6), "teapot-1e20": (1e20, 0.0),
         "teapot-1e-25": (1e-25, 3e-25)}


@pytest.mark.parametrize("case", [
    pytest.param(c, marks=[pytest.mark.slow] if c == "teapot-1e20" else []) for c in CASES])
def test_double_trace_is_exact_to_1e_12(case):
    """teapot-1e20 in `make test-long` (a scale is a program of its own): teapot-1e-25
    checks a scene stored scaled in `make test`."""
    s, offset = CASES[case]
    v, f = real_mesh_arrays("teapot.obj")
    v = v * s + offset
    tree = build(v, f, keep_double=True)
    tracer = Tracer(tree)
    o, d = rays(tree, 1001, seed=3)
    single = tracer.trace(o, d)
    double = tracer.trace(o, d, precision="double")
    assert np.array_equal(single.prim, double.prim)
    assert double.t.dtype == double.u.dtype == double.v.dtype == np.float64
    hit = np.flatnonzero(double.prim != MISS)
    assert len(hit) > 200
    miss = double.prim == MISS
    assert np.all(np.isposinf(double.t[miss])) and np.all(double.u[miss] == 0)
    for i in hit[:40]:
        t, u, w = exact_hit(v[f[double.prim[i]]], o[i], d[i])
        assert abs(Fraction(float(double.t[i])) - t) <= Fraction(1, 10 ** 12) * abs(t)
        assert abs(Fraction(float(double.u[i])) - u) <= Fraction(1, 10 ** 12)
        assert abs(Fraction(float(double.v[i])) - w) <= Fraction(1, 10 ** 12)
    # and the float32 answer is the double one to float32 precision
    rel = np.abs(single.t[hit] - double.t[hit]) / double.t[hit]
    assert np.percentile(rel, 99) <= 1e-6
    # image-shaped rays: the same answers, shaped as the rays
    image = tracer.trace(o[:1000].reshape(20, 50, 3), d[:1000].reshape(20, 50, 3),
                         precision="double")
    for field in ("t", "prim", "u", "v"):
        assert np.array_equal(getattr(image, field).ravel(), getattr(double, field)[:1000])
    assert image.t.shape == (20, 50) and image.normal.shape == (20, 50, 3)


def test_double_render():
    v, f = real_mesh_arrays("spot.obj")
    tree = build(v, f, keep_double=True)
    lo, hi = tree.world_box()
    camera = Camera.frame(lo, hi, 40, 30)
    tracer = Tracer(tree)
    aovs = ("depth", "distance", "normal", "bary", "id", "position")
    single = tracer.render(camera, aovs=aovs)
    double = tracer.render(camera, aovs=aovs, precision="double")
    assert list(double) == list(aovs)
    for name in ("depth", "distance", "bary", "position"):
        assert double[name].dtype == np.float64, name
    assert np.array_equal(double["normal"], single["normal"])
    assert np.array_equal(double["id"], single["id"])
    ids = double["id"].reshape(-1)
    o, d = camera.rays()
    hit = np.flatnonzero(ids != MISS)
    assert len(hit) > 100
    for i in hit[::max(1, len(hit) // 25)]:
        t, u, w = exact_hit(v[f[ids[i]]], o[i], d[i])
        assert abs(Fraction(float(double["depth"].reshape(-1)[i])) - t) <= Fraction(1, 10 ** 12) * t
        assert abs(Fraction(float(double["bary"].reshape(-1, 2)[i, 0])) - u) <= Fraction(1, 10 ** 12)
    rel = np.abs(single["depth"].reshape(-1)[hit] - double["depth"].reshape(-1)[hit])
    assert np.max(rel / double["depth"].reshape(-1)[hit]) <= 1e-5
    p = double["position"].reshape(-1, 3)
    assert np.all(np.isnan(p[ids == MISS])) and np.all(np.isfinite(p[hit]))


def test_double_needs_the_float64_triangles():
    v, f = real_mesh_arrays("teapot.obj")
    tree = build(v, f)
    assert tree.triangles64 is None and tree.stats()["double_bytes"] == 0
    tracer = Tracer(tree)
    o, d = rays(tree, 5, seed=1)
    with pytest.raises(KdrayError, match="keep_double") as info:
        tracer.trace(o, d, precision="double")
    assert "\n" not in str(info.value)
    with pytest.raises(KdrayError, match="precision"):
        tracer.trace(o, d, precision="half")
    for query in (tracer.occluded, tracer.count, tracer.intersections):
        with pytest.raises(KdrayError, match="keep_double"):
            query(o, d, precision="double")
        with pytest.raises(KdrayError, match="precision must be"):
            query(o, d, precision="half")
    with_double = tree.with_double(v, f)
    assert with_double.stats()["double_bytes"] == 72 * len(f)
    assert Tracer(with_double).trace(o, d, precision="double").t.dtype == np.float64
    with pytest.raises(TreeError):
        tree.with_double(v, f[:-1])
    # another mesh of as many faces: its triangles are not the tree's
    with pytest.raises(TreeError, match="not the tree's"):
        tree.with_double(v + 1.0, f)
    with pytest.raises(TreeError, match="triangle 3 is not the tree's"):
        tree.with_double(v, np.concatenate([f[:3], f[3:4, ::-1], f[4:]]))
    # numbers only, as build takes them: strings and ragged lists are refused
    with pytest.raises(TreeError, match="numeric vertices"):
        tree.with_double(v.astype(str), f)
    with pytest.raises(TreeError, match="numeric arrays"):
        tree.with_double([[0, 0], [1]], f)


def test_cli_precision_double(capsys, tmp_path):
    """--precision double: the EXR holds the float64 depth rounded once to float32; with
    --tree the float64 triangles come from SCENE, and --cull keeps them by input id."""
    from kdray.images import read_exr
    from kdray.load import load
    scene = real_mesh("teapot.obj")
    out = {}
    for name, extra in (("single", []), ("double", ["--precision", "double"]),
                        ("cull", ["--precision", "double", "--cull"])):
        out[name] = tmp_path / f"{name}.exr"
        code, _, err = run(capsys, "render", scene, "-o", out[name], "--size", "48x32",
                           "--aov", "depth,id", *extra)
        assert code == 0, err
    a, b, c = (read_exr(out[k]) for k in ("single", "double", "cull"))
    assert np.array_equal(a["id"], b["id"]) and np.array_equal(b["id"], c["id"])
    assert np.array_equal(b["depth"], c["depth"])
    m = load(scene)
    tree = build(m.vertices, m.faces, keep_double=True)
    lo, hi = tree.world_box()
    exact = Tracer(tree).render(Camera.frame(lo, hi, 48, 32), aovs="depth,id", precision="double")
    assert np.array_equal(b["depth"], exact["depth"].astype(np.float32))
    tree.save(tmp_path / "t.kdt")
    code, _, err = run(capsys, "render", scene, "--tree", tmp_path / "t.kdt", "-o",
                       tmp_path / "tree.exr", "--size", "48x32", "--aov", "depth,id",
                       "--precision", "double")
    assert code == 0, err
    assert np.array_equal(read_exr(tmp_path / "tree.exr")["depth"], b["depth"])
    code, _, err = run(capsys, "render", SCENES / "cornell.obj", "--tree", tmp_path / "t.kdt",
                       "-o", tmp_path / "bad.exr", "--precision", "double")
    assert code == 1 and "is not the mesh of" in err and err.count("\n") == 1


def test_orthographic_double_render_far_away_keeps_the_single_renders_hits():
    """An orthographic camera's pixels far from the world's origin (a sphere 1e-3 across
    at 1e12): its double render names the triangles of its single render (whose
    kernel makes the rays relative to the tree), every bary inside its triangle; it
    had traced the world float64 origins, whose offsets had lost their last digits
    (505 of 1024 ids differed, bary down to -1.18)."""
    from kdray.load import load
    mesh = load(SCENES / "sphere.obj")
    off = np.array([1e12, -6e11, 4e11])
    v = mesh.vertices * 1e-3 + off
    tracer = Tracer(build(v, mesh.faces, keep_double=True))
    pose = np.eye(4)
    pose[:3, 3] = off + [0.0, 0.0, -3e-3]
    K = np.array([[32 / 2.4e-3, 0, 16], [0, 32 / 2.4e-3, 16], [0, 0, 1]])
    camera = Camera.from_intrinsics(K, pose, 32, 32, model="orthographic")
    single = tracer.render(camera, aovs="id,depth")
    double = tracer.render(camera, aovs="id,depth,bary", precision="double")
    assert np.array_equal(single["id"], double["id"]) and (single["id"] != MISS).sum() > 400
    hit = double["id"] != MISS
    u, w = double["bary"][..., 0][hit], double["bary"][..., 1][hit]
    assert u.min() > -1e-9 and w.min() > -1e-9 and (1 - u - w).min() > -1e-9
    assert np.allclose(double["depth"][hit], single["depth"][hit], rtol=1e-5)


def test_a_triangle_collinear_in_float64_takes_its_float32_copys_plane():
    """A triangle whose float64 vertices are collinear (no plane) while its float32 copy
    is not (the tree keeps it, the kernel hits it): the double answers' t, u, v come
    from the copy's plane in float64, not NaN."""
    v = np.array([[0.7012481689453125, 0.2739229202270508, 0.022272109985351562],
                  [1.2408215962350368, 1.8895817659795284, -2.3957808427512646],
                  [2.3199684508144855, 5.120899457484484, -7.231886748224497],
                  [5.0, 5.0, 5.0], [6.0, 5.0, 5.0], [5.0, 6.0, 5.0]])
    assert not np.cross(v[1] - v[0], v[2] - v[0]).any()
    tree = build(v, np.array([[0, 1, 2], [3, 4, 5]]), keep_double=True)
    assert 0 in tree.tri_ids
    stored = tree.world(tree.triangles[list(tree.tri_ids).index(0)].astype(np.float64))
    n = np.cross(stored[1] - stored[0], stored[2] - stored[0])
    n /= np.linalg.norm(n)
    o = np.random.default_rng(1).dirichlet([5, 5, 5], 500) @ stored + 0.5 * n
    d = np.broadcast_to(-n, o.shape)
    tracer = Tracer(tree)
    single = tracer.trace(o, d)
    double = tracer.trace(o, d, precision="double")
    hit = double.prim == 0
    assert hit.sum() > 50 and np.array_equal(single.prim, double.prim)
    assert np.allclose(double.t[hit], single.t[hit], rtol=1e-6)
    assert np.isfinite(double.u[hit]).all() and np.isfinite(double.v[hit]).all()
    listed = tracer.intersections(o, d, precision="double")
    assert np.isfinite(listed.t).all() and np.isfinite(listed.u).all()


def test_t_of_triangles_far_larger_than_t_is_exact_to_a_few_roundings():
    """plane_hits' t where the triangle reaches far beyond the hit (10^2 to 10^8 times
    t: a ground plane under a small object), at random incidences, against the exact
    rational plane hit: within 4 float64 roundings (in plain float64 the plane's
    cancellation lost about D / (t cos) of them: 886,000 for 2e6 across at t 1.2)."""
    from kdray.double import plane_hits
    rng = np.random.default_rng(12)
    tri, o, d = [], [], []
    for size in 10.0 ** rng.uniform(2, 8, 300):
        normal = rng.normal(size=3)
        normal /= np.linalg.norm(normal)
        u = np.cross(normal, rng.normal(size=3))
        u /= np.linalg.norm(u)
        w = np.cross(normal, u)
        centre = rng.normal(size=3) * 3
        corners = [centre + size * (np.cos(a) * u + np.sin(a) * w)
                   for a in rng.uniform(0, 2 * np.pi) + np.array([0, 2.1, 4.2])]
        hit = centre + rng.uniform(-0.2, 0.2, 2) @ np.array([u, w]) * size
        direction = normal + rng.normal(size=3) * 0.5
        t_true = rng.uniform(0.5, 2.0)
        tri.append(corners)
        o.append(hit - t_true * direction)
        d.append(direction)
    tri, o, d = np.array(tri), np.array(o), np.array(d)
    t = plane_hits(tri, o, d)[0]
    for k in range(len(t)):
        P = [[Fraction(x) for x in p] for p in tri[k]]
        O, D = [Fraction(x) for x in o[k]], [Fraction(x) for x in d[k]]
        e1 = [P[1][i] - P[0][i] for i in range(3)]
        e2 = [P[2][i] - P[0][i] for i in range(3)]
        n = [e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2],
             e1[0] * e2[1] - e1[1] * e2[0]]
        exact = (sum(n[i] * (P[0][i] - O[i]) for i in range(3))
                 / sum(n[i] * D[i] for i in range(3)))
        assert abs(Fraction(t[k]) - exact) <= 4 * np.spacing(float(exact)), k


def test_double_hits_at_the_origin_do_not_count():
    """Rays from float64 points on a mesh's faces (trimesh.sample), given as they are:
    in double precision a hit whose float64 t is not in (t_min, t_max), or whose origin
    lies on its float64 plane (within ON_PLANE), does not count, and the ray takes its
    next hit: the same hits, t and normals as from offset_origins' origins, which need
    no such rule. Rays from points off the surface keep the single hits. Also far from
    the world's origin (1e6 of the mesh's size), where a sampled point is off its
    plane by its world coordinates' rounding (the own face had been hit there)."""
    import trimesh
    import kdray
    torus = trimesh.creation.torus(1.0, 0.3, major_sections=24, minor_sections=12)
    far = trimesh.Trimesh(torus.vertices + [1e6, -2e5, 3e5], torus.faces, process=False)
    for mesh in (trimesh.creation.icosphere(2), torus, far):
        tree = build(mesh.vertices, mesh.faces, keep_double=True)
        tracer = Tracer(tree)
        o, face = trimesh.sample.sample_surface(mesh, 800, seed=4)
        normal = mesh.face_normals[face]
        rng = np.random.default_rng(4)
        d = rng.normal(size=o.shape)
        for dd in (normal, -normal, d, -d):
            got = tracer.trace(o, dd, precision="double")
            assert not (got.prim == face).any() and (got.t > 0).all()
            want = tracer.trace(kdray.offset_origins(tree, o, face, dd), dd)
            assert np.array_equal(got.prim, want.prim)
            assert np.array_equal(got.normal, want.normal)
            hit = got.hit                # t: the float64 plane's, from the rays as given
            from kdray.double import plane_hits
            t = plane_hits(tree.triangles64[got.prim[hit]], o[hit], dd[hit])[0]
            np.testing.assert_array_equal(got.t[hit], t)
            listed = tracer.intersections(o, dd, precision="double")
            assert not (listed.prim == face[listed.ray]).any() and (listed.t > 0).all()
            nearest = tracer.intersections(o, dd, max_hits=1, precision="double")
            assert np.array_equal(nearest.prim, got.prim[hit])
            rank = np.arange(len(listed.t)) - listed.offsets[listed.ray]
            for k in (2, 3, 5):
                first = tracer.intersections(o, dd, max_hits=k, precision="double")
                assert np.array_equal(first.prim, listed.prim[rank < k])
                assert np.array_equal(first.t, listed.t[rank < k])
        inside = o - 0.01 * normal                       # off the surface: no change
        single = tracer.trace(inside, d)
        assert np.array_equal(tracer.trace(inside, d, precision="double").prim, single.prim)


def test_double_occluded_and_count_drop_the_hits_that_do_not_count():
    """occluded and count with precision="double" take the hits that count in float64,
    as trace does: rays from float64 points on a mesh's faces, given as they are, are
    not occluded by (and do not cross) their own face, also 1e6 of the mesh's size from
    the world's origin, where the float32 answers count it in about half the rays.
    Oracles: occluded is trace(..., precision="double").hit ray for ray; count is the
    float64 brute force's crossings (kdray.reference.all_hits, the count's rule) less
    the ray's own face, over a t range a ray too, and the float32 count of the same
    rays from offset_origins' origins. Points off the surface keep the single answers."""
    import trimesh
    import kdray
    from kdray.reference import all_hits
    torus = trimesh.creation.torus(1.0, 0.3, major_sections=24, minor_sections=12)
    far = trimesh.Trimesh(torus.vertices + [1e6, -2e5, 3e5], torus.faces, process=False)
    rng = np.random.default_rng(7)
    for mesh in (trimesh.creation.icosphere(2), torus, far):
        tree = build(mesh.vertices, mesh.faces, keep_double=True)
        tracer = Tracer(tree)
        o, face = trimesh.sample.sample_surface(mesh, 600, seed=5)
        normal = mesh.face_normals[face]
        d = rng.normal(size=o.shape)
        t_max = np.where(rng.random(len(o)) < 0.5, np.inf, rng.random(len(o)) * 2.0)
        lost = 0
        for dd in (normal, -normal, d, -d):
            for hi in (np.inf, t_max):
                occluded = tracer.occluded(o, dd, t_max=hi, precision="double")
                assert occluded.dtype == bool
                assert np.array_equal(occluded, tracer.trace(o, dd, t_max=hi,
                                                             precision="double").hit)
                count = tracer.count(o, dd, t_max=hi, precision="double")
                assert count.dtype == np.int32
                ray, prim, _, _, _ = all_hits(tree.triangles64, o, dd, 0.0, hi, crossing=True)
                own = prim == face[ray]
                want = np.bincount(ray[~own], minlength=len(o))
                np.testing.assert_array_equal(count, want)
                away = kdray.offset_origins(tree, o, face, dd)
                np.testing.assert_array_equal(count, tracer.count(away, dd, t_max=hi))
                np.testing.assert_array_equal(occluded, tracer.occluded(away, dd, t_max=hi))
                lost += int((tracer.count(o, dd, t_max=hi) != count).sum())
        assert lost > 0                  # the float32 answers count the own face
        inside = o - 0.01 * normal
        np.testing.assert_array_equal(tracer.count(inside, d, precision="double"),
                                      tracer.count(inside, d))
        np.testing.assert_array_equal(tracer.occluded(inside, d, precision="double"),
                                      tracer.occluded(inside, d))
