"""The kernels on every OpenCL implementation present (the `runtime` fixture, conftest.py):
the same answer as the float64 oracle, and bit for bit the same answer at every work
size GPUs and CPUs use, with packets and without, at every stack size, for rays and for
camera renders. Ray counts are multiples of no work size; outputs are poisoned first.

Intel's CPU runtime runs a work-group's work-items in SIMD lanes, as GPUs do: a kernel
that is right on PoCL (work-items one after another) can be wrong there
(tests/repros/intel_cpu_vec3_call.py). Oclgrind runs the GPU path (one ray a work-item,
interleaved slots, copied buffers) on small cases and fails a test on any invalid
access, data race or divergent barrier it sees. Scenes come from scenes/ and from
random triangles, so these tests need nothing outside the repository."""
import dataclasses
import json
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

import trees
from helpers import (SCENES, camera_for, check_hits, force_ray_order, random_rays, soup,
                     split_plane_rays)
from kdray import layout
from kdray.layout import MISS
from kdray.errors import KdrayError
from kdray.load import load
from kdray.trace import PACKETS, Tracer, max_local_size, pocl_item_bytes

# (rays per work-item, local size, batch size, groups): one item at a time, odd sizes,
# the sizes GPUs use (32: a warp, 64: a wavefront, 128, 256), the same with packets
WORK_SIZES = [(1, 1, 1, 1), (1, 4, 12, 3), (1, 16, 64, 4), (1, 32, 64, 2), (1, 64, 256, 2),
              (1, 128, 256, 2), (1, 256, 512, 1),
              (8, 1, 8, 1), (8, 4, 96, 3), (8, 16, 128, 5), (8, 32, 256, 2), (8, 64, 512, 2),
              (8, 128, 1024, 1), (8, 256, 2048, 1),
              (16, 1, 16, 1), (16, 8, 1024, 4), (16, 32, 512, 2)]
WORK_SIZES_CORE = [(1, 1, 1, 1), (1, 4, 12, 3), (1, 64, 256, 2), (1, 256, 512, 1),
                   (8, 4, 96, 3), (16, 32, 512, 2)]
"""The work sizes `make test` tries: one item at a time, an odd size, a wavefront (the
GPUs' default), the largest group, and packets of each width in odd groups and a
warp's; the others in `make test-long`. Each work size is a program of its own (about
1.5 s to compile with packets)."""

_TREES = {}


def scene_tree(name):
    """A tree of a scene: "sphere" (scenes/sphere.obj, 1,280 triangles, SAH), "cornell"
    (32 triangles, SAH) or "soup" (300 random triangles of mixed sizes with exact ties,
    median splits 18 deep: many leaves and deep stacks)."""
    if name not in _TREES:
        if name == "soup":
            v, f = soup(5)
            _TREES[name] = trees.split_tree(v, f, max_depth=18, leaf_size=4)
        else:
            from kdray.builder import build
            mesh = load(SCENES / f"{name}.obj")
            _TREES[name] = build(mesh.vertices, mesh.faces)
    return _TREES[name]


