"""Tracer against the float64 brute-force oracle (kdray.reference), on trees of several
shapes: a single leaf, median and random splits (tests/trees.py) and kdray.build's SAH
trees. Hits must agree ray by ray; where they differ the difference must be a tie or a
ray grazing an edge, checked in float64 on the triangles themselves."""

import dataclasses

import numpy as np
import pytest

import trees
from helpers import (RTOL_T, assert_watertight, camera_for, check_hits, force_ray_order,
                     random_rays, real_mesh_arrays, soup, split_plane_rays)
from kdray import layout
from kdray import trace as ktrace
from kdray.device import has_fp64
from kdray.errors import KdrayError
from kdray.reference import brute_force
from kdray.trace import MISS, PACKETS, Tracer, default_stack_size
from kdray.wide import STACK_GROUPS




mesh = real_mesh_arrays


def sah_tree(vertices, faces):
    from kdray.builder import build
    return build(vertices, faces)


# -- trees of several shapes ---------------------------------------------------------

TREE_KINDS = {
    "leaf": lambda v, f: trees.leaf_tree(v, f),
    "median": lambda v, f: trees.split_tree(v, f, max_depth=18, leaf_size=4),
    "random": lambda v, f: trees.split_tree(v, f, max_depth=14, split="random", seed=7),
    "sah": sah_tree,
}


@pytest.mark.parametrize("kind", list(TREE_KINDS))
def test_soup_matches_reference(kind, tracers):
    v, f = soup(1)
    tree = TREE_KINDS[kind](v, f)
    tree.validate()
    o, d = random_rays(tree, 3001, seed=2)
    hits = tracers(tree).trace(o, d)
    assert check_hits(hits, tree, o, d) > 1000


_MESH_TREES = {}


def mesh_tree(name, kind):
    if (name, kind) not in _MESH_TREES:
        v, f = mesh(name)
        _MESH_TREES[name, kind] = TREE_KINDS[kind](v, f)
    return _MESH_TREES[name, kind]


@pytest.mark.parametrize("name,kind,n", [
    ("teapot.obj", "median", 1501), pytest.param("teapot.obj", "random", 1501, marks=pytest.mark.slow),
    ("teapot.obj", "sah", 1501), ("fandisk.obj", "sah", 1201),
    pytest.param("spot.obj", "median", 1201, marks=pytest.mark.slow), ("spot.obj", "sah", 1201),
    ("stanford-bunny.obj", "sah", 401),
])
def test_mesh_matches_reference(name, kind, n, tracers):
    """Real meshes against the oracle, in trees of several shapes. The random splits of
    the teapot and the median splits of spot in `make test-long` (each kind is in
    `make test` on the teapot, and on random triangles in test_soup_matches_reference)."""
    tree = mesh_tree(name, kind)
    o, d = random_rays(tree, n, seed=len(name))
    hits = tracers(tree).trace(o, d)
    assert check_hits(hits, tree, o, d) > n // 3


def test_t_range(tracers):
    """t_min and t_max narrow the hits, strictly: t_min < t < t_max."""
    tree = mesh_tree("teapot.obj", "sah")
    o, d = random_rays(tree, 1001, seed=5, inside=0.5)
    full = tracers(tree).trace(o, d)
    t_min, t_max = np.float32(0.05), np.float32(0.8)
    part = tracers(tree).trace(o, d, t_min=t_min, t_max=t_max)
    check_hits(part, tree, o, d, t_min=float(t_min), t_max=float(t_max))
    # hits of the full range inside (t_min, t_max) stay; those before t_min are replaced
    keep = (full.t > t_min) & (full.t < t_max)
    assert np.array_equal(part.prim[keep], full.prim[keep])
    assert np.all(part.t[full.t <= t_min] > t_min)
    with pytest.raises(KdrayError):
        tracers(tree).trace(o, d, t_min=-1.0)


# -- watertightness --------------------------------------------------------------------------

def convex_mesh():
    """A closed, convex, stretched icosphere (5120 triangles) off the origin."""
    import trimesh
    sphere = trimesh.creation.icosphere(subdivisions=4)
    shift = np.random.default_rng(16).normal(size=3)
    return sphere.vertices * np.array([1.0, 0.7, 1.3]) + shift, sphere.faces


def vertex_and_edge_rays(tree, seed, offset=(0.0, 0.0, 0.0)):
    """Rays from a point inside the mesh (its centre + offset) through every vertex,
    every edge midpoint and a random point of every edge of the tree's triangles;
    d = target - origin, so the surface is at t = 1."""
    rng = np.random.default_rng(seed)
    rel = tree.triangles.astype(np.float64)                 # the tracer's vertices
    center = rel.reshape(-1, 3).mean(axis=0) + np.asarray(offset)
    edges = np.concatenate([rel[:, [0, 1]], rel[:, [1, 2]], rel[:, [2, 0]]])
    w = rng.random((len(edges), 1))
    targets = np.concatenate([rel.reshape(-1, 3),                       # vertices
                              0.5 * (edges[:, 0] + edges[:, 1]),         # edge midpoints
                              w * edges[:, 0] + (1 - w) * edges[:, 1]])  # edge points
    return np.broadcast_to(center + tree.origin, targets.shape), targets - center


@pytest.mark.parametrize("kind", ["median", "sah"])
def test_watertight(kind, tracers):
    """Rays from inside a closed convex mesh through its vertices and along its edges
    never leak between triangles (Woop et al.'s guarantee), also where a vertex lies on
    several split planes (SAH trees put planes at vertices) and for any stack size."""
    v, f = convex_mesh()
    tree = TREE_KINDS[kind](v, f)
    for offset in [(0.0, 0.0, 0.0), (0.013, -0.021, 0.007)]:
        o, d = vertex_and_edge_rays(tree, seed=17, offset=offset)
        assert_watertight(tracers, tree, o, d, (1, 2, None), atol=1e-4, label=f"offset {offset}")


def test_watertight_closed_cad_mesh(tracers):
    """The same from a point inside fandisk (closed, non-convex, with axis-aligned faces
    and many vertices on split planes): every ray through a vertex or an edge hits."""
    import trimesh
    v, f = mesh("fandisk.obj")
    tree = mesh_tree("fandisk.obj", "sah")
    solid = trimesh.Trimesh(v, f, process=False)
    assert solid.is_watertight
    # a point inside: halfway between where a ray from outside enters and leaves
    lo, hi = solid.bounds
    o = lo - 0.5 * (hi - lo)
    d = 0.5 * (lo + hi) - o
    enter = brute_force(v[f], o[None], d[None])
    leave = brute_force(v[f], o[None], d[None], t_min=enter.t[0] * (1 + 1e-9))
    assert enter.hit[0] and leave.hit[0]
    inside = o + d * 0.5 * (enter.t[0] + leave.t[0])
    center = tree.triangles.reshape(-1, 3).astype(np.float64).mean(axis=0) + tree.origin
    o, d = vertex_and_edge_rays(tree, seed=19, offset=inside - center)
    for size in (1, None):
        hits = tracers(tree, stack_size=size).trace(o, d)
        leaks = np.count_nonzero(hits.prim == MISS)
        assert leaks == 0, f"{leaks} of {len(d)} rays leaked (stack {size})"


# -- every output written, any ray count ------------------------------------------------

@pytest.mark.parametrize("n", [0, 1, 31, 1_000_003])
def test_every_output_written(n):
    """Outputs are poisoned (NaN / 0x7FBADBAD) before the launch; every element must be
    overwritten, for counts that fit no work size."""
    v, f = soup(3, m=100)
    tree = trees.split_tree(v, f, max_depth=10, leaf_size=2)
    tr = Tracer(tree)
    tr._poison_outputs = True
    o, d = random_rays(tree, n, seed=n)
    hits = tr.trace(o, d)
    assert hits.t.shape == (n,) and hits.prim.shape == (n,) and hits.normal.shape == (n, 3)
    assert hits.t.dtype == np.float32 and hits.prim.dtype == np.uint32
    assert not np.any(np.isnan(hits.t)) and not np.any(np.isnan(hits.u))
    assert not np.any(np.isnan(hits.v)) and not np.any(np.isnan(hits.normal))
    hit = hits.prim != MISS
    assert np.all(hits.prim[hit] < tree.n_input_tris)
    assert np.all(np.isfinite(hits.t[hit])) and np.all(np.isposinf(hits.t[~hit]))
    assert np.allclose(np.linalg.norm(hits.normal[hit], axis=1), 1, atol=1e-6)
    if n > 1000:
        assert 0.1 * n < hit.sum() < 0.95 * n
        # the same rays traced in a small batch give the same answers
        sub = np.random.default_rng(0).choice(n, 997, replace=False)
        small = tr.trace(o[sub], d[sub])
        assert np.array_equal(small.prim, hits.prim[sub])
        assert np.array_equal(small.t, hits.t[sub])
    elif n:
        check_hits(hits, tree, o, d)


# -- short stack and restart -------------------------------------------------------------

def deep_tree():
    """Median splits down to single triangles: depth 22 on the teapot."""
    if ("teapot.obj", "deep") not in _MESH_TREES:
        v, f = mesh("teapot.obj")
        _MESH_TREES["teapot.obj", "deep"] = trees.split_tree(v, f, max_depth=30, leaf_size=1)
    return _MESH_TREES["teapot.obj", "deep"]


