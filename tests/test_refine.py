"""Depth, u and v accurate whatever a triangle's size against t (Tracer(refine=True)):
small objects on ground planes and beside walls 1e3..1e7 times their size, a huge
triangle just in front of the eye, long slivers spanning the scene, each also far from
the origin, on every OpenCL implementation present.

The oracle is independent of the kernels: kdray.reference.brute_force (float64) says
which triangle each ray hits, and t, u, v of that triangle come from its plane in
float64 (`plane_hits`): t against the float64 input (the accuracy users see), and t,
u, v against the tree's own float32 triangle and the ray as the kernel rounds it
(what the kernel can reach: a few float32 roundings). The scenes' large triangles
have vertices that float32 holds exactly (integers and binary fractions below 2^24),
so that their stored triangles are the input's; the small objects' vertices round to
float32 at their own scale, which moves t by ~1e-8 of it."""
import numpy as np
import pytest

from kdray.builder import build
from kdray.camera import Camera
from kdray.layout import MISS
from kdray.reference import brute_force
from kdray.trace import Tracer

P99, MAX = 1e-6, 4e-6          # relative depth error against the float64 input
OWN = 2.0 ** -22               # t (relative), u and v against the tree's own triangle: 4 roundings
OFFSETS = [(0.0, 0.0, 0.0), (3e6, -2e6, 1e6)]


def icosphere(center, radius):
    """A ball whose vertices are on a grid of 2^-16: float32 holds them exactly
    relative to the scenes' origins."""
    import trimesh
    s = trimesh.creation.icosphere(subdivisions=2, radius=radius)
    v = np.round(s.vertices * 2.0 ** 16) * 2.0 ** -16
    return v + np.asarray(center, dtype=np.float64), s.faces


def quad(corners):
    """Two triangles of the quad corners (4, 3), in order around it."""
    return np.asarray(corners, dtype=np.float64), np.array([[0, 1, 2], [0, 2, 3]])


def merge(*parts):
    vs, fs, n = [], [], 0
    for v, f in parts:
        vs.append(v)
        fs.append(f + n)
        n += len(v)
    return np.concatenate(vs), np.concatenate(fs)


def ground(ratio):
    """A unit ball resting on the plane y = x/4 + z/8 (exact in float32) of half-size
    R = 2^k ~ ratio / 2, seen from 2 units away."""
    R = 2.0 ** round(np.log2(ratio / 2))
    plane = quad([(x, x / 4 + z / 8, z) for x, z in ((-R, -R), (R, -R), (R, R), (-R, R))])
    ball = icosphere((0.0, 0.5 + 1e-3, 0.0), 0.5)
    return merge(plane, ball), Camera.look_at((1.25, 1.5, 1.75), (0.0, 0.25, 0.0), fov_deg=70,
                                              width=48, height=32)


def wall(ratio):
    """A unit ball beside a wall x = -0.75 of half-size R, the eye 0.25 from the wall,
    looking along it."""
    R = 2.0 ** round(np.log2(ratio / 2))
    plane = quad([(-0.75, -R, -R), (-0.75, R, -R), (-0.75, R, R), (-0.75, -R, R)])
    ball = icosphere((0.0, 0.0, 0.0), 0.5)
    return merge(plane, ball), Camera.look_at((-0.5, 0.25, 3.0), (-0.25, 0.0, 0.0), fov_deg=60,
                                              width=48, height=32)


def near_triangle(size):
    """One triangle 2^k ~ size across, 1/64 in front of the eye (covering the view),
    and a ball behind it."""
    R = 2.0 ** round(np.log2(size))
    tri = (np.array([(-R, -R, -1 / 64), (R, -R / 2, -1 / 64), (0.0, R, -1 / 64)]), np.array([[0, 1, 2]]))
    ball = icosphere((0.0, 0.0, -3.0), 0.5)
    return merge(tri, ball), Camera.look_at((0.0, 0.0, 0.0), (0.125, 0.0625, -1.0), fov_deg=60,
                                            width=48, height=32)


