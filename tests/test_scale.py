"""Any scale: a scene scaled uniformly by 1e-30 .. 1e30 (and to float32's edges) gives the
picture and the relative accuracy of the unscaled scene, on every OpenCL implementation
present. Outside what float32 depths can hold, building is a one-line error.

A scene outside 2^-28 .. 2^28 across is stored divided by the power of two nearest its
size (KdTree.scale), so the kernels' products of coordinates neither overflow nor
underflow for rays from thousands of its sizes away; a power-of-two scale changes no rounding, so a scene scaled by 2^k renders
exactly 2^k times the unscaled depths."""
import warnings

import numpy as np
import pytest

from helpers import SCENES, real_mesh_arrays
from kdray.builder import build
from kdray.camera import Camera
from kdray.errors import MeshError
from kdray.layout import MISS
from kdray.reference import brute_force
from kdray.trace import Tracer

DECIMAL = [1e-30, 1e-20, 1e-17, 1e15, 1e20, 1e30]
BINARY = [2.0 ** -120, 2.0 ** -60, 2.0 ** 50, 2.0 ** 120]
LONG = {1e-20, 1e-17, 1e15, 1e20, 2.0 ** -60, 2.0 ** 50}
"""Scales checked in `make test-long` only: each scale is a program of its own (its power
of two is compiled in), and every one of these is stored divided by its power of two,
as the extremes are; `make test` keeps the extremes, 1e-30 and 1e30, 2^-120 and 2^120."""


def scales(values, name):
    return [pytest.param(s, id=name(s), marks=[pytest.mark.slow] if s in LONG else [])
            for s in values]


def fandisk():
    return real_mesh_arrays("fandisk.obj")


def render(v, f, runtime, size=(64, 48)):
    tree = build(v, f)
    lo, hi = tree.world_box()
    camera = Camera.frame(lo, hi, *size)
    images = Tracer(tree, device=runtime.spec).render(camera, aovs=("depth", "id", "position"))
    return tree, camera, images


@pytest.fixture(scope="module")
def unscaled():
    return {}


def reference_of(runtime, unscaled):
    if runtime.name not in unscaled:
        unscaled[runtime.name] = render(*fandisk(), runtime)
    return unscaled[runtime.name]


@pytest.mark.parametrize("s", scales(BINARY, lambda s: f"2^{int(np.log2(s))}"))
def test_power_of_two_scales_render_exactly_scaled(runtime, unscaled, s):
    if runtime.simulator and s not in (2.0 ** -120, 2.0 ** 120):
        pytest.skip("a simulator runs the extremes only")
    tree0, _, want = reference_of(runtime, unscaled)
    v, f = fandisk()
    tree, _, got = render(v * s, f, runtime)
    assert tree.scale != 1.0 and len(tree.triangles) == len(tree0.triangles)
    assert np.array_equal(got["id"], want["id"])
    assert np.array_equal(got["depth"], (want["depth"].astype(np.float64) * s).astype(np.float32))


@pytest.mark.parametrize("s", scales(DECIMAL, lambda s: f"{s:g}"))
def test_any_scale_gives_the_unscaled_picture(runtime, unscaled, s):
    """The same triangle at almost every pixel (rounding the scaled vertices may move
    an edge pixel), the depth s times the unscaled to float32 precision, and no
    triangle lost as degenerate."""
    if runtime.simulator and s not in (1e-30, 1e30):
        pytest.skip("a simulator runs the extremes only")
    tree0, _, want = reference_of(runtime, unscaled)
    v, f = fandisk()
    tree, _, got = render(v * s, f, runtime)
    assert len(tree.triangles) == len(tree0.triangles)
    same = got["id"] == want["id"]
    assert same.mean() >= 0.995
    hit = same & (want["id"] != MISS)
    assert hit.mean() > 0.1
    rel = np.abs(got["depth"][hit] / s - want["depth"][hit]) / want["depth"][hit]
    assert rel.max() <= 2e-6, rel.max()


@pytest.mark.parametrize("s", [pytest.param(1e-30, id="1e-30"),
                               pytest.param(1e25, id="1e25", marks=pytest.mark.slow)])
def test_traced_rays_at_extreme_scales_match_float64(runtime, s):
    """Random rays into the scaled teapot, far from the origin too: the float64 oracle's
    hits, depth to 1e-6. 1e25 in `make test-long` (in `make test` 1e30 and 2^120 render
    the scaled fandisk)."""
    v, f = real_mesh_arrays("teapot.obj")
    v = (v + np.array([3.0, -1.0, 2.0])) * s
    tree = build(v, f)
    rng = np.random.default_rng(7)
    lo, hi = tree.world_box()
    n = runtime.small(3001, 301)
    target = lo + rng.random((n, 3)) * (hi - lo)
    o = target + rng.normal(size=(n, 3)) * np.linalg.norm(hi - lo)
    d = (target - o) / s                 # t ~ s: directions in units of the scene
    hits = Tracer(tree, device=runtime.spec).trace(o, d)
    ref = brute_force(v[f], o, d)
    ours = np.where(hits.prim == MISS, -1, hits.prim.astype(np.int64))
    assert np.mean(ours == ref.prim) >= 0.995
    same = (ours >= 0) & (ours == ref.prim)
    assert same.sum() > n // 5
    rel = np.abs(hits.t[same] - ref.t[same]) / ref.t[same]
    assert np.percentile(rel, 99) <= 1e-6 and rel.max() <= 4e-6, (np.percentile(rel, 99), rel.max())