def rays(runtime, tree, n_cpu, n_simulator, seed):
    """Random rays (most from outside towards the scene, some inside) and rays in the
    tree's split planes: n_cpu of them on a CPU or GPU, n_simulator on a simulator."""
    n = runtime.small(n_cpu, n_simulator)
    o, d = random_rays(tree, n - n // 10, seed=seed, inside=0.3)
    o2, d2 = split_plane_rays(tree, n // 10, seed=seed + 1)
    return np.concatenate([o, o2]), np.concatenate([d, d2])


def same_hits(a, b):
    for field in ("t", "prim", "u", "v", "normal"):
        assert np.array_equal(getattr(a, field), getattr(b, field), equal_nan=True), field


@pytest.mark.parametrize("scene", ["sphere", "soup"])
def test_matches_the_oracle(runtime, scene):
    """The default configuration of each implementation agrees with float64 brute force
    (ties and float32 grazes of edges allowed, as everywhere in test_trace)."""
    tree = scene_tree(scene)
    o, d = random_rays(tree, runtime.small(3001, 301), seed=21)
    hits = Tracer(tree, device=runtime.spec).trace(o, d)
    assert check_hits(hits, tree, o, d) > len(o) // 4


@pytest.mark.parametrize("sizes", ["core", pytest.param("more", marks=pytest.mark.slow)])
@pytest.mark.parametrize("scene", ["soup", pytest.param("sphere", marks=pytest.mark.slow)])
def test_work_sizes_do_not_change_results(runtime, scene, sizes):
    """Local size, batch size, group count, packets and the slots each work-item takes
    (runs of the batch, as on CPUs, or every local_size-th packet, as on GPUs) change
    the schedule, never the answer: bit for bit the result of one ray at a time, with
    every poisoned output written; with packets, rays shaped as an image 13 wide too
    (packets of 4 x packet / 4 of them). Sizes the device cannot take are left out.
    `make test` runs WORK_SIZES_CORE on the soup, the deeper tree (on a simulator those
    without packets: its packet kernels are checked in `make test` by the one-origin
    and stack-size tests); `make test-long` the other sizes, and the sphere."""
    core = [s for s in WORK_SIZES_CORE if not (runtime.simulator and s[0] > 1)]
    sizes = core if sizes == "core" else [s for s in WORK_SIZES if s not in core]
    tree = scene_tree(scene)
    o, d = rays(runtime, tree, 4001, 307, seed=22)
    base = Tracer(tree, device=runtime.spec, packet=1, local_size=1, batch_size=1,
                  groups=1).trace(o, d)
    assert base.hit.sum() > len(o) // 4
    m = len(o) // 13 * 13
    image = (o[:m].reshape(-1, 13, 3), d[:m].reshape(-1, 13, 3))
    tried = 0
    for packet, local, batch, groups in sizes:
        tr = Tracer(tree, device=runtime.spec, packet=packet, local_size=1, batch_size=packet,
                    groups=1)
        if local > max_local_size(tr.device, packet, tr.packet_stack_size):
            continue
        if runtime.simulator and local in (16, 128):
            continue        # Oclgrind is slow: 32, 64 and 256 stand for the GPU sizes
        tr = Tracer(tree, device=runtime.spec, packet=packet, local_size=local,
                    batch_size=batch, groups=groups)
        tr._poison_outputs = True
        for item_runs in (False,) if runtime.simulator else (True, False):
            tr._item_runs = item_runs            # a kernel argument: the same program
            same_hits(tr.trace(o, d), base)
            if packet > 1:
                same_hits(tr.trace(*image), base[:m]._reshaped((m // 13, 13)))
            tried += 1
    skipped = sum(local in (16, 128) for _, local, _, _ in sizes)
    assert tried >= (len(sizes) - skipped if runtime.simulator else 2 * len(sizes) - 4)


def test_groups_fit_the_runtime(runtime):
    """A Tracer takes no work-group the runtime cannot run: PoCL keeps every work-item's
    private data on the stack of the thread that runs the group, and with packets a
    group of 256 overflowed a thread's 8 MiB stack and crashed the process (PoCL 3.0).
    Such a group is refused with a message that says why; the largest taken runs."""
    tree = scene_tree("soup")
    o, d = rays(runtime, tree, 1001, 101, seed=24)
    base = Tracer(tree, device=runtime.spec, packet=1).trace(o, d)
    for packet in (1, *PACKETS):
        probe = Tracer(tree, device=runtime.spec, packet=packet, local_size=1,
                       batch_size=packet, groups=1)
        most = max_local_size(probe.device, packet, probe.packet_stack_size)
        assert 1 <= most <= probe.device.max_work_group_size
        if runtime.name == "pocl" and packet > 1:
            assert most < probe.device.max_work_group_size     # the stack binds
            with pytest.raises(KdrayError, match="stack"):
                Tracer(tree, device=runtime.spec, packet=packet, local_size=most + 1)
            # the same group on a deeper tree (a larger packet stack) does not fit either
            deep = dataclasses.replace(tree, depth=63)
            assert max_local_size(probe.device, packet, 64) < most
            with pytest.raises(KdrayError, match="stack"):
                Tracer(tree, device=runtime.spec, packet=packet, local_size=most).with_tree(deep)
        if runtime.simulator:
            continue        # Oclgrind: the GPU sizes are tried above
        local = min(most, 512)
        tr = Tracer(tree, device=runtime.spec, packet=packet, local_size=local,
                    batch_size=local * packet, groups=2)
        same_hits(tr.trace(o, d), base)


def test_pocl_frames_fit_the_bound(runtime):
    """The frames of PoCL's compiled packet kernels (tests/pocl_frames.py, run in its own
    process for a fresh kernel cache) stay within the stack bytes max_local_size allows a
    work-item: a kernel change that grows them past it fails here, not as a crash (or a
    silent overflow into other memory) at a large work-group."""
    if runtime.name != "pocl":
        pytest.skip("PoCL's work-groups only: it runs a group's work-items on one stack")
    script = Path(__file__).with_name("pocl_frames.py")
    done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True,
                          cwd=script.parent.parent, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    rows = json.loads(done.stdout.splitlines()[-1])
    kernels = {(r["kernel"], r["packet"], r["packet_stack"]) for r in rows}
    for packet in PACKETS:
        stacks = {s for k, p, s in kernels if k == "trace_rays" and p == packet}
        assert len(stacks) == 2, kernels        # the soup's packet stack and the deepest
        assert any(k == "render_camera" and p == packet for k, p, _ in kernels), kernels
    for r in rows:
        item = r["frame_bytes"] / r["local_size"]
        allowed = pocl_item_bytes(r["packet"], r["packet_stack"])
        if r["kernel"] in ("trace_rays", "render_camera"):
            # a frame this small means the pattern read no longer finds the real one
            assert item > 1024, r
        assert item <= allowed, (r, allowed)


def test_stack_sizes_do_not_change_results(runtime):
    """A short stack of 1, 2 or 4 entries restarts (counted by the STATS build) and
    gives the full stack's hits bit for bit; packets give them too."""
    tree = scene_tree("soup")
    assert tree.depth >= 12
    o, d = rays(runtime, tree, 2001, 211, seed=23)
    results = {}
    for size in (1, 2, 4, 32):
        results[size] = Tracer(tree, device=runtime.spec, stack_size=size, packet=1)._trace(
            o, d, stats=True)
    restarts = {size: int(stats[:, 3].sum()) for size, (_, stats) in results.items()}
    assert restarts[1] > restarts[4] > 0 and restarts[32] == 0
    for size in (1, 2, 4):
        same_hits(results[size][0], results[32][0])
    for packet in PACKETS:
        same_hits(Tracer(tree, device=runtime.spec, packet=packet).trace(o, d), results[32][0])


def test_direction_scales_around_the_packets_inverse(runtime):
    """A packet finds its split planes' t with 1 / d when every lane's direction
    components are 0 or between 2^-125 and 2^125 in magnitude, and divides otherwise
    (packet.cl, kd_inverse_far). Directions scaled by powers of two on both sides of
    that range, and with a component tiny or subnormal in some lanes, give bit for bit
    what one ray at a time gives (which always divides); a power-of-two scale well
    inside the range multiplies t by its inverse exactly and changes no hit."""
    if runtime.simulator:
        pytest.skip("Oclgrind runs the GPU path, one ray a work-item: no packets")
    tree = scene_tree("sphere")
    o, d = camera_for(tree, 64, 40).rays()
    tiny = d.copy()
    rng = np.random.default_rng(26)
    for value in (1e-40, -1e-40, 2e-38, -7e-39):       # subnormal, below 2^-125
        tiny[rng.choice(len(d), len(d) // 16, replace=False), rng.integers(3)] = value
    single = Tracer(tree, device=runtime.spec, packet=1)
    base = single.trace(o, d)
    assert base.hit.sum() > len(d) // 4
    for packet in PACKETS:
        tr = Tracer(tree, device=runtime.spec, packet=packet)
        for k in (-100, 100, 126, 127):
            scaled = d * 2.0 ** k
            hits = tr.trace(o, scaled)
            same_hits(hits, single.trace(o, scaled))
            if abs(k) == 100:
                assert np.array_equal(hits.prim, base.prim)
                assert np.array_equal(hits.t, (base.t * 2.0 ** -k).astype(np.float32))
        same_hits(tr.trace(o, tiny), single.trace(o, tiny))


def test_subnormal_direction_crosses_a_split_far_away(runtime):
    """The case that makes a packet divide (kd_inverse_far): rays along z whose x
    component is subnormal (-1e-40) start at x = 0, beside the root's split plane at
    x = -5e-34, and cross it at t = 5e6, before they reach the two strips of
    triangles at z = 2e7 on either side of it. 1 / d overflows to -inf, and with it
    the plane's t would be +inf, "never crossed": the rays would miss. They hit the
    x < 0 strip, one ray at a time and in packets."""
    if runtime.simulator:
        pytest.skip("Oclgrind runs the GPU path, one ray a work-item: no packets")
    from kdray.builder import build
    e, z = 5e-34, 2e7
    quads = [[(side * e, y0, z), (side, y0, z), (side, y0 + 0.05, z), (side * e, y0 + 0.05, z)]
             for side in (1, -1) for y0 in np.arange(40) * 0.05 - 1.0]
    v = np.array(quads, dtype=np.float64).reshape(-1, 3)
    f = (np.arange(len(quads))[:, None, None] * 4 + np.array([[0, 1, 2], [0, 2, 3]])).reshape(-1, 3)
    tree = build(v, f)
    lo = layout.split(tree.nodes[:1])[0]
    assert layout.split_axis(tree.nodes[:1])[0] == 0 and -1e-33 < lo < 0   # the plane
    n = 67
    o = np.zeros((n, 3))
    o[:, 1] = np.linspace(-0.53, 0.47, n)
    d = np.zeros((n, 3))
    d[:, 0], d[:, 2] = -1e-40, 1.0
    base = Tracer(tree, device=runtime.spec, packet=1).trace(o, d)
    assert np.all(base.prim >= len(f) // 2) and np.all(base.t == np.float32(z))
    for packet in PACKETS:
        same_hits(Tracer(tree, device=runtime.spec, packet=packet).trace(o, d), base)


def test_directions_below_2_128_cross_the_wide_nodes_boxes(runtime):
    """The same line traced with directions scaled down to components below 2^-128 (1 /
    d overflows to inf, while a box's planes are crossed at finite t) from beside a
    wide node's box: the wide nodes' walk, lone rays and packets, finds the k-d walk's
    hits, occlusions and counts (it had culled the box: every such hit lost)."""
    if runtime.simulator:
        pytest.skip("Oclgrind runs the GPU path, one ray a work-item: no wide nodes")
    from kdray.builder import build
    rng = np.random.default_rng(0)
    side = np.array([[-1.0, -1, 0], [-0.9, -1, 0], [-1.0, 1, 0]]) + np.zeros((16, 1, 1))
    side[:, :, 1] += np.arange(16)[:, None] * 0.01
    xs = np.linspace(0, 1, 17)
    strip = np.array([[[xs[i], -1, 0], [xs[i + 1], -1, 0], [xs[i], 1, 0]] for i in range(16)])
    tri = np.concatenate([side, strip])
    tree = build(tri.reshape(-1, 3), np.arange(3 * len(tri)).reshape(-1, 3))
    grid = np.stack(np.meshgrid(np.linspace(-0.5, -0.3, 16), np.linspace(-0.9, 0.9, 16)), -1)
    o = np.concatenate([grid.reshape(-1, 2), np.ones((256, 1))], axis=1)
    o += rng.normal(size=o.shape) * 1e-3 * [1, 1, 0]
    for scale in (1.0, 1e-30, 5e-39, 3e-39):
        d = np.tile([0.8 * scale, 0.0, -1.0 * scale], (256, 1))
        base_tracer = Tracer(tree, device=runtime.spec, packet=1)
        base = base_tracer.trace(o, d)
        assert (base.prim != MISS).sum() > 100
        for packet in PACKETS:
            tracer = Tracer(tree, device=runtime.spec, packet=packet)
            same_hits(tracer.trace(o, d), base)
            same_hits(tracer.trace(o.reshape(16, 16, 3), d.reshape(16, 16, 3))._reshaped((256,)),
                      base)
            assert np.array_equal(tracer.occluded(o, d), base.prim != MISS)
            assert np.array_equal(tracer.count(o, d), base_tracer.count(o, d))


def test_the_scene_box_never_decides_a_hit(runtime):
    """Rays that touch the cube [-1, 1]^3 only at a point of one of its edges (on the
    scene's box: they come from outside one face and leave beside the other; or pass
    a float32 rounding beside it), and rays
    from inside whose t_min lies a rounding below their hit on a face (on the box too),
    hit as they do in a tree whose box is larger (a far triangle added, the same
    origin): the box clip's roundings are within the planes' slack (traverse.cl,
    KD_BOX_ENTER), for trace and occluded, one ray at a time and in packets."""
    from helpers import grid_cube
    from kdray.builder import build
    v, f = grid_cube(1)
    tree = build(v, f)
    far = build(np.vstack([v, [[30, 30, 30], [31, 30, 30], [30, 31, 30]]]),
                 np.vstack([f, [[len(v), len(v) + 1, len(v) + 2]]]), origin=tree.origin)
    rng = np.random.default_rng(31)
    n = runtime.small(1200, 48)
    k = rng.integers(0, 3, n)                     # the edge's axis
    i, j = (k + 1) % 3, (k + 2) % 3
    si, sj = rng.choice([-1.0, 1.0], (2, n))
    rows = np.arange(n)
    p = np.zeros((n, 3))
    p[rows, k] = rng.uniform(-0.9, 0.9, n)
    p[rows, i], p[rows, j] = si, sj
    d = np.zeros((n, 3))
    d[rows, k] = rng.uniform(-1, 1, n)
    d[rows, i] = si * rng.uniform(0.2, 1, n)      # leaving face i's slab after p
    d[rows, j] = -sj * rng.uniform(0.2, 1, n)     # from outside face j before p
    o = p - 2.0 * d
    # from inside to a face, t_min a float32 step or two below the hit
    q = rng.uniform(-0.9, 0.9, (n, 3))
    e = rng.normal(size=(n, 3))
    packets = [None] if runtime.simulator else [1, *PACKETS]
    for packet in packets:
        small, large = (Tracer(t, device=runtime.spec, packet=packet) for t in (tree, far))
        # (the float32 rays pass through the edge or a rounding beside it: half hit)
        hits = small.trace(o, d)
        assert hits.hit.mean() > 0.3 and np.allclose(hits.t[hits.hit], 2.0, rtol=1e-5)
        same_hits(hits, large.trace(o, d))
        assert np.array_equal(small.occluded(o, d), hits.hit)
        t = large.trace(q, e).t.astype(np.float64)
        for t_min in (t * (1 - 1e-7), t * (1 - 2e-7), t):
            same_hits(small.trace(q, e, t_min=t_min), large.trace(q, e, t_min=t_min))
            assert np.array_equal(small.occluded(q, e, t_min=t_min),
                                  large.occluded(q, e, t_min=t_min))


def one_origin_rays(tree, seed, n_points, per_point=16):
    """Rays from one point inside the scene's box: per_point of them, one packet's worth,
    at each of n_points of the tree's vertices and edge midpoints, the first exactly at
    it (its float64 direction), the others turned by a few float32 ulps: rays that touch
    or just miss a triangle's corner or edge, in packets of one origin and one shear."""
    rng = np.random.default_rng(seed)
    lo, hi = tree.world_box()
    o = lo + (0.3 + 0.4 * rng.random(3)) * (hi - lo)
    tri = (np.asarray(tree.triangles, dtype=np.float64) * tree.scale + tree.origin)
    pick = tri[rng.integers(0, len(tri), n_points)]
    at = np.where(rng.random((n_points, 1)) < 0.5, pick[:, 0], 0.5 * (pick[:, 0] + pick[:, 1]))
    d = np.repeat(at - o, per_point, axis=0)
    ulp = np.spacing(np.abs(d).astype(np.float32)).astype(np.float64)
    d[1:] += rng.integers(-3, 4, size=d[1:].shape) * ulp[1:]
    d[::per_point] = at - o
    return o, d


@pytest.mark.slow_on_simulator(cull="rule")
@pytest.mark.parametrize("cull", ["every leaf", "rule"])
@pytest.mark.parametrize("packet", [8, pytest.param(16, marks=pytest.mark.slow)])
@pytest.mark.parametrize("scene", [pytest.param("soup", marks=pytest.mark.slow), "sphere"])
def test_packets_of_one_origin_cull_exactly(runtime, scene, packet, cull):
    """A packet whose rays share an origin and shear axes leaves out at once the
    triangles no lane can hit (packet.cl, kd_block_culls, from bounds on the lanes'
    sheared vertices): bit for bit the answer of one ray at a time, for a camera's
    image (render and trace) and for rays from one point that touch or just miss
    corners and edges, where a triangle culled wrongly would be a lost hit. The
    camera's rays are traced as float64 (the float32 directions widened exactly): the
    same rays, with the programs the other rays use. Every leaf culled, or by the
    kernel's rule (culled or ray by ray). `make test` runs packets of 8 on the sphere,
    whose leaves hold several blocks of triangles (on a simulator every leaf culled);
    `make test-long` packets of 16 (whose culling by the kernel's rule every render of
    an AVX-512 CPU's default Tracer goes through), the soup, and the rule on a
    simulator."""
    tree = scene_tree(scene)
    w, h = runtime.small((67, 41), (19, 9))
    cam = camera_for(tree, w, h)
    o, d = one_origin_rays(tree, seed=31, n_points=runtime.small(400, 24))
    scalar = Tracer(tree, device=runtime.spec, packet=1)
    base_image = scalar.render(cam, aovs=("depth", "normal", "bary", "id"))
    base = scalar.trace(o, d)
    assert base.hit.sum() > len(o) // 2
    cam_o, cam_d = scalar.camera_rays(cam)
    cam_d = cam_d.astype(np.float64)
    base_cam = scalar.trace(cam_o.reshape(h, w, 3), cam_d.reshape(h, w, 3))
    tr = Tracer(tree, device=runtime.spec, packet=packet)
    tr._cull_lane_ratio = {"every leaf": 0.0, "rule": None}[cull]   # 0: none ray by ray
    tr._poison_outputs = True
    same_hits(tr.trace(o, d), base)
    same_hits(tr.trace(o, d.reshape(-1, 4, 3)), base._reshaped((len(d) // 4, 4)))
    same_hits(tr.trace(cam_o.reshape(h, w, 3), cam_d.reshape(h, w, 3)), base_cam)
    images = tr.render(cam, aovs=("depth", "normal", "bary", "id"))
    for name, image in base_image.items():
        assert np.array_equal(images[name], image, equal_nan=True), name


@pytest.mark.parametrize("scene,packet", [
    ("sphere", 8), pytest.param("sphere", 16, marks=pytest.mark.slow),
    pytest.param("soup", 8, marks=pytest.mark.slow), pytest.param("soup", 16, marks=pytest.mark.slow)])
def test_plain_vector_ops_give_the_same_hits(runtime, scene, packet):
    """The packets' code for PoCL (KD_PLAIN_VECTOR_OPS: no vload or shuffle, which it
    calls out of line) on every runtime with packets, so that it is checked where PoCL
    cannot run: bit for bit the answer of one ray at a time, for rays, rays shaped as
    an image, and a render, in leaves read ray by ray and culled. Packets of 8 on the
    sphere, whose leaves hold several blocks of triangles to deal, run in `make test`;
    packets of 16, and the soup, in `make test-long`."""
    tree = scene_tree(scene)
    if Tracer(tree, device=runtime.spec).packet == 1:
        pytest.skip("no packets on this runtime")
    o, d = rays(runtime, tree, 2001, 307, seed=23)
    w, h = 37, 21
    cam = camera_for(tree, w, h)
    scalar = Tracer(tree, device=runtime.spec, packet=1)
    base, base_image = scalar.trace(o, d), scalar.render(cam, aovs=("depth", "id"))
    m = len(o) // 12 * 12
    for cull_ratio in (None, 0.0):
        tr = Tracer(tree, device=runtime.spec, packet=packet)
        tr._plain_vector_ops = True
        tr._cull_lane_ratio = cull_ratio
        tr._poison_outputs = True
        same_hits(tr.trace(o, d), base)
        same_hits(tr.trace(o[:m].reshape(-1, 12, 3), d[:m].reshape(-1, 12, 3)),
                  base[:m]._reshaped((m // 12, 12)))
        images = tr.render(cam, aovs=("depth", "id"))
        for name, image in base_image.items():
            assert np.array_equal(images[name], image, equal_nan=True), name


@pytest.mark.parametrize("scene", ["cornell", "sphere"])
def test_render_is_trace_of_the_camera_rays(runtime, scene):
    """A render (pixels in tiles; on CPUs packets of 4 x 2 or 4 x 4 pixels) writes every
    pixel, poisoned first, with the hit of its own ray; on Oclgrind, a device of 128 MiB,
    the launches are sized to its memory. Sizes that fit no tile or packet."""
    tree = scene_tree(scene)
    default = Tracer(tree, device=runtime.spec).packet
    w, h = runtime.small((131, 67), (29, 11))
    cam = camera_for(tree, w, h)
    for packet in PACKETS if default > 1 else (default,):
        tr = Tracer(tree, device=runtime.spec, packet=packet)
        tr._poison_outputs = True
        images = tr.render(cam, aovs=("depth", "normal", "bary", "id"))
        hits = tr.trace(*tr.camera_rays(cam))
        assert np.array_equal(images["depth"].ravel(), hits.t)
        assert np.array_equal(images["id"].ravel(), hits.prim)
        assert np.array_equal(images["bary"].reshape(-1, 2), np.stack([hits.u, hits.v], 1))
        assert np.array_equal(images["normal"].reshape(-1, 3), hits.normal)
        assert (images["id"] != 0xFFFFFFFF).sum() > w * h // 10


WIDTHS = ["default", pytest.param("other", marks=pytest.mark.slow)]
"""The packet widths of `poisoned_tracers`: the device's default (and a GPU's work sizes)
in `make test`, the other widths in `make test-long` (each a program of its own; on a
CPU whose default is the other width every test goes through it)."""


def poisoned_tracers(runtime, tree, widths="default"):
    """Tracers of `tree` with poisoned outputs at a CPU's work sizes (its default local
    and batch sizes: the programs other tests build) and at a GPU's without packets (on
    a simulator, one small size). widths: "default", a CPU's sizes with the device's
    default packet width (8 where that is 1) and a GPU's; "other", a CPU's sizes with the
    other widths."""
    first = Tracer(tree, device=runtime.spec).packet
    first = first if first in PACKETS else PACKETS[0]
    if widths == "other":
        if runtime.simulator:
            pytest.skip("a simulator runs one small work size")
        sizes = [(p, 8, 128 * p, 4) for p in PACKETS if p != first]
    elif runtime.simulator:
        sizes = [(1, 4, 12, 3)]
    else:
        sizes = [(first, 8, 128 * first, 4), (1, 64, 256, 2)]
    for packet, local, batch, groups in sizes:
        tr = Tracer(tree, device=runtime.spec, packet=packet, local_size=local, batch_size=batch,
                    groups=groups)
        tr._poison_outputs = True
        yield tr


@pytest.mark.parametrize("widths", WIDTHS)
@pytest.mark.parametrize("model", ["opencv", "fisheye", "equirectangular", "orthographic"])
def test_camera_model_render_is_trace_of_its_rays(runtime, model, widths):
    """A camera model's render (its rays made in the kernel from a ray map, RAY_MAP)
    writes every pixel, poisoned first: the hit of its own ray (Tracer.camera_rays:
    the map turned by the pose with the kernel's float32 arithmetic), or a miss where
    the pixel has no ray (a fisheye whose image circle is smaller than the image, a
    distortion that folds over); with packets and without, at GPU and CPU work sizes."""
    from kdray import Camera
    tree = scene_tree("sphere")
    w, h = runtime.small((77, 53), (23, 13))
    pin = camera_for(tree, w, h)
    f = 0.15 * w if model != "equirectangular" else w / (2 * np.pi)
    K = np.array([[f, 0, w / 2], [0, f if model != "equirectangular" else h / np.pi, h / 2],
                  [0, 0, 1]])
    distortion = {"opencv": (-0.45, 0.08, 1e-3, -2e-3, 0.05), "fisheye": (0.05, -0.01, 0.0, 0.0),
                  "equirectangular": (), "orthographic": ()}[model]
    if model == "opencv":
        K = pin.K
    if model == "orthographic":             # the sphere (radius 1) across most of the image
        distortion = ()
        K = np.array([[0.4 * w, 0, w / 2], [0, 0.4 * w, h / 2], [0, 0, 1]])
    cam = Camera(w, h, K, pin.cam_to_world, model, distortion)
    for tr in poisoned_tracers(runtime, tree, widths):
        images = tr.render(cam, aovs=("depth", "normal", "bary", "id", "distance", "position"))
        o, d = tr.camera_rays(cam)
        hits = tr.trace(o, d)
        valid = images["valid"].ravel()
        assert np.array_equal(valid, ~np.isnan(d[:, 0]))
        assert np.array_equal(images["depth"].ravel(), hits.t)
        assert np.array_equal(images["id"].ravel(), hits.prim)
        assert np.array_equal(images["bary"].reshape(-1, 2), np.stack([hits.u, hits.v], 1))
        assert np.array_equal(images["normal"].reshape(-1, 3), hits.normal)
        assert np.all(np.isinf(images["distance"].ravel()[~valid]))
        assert np.all(np.isnan(images["position"].reshape(-1, 3)[~valid]))
        hit = images["id"].ravel() != 0xFFFFFFFF
        assert hit.sum() >= (1 if runtime.simulator else 20) and not hit[~valid].any()
        if model == "fisheye":
            assert 0 < (~valid).sum() < w * h // 2        # the corners are past its field


@pytest.mark.parametrize("widths", WIDTHS)
def test_lidar_scan_is_trace_of_its_rays(runtime, widths):
    """A scan (its rays made in the kernel from the Lidar's direction map, RAY_MAP; rows
    beams, columns azimuth steps) gives, for every beam, the hit of its own ray: the
    map turned by the pose with the kernel's float32 arithmetic, from inside a sphere
    (every beam hits) and with max_range cutting some; with packets and without."""
    from kdray import Lidar
    from kdray.layout import MISS
    tree = scene_tree("sphere")
    channels, columns = runtime.small((16, 131), (5, 19))
    lidar = Lidar.from_dict({"channels": channels, "fov_up": 40.0, "fov_down": -60.0,
                             "columns": columns, "max_range": 1.05})
    c, s = np.cos(0.7), np.sin(0.7)
    pose = np.array([[c, -s, 0, 0.1], [s, c, 0, -0.2], [0, 0, 1, 0.05], [0, 0, 0, 1.0]])
    M = pose[:3, :3].astype(np.float32)
    v = lidar.directions().astype(np.float32)
    d = np.stack([M[r, 0] * v[:, 0] + M[r, 1] * v[:, 1] + M[r, 2] * v[:, 2] for r in range(3)], 1)
    for tr in poisoned_tracers(runtime, tree, widths):
        scan = tr.scan(lidar, pose)
        eye = tr._origin + tr._scale * ((pose[:3, 3] - tr._origin) / tr._scale).astype(np.float32)
        hits = tr.trace(eye, d)
        near = hits.t < lidar.max_range
        assert np.array_equal(scan["range"].ravel(), np.where(near, hits.t, np.inf))
        assert np.array_equal(scan["id"].ravel(), np.where(near, hits.prim, MISS))
        assert hits.hit.all() and 0 < near.sum() < near.size        # max_range cuts some


@pytest.mark.slow_on_simulator()
@pytest.mark.parametrize("packet", PACKETS)
def test_packet_kernels_say_they_are_vectorized_by_hand(runtime, packet, tmp_path):
    """Both entry points of a packet program carry vec_type_hint of the packet's float
    vector (render.cl, KD_VEC_HINT), as the implementation reports them
    (CL_KERNEL_ATTRIBUTES). Without it Intel's CPU runtime transposes a work-group's
    packets across its vector lanes: about 30 times slower with AVX2. Built from
    source with pyopencl's binary cache in a folder of its own (a program loaded from
    that cache reports no attributes on Intel's runtime); an implementation that
    reports none is skipped. Each case compiles from nothing: on a simulator in
    `make test-long` (the attribute is the source's, checked on the CPU runtimes)."""
    from kdray import device as _device
    cl = _device._cl()
    device = _device.choose_device(runtime.spec)
    options = _device.build_options(device, {"LOCAL_SIZE": 8, "BATCH_SIZE": 8 * packet,
                                             "PACKET": packet, "OUT_T": None})
    source = (_device.KERNEL_DIR / "render.cl").read_text(encoding="utf-8")
    context = _device.new_context(device)
    with warnings.catch_warnings():          # PoCL's and Intel's harmless notes
        warnings.simplefilter("ignore", cl.CompilerWarning)
        program = cl.Program(context, source).build(options, cache_dir=str(tmp_path))
    for name in ("trace_rays", "render_camera"):
        try:
            attributes = cl.Kernel(program, name).get_info(cl.kernel_info.ATTRIBUTES)
        except cl.Error as error:        # OpenCL before 1.2
            pytest.skip(f"{runtime.spec}: no kernel attributes ({error})")
        if not attributes.strip():
            pytest.skip(f"{runtime.spec} reports no kernel attributes")
        # reported after preprocessing (Intel, PoCL) or as render.cl declares it, its
        # macro floatP for float{packet} (NVIDIA: "as they were declared", the spec says)
        declared = attributes.replace(" ", "")
        assert (f"vec_type_hint(float{packet})" in declared
                or "vec_type_hint(floatP)" in declared), attributes


@pytest.mark.parametrize("packet", [1, *PACKETS])
def test_rays_taken_in_an_order_give_the_same_hits(runtime, monkeypatch, packet):
    """Rays in no order of their own, traced in an order (kdray.ray_order: trace_rays
    reads each ray and writes its outputs through it), give bit for bit the hits of
    the same rays taken as they come, in packets and one a work-item, at a count that
    leaves a packet short, rays from one point (taken by direction) too; and the order
    is taken, by the keys numpy computes."""
    import kdray.ray_order as ray_order
    import kdray.trace as trace
    tree = scene_tree("soup")
    o, d = rays(runtime, tree, 4001, 307, seed=23)
    order = np.random.default_rng(24).permutation(len(o))
    o, d = o[order], d[order]                    # the split-plane rays among the others
    tr = Tracer(tree, device=runtime.spec, packet=packet)
    tr._poison_outputs = True
    base = tr.trace(o, d)
    # rays from one point, of many lengths, taken by direction (ray_order.direction_keys)
    lo, hi = tree.world_box()
    centre = 0.5 * (lo + hi)
    one_d = d * np.random.default_rng(25).uniform(0.1, 10.0, size=(len(d), 1))
    one_base = tr.trace(centre, one_d)
    taken = force_ray_order(monkeypatch, trace)
    same_hits(tr.trace(o, d), base)
    same_hits(tr.trace(centre, one_d), one_base)
    assert len(taken) == 2 and all(t is not None for t in taken)
    for t in taken:
        assert np.array_equal(np.sort(t), np.arange(len(o)))
    # its keys (kernels/ray_order.cl) are numpy's but where float rounds otherwise
    keys = ray_order.device_keys(tr, o, d, lo, hi)
    assert np.mean(keys == ray_order.ray_keys(o, d, lo, hi)) > 0.99
    keys = ray_order.device_keys(tr, centre[None], one_d, lo, hi, 0, keys="direction")
    assert np.mean(keys == ray_order.direction_keys(one_d)) > 0.99
    assert np.array_equal(taken[1], np.argsort(keys, kind="stable"))
    # rays that follow their origins (toward a point beyond the box), by their cells
    light = hi + (hi - lo)
    to_light = light - o
    assert ray_order.follow(o, to_light, lo, hi)
    keys = ray_order.device_keys(tr, o, to_light, lo, hi, keys="cell")
    assert np.mean(keys == ray_order.cell_keys(o, to_light, lo, hi)) > 0.99
    ordered = tr.trace(o, to_light)
    assert len(taken) == 3 and taken[2] is not None
    assert np.array_equal(np.sort(taken[2]), np.arange(len(o)))
    by_key = keys[taken[2]].astype(np.int64)      # (taken from the rays in the tree's frame)
    assert np.mean(by_key[1:] >= by_key[:-1]) > 0.99
    monkeypatch.setattr(trace, "ray_order", lambda *args: None)
    same_hits(ordered, tr.trace(o, to_light))