def slivers(length):
    """Long thin triangles (2^k ~ length long, 2^-8 wide) side by side, seen from
    above at 1 unit."""
    L = 2.0 ** round(np.log2(length))
    w = 2.0 ** -8
    v, f = [], []
    for i in range(-32, 32):
        x = i * 2.0 ** -6
        v += [(x, 0.0, -L), (x + w, 0.0, L), (x, 2.0 ** -10, L)]
        f.append([len(v) - 3, len(v) - 2, len(v) - 1])
    return (np.array(v), np.array(f)), Camera.look_at((0.0, 1.0, 0.5), (0.0, 0.0, 0.0),
                                                      fov_deg=40, width=48, height=32)


CASES = {"ground-1e3": lambda: ground(1e3), "ground-1e5": lambda: ground(1e5),
         "ground-1e7": lambda: ground(1e7), "wall-1e3": lambda: wall(1e3),
         "wall-1e7": lambda: wall(1e7), "near-1e5": lambda: near_triangle(1e5),
         "slivers-1e3": lambda: slivers(1e3)}


def plane_hits(tri, o, d):
    """(t, u, v) of rays o + t d on the planes of their triangles tri (k, 3, 3), float64."""
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    n = np.cross(e1, e2)
    t = np.einsum("ij,ij->i", n, tri[:, 0] - o) / np.einsum("ij,ij->i", n, d)
    h = o + t[:, None] * d - tri[:, 0]
    nn = np.einsum("ij,ij->i", n, n)
    u = np.einsum("ij,ij->i", np.cross(h, e2), n) / nn
    v = np.einsum("ij,ij->i", np.cross(e1, h), n) / nn
    return t, u, v


def errors(name, offset, runtime, refine=True, rays="trace"):
    """Errors of a case's hits on the rays that hit the same triangle as the oracle:
    (t relative to the float64 input's, t relative to the tree's own float32 triangle
    and ray, |u - u_ref| + |v - v_ref| on that triangle), and the fraction of rays
    whose triangle (or hit or miss) differs."""
    (v, f), camera = CASES[name]()
    v = v + np.asarray(offset)
    pose = np.array(camera.cam_to_world)
    pose[:3, 3] += offset
    camera = Camera.from_intrinsics(camera.K, pose, camera.width, camera.height)
    tree = build(v, f)
    tracer = Tracer(tree, device=runtime.spec, refine=refine)
    if refine and not tracer.refine:
        pytest.skip(f"{runtime.name} has no double precision (cl_khr_fp64)")
    if rays == "trace":
        o, d = camera.rays()
        hits = tracer.trace(o, d)
    else:
        o, d = tracer.camera_rays(camera)
        images = tracer.render(camera, aovs=("depth", "bary", "id"))
        hits = tracer.trace(o, d)
        assert np.array_equal(images["depth"].ravel(), hits.t)
        assert np.array_equal(images["id"].ravel(), hits.prim)
    o, d = np.asarray(o, np.float64), np.asarray(d, np.float64)
    ref = brute_force(v[f], o, d)
    ours = np.where(hits.prim == MISS, -1, hits.prim.astype(np.int64))
    same = (ours >= 0) & (ours == ref.prim)
    t_input, _, _ = plane_hits(v[f][ours[same]], o[same], d[same])
    assert np.allclose(t_input, ref.t[same], rtol=1e-9)          # the two oracles agree
    # the tree's triangle as stored and the ray as the kernel rounds it
    index = np.empty(tree.n_input_tris, dtype=np.int64)
    index[tree.tri_ids] = np.arange(len(tree.tri_ids))
    tri32 = tree.triangles[index[ours[same]]].astype(np.float64)
    o_rel, d_k = o[same] - tree.origin, d[same]
    if not (rays == "trace" and tracer.refine and tracer._rays_in_kernel):
        # refined from the float ray it traced (from the double one where it reads them)
        o_rel, d_k = (x.astype(np.float32).astype(np.float64) for x in (o_rel, d_k))
    t_own, u_own, v_own = plane_hits(tri32, o_rel, d_k)
    rel = np.abs(hits.t[same] - t_input) / t_input
    own = np.abs(hits.t[same] - t_own) / t_own
    uv = np.abs(hits.u[same] - u_own) + np.abs(hits.v[same] - v_own)
    # Rays naming another triangle than the oracle: the float test's edge functions
    # decide, and on a huge triangle they resolve less than a unit near the triangle's
    # far-away vertices, so that near its shared edge the neighbour can win (in the
    # same plane: the same t). The one named must lie on the ray (its barycentrics
    # within float resolution of it), not before the nearest hit.
    other = np.flatnonzero((ours != ref.prim) & (ours >= 0) & (ref.prim >= 0))
    if len(other):
        t_o, u_o, v_o = plane_hits(v[f][ours[other]], o[other], d[other])
        assert np.all(np.minimum(np.minimum(u_o, v_o), 1 - u_o - v_o) >= -1e-6)
        assert np.all(t_o >= ref.t[other] * (1 - 1e-9))
    # a ray hits in one and misses in the other only where it grazes a huge triangle
    # far away (the small objects are within 8 units of the eye)
    either = np.flatnonzero((ours >= 0) != (ref.prim >= 0))
    far = np.where(ours[either] >= 0, hits.t[either], ref.t[either])
    assert np.all(far > 1e3), far
    return rel, own, uv, (len(other) + len(either)) / len(ours), np.count_nonzero(same)