@pytest.mark.parametrize("e", [0.0, 27.5, 28.5, 39.5])
def test_rays_from_far_away_hit_large_scenes(e):
    """A quad 2^e across, traced, counted and tested for occlusion from 100 and 10,000
    of its sizes away (an eye far off a large scene): every query hits it once, t to
    float32's precision. At scale 1 up to 2^40 across, a quad of 2^39.5 lost every
    hit from 1000 sizes away: the triangle test's products (cubes of the vertices'
    offsets from the ray's origin) overflowed float32."""
    s = 2.0 ** e
    v = np.array([[-0.5, 0, -0.5], [0.5, 0, -0.5], [0.5, 0, 0.5], [-0.5, 0, 0.5]]) * s
    tracer = Tracer(build(v, np.array([[0, 2, 1], [0, 3, 2]])))
    assert tracer.tree.scale == (1.0 if e <= 28 else 2.0 ** round(e))
    d = np.array([0.3, -1.0, 0.2]) / np.linalg.norm([0.3, -1.0, 0.2])
    for away in (100.0, 10000.0):
        o = (np.array([0.1, 0.0, -0.2]) - away * d) * s           # the hit at t = away * s
        hits = tracer.trace(o[None], d[None])
        assert hits.prim[0] == 0 and abs(hits.t[0] / (away * s) - 1) < 1e-6
        assert tracer.occluded(o[None], d[None])[0] and tracer.count(o[None], d[None])[0] == 1


@pytest.mark.parametrize("k", [0, -41])
def test_small_scenes_keep_the_nearest_of_two_close_surfaces(k):
    """Two concentric spheres 4e-6 of their size apart, scaled by 2^k: every ray from
    outside takes the outer sphere as its nearest hit. At scale 1 down to 2^-40
    across, the triangle test's products fell into float32's subnormals, and the
    scene 2^-40 across took the inner one for 746 rays in 20,000."""
    v, f = _sphere()
    v = v.astype(np.float32).astype(np.float64)
    both = np.concatenate([v, (v * (1 - 4e-6)).astype(np.float32).astype(np.float64)])
    faces = np.concatenate([f, f + len(v)])
    rng = np.random.default_rng(3)
    n = 20000
    out = rng.normal(size=(n, 3))
    o = 5.0 * out / np.linalg.norm(out, axis=1, keepdims=True)
    d = (rng.uniform(-0.6, 0.6, (n, 3)) - o).astype(np.float32).astype(np.float64)
    s = 2.0 ** k
    tree = build(s * both, faces)
    for refine in (True, False):
        hits = Tracer(tree, refine=refine).trace(s * o, d)
        assert hits.hit.sum() > n // 2 and (hits.prim[hits.hit] < len(f)).all()


def _sphere():
    from kdray.load import load
    m = load(SCENES / "sphere.obj")
    return np.asarray(m.vertices, np.float64), np.asarray(m.faces)


@pytest.mark.parametrize("s", [1e-40, 1e39])
def test_beyond_float32_is_a_one_line_error(s):
    v, f = fandisk()
    with pytest.raises(MeshError, match="across") as info:
        build(v * s, f)
    assert "\n" not in str(info.value)


def test_cli_renders_and_refuses_scaled_scenes(capsys, tmp_path):
    """kdray render of a scene 1e30 across writes its image; of one 1e40 across says
    why in one line, with no numpy warning."""
    from helpers import run
    from kdray.images import read_exr
    import trimesh
    mesh = trimesh.load(SCENES / "cornell.obj", force="mesh")
    for s, code_wanted in ((1e30, 0), (1e40, 1)):
        path = tmp_path / f"cornell-{s:g}.obj"
        mesh.copy().apply_scale(s).export(path)
        out = tmp_path / f"{s:g}.exr"
        with warnings.catch_warnings():
            warnings.simplefilter("error", RuntimeWarning)      # numpy's overflow warnings
            code, printed, err = run(capsys, "render", path, "-o", out, "--size", "32x24")
        assert code == code_wanted, err
        if code == 0:
            depth = read_exr(out)["depth"]
            assert np.isfinite(depth).mean() > 0.2 and np.nanmax(depth[np.isfinite(depth)]) > 1e29
        else:
            assert err.count("\n") == 1 and "across" in err and "Warning" not in err


def test_scaled_tree_file_round_trip(tmp_path):
    v, f = fandisk()
    tree = build(v * 1e30, f)
    assert tree.scale == 2.0 ** round(np.log2(np.max(np.ptp(v * 1e30, axis=0))))
    tree.save(tmp_path / "t.kdt")
    from kdray.tree import KdTree
    back = KdTree.load(tmp_path / "t.kdt")
    assert back == tree and back.scale == tree.scale
    back.validate()