@pytest.mark.parametrize("kind", ["median", "sah"])
def test_stack_size_does_not_change_results(kind, tracers):
    """Bit-identical hits for stacks of 1, 2, 4 and 32 entries on trees deep enough that
    small stacks restart (counted by the STATS build of the kernel), for random rays,
    rays in split planes and rays through vertices (where split planes cross)."""
    tree = deep_tree() if kind == "median" else mesh_tree("teapot.obj", "sah")
    assert tree.depth >= 16
    o, d = random_rays(tree, 2001, seed=11, inside=0.5)
    o2, d2 = split_plane_rays(tree, 600, seed=12)
    o3, d3 = vertex_and_edge_rays(tree, seed=13)
    pick = np.random.default_rng(14).choice(len(d3), 2000, replace=False)
    o, d = np.concatenate([o, o2, o3[pick]]), np.concatenate([d, d2, d3[pick]])
    results = {}
    for size in (1, 2, 4, 32):
        hits, stats = tracers(tree, stack_size=size, packet=1)._trace(o, d, stats=True,
                                                                     t_min=surface_t_min(tree))
        results[size] = (hits, stats)
    restarts = {size: int(stats[:, 3].sum()) for size, (_, stats) in results.items()}
    assert restarts[1] > restarts[2] > restarts[4] > 0
    assert restarts[32] == 0
    base = results[32][0]
    for size in (1, 2, 4):
        hits = results[size][0]
        for field in ("t", "prim", "u", "v", "normal"):
            assert np.array_equal(getattr(hits, field), getattr(base, field), equal_nan=True), \
                (size, field)
    n = len(d) - len(pick)              # rays aimed at vertices: see test_watertight
    check_hits(base[:n], tree, o[:n], d[:n], t_min=surface_t_min(tree), frame="tree")


def packet_rays(tree, camera_size=67):
    """Every kind of ray the packet kernel must agree on, (origins, directions): a
    camera's (coherent, one origin), random ones (each lane its own origin and
    direction), rays in split planes, at vertices and edges, axis-parallel with signed
    zeros, and invalid ones (NaN, inf, zero direction) mixed in."""
    lo, hi = tree.origin + tree.bounds.astype(np.float64)
    from kdray import Camera
    cam = Camera.frame(lo, hi, camera_size, camera_size - 6)
    o1, d1 = cam.rays()
    o2, d2 = random_rays(tree, 3001, seed=21, inside=0.5)
    o3, d3 = split_plane_rays(tree, 500, seed=22)
    o4, d4 = vertex_and_edge_rays(tree, seed=23)
    o5, d5 = axis_rays(tree, 700, seed=24)
    o = np.concatenate([o1, o2, o3, o4[:3000], o5])
    d = np.concatenate([d1, d2, d3, d4[:3000], d5]).astype(np.float64)
    bad = np.random.default_rng(25).choice(len(d), 40, replace=False)
    d[bad[:10], 0] = np.nan
    d[bad[10:20]] = 0.0
    o[bad[20:30], 1] = np.inf
    d[bad[30:], 2] = -np.inf
    return o, d


LEAF_RULES = ["rule", "by triangle", "by ray", "never alone", "all alone"]
"""How test_packets_equal_single_rays has a packet test its leaves. Each forced rule is
two programs of its own (trace and render): `make test` runs the kernel's rule with
both packet widths, and with packets of 8 always triangle by triangle (culled) and never
alone (the only way packets whose origins diverge stay packets); `make test-long` the
others, always ray by ray and always alone: paths the rule itself takes on these rays
(leaves that few of a packet's lanes reach, packets whose origins diverge)."""
FAST_LEAF_RULES = {("rule", 8), ("rule", 16), ("by triangle", 8), ("never alone", 8)}


@pytest.mark.parametrize("kind", ["median", "sah"])
@pytest.mark.parametrize("leaf,packet", [
    pytest.param(leaf, packet, marks=[] if (leaf, packet) in FAST_LEAF_RULES else [pytest.mark.slow])
    for leaf in LEAF_RULES for packet in PACKETS])
def test_packets_equal_single_rays(packet, kind, leaf, tracers):
    """Packets of 8 or 16 rays in vector lanes (CPUs) give bit for bit what one ray per
    work-item gives, for coherent and incoherent rays, rays the packet hands to the
    scalar kernel (split planes, diverging origins) and invalid rays; also with t_min
    and t_max, for a camera render, and with a packet count that leaves lanes empty.
    Leaves tested by the kernel's rule, always triangle by triangle (a packet's rays
    against one triangle; a packet of one origin culls first) and always ray by ray
    (one ray against a packet's width of triangles) agree; so do packets whose rays
    are traced alone (each leaf a packet's width of triangles at a time) by the
    kernel's rule, never, and always."""
    tree = deep_tree() if kind == "median" else mesh_tree("teapot.obj", "sah")
    o, d = packet_rays(tree)
    single = tracers(tree, packet=1)
    packed = Tracer(tree, packet=packet)
    packed._lane_ratio = {"by triangle": 0.0, "by ray": np.inf}.get(leaf)
    packed._cull_lane_ratio = packed._lane_ratio
    packed._alone_spread = {"never alone": np.inf, "all alone": -1.0}.get(leaf)
    packed._alone_turn = {"never alone": np.inf}.get(leaf)
    for t_min, t_max in [(0.0, np.inf), (surface_t_min(tree), np.inf), (0.3, 2.5)]:
        a = single.trace(o, d, t_min=t_min, t_max=t_max)
        b = packed.trace(o, d, t_min=t_min, t_max=t_max)
        for field in ("t", "prim", "u", "v", "normal"):
            assert np.array_equal(getattr(a, field), getattr(b, field), equal_nan=True), \
                (t_min, t_max, field)
    assert 0.2 * len(d) < np.count_nonzero(a.hit) < 0.9 * len(d)
    camera = camera_for(tree, 61, 37)
    ra = single.render(camera, aovs="all")
    rb = packed.render(camera, aovs="all")
    for name in ra:
        assert np.array_equal(ra[name], rb[name], equal_nan=True), name


OWN_PATHS_FAST = {("rule", "median"), ("rule", "soup"), ("every packet alone", "soup"),
                  ("stack of 2", "soup")}
"""test_rays_on_their_own_paths_equal_single_rays's cases in `make test`: the rule on
two trees, every setting on the soup (each setting and tree is a program of its own);
the others in `make test-long`."""


@pytest.mark.parametrize("setting,kind", [
    pytest.param(setting, kind, marks=[] if (setting, kind) in OWN_PATHS_FAST else [pytest.mark.slow])
    for setting in ["rule", "every packet alone", "stack of 2"]
    for kind in ["median", "sah", "soup"]])
def test_rays_on_their_own_paths_equal_single_rays(kind, setting, tracers):
    """Rays that share no path (each lane its own origin, or one origin and diverging
    directions: kd_alone), and the lanes a packet hands over, walk the wide nodes two at
    a time (kernels/wide.cl): bit for bit what one ray a work-item gives, and the
    oracle's hits. Packets mix every kind of ray (shuffled: split planes and vertices
    beside random and invalid rays) and a count that leaves lanes empty; rays from one
    point in random directions. By the kernel's rule, with every packet alone, and with
    a packet stack of 2 (lanes leave a packet when its stack is full); in a deep tree,
    a mesh's and a soup's (triangles across many leaves, where a hit past a leaf's exit
    must not end a ray)."""
    tree = {"median": deep_tree, "sah": lambda: mesh_tree("teapot.obj", "sah"),
            "soup": lambda: sah_tree(*soup(7, m=2000))}[kind]()
    o, d = packet_rays(tree, camera_size=19)
    order = np.random.default_rng(31).permutation(len(d))
    o, d = o[order][:-5], d[order][:-5]
    lo, hi = tree.origin + tree.bounds.astype(np.float64)
    d_one = np.random.default_rng(32).normal(size=(2003, 3))
    o_one = np.tile(lo + (hi - lo) * np.array([0.4, 0.55, 0.5]), (len(d_one), 1))
    single = tracers(tree, packet=1)
    packed = Tracer(tree)
    if packed.packet == 1:
        pytest.skip("no packets on this device")
    packed._poison_outputs = True
    if setting == "every packet alone":
        packed._alone_spread = -1.0
    if setting == "stack of 2":
        packed.packet_stack_size = 2
    for rays in [(o, d), (o_one, d_one)]:
        a = single.trace(*rays)
        b = packed.trace(*rays)
        for field in ("t", "prim", "u", "v", "normal"):
            assert np.array_equal(getattr(a, field), getattr(b, field), equal_nan=True), field
    assert check_hits(b, tree, o_one, d_one) > len(d_one) // 2
    assert 0.2 * len(d) < np.count_nonzero(a.hit) < 0.9 * len(d)


@pytest.mark.parametrize("packet", [1, *PACKETS])
def test_rays_in_no_order_are_taken_in_one_with_the_same_hits(monkeypatch, packet, tracers):
    """Rays in no order of their own through a tree (kdray.ray_order, forced here for a
    small tree) are traced in the order of their octant and origin's cell, each ray's
    outputs written at its own index: bit for bit the hits taken as they come, with
    every output (each hit refined from the caller's rays, read through the order),
    within a t range, from one origin, from float32 arrays; every kind of ray mixed in
    (shuffled) and a count that leaves a packet short."""
    tree = mesh_tree("teapot.obj", "sah")
    o, d = packet_rays(tree, camera_size=19)
    shuffle = np.random.default_rng(33).permutation(len(d))
    o, d = o[shuffle][:-3], d[shuffle][:-3]
    tr = tracers(tree, packet=packet)
    if packet > 1 and tr.packet != packet:
        pytest.skip("no such packets on this device")
    one = o[0] if np.isfinite(o[0]).all() else tree.world_box()[0] - 1.0
    span = float(np.linalg.norm(np.subtract(*tree.world_box())))
    cases = [(o, d, 0.0, np.inf), (o, d, 0.2 * span, 0.7 * span), (one, d, 0.0, np.inf),
             (o.astype(np.float32), d.astype(np.float32), 0.0, np.inf)]
    outputs = ("t", "prim", "u", "v", "normal")
    plain = [tr.trace(a, b, t0, t1, outputs=("uv", "normal")) for a, b, t0, t1 in cases]
    taken = force_ray_order(monkeypatch, ktrace)
    tr._poison_outputs = True
    try:
        for (a, b, t0, t1), want in zip(cases, plain):
            got = tr.trace(a, b, t0, t1, outputs=("uv", "normal"))
            for field in outputs:
                assert np.array_equal(getattr(got, field), getattr(want, field),
                                      equal_nan=True), (field, t0)
        # rays converted on the host (float32, in the tree's frame: a GPU's way)
        on_host = Tracer(tree, packet=packet)
        on_host._rays_in_kernel = False
        want = on_host.trace(o, d, outputs=("uv", "normal"))
        assert taken.pop() is not None
        on_host._poison_outputs = True
        monkeypatch.setattr(ktrace, "ray_order", lambda *args: None)
        got = on_host.trace(o, d, outputs=("uv", "normal"))
        for field in outputs:
            assert np.array_equal(getattr(got, field), getattr(want, field), equal_nan=True)
    finally:
        tr._poison_outputs = False
    assert len(taken) == len(cases) and all(t is not None for t in taken)
    assert 0.2 * len(d) < np.count_nonzero(plain[0].hit) < 0.9 * len(d)