def check(rel, own, uv, other, n, max_other=0.002):
    assert n > 100 and other <= max_other
    assert np.percentile(rel, 99) <= P99 and rel.max() <= MAX, (np.percentile(rel, 99), rel.max())
    assert own.max() <= OWN and uv.max() <= OWN, (own.max(), uv.max())


@pytest.mark.parametrize("offset", OFFSETS, ids=["at-0", "far"])
@pytest.mark.parametrize("name", list(CASES))
def test_refined_depth_is_accurate(runtime, name, offset):
    if runtime.simulator and name not in ("ground-1e7", "near-1e5"):
        pytest.skip("a simulator runs the two hardest cases only")
    check(*errors(name, offset, runtime), max_other=0.05 if name.endswith("1e7") else 0.002)


@pytest.mark.parametrize("name", ["ground-1e7", "wall-1e3", "slivers-1e3"])
def test_refined_render_is_accurate(runtime, name):
    """The same for renders: their float32 camera rays, the kernel's own."""
    if runtime.simulator and name != "ground-1e7":
        pytest.skip("a simulator runs the hardest case only")
    check(*errors(name, OFFSETS[1], runtime, rays="render"),
          max_other=0.05 if name.endswith("1e7") else 0.002)


def test_the_float_test_alone_is_not_enough(runtime):
    """The cases need the refinement: without it the float test's t on the 1e7 ground
    plane is off by far more than the bound (so the tests above can fail)."""
    if runtime.simulator:
        pytest.skip("checked on the CPU runtimes")
    rel, own, _, _, _ = errors("ground-1e7", OFFSETS[0], runtime, refine=False)
    assert rel.max() > 100 * MAX and own.max() > 100 * MAX


def test_rays_leaving_a_huge_triangle_skip_it_and_rays_reaching_it_hit(runtime):
    """Rays from points near the centre of a quad 2^20 across, moved 1e-4 along their
    direction (ambient-occlusion rays) or against it: the quad lies behind the first
    (its t and error bound below t_min: missed without double, triangle.cl) and ahead of
    the second (hit at t = 1e-4, from double). Every answer, in packets and one ray a
    work-item alike."""
    R = 2.0 ** 19
    v, f = quad([(-R, 0.0, -R), (R, 0.0, -R), (R, 0.0, R), (-R, 0.0, R)])
    f = f[:, ::-1]                                 # either side: the test is two-sided
    tree = build(v, f)
    rng = np.random.default_rng(31)
    n = runtime.small(4001, 61)
    p = np.column_stack([rng.uniform(-1, 1, n), np.zeros(n), rng.uniform(-1, 1, n)])
    d = rng.normal(size=(n, 3))
    d[:, 1] = np.abs(d[:, 1]) + 0.05               # away from the quad, never along it
    d /= np.linalg.norm(d, axis=1)[:, None]
    eps = 1e-4
    answers = []
    for packet in [1] if runtime.simulator else [1, None]:
        tr = Tracer(tree, device=runtime.spec, packet=packet)
        leaving = tr.trace(p + eps * d, d)
        reaching = tr.trace(p - eps * d, d)
        assert not leaving.hit.any()
        assert reaching.hit.all()
        assert np.allclose(reaching.t, eps, rtol=1e-3), (reaching.t.min(), reaching.t.max())
        answers.append((leaving.t, reaching.t, reaching.prim, reaching.u))
    for a, b in zip(answers[0], answers[-1]):
        assert np.array_equal(a, b)