def test_which_rays_are_put_in_order(tracers):
    """kdray.ray_order: random rays, rays from outside the box and ambient-occlusion-like
    rays (points in turn, random directions) are in no order of their own and are
    sorted by octant, then by the Morton code of the cell where they enter the box (the
    origin's, inside it); a camera's rows, a lidar's sweep from one point and rays
    already in order are left as they come, as are too few rays and small trees. The
    order is a permutation, stable within a key; the device's keys are numpy's but
    where an entry lies within float rounding of a cell's side."""
    import kdray.ray_order as ro
    from kdray import Camera
    tree = mesh_tree("teapot.obj", "sah")
    tr = tracers(tree)
    rng = np.random.default_rng(41)
    lo, hi = tree.world_box()
    n = ro.ORDER_FROM + 77
    o = lo + (hi - lo) * rng.random((n, 3))
    d = rng.normal(size=(n, 3))
    o[::4] = 0.5 * (lo + hi) + 4 * (hi - lo) * rng.normal(size=(len(o[::4]), 3))
    d[::4] = lo + (hi - lo) * rng.random((len(o[::4]), 3)) - o[::4]    # into the box
    d[5], d[6], o[7] = [0.0, 1.0, 0.0], [0.0, 0.0, 0.0], np.nan      # axis, zero, NaN
    key = ro.ray_keys(o, d, lo, hi)
    octant = (d[:, 0] < 0) + 2 * (d[:, 1] < 0) + 4 * (d[:, 2] < 0)
    assert np.array_equal(key >> 12, octant)
    with np.errstate(all="ignore"):
        t = np.max(np.where(d < 0, hi - o, lo - o) / d, axis=1, initial=0.0)
        entry = o + np.where(np.isfinite(t), t, 0.0)[:, None] * d
        cell = np.clip(((entry - lo) / (hi - lo) * 16), 0, 15)
    inside = np.all((o >= lo) & (o <= hi), axis=1)
    cell = np.where(np.isfinite(cell), cell, 0).astype(int)
    for k in range(3):                          # bit b of axis k's cell at bit 3 b + k
        for b in range(4):
            assert np.array_equal(((key >> (3 * b + k)) & 1)[inside], ((cell[:, k] >> b) & 1)[inside])
    with np.errstate(all="ignore"):
        x = (entry - lo) / (hi - lo) * 16         # off an inner side of a cell by > 1e-3
        near = np.rint(x)
        clear = np.all((np.abs(x - near) > 1e-3) | (near <= 0) | (near >= 16), axis=1)
        enters = np.all((x > -1e-6) & (x < 16 + 1e-6), axis=1)
    outside = ~inside & clear & enters
    assert outside.sum() > n // 10                # rays from outside that enter the box
    assert np.array_equal(key[outside] & 0xFFF, ro.ray_keys(entry[outside], d[outside], lo, hi) & 0xFFF)
    # on the device, from float64 and float32 arrays and one origin
    for a, b, step in ((o, d, 1), (o.astype(np.float32), d.astype(np.float32), 1),
                       (o[:1], d, 0)):
        want = ro.ray_keys(a, b, lo, hi, step)
        got = ro.device_keys(tr, a, b, lo, hi, step)
        assert got.dtype == np.uint16 and np.mean(got == want) > 0.999
        assert np.array_equal(got >> 12, want >> 12)
    assert tr.device_bytes < ro.ORDER_TREE_BYTES
    assert ro.ray_order(tr, o, d, lo, hi) is None         # the teapot's tree is small
    keep = ro.ORDER_TREE_BYTES
    try:
        ro.ORDER_TREE_BYTES = 0
        order = ro.ray_order(tr, o, d, lo, hi)
        assert order is not None and order.dtype == np.uint32
        assert np.array_equal(np.sort(order), np.arange(n))
        got = ro.device_keys(tr, o, d, lo, hi)
        assert np.all(np.diff(got[order].astype(np.int64)) >= 0)
        same = got[order][1:] == got[order][:-1]
        assert np.all(np.diff(order.astype(np.int64))[same] > 0)       # stable
        # points in turn (a mesh's triangles in order), random directions
        walk = np.repeat(lo + (hi - lo) * rng.random((n // 8 + 1, 3)), 8, axis=0)[:n]
        assert ro.ray_order(tr, walk, d, lo, hi) is not None
        assert ro.ray_order(tr, o[:ro.ORDER_FROM - 1], d[:ro.ORDER_FROM - 1], lo, hi) is None
        # a camera's rows, a sweep from one point, rays already in order: as they come
        co, cd = Camera.frame(lo, hi, 512, 384).rays()      # 2^17 rays or more
        assert ro.ray_order(tr, co, cd, lo, hi) is None
        angle = np.linspace(0, 2 * np.pi, n)
        sweep = np.stack([np.cos(angle), np.sin(angle), 0.1 * np.ones(n)], axis=1)
        assert ro.ray_order(tr, 0.5 * (lo + hi)[None], sweep, lo, hi, 0) is None
        assert ro.ray_order(tr, o[order], d[order], lo, hi) is None
    finally:
        ro.ORDER_TREE_BYTES = keep


def test_rays_from_one_point_are_put_in_order_of_direction(tracers):
    """kdray.ray_order: rays from one point, or from points within CONCENTRATED of the
    box's longest side, are sorted by their directions' keys at any size of tree (from
    DIRECTION_ORDER_FROM rays): each key names a cell of a 256 x 256 grid over the
    octahedral map whose centre, mapped back to the sphere, lies within the cell's
    reach of the direction; a direction and its multiples share a key; the device's
    keys are numpy's but where a direction lies within float rounding of a cell's
    side. Rays from spread points keep the entry keys (and the tree-size rule), and a
    sweep from one point, already in order, is left as it comes."""
    import kdray.ray_order as ro
    tree = mesh_tree("teapot.obj", "sah")
    tr = tracers(tree)
    lo, hi = tree.world_box()
    rng = np.random.default_rng(47)
    n = ro.DIRECTION_ORDER_FROM + 77
    d = rng.normal(size=(n, 3))
    d[:6] = [[0, 0, 1], [0, 0, -1], [1, 0, 0], [0, -1, 0], [0, 0, 0], [np.nan, 0, 1]]
    key = ro.direction_keys(d)
    assert key.dtype == np.uint16
    assert np.array_equal(ro.direction_keys(d * rng.uniform(1e-3, 1e3, size=(n, 1))), key)
    # the key's cell (bits 2 b: column, 2 b + 1: row) mapped back by the inverse
    # octahedral map: its centre's direction is within the cell's reach of d's
    col = sum(((key.astype(np.int64) >> (2 * b)) & 1) << b for b in range(8))
    row = sum(((key.astype(np.int64) >> (2 * b + 1)) & 1) << b for b in range(8))
    u, v = (col + 0.5) / 128 - 1, (row + 0.5) / 128 - 1
    w = 1 - np.abs(u) - np.abs(v)
    back = np.stack([np.where(w < 0, (1 - np.abs(v)) * np.sign(u), u),
                     np.where(w < 0, (1 - np.abs(u)) * np.sign(v), v), w], axis=1)
    back /= np.linalg.norm(back, axis=1)[:, None]
    unit = d[6:] / np.linalg.norm(d[6:], axis=1)[:, None]
    angle = np.arccos(np.clip(np.sum(unit * back[6:], axis=1), -1, 1))
    assert angle.max() < 0.03                     # a cell spans at most ~0.017 rad
    # +z at the map's centre (cell 128, 128), -z folded to its corner (255, 255), +x at
    # the middle of its right side (255, 128), -y of its bottom (128, 0)
    assert list(key[:4]) == [0xC000, 0xFFFF, 0xD555, 0x4000]
    # on the device, from float64 and float32 arrays
    for a in (d, d.astype(np.float32)):
        got = ro.device_keys(tr, lo[None], a, lo, hi, 0, keys="direction")
        assert got.dtype == np.uint16 and np.mean(got == key) > 0.999
    # one origin, or origins within a cell: ordered by direction, though the tree is small
    centre = 0.5 * (lo + hi)
    near = centre + (hi - lo).max() * ro.CONCENTRATED / 2 * rng.uniform(-1, 1, size=(n, 3))
    assert tr.device_bytes < ro.ORDER_TREE_BYTES
    for o, step in ((centre[None], 0), (np.tile(centre, (n, 1)), 1), (near, 1)):
        assert ro.concentrated(o, d, lo, hi, step)
        order = ro.ray_order(tr, o, d, lo, hi, step)
        assert order is not None and np.array_equal(np.sort(order), np.arange(n))
        got = ro.device_keys(tr, o, d, lo, hi, step, keys="direction")
        assert np.all(np.diff(got[order].astype(np.int64)) >= 0)
        assert ro.ray_order(tr, o[:1] if step == 0 else o[:n - 100], d[:n - 100], lo, hi,
                            step) is None                     # too few
    spread = lo + (hi - lo) * rng.random((n, 3))
    assert not ro.concentrated(spread, d, lo, hi)
    assert not ro.concentrated(centre + 2 * (near - centre), d, lo, hi)   # twice as far
    assert ro.ray_order(tr, spread, d, lo, hi) is None        # small tree: as they come
    angle = np.linspace(0, 2 * np.pi, n)
    sweep = np.stack([np.cos(angle), np.sin(angle), 0.1 * np.ones(n)], axis=1)
    assert ro.ray_order(tr, centre[None], sweep, lo, hi, 0) is None


def _surface_points(v, f, n, rng):
    """(points (n, 3), unit normals (n, 3)) uniform by area on the triangles v[f] of
    nonzero area."""
    tri = v[f]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = np.linalg.norm(normal, axis=1)
    pick = rng.choice(len(f), size=n, p=area / area.sum())
    r = rng.random((n, 2))
    r[r.sum(axis=1) > 1] = 1 - r[r.sum(axis=1) > 1]
    a, b, c = tri[pick, 0], tri[pick, 1], tri[pick, 2]
    return a + r[:, :1] * (b - a) + r[:, 1:] * (c - a), normal[pick] / area[pick, None]


def test_rays_that_follow_their_origins_are_put_in_order_of_cell(tracers, monkeypatch):
    """kdray.ray_order: rays from points spread over a mesh whose directions follow their
    points (toward a point light, along the sun's direction, into the surface along its
    normals) are sorted by the 32^3 cell where they enter the box (`cell_keys`) at any
    size of tree, from FOLLOW_ORDER_FROM rays; rays from the same points in random
    directions, or in random directions about each normal (ambient occlusion), are
    not (`follow`). A key is the Morton code of the entry's cell; the device's keys are
    numpy's but where an entry lies within float rounding of a cell's side; rays
    already in that order are left as they come; and trace, occluded, count and
    intersections answer exactly as they do with the rays as they come."""
    import kdray.query_rays as kquery
    import kdray.ray_order as ro
    tree = mesh_tree("teapot.obj", "sah")
    tr = tracers(tree)
    v, f = mesh("teapot.obj")
    lo, hi = (np.asarray(b, dtype=np.float64) for b in tree.world_box())
    rng = np.random.default_rng(53)
    n = ro.FOLLOW_ORDER_FROM + 77
    p, normal = _surface_points(v, f, n, rng)
    light = 0.5 * (lo + hi) + 2 * (hi - lo) * np.array([0.3, 1.0, 0.6])
    random_d = rng.normal(size=(n, 3))
    ao = normal + random_d / np.linalg.norm(random_d, axis=1)[:, None]
    follow = {"point light": light - p, "sun": np.tile([0.3, 1.0, 0.6], (n, 1)),
              "normals": -normal}
    for name, d in {**follow, "random": random_d, "ambient occlusion": ao}.items():
        assert ro.follow(p, d, lo, hi) == (name in follow), name
    d = follow["point light"]
    o = p + 1e-6 * d
    key = ro.cell_keys(o, d, lo, hi)
    assert key.dtype == np.uint16 and key.max() < 1 << 15
    x = (o - lo) / (hi - lo) * 32                # every origin lies in the box
    cell = np.clip(np.floor(x), 0, 31).astype(np.int64)
    clear = np.all((np.abs(x - np.rint(x)) > 1e-6) | (np.rint(x) <= 0) | (np.rint(x) >= 32), axis=1)
    for k in range(3):                           # bit b of axis k's cell at bit 3 b + k
        for b in range(5):
            assert np.array_equal(((key >> (3 * b + k)) & 1)[clear], ((cell[:, k] >> b) & 1)[clear])
    # from outside the box: the cell where the ray enters it
    out_o = o + 3 * np.linalg.norm(hi - lo) * d / np.linalg.norm(d, axis=1)[:, None]
    with np.errstate(all="ignore"):
        t = np.max(np.where(-d < 0, hi - out_o, lo - out_o) / -d, axis=1, initial=0.0)
    entry = out_o - t[:, None] * d
    assert np.mean(ro.cell_keys(out_o, -d, lo, hi) == ro.cell_keys(entry, -d, lo, hi)) > 0.99
    for a, b, step in ((o, d, 1), (o.astype(np.float32), d.astype(np.float32), 1),
                       (o[:1], d, 0)):
        want = ro.cell_keys(a, b, lo, hi, step)
        got = ro.device_keys(tr, a, b, lo, hi, step, keys="cell")
        assert got.dtype == np.uint16 and np.mean(got == want) > 0.999
    assert tr.device_bytes < ro.ORDER_TREE_BYTES
    for name, d in follow.items():
        order = ro.ray_order(tr, p, d, lo, hi)
        assert order is not None and np.array_equal(np.sort(order), np.arange(n)), name
        got = ro.device_keys(tr, p, d, lo, hi, keys="cell")
        assert np.all(np.diff(got[order].astype(np.int64)) >= 0)
        same = got[order][1:] == got[order][:-1]
        assert np.all(np.diff(order.astype(np.int64))[same] > 0)       # stable
        assert ro.ray_order(tr, p[order], d[order], lo, hi) is None     # in order already
        assert ro.ray_order(tr, p[:n - 100], d[:n - 100], lo, hi) is None  # too few
    assert ro.ray_order(tr, p, random_d, lo, hi) is None     # small tree: as they come
    # the answers, ordered and as they come
    d = follow["point light"]
    t_max = np.full(n, 1.0)
    t_max[::7] = 0.5
    taken = []

    def answers():
        hits = tr.trace(o, d, 0.0, t_max)
        listed = tr.intersections(o, d, 0.0, t_max)
        return (hits.t, hits.prim, hits.u, hits.v, hits.normal,
                tr.occluded(o, d, 0.0, t_max), tr.count(o, d, 0.0, t_max),
                listed.offsets, listed.t, listed.prim, listed.u, listed.v)

    def spy(*args):
        taken.append(ro.ray_order(*args))
        return taken[-1]

    tr._poison_outputs = True
    try:
        monkeypatch.setattr(ktrace, "ray_order", spy)
        monkeypatch.setattr(kquery, "ray_order", spy)
        ordered = answers()
        assert taken and all(t is not None for t in taken)
        monkeypatch.setattr(ktrace, "ray_order", lambda *args: None)
        monkeypatch.setattr(kquery, "ray_order", lambda *args: None)
        as_they_come = answers()
    finally:
        tr._poison_outputs = False
    for a, b in zip(ordered, as_they_come):
        assert np.array_equal(a, b, equal_nan=True)
    assert 0.2 * n < np.count_nonzero(ordered[5]) < 0.9 * n


def test_order_keys_hold_far_from_the_origin(tracers):
    """kdray.ray_order's keys on the device are numpy's for a scene 1e6 from the world's
    origin, whose rays (float64, read as given) are taken relative to the box's corner
    in float64: a float32 corner, off by up to 0.03 there, moved the teapot's cells
    (60 % of the keys agreed)."""
    import kdray.ray_order as ro
    v, f = mesh("teapot.obj")
    tree = sah_tree(v + (1e6 + 1.0 / 3), f)          # a corner no float32 holds
    tr = tracers(tree)
    lo, hi = (np.asarray(b, dtype=np.float64) for b in tree.world_box())
    rng = np.random.default_rng(59)
    o = lo + (hi - lo) * rng.random((5001, 3))
    d = hi + (hi - lo) - o
    for keys, numpy_keys in (("cell", ro.cell_keys), ("entry", ro.ray_keys)):
        got = ro.device_keys(tr, o, d, lo, hi, keys=keys)
        assert np.mean(got == numpy_keys(o, d, lo, hi)) > 0.999, keys

def reversed_leaves(tree):
    """The same tree with every leaf's triangle list reversed (a valid tree, the same
    hits): the device's copies of each leaf then come in the other order."""
    leaf = layout.is_leaf(tree.nodes)
    n = layout.n_prims(tree.nodes)[leaf].astype(np.int64)
    off = layout.leaf_offset(tree.nodes)[leaf].astype(np.int64)
    start, count = np.repeat(off, n), np.repeat(n, n)
    at = start + np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
    leaf_tris = tree.leaf_tris.copy()
    leaf_tris[at] = tree.leaf_tris[2 * start + count - 1 - at]
    return dataclasses.replace(tree, leaf_tris=leaf_tris)


@pytest.mark.parametrize("packet", [1, *PACKETS])
def test_ties_go_to_the_lowest_input_id_in_any_device_order(packet):
    """The device keeps a copy of each triangle per leaf, in the leaves' order
    (layout.device_triangles); a tie in t still goes to the lowest input id, whatever
    that order: every triangle of the teapot twice (coincident copies, ids i and i + m),
    traced with every leaf's list reversed."""
    v, f = mesh("teapot.obj")
    m = len(f)
    tree = sah_tree(v, np.concatenate([f, f]))
    o, d = random_rays(tree, 1999, seed=31)
    base = Tracer(tree, packet=packet).trace(o, d)
    assert np.count_nonzero(base.hit) > 0.2 * len(d)
    assert np.all(base.prim[base.hit] < m)
    flipped = reversed_leaves(tree)
    flipped.validate()
    ids = [layout.device_triangles(t)[2].astype(np.int64) for t in (tree, flipped)]
    for a, b in zip(ids, ids[1:]):      # the copy of i + m comes first where i came first
        assert np.any((a[:-1] + m == a[1:]) & (b[:-1] == b[1:] + m))
    reversed_order = Tracer(flipped, packet=packet).trace(o, d)
    for field in ("t", "prim", "u", "v", "normal"):
        assert np.array_equal(getattr(base, field), getattr(reversed_order, field)), field


@pytest.mark.parametrize("run", [1, 8, 16])
def test_device_triangles_are_each_leafs_run(run):
    """device_triangles (and device_nodes alone): the device nodes are the tree's but
    for leaf offsets, each a multiple of `run`; leaf i's triangles are copies
    [leaf_offset, leaf_offset + n_prims) of the tree's, with their input ids; the rest of its last run, and
    nothing else, is padding (zeros, id MISS); device_sizes counts what it makes."""
    v, f = mesh("teapot.obj")
    tree = sah_tree(v, f)
    nodes, tris, ids = layout.device_triangles(tree, run)
    assert np.array_equal(layout.device_nodes(tree, run), nodes)     # without the copies
    assert nodes.dtype == np.uint32 and tris.dtype == np.float32 and ids.dtype == np.uint32
    assert len(tris) == len(ids) == layout.n_device_triangles(tree.nodes, run) >= len(tree.leaf_tris)
    assert layout.device_sizes(tree, run) == {"nodes": tree.nodes.nbytes,
                                             "triangles": layout.triangle_blocks(tris).nbytes,
                                             "triangle ids": ids.nbytes}
    leaf = layout.is_leaf(tree.nodes)
    assert np.array_equal(nodes[~leaf], tree.nodes[~leaf])
    assert np.array_equal(nodes[leaf, 0], tree.nodes[leaf, 0])
    if run == 1:
        assert len(tris) == len(tree.leaf_tris)
    listed_anywhere = np.zeros(len(tris), dtype=bool)
    for n, off, tree_off in zip(layout.n_prims(nodes)[leaf], layout.leaf_offset(nodes)[leaf],
                                layout.leaf_offset(tree.nodes)[leaf]):
        assert off % run == 0
        listed = tree.leaf_tris[tree_off:tree_off + n]
        assert np.array_equal(tris[off:off + n], tree.triangles[listed])
        assert np.array_equal(ids[off:off + n], tree.tri_ids[listed])
        listed_anywhere[off:off + n] = True
    assert not tris[~listed_anywhere].any()
    assert (ids[~listed_anywhere] == layout.MISS).all()
    assert (~listed_anywhere).sum() == len(tris) - len(tree.leaf_tris)


@pytest.mark.parametrize("packet", [1, pytest.param(8, marks=pytest.mark.slow),
                                    pytest.param(16, marks=pytest.mark.slow)])
def test_rays_converted_in_the_kernel(packet, tracers):
    """float64 and float32 rays shifted and rounded by trace_rays (RAYS_WORLD) give bit
    for bit what the host's conversion gives: rays near and far (1e6) from the tree's
    origin, one shared (3,) origin, NaN/inf and overflowing components, float32 input
    and mixed types. (Without refinement: refined hits take t, u, v from the rays
    themselves, below.) Four programs a packet width: `make test` runs one ray a
    work-item, `make test-long` packets too (in `make test` every other test traces
    float64 rays with the default packets, test_image_shaped_rays float32 origins and
    directions, test_rays_anywhere_in_memory both in float32)."""
    v, f = mesh("teapot.obj")
    shift = np.array([1e6, -3e5, 7.25e5])
    tree = sah_tree(v + shift, f)
    o, d = random_rays(tree, 2003, seed=29)      # world coordinates, near the teapot
    o, d = o.copy(), d.copy()
    o[5], d[6], d[7, 1], o[8, 2] = np.nan, np.inf, 1e300, -1e300
    in_kernel = tracers(tree, packet=packet, refine=False)
    if not in_kernel._rays_in_kernel:        # a GPU converts on the host unless it refines
        if not has_fp64(in_kernel.device):
            pytest.skip("no double precision on the device: rays are converted on the host")
        in_kernel = Tracer(tree, packet=packet, refine=False)
        in_kernel._rays_in_kernel = True
    on_host = Tracer(tree, packet=packet, refine=False)
    on_host._rays_in_kernel = False
    eye = tree.origin + np.array([0.1, -2.0, 0.3])
    with np.errstate(over="ignore"):
        cases = [(o, d), (eye, d), (o.astype(np.float32), d), (list(eye), d.astype(np.float32)),
                 (o[:1], d[:1]), (o[:0], d[:0])]
    for k, (oo, dd) in enumerate(cases):
        assert in_kernel._rays(oo, dd)[3] is not None, k      # float32 and float64 alike
        a, b = in_kernel.trace(oo, dd, t_min=1e-3), on_host.trace(oo, dd, t_min=1e-3)
        for field in ("t", "prim", "u", "v", "normal"):
            assert np.array_equal(getattr(a, field), getattr(b, field), equal_nan=True), (k, field)
    assert np.count_nonzero(in_kernel.trace(o, d).hit) > 0.2 * len(d)
    # refined from the double rays or from their float rounding: the same hits, t
    # within the rounding of the rays
    refined, from_float = tracers(tree, packet=packet), Tracer(tree, packet=packet)
    from_float._rays_in_kernel = False
    a, b = refined.trace(o, d, t_min=1e-3), from_float.trace(o, d, t_min=1e-3)
    assert np.array_equal(a.prim, b.prim) and np.array_equal(a.normal, b.normal)
    assert np.allclose(a.t, b.t, rtol=1e-5, equal_nan=True)


def test_huge_page_copy_equals_its_array_at_every_size():
    """host.huge_page_copy: the array's values, shape and dtype, C-contiguous, starting on
    a huge page where it holds one (and where Python can advise it), on a page
    otherwise; the input left as it was (a Fortran-ordered one too)."""
    import mmap
    from kdray.host import HUGE_PAGE, PAGE, huge_page_copy
    rng = np.random.default_rng(5)
    for n, dtype in [(0, np.float32), (7, np.uint32), (HUGE_PAGE // 8 - 1, np.float64),
                     (HUGE_PAGE // 4, np.float32), (3 * HUGE_PAGE // 4 + 5, np.uint32)]:
        a = (rng.random(n) * 1e6).astype(dtype)
        before = a.copy()
        c = huge_page_copy(a)
        assert c.dtype == a.dtype and c.shape == a.shape and c.flags.c_contiguous
        assert np.array_equal(c, a) and np.array_equal(a, before)
        big = a.nbytes >= HUGE_PAGE and hasattr(mmap, "MADV_HUGEPAGE")
        assert n == 0 or c.ctypes.data % (HUGE_PAGE if big else PAGE) == 0
        c[...] = 0                               # a copy, writable: not the input
        assert np.array_equal(a, before)
    f = np.asfortranarray(rng.random((300, 3)))
    assert np.array_equal(huge_page_copy(f), f)


def test_tree_buffers_live_in_the_hosts_memory_on_a_cpu(tracers):
    """On a CPU device a Tracer's tree buffers are host memory it keeps (huge-page
    copies, Tracer._tree_buffer), and traces through them give the hits of a Tracer
    whose buffers are the runtime's own copies."""
    from kdray.host import HUGE_PAGE
    tree = mesh_tree("teapot.obj", "sah")
    tracer = tracers(tree)
    if not tracer._zero_copy:
        pytest.skip("a GPU keeps device copies")
    for buf in (tracer._nodes, tracer._tris, tracer._tri_ids):
        host = buf.hostbuf
        assert host is not None and host.nbytes == buf.size
        if host.nbytes >= HUGE_PAGE:
            assert host.ctypes.data % HUGE_PAGE == 0
    o, d = random_rays(tree, 3001, seed=11)
    want = tracer.trace(o, d)
    copied = Tracer(tree)
    copied._tree_buffer = copied._buffer          # the runtime's copies
    copied._upload(tree)
    got = copied.trace(o, d)
    assert np.array_equal(want.prim, got.prim) and np.array_equal(want.t, got.t)


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_rays_anywhere_in_memory(dtype, tracers):
    """Ray arrays at any address give the hits of page-aligned copies: slices of larger
    arrays (origins and directions at different element offsets within a page) and
    arrays not even aligned to their element size. (On Intel's runtime the first are
    read in place from the start of their page, the others copied: _input_buffer.)
    An origin broadcast to every ray gives the hits of the (3,) origin. (Arrays from
    host.COPY_BELOW bytes on are used in place.)"""
    from kdray.host import COPY_BELOW
    from kdray.host import page_aligned_empty
    tree = mesh_tree("teapot.obj", "sah")
    o, d = random_rays(tree, 1001, seed=3)
    assert o.astype(dtype).nbytes >= COPY_BELOW
    tracer = tracers(tree)

    def placed(a, shift):
        """a (N, 3) as `dtype`, starting `shift` bytes after a page boundary"""
        raw = page_aligned_empty((a.nbytes + shift + 8,), np.uint8)
        out = np.ndarray(a.shape, dtype, buffer=raw, offset=shift)
        out[...] = a
        return out

    base = tracer.trace(placed(o, 0), placed(d, 0))
    assert np.count_nonzero(base.hit) > 0.2 * len(d)
    size = np.dtype(dtype).itemsize
    for o_shift, d_shift in [(size, 3 * size), (170 * size, 511 * size), (1, 3), (0, 4095)]:
        oo, dd = placed(o, o_shift), placed(d, d_shift)
        assert oo.ctypes.data % 4096 == o_shift
        for hits in (tracer.trace(oo, dd), tracer.trace(oo[7], dd[7:])):
            ref = base if len(hits) == len(d) else tracer.trace(placed(o[7], 0), placed(d[7:], 0))
            for field in ("t", "prim", "u", "v", "normal"):
                assert np.array_equal(getattr(hits, field), getattr(ref, field), equal_nan=True), \
                    (o_shift, d_shift, field)
    # one origin broadcast to every ray (stride 0, as camera_rays gives it) is read once
    eye = o[7].astype(dtype)
    shared = [tracer.trace(x, d.astype(dtype)) for x in
              (eye, np.broadcast_to(eye, d.shape), np.ascontiguousarray(np.broadcast_to(eye, d.shape)))]
    for hits in shared[1:]:
        for field in ("t", "prim", "u", "v", "normal"):
            assert np.array_equal(getattr(hits, field), getattr(shared[0], field), equal_nan=True), field


def test_small_arrays_copied_large_in_place_same_answers(tracers, monkeypatch):
    """On a CPU device a launch uses host arrays from host.COPY_BELOW bytes on in place
    (the buffer is the array) and copies smaller ones; every query gives the same
    answers bit for bit with all of them in place (and on pages) and all of them copied
    (and anywhere in memory), outputs poisoned first: 3001 rays (no multiple of a work
    size), and 100 (whose ray order, taken here however few they are, is small too)."""
    import math
    import kdray.host as khost
    import kdray.query_rays as kquery
    import kdray.ray_order as kray_order
    tree = mesh_tree("teapot.obj", "sah")
    tracer = tracers(tree)
    if not tracer._zero_copy:
        pytest.skip("a GPU copies every array")
    small, large = np.zeros(khost.COPY_BELOW // 8 - 1), np.zeros(khost.COPY_BELOW // 8)
    assert tracer._input_buffer(small)[0].hostbuf is None
    assert tracer._output_buffer(small).hostbuf is None
    assert tracer._input_buffer(large)[0].hostbuf is not None
    assert tracer._output_buffer(large).hostbuf is not None
    o, d = random_rays(tree, 3001, seed=5)
    t_max = np.linspace(0.5, 4.0, len(d))
    lo, hi = tree.world_box()
    points = np.random.default_rng(5).uniform(lo, hi, (3001, 3))
    taken = [force_ray_order(monkeypatch, ktrace), force_ray_order(monkeypatch, kquery)]

    def answers():
        out = []
        for n in (len(d), 100):
            hits = tracer.trace(o[:n], d[:n], outputs=("uv", "normal"))
            lists = tracer.intersections(o[:n], d[:n], t_max=t_max[:n])
            near = tracer.closest_points(points[:n])
            out += [hits.t, hits.prim, hits.u, hits.v, hits.normal,
                    tracer.occluded(o[:n], d[:n], t_max=t_max[:n]), tracer.count(o[:n], d[:n]),
                    lists.offsets, lists.t, lists.prim, lists.u, lists.v,
                    tracer.contains(points[:n]), near.distance, near.point, near.prim]
        return out

    def off_page(shape, dtype):
        """an array used in place that starts 4 bytes past a page (a caller's might)"""
        raw = khost.page_aligned_empty((math.prod(shape) * np.dtype(dtype).itemsize + 4,),
                                       np.uint8)
        return np.ndarray(shape, dtype, buffer=raw, offset=4)

    tracer._poison_outputs = True
    try:
        monkeypatch.setattr(khost, "COPY_BELOW", 0)
        in_place = answers()
        # the orders' arrays off their page, in place: read from their start
        with monkeypatch.context() as m:
            m.setattr(kray_order, "page_aligned_empty", off_page)
            off = answers()
        monkeypatch.setattr(khost, "COPY_BELOW", 1 << 62)
        copied = answers()
    finally:
        tracer._poison_outputs = False
    for orders in taken:                          # trace's and the queries' orders
        assert any(order is not None and len(order) == 100 for order in orders)
        assert any(order is not None and order.ctypes.data % khost.PAGE for order in orders)
    assert np.count_nonzero(in_place[1] != MISS) > 0.2 * len(d)
    for k, (a, b, c) in enumerate(zip(in_place, copied, off)):
        assert a.dtype == b.dtype and np.array_equal(a, b, equal_nan=True), k
        assert np.array_equal(a, c, equal_nan=True), k


def test_trace_outputs_leave_out_what_is_not_asked(tracers):
    """trace(outputs=) computes only what it is asked besides t and prim, and what it
    computes is what the full trace gives; precision="double" too. Unknown names are
    a KdrayError."""
    tree = mesh_tree("teapot.obj", "sah")
    o, d = random_rays(tree, 1003, seed=5)
    tracer = tracers(tree)
    full = tracer.trace(o, d)
    assert np.count_nonzero(full.hit) > 0.2 * len(d)
    for outputs in [(), ("uv",), ("normal",), "normal", ("normal", "uv")]:
        hits = tracer.trace(o, d, outputs=outputs)
        asked = {outputs} if isinstance(outputs, str) else set(outputs)
        assert np.array_equal(hits.t, full.t) and np.array_equal(hits.prim, full.prim)
        for name, fields in (("uv", ("u", "v")), ("normal", ("normal",))):
            for field in fields:
                value = getattr(hits, field)
                if name in asked:
                    assert np.array_equal(value, getattr(full, field)), (outputs, field)
                else:
                    assert value is None, (outputs, field)
    with pytest.raises(KdrayError, match="unknown trace outputs"):
        tracer.trace(o, d, outputs=("depth",))
    for outputs in (None, 1):                    # no names: kdray's error, not Python's
        with pytest.raises(KdrayError, match="outputs must be names"):
            tracer.trace(o, d, outputs=outputs)
    with pytest.raises(KdrayError, match="refine must be True or False"):
        Tracer(tracer.tree, refine="no")
    # the kernels' 32-bit batch counter: 2^32 rays a batch added nothing (an endless
    # kernel), more than 2^30 in all could wrap
    step = tracer.local_size * tracer.packet
    for batch, groups in ((2 ** 32 // step * step, 1), ((2 ** 20 // step + 1) * step, 1024)):
        with pytest.raises(KdrayError, match=r"at most 2\^30"):
            Tracer(tracer.tree, batch_size=batch, groups=groups)
    from kdray.builder import build
    tracer64 = tracers(build(*mesh("teapot.obj"), keep_double=True))
    full = tracer64.trace(o, d, precision="double")
    hits = tracer64.trace(o, d, precision="double", outputs=())
    assert np.array_equal(hits.t, full.t) and np.array_equal(hits.prim, full.prim)
    assert hits.u is None and hits.v is None and hits.normal is None and full.u.dtype == np.float64


def test_packet_stats_count_the_same_work(tracers):
    """On coherent camera rays a packet's lanes visit the nodes and leaves the single
    rays visit (lanes are masked to their own), and restarts never happen."""
    tree = mesh_tree("teapot.obj", "sah")
    o, d = camera_for(tree, 64, 48).rays()
    _, s1 = tracers(tree, packet=1)._trace(o, d, stats=True)
    for packet in PACKETS:
        _, sp = tracers(tree, packet=packet)._trace(o, d, stats=True)
        assert np.array_equal(s1[:, :3], sp[:, :3]), packet
        assert sp[:, 3].sum() == 0


def test_default_stack_size(tracers):
    """depth + 1 entries rounded up to 8, 16, 32 or 64: few program variants."""
    from types import SimpleNamespace
    tree = deep_tree()
    assert tracers(tree).stack_size == default_stack_size(tree) == 32 >= tree.depth + 1
    sizes = [default_stack_size(SimpleNamespace(depth=depth)) for depth in (0, 7, 8, 15, 16, 31, 32, 63)]
    assert sizes == [8, 8, 16, 16, 32, 32, 64, 64]
    with pytest.raises(KdrayError):
        Tracer(tree, stack_size=0)
    with pytest.raises(KdrayError):
        Tracer(tree, stack_size=65)


def test_rays_per_launch():
    """Launches are sized to the device's memory left beside the tree, each buffer to
    its largest allocation, at most MAX_RAYS_PER_LAUNCH rays; 0 when not one ray fits."""
    from kdray.device_tree import MAX_RAYS_PER_LAUNCH, rays_per_launch
    MiB = 2**20
    widths = [12, 12, 4, 8, 12, 4]                      # float o, d; T, UV, NORMAL, ID
    assert rays_per_launch(64 * 2**30, 16 * 2**30, 100 * MiB, widths) == MAX_RAYS_PER_LAUNCH
    n = rays_per_launch(128 * MiB, 128 * MiB, 10 * MiB, widths)
    assert n == (118 * MiB) // 52
    assert rays_per_launch(128 * MiB, MiB, 10 * MiB, widths) == MiB // 12
    assert rays_per_launch(128 * MiB, 128 * MiB, 128 * MiB - 51, widths) == 0
    assert rays_per_launch(128 * MiB, 128 * MiB, 0, [640 * 4], cap=7) == 7


# -- precision far from the origin --------------------------------------------------------

def test_far_from_origin(tracers):
    """The teapot moved by 1e6 (and its rays with it) traces as accurately as at 0."""
    v, f = mesh("teapot.obj")
    shift = np.array([1e6, -1e6, 1e6])
    near_tree, far_tree = sah_tree(v, f), sah_tree(v + shift, f)
    assert np.all(np.abs(far_tree.origin) > 9e5)
    o, d = random_rays(near_tree, 1501, seed=13)
    near = tracers(near_tree).trace(o, d)
    far = tracers(far_tree).trace(o + shift, d)
    n_hit = check_hits(far, far_tree, o + shift, d)
    assert n_hit > 500
    both = (near.prim != MISS) & (far.prim == near.prim)
    assert both.sum() > 0.99 * n_hit
    assert np.allclose(far.t[both], near.t[both], rtol=RTOL_T)


# -- zero direction components, rays in split planes ---------------------------------------

def axis_rays(tree, n, seed):
    """Rays parallel to an axis (two components +0.0 or -0.0), in both senses."""
    rng = np.random.default_rng(seed)
    lo = tree.bounds[0].astype(np.float64) + tree.origin
    hi = tree.bounds[1].astype(np.float64) + tree.origin
    o = lo + rng.random((n, 3)) * (hi - lo)
    axis = rng.integers(3, size=n)
    sign = rng.choice([-1.0, 1.0], size=n)
    d = np.where(rng.random((n, 3)) < 0.5, 0.0, -0.0)
    d[np.arange(n), axis] = sign * rng.uniform(0.5, 2.0, size=n)
    # start outside the box, on the far side of the travel
    o[np.arange(n), axis] = np.where(sign > 0, lo[axis] - 1.0, hi[axis] + 1.0)
    return o, d


def surface_t_min(tree):
    """A t_min (for unit directions) that leaves out hits on a surface the ray starts
    on, whose sign is a matter of rounding."""
    return 1e-5 * float(np.linalg.norm(tree.bounds[1].astype(np.float64) - tree.bounds[0]))


def test_axis_parallel_rays_signed_zeros(tracers):
    tree = mesh_tree("fandisk.obj", "sah")
    o, d = axis_rays(tree, 801, seed=14)
    hits = tracers(tree).trace(o, d)
    assert check_hits(hits, tree, o, d, frame="tree") > 200
    # flipping the sign of the zero components changes nothing
    flipped_d = np.where(d == 0, -d, d)
    assert np.array_equal(np.signbit(flipped_d) != np.signbit(d), d == 0)
    flipped = tracers(tree).trace(o, flipped_d)
    assert np.array_equal(flipped.prim, hits.prim) and np.array_equal(flipped.t, hits.t)


@pytest.mark.parametrize("kind", ["sah", "median"])
def test_rays_in_split_planes(kind, tracers):
    tree = mesh_tree("fandisk.obj" if kind == "sah" else "teapot.obj", kind)
    o, d = split_plane_rays(tree, 701, seed=15)
    # most rays really start on their plane in the tracer's float32 coordinates
    o32 = (o - tree.origin).astype(np.float32)
    splits = layout.split(tree.nodes)[~layout.is_leaf(tree.nodes)]
    on_plane = np.isin(o32, splits).any(axis=1)
    assert on_plane.mean() > 0.9
    assert (on_plane & (d == 0).any(axis=1)).mean() > 0.5
    t_min = surface_t_min(tree)
    hits = tracers(tree).trace(o, d, t_min=t_min)
    assert check_hits(hits, tree, o, d, t_min=t_min, frame="tree") > 100


def test_in_plane_ray_sees_both_sides(tracers):
    """A ray in the plane z = 0 of the root's split, with one wall below the plane and
    one above it, each touching the plane with an edge and listed on its side only; an
    inner split makes a short stack overflow. Both walls must be found from either end,
    whatever the stack size."""
    wall = lambda x, z0, z1: [[[x, -1, z0], [x, 1, z0], [x, 1, z1]], [[x, -1, z0], [x, 1, z1], [x, -1, z1]]]
    tris = np.array(wall(1.0, -1.0, 0.0) + wall(2.0, 0.0, 1.0), dtype=np.float32)
    # root: z = 0; below: x = 1.5 split (wall at x = 1 left); above: leaf with the x = 2 wall
    nodes = np.concatenate([
        layout.make_interior([2], [0.0], [4]),
        layout.make_interior([0], [1.5], [3]),
        layout.make_leaf([2], [0]),
        layout.make_leaf([0], [0]),
        layout.make_leaf([2], [2]),
    ])
    from kdray.tree import BuildParams, KdTree
    tree = KdTree(nodes=nodes, leaf_tris=np.array([0, 1, 2, 3], dtype=np.uint32), triangles=tris,
                  tri_ids=np.arange(4, dtype=np.uint32), origin=np.zeros(3),
                  bounds=np.array([[0, -1, -1], [3, 1, 1]], dtype=np.float32), n_input_tris=4,
                  depth=2, params=BuildParams(max_depth=2).resolved(4))
    tree.validate()
    o = np.array([[0.0, 0.3, 0.0], [3.0, -0.2, 0.0], [0.0, 0.3, 0.0], [3.0, -0.2, 0.0]])
    d = np.array([[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [1.0, 0.0, -0.0], [-1.0, 0.0, -0.0]])
    for size in (1, 2, 3):
        hits = tracers(tree, stack_size=size).trace(o, d)
        assert hits.t.tolist() == [1.0, 1.0, 1.0, 1.0], size
        assert set(hits.prim[[0, 2]]) <= {0, 1} and set(hits.prim[[1, 3]]) <= {2, 3}
    check_hits(hits, tree, o, d)


def test_bad_rays_miss(tracers):
    """Zero, NaN and infinite directions or origins miss instead of hanging or hitting."""
    tree = mesh_tree("teapot.obj", "sah")
    c = tree.origin
    o = np.array([c, c, c, c + np.nan, c + np.inf, c - 10])
    d = np.array([[0, 0, 0], [np.nan, 1, 0], [np.inf, 0, 0], [0, 0, 1], [0, 0, 1], [0, 0, 0]])
    hits = tracers(tree).trace(o, d)
    assert np.all(hits.prim == MISS) and np.all(np.isposinf(hits.t))


@pytest.mark.parametrize("packet", [1, pytest.param(8, marks=pytest.mark.slow), 16])
def test_image_shaped_rays(monkeypatch, packet, tracers):
    """Rays shaped (H, W, 3) or (B, H, W, 3), which trace_rays takes in packets of 4 x
    packet / 4 pixels, give the hits of the same rays in (N, 3) rows bit for bit, shaped
    as the rays (normal (..., 3)), every poisoned output written: sizes that no block
    fits, one origin or one a ray, float32 and float64, several launches of whole bands
    of blocks, and a band wider than a launch (traced in rows). Packets of 8 in
    `make test-long` (those of 16 share their programs with the other tests on an
    AVX-512 CPU); in `make test` test_runtimes.py's work sizes trace an image 13 wide
    in packets of 8 on every CPU runtime."""
    import kdray.device_tree
    tree = mesh_tree("spot.obj", "sah")
    tr = tracers(tree, packet=packet)
    tr._poison_outputs = True
    rng = np.random.default_rng(5)
    for (w, h), max_rays in [((1, 1), None), ((7, 3), None), ((65, 9), None),
                             ((13, 11), 120), ((13, 11), 50)]:
        if max_rays:
            monkeypatch.setattr(kdray.device_tree, "MAX_RAYS_PER_LAUNCH", max_rays)
        cam = camera_for(tree, w, h)
        eye, d = tr.camera_rays(cam)
        o = eye + rng.normal(scale=1e-3, size=d.shape)        # an origin a ray
        d64 = d.astype(np.float64)
        for oo, dd in [(o, d), (eye[0], d64), (o.astype(np.float32), d64)]:
            rows, _ = tr._trace(oo, dd)        # (N, 3) rays in rows: no search for an image
            shaped = oo if oo.shape == (3,) else oo.reshape(h, w, 3)
            image = tr.trace(shaped, dd.reshape(h, w, 3))
            for field in ("t", "prim", "u", "v", "normal"):
                got, want = getattr(image, field), getattr(rows, field)
                assert got.shape == (h, w) + want.shape[1:], (w, h, field)
                assert np.array_equal(got.reshape(want.shape), want, equal_nan=True), (w, h, field)
        # a batch of images: the second the first upside down
        both = np.stack([d.reshape(h, w, 3), d.reshape(h, w, 3)[::-1]])
        hits = tr.trace(np.stack([o.reshape(h, w, 3), o.reshape(h, w, 3)[::-1]]), both)
        assert hits.t.shape == (2, h, w) and hits.normal.shape == (2, h, w, 3)
        assert np.array_equal(hits.prim[1], hits.prim[0][::-1])
        assert np.array_equal(hits.t[1], hits.t[0][::-1], equal_nan=True)
        assert np.array_equal(hits.prim[0].ravel(), tr.trace(o, d).prim)
        monkeypatch.undo()
    assert np.count_nonzero(hits.hit) > 0.1 * hits.hit.size
    # outputs left out stay None; the object lookup keeps the shape
    hits = tr.trace(eye[0], d.reshape(h, w, 3), outputs=())
    assert hits.u is None and hits.normal is None and hits.object.shape == (h, w)
    tr._poison_outputs = False


def spy_image_widths(monkeypatch, tr):
    """(widths, the real _trace): every later Tracer._trace call of `tr` appends the
    image_w it was given to the list widths."""
    widths = []
    real_trace = tr._trace

    def spy(*args, image_w=0, **kwargs):
        widths.append(image_w)
        return real_trace(*args, image_w=image_w, **kwargs)
    monkeypatch.setattr(tr, "_trace", spy)
    return widths, real_trace


@pytest.mark.parametrize("packet", [1, *PACKETS])
def test_rows_of_an_image_are_traced_in_blocks(monkeypatch, packet, tracers):
    """(N, 3) rays that are a camera's image in rows are traced as that image (in
    blocks, with packets) and give the hits of rows bit for bit, every poisoned
    output written; an image narrower than ray_grid.MIN_WIDTH is found as a grid of
    a few of its rows; random rays stay rows; with packets of 1 nothing is looked
    for. The search starts at IMAGE_SEARCH_MIN_RAYS rays: 0 here, so that small images
    take it; at the default a small image stays rows."""
    tree = mesh_tree("spot.obj", "sah")
    tr = tracers(tree, packet=packet)
    default_min_rays = ktrace.IMAGE_SEARCH_MIN_RAYS
    monkeypatch.setattr(ktrace, "IMAGE_SEARCH_MIN_RAYS", 0)
    tr._poison_outputs = True
    widths, _ = spy_image_widths(monkeypatch, tr)
    hit = total = 0
    for w, h in [(37, 21), (64, 5), (9, 40)]:
        eye, d = tr.camera_rays(camera_for(tree, w, h))
        image = tr.trace(eye, d)
        rows, _ = tr._trace(eye, d)            # rows: trace's search for an image skipped
        found, rows_w = widths[-2:]
        assert rows_w == 0
        # a grid as wide as the image, or (narrower than 16) as a few of its rows
        assert (found == 0) if packet == 1 else (found >= 16 and found % w == 0), (w, h, found)
        for field in ("t", "prim", "u", "v", "normal"):
            assert np.array_equal(getattr(image, field), getattr(rows, field), equal_nan=True)
        hit += np.count_nonzero(image.hit)
        total += len(image)
    assert hit > 0.1 * total
    o, d = random_rays(tree, 4096, seed=6)
    tr.trace(o, d)
    assert widths[-1] == 0
    # the default: an image of fewer rays than IMAGE_SEARCH_MIN_RAYS stays rows
    monkeypatch.setattr(ktrace, "IMAGE_SEARCH_MIN_RAYS", default_min_rays)
    eye, d = tr.camera_rays(camera_for(tree, 37, 21))
    assert len(d) < default_min_rays
    tr.trace(eye, d)
    assert widths[-1] == 0
    tr._poison_outputs = False


@pytest.mark.parametrize("packet", PACKETS)
def test_a_stale_image_width_changes_no_hit(monkeypatch, packet):
    """(N, 3) rays of a count traced before are traced at once as the image width
    found for that count, and searched for again while the kernel runs (trace.py,
    _image_width): an image of another width with the same count gives the hits of
    rows bit for bit, and the next call uses its own width. Random rays fail the quick
    check (ray_grid.rows_coherent) and are rows at once, the width kept for the count
    left as it was, so that a camera's rays traced between random ones of the same
    count keep theirs."""
    tree = mesh_tree("spot.obj", "sah")
    tr = Tracer(tree, packet=packet)
    monkeypatch.setattr(ktrace, "IMAGE_SEARCH_MIN_RAYS", 0)
    tr._poison_outputs = True
    widths, real_trace = spy_image_widths(monkeypatch, tr)
    wide = tr.camera_rays(camera_for(tree, 64, 30))
    narrow = tr.camera_rays(camera_for(tree, 48, 40))              # 1,920 rays each
    o, d = random_rays(tree, 1920, seed=8)
    for rays, used, kept in [(wide, 64, 64), (narrow, 64, 48), (narrow, 48, 48),
                             ((o, d), 0, 48), (narrow, 48, 48), ((o, d), 0, 48),
                             (wide, 48, 64), (wide, 64, 64)]:
        hits = tr.trace(*rays)
        assert widths[-1] == used
        assert tr._widths[1920] == kept
        rows, _ = real_trace(*rays)
        for field in ("t", "prim", "u", "v", "normal"):
            assert np.array_equal(getattr(hits, field), getattr(rows, field), equal_nan=True)
    assert np.count_nonzero(hits.hit) > 200


def test_input_checks(tracers):
    tree = mesh_tree("teapot.obj", "sah")
    tr = tracers(tree)
    with pytest.raises(KdrayError):
        tr.trace(np.zeros((3, 3)), np.ones((4, 3)))
    with pytest.raises(KdrayError):
        tr.trace(np.zeros((3, 2)), np.ones((3, 2)))
    with pytest.raises(KdrayError, match="directions"):
        tr.trace(np.zeros(3), np.ones(3))
    with pytest.raises(KdrayError, match="origins"):
        tr.trace(np.zeros((4, 2, 3)), np.ones((2, 4, 3)))
    with pytest.raises(KdrayError, match="origins"):
        tr.trace(np.zeros((8, 3)), np.ones((2, 4, 3)))
    # a single origin broadcasts; float32 input works
    hits = tr.trace(tree.origin - [0, 0, 10], np.array([[0, 0, 1]], dtype=np.float32))
    assert len(hits) == 1


# -- render ----------------------------------------------------------------------------------

def test_render_rays_match_host_rays(tracers):
    """Rays made on the device equal the host's: render == trace(camera_rays), bit for
    bit; and the depth agrees with float64 camera rays (Camera.rays) to 1e-5."""
    tree = mesh_tree("spot.obj", "sah")
    cam = camera_for(tree, 97, 61)
    tr = tracers(tree)
    images = tr.render(cam, aovs=("depth", "normal", "bary", "id"))
    o, d = tr.camera_rays(cam)
    hits = tr.trace(o, d)
    assert np.array_equal(images["depth"].ravel(), hits.t)
    assert np.array_equal(images["id"].ravel(), hits.prim)
    assert np.array_equal(images["normal"].reshape(-1, 3), hits.normal)
    assert np.array_equal(images["bary"].reshape(-1, 2), np.stack([hits.u, hits.v], 1))
    hit = hits.prim != MISS
    assert 0.1 < hit.mean() < 0.9
    # independent float64 rays: the same triangles almost everywhere, t equal to 1e-5
    o64, d64 = cam.rays()
    ref = tr.trace(o64, d64)
    same = hit & (ref.prim == hits.prim)
    assert same.sum() > 0.99 * hit.sum()
    assert np.allclose(images["depth"].ravel()[same], ref.t[same], rtol=RTOL_T)
    # and t is the z-depth: camera-z of the hit point
    p = o64[same] + hits.t[same, None].astype(np.float64) * d64[same]
    z = (p - cam.eye) @ cam.rotation[:, 2]
    assert np.allclose(z, hits.t[same], rtol=RTOL_T)


@pytest.mark.parametrize("packet", [1, 8])
def test_render_tiles_cover_every_pixel(monkeypatch, packet, tracers):
    """render takes pixels in 64 x 8 tiles: sizes that no tile, packet or launch fits
    (1 x 1, a width of 65, rows split over several launches, one row per launch) give
    every pixel exactly its own ray: outputs poisoned first, equal to trace(camera_rays)."""
    import kdray.device_tree
    tree = mesh_tree("spot.obj", "sah")
    tr = tracers(tree, packet=packet)
    tr._poison_outputs = True
    for (w, h), max_rays in [((1, 1), None), ((7, 3), None), ((65, 9), None),
                             ((130, 17), 600), ((97, 23), 50)]:
        if max_rays:
            monkeypatch.setattr(kdray.device_tree, "MAX_RAYS_PER_LAUNCH", max_rays)
        cam = camera_for(tree, w, h)
        images = tr.render(cam, aovs=("depth", "id", "bary"))
        hits = tr.trace(*tr.camera_rays(cam))
        assert np.array_equal(images["depth"].ravel(), hits.t), (w, h)
        assert np.array_equal(images["id"].ravel(), hits.prim), (w, h)
        assert np.array_equal(images["bary"].reshape(-1, 2), np.stack([hits.u, hits.v], 1))
        monkeypatch.undo()
    tr._poison_outputs = False


def test_render_aovs(tracers):
    tree = mesh_tree("teapot.obj", "sah")
    cam = camera_for(tree, 64, 48)
    tr = tracers(tree)
    everything = ("depth", "distance", "normal", "bary", "id", "position")
    images = tr.render(cam, aovs=everything)
    assert list(images) == list(everything)
    shapes = {"depth": (48, 64), "distance": (48, 64), "normal": (48, 64, 3),
              "bary": (48, 64, 2), "id": (48, 64), "position": (48, 64, 3)}
    for name, shape in shapes.items():
        assert images[name].shape == shape, name
        assert images[name].dtype == (np.uint32 if name == "id" else np.float32), name
    miss = images["id"] == MISS
    assert miss.any() and (~miss).any()
    assert np.all(np.isposinf(images["depth"][miss])) and np.all(np.isposinf(images["distance"][miss]))
    assert np.all(images["normal"][miss] == 0) and np.all(images["bary"][miss] == 0)
    assert np.all(np.isnan(images["position"][miss]))
    # distance = depth * |d|; position lies on the hit triangle, at that distance from the eye
    o, d = tr.camera_rays(cam)
    hit = ~miss.ravel()
    dist = images["distance"].ravel()[hit]
    assert np.allclose(dist, images["depth"].ravel()[hit] * np.linalg.norm(d[hit], axis=1), rtol=1e-6)
    pos = images["position"].reshape(-1, 3)[hit].astype(np.float64)
    assert np.allclose(np.linalg.norm(pos - cam.eye, axis=1), dist, rtol=1e-5)
    tri = trees.world_triangles(tree)[images["id"].ravel()[hit]]
    uv = images["bary"].reshape(-1, 2)[hit].astype(np.float64)
    p_bary = (1 - uv.sum(1))[:, None] * tri[:, 0] + uv[:, :1] * tri[:, 1] + uv[:, 1:] * tri[:, 2]
    scale = np.linalg.norm(tree.bounds[1] - tree.bounds[0])
    assert np.allclose(pos, p_bary, atol=1e-5 * scale)
    # a subset asks for less and gets the same values
    few = tr.render(cam, aovs=("id", "depth"))
    assert list(few) == ["id", "depth"]
    assert np.array_equal(few["id"], images["id"]) and np.array_equal(few["depth"], images["depth"])
    with pytest.raises(KdrayError):
        tr.render(cam, aovs=("depth", "albedo"))
    with pytest.raises(KdrayError):
        tr.render(cam, aovs=())


def test_render_compiles_only_what_is_asked():
    tree = mesh_tree("teapot.obj", "sah")
    tr = Tracer(tree)
    cam = camera_for(tree, 16, 8)
    tr.render(cam, aovs=("id",))
    (key,) = tr._programs
    defines = dict(key)
    assert "OUT_ID" in defines
    assert not {"OUT_T", "OUT_UV", "OUT_NORMAL", "STATS"} & set(defines)
    tr.render(cam, aovs=("id",))
    assert len(tr._programs) == 1                       # built once, reused
    tr.render(cam, aovs=("distance",))
    assert {k for k, _ in list(tr._programs)[1]} >= {"OUT_T"}
    assert not {"OUT_ID", "OUT_UV", "OUT_NORMAL"} & {k for k, _ in list(tr._programs)[1]}


def test_compile_builds_what_render_and_trace_use():
    """compile(aovs) builds and launches render's program for those AOVs: a render
    afterwards builds nothing; compile(trace=True) also builds trace's programs
    (float64 and float32 rays). What is traced after it is unchanged."""
    tree = mesh_tree("teapot.obj", "sah")
    tr = Tracer(tree)
    assert tr.compile(("depth", "id")) is tr
    (key,) = tr._programs
    assert {"OUT_T", "OUT_ID"} <= dict(key).keys()
    assert not {"OUT_UV", "OUT_NORMAL"} & dict(key).keys()
    cam = camera_for(tree, 24, 16)
    images = tr.render(cam, aovs=("id", "depth"))
    assert len(tr._programs) == 1
    tr.compile(trace=True)
    n = len(tr._programs)
    o, d = random_rays(tree, 101, seed=5)
    hits = tr.trace(o, d)
    tr.trace(o.astype(np.float32), d.astype(np.float32))
    assert len(tr._programs) == n
    fresh = Tracer(tree).trace(o, d)
    assert all(np.array_equal(getattr(hits, k), getattr(fresh, k), equal_nan=True)
               for k in ("t", "prim", "u", "v", "normal"))
    again = Tracer(tree).render(cam, aovs=("id", "depth"))
    assert all(np.array_equal(images[k], again[k]) for k in images)


def test_compile_for_other_stack_sizes():
    """compile(stack_sizes=...) also builds the programs of trees of those stack sizes
    (as `kdray setup` does), launched on this tree, and leaves the Tracer's own sizes
    and answers as they were; the wide walks' stack groups are shared by trees of
    different depths (wide.STACK_GROUPS)."""
    tree = mesh_tree("teapot.obj", "sah")
    tr = Tracer(tree)
    own = (tr.stack_size, tr.packet_stack_size)
    assert tr.compile(("depth",), stack_sizes=(8, 16)) is tr
    assert (tr.stack_size, tr.packet_stack_size) == own
    sizes = {dict(key)["STACK_SIZE"] for key in tr._programs}
    assert sizes == {own[0], 8, 16}
    if tr.packet > 1:
        assert {dict(key)["PACKET_STACK_SIZE"] for key in tr._programs} == {own[1], 8, 16}
        assert {dict(key).get("WIDE_STACK") for key in tr._programs} == {STACK_GROUPS[0]}
        other = Tracer(mesh_tree("spot.obj", "sah"))        # 4 levels; the teapot 5
        assert other._wide()[1] == tr._wide()[1] == STACK_GROUPS[0]
    cam = camera_for(tree, 24, 16)
    n = len(tr._programs)
    images = tr.render(cam, aovs=("depth",))
    assert len(tr._programs) == n                      # its own program came first
    again = Tracer(tree).render(cam, aovs=("depth",))
    assert np.array_equal(images["depth"], again["depth"])
