"""Ray queries beyond the nearest hit (kdray.rays, kernels/queries.cl) against
independent oracles: the float64 brute force (kdray.reference.all_hits), kdray's own
nearest hit (occluded is trace's hit, ray for ray), and geometry (a ray through a
convex closed mesh crosses it exactly twice, from inside once, whatever vertex or edge
it passes through)."""
import numpy as np
import pytest

from helpers import (RTOL_T, SCENES, camera_for, edge_distance, edge_midpoints,
                     force_ray_order, graze_tolerance, grid_cube, icosphere, random_rays,
                     real_mesh_arrays, split_plane_rays)
from kdray import ray_order as kray_order
from kdray import hit_lists, query_rays
from kdray import rays as krays
from kdray.builder import build
from kdray.errors import KdrayError
from kdray import layout
from kdray.layout import MISS
from kdray.load import load
from kdray.points import spatial_order
from kdray.reference import all_hits
from kdray.trace import PACKETS, Tracer
from kdray.tree import BuildParams, KdTree


@pytest.fixture(scope="module")
def teapot_tree():
    return build(*real_mesh_arrays("teapot.obj"))


def ranges(rng, n, t_hint):
    """Per-ray t ranges: some (0, inf), some cut around a typical t."""
    lo = np.where(rng.random(n) < 0.5, 0.0, rng.random(n) * t_hint)
    hi = np.where(rng.random(n) < 0.3, np.inf, lo + rng.random(n) * 2 * t_hint)
    return lo, hi


def poisoned_case(runtime, tree, n, seed):
    """(o, d, tracer): n seeded random rays (`random_rays`) and a Tracer on the
    runtime whose output buffers are poisoned before each launch."""
    o, d = random_rays(tree, n, seed=seed)
    tracer = Tracer(tree, device=runtime.spec)
    tracer._poison_outputs = True
    return o, d, tracer


def eye_image(tree, side):
    """(eye (3,), directions (side, side, 3)): an image's rays from one eye in front of
    the tree's box to a grid of points across its middle."""
    lo, hi = tree.world_box()
    g = np.linspace(0.05, 0.95, side)
    target = lo + (hi - lo) * np.stack(np.meshgrid(g, g, [0.5], indexing="ij"), -1)[:, :, 0]
    eye = lo + (hi - lo) * np.array([0.5, 0.5, -1.5])
    return eye, target - eye


def test_occluded_is_traces_hit(runtime, teapot_tree):
    tree = teapot_tree
    n = runtime.small(3001, 61)
    o, d, tracer = poisoned_case(runtime, tree, n, seed=3)
    for t_min, t_max in ((0.0, np.inf), (0.3, 0.9)):
        assert (tracer.occluded(o, d, t_min, t_max) == tracer.trace(o, d, t_min, t_max).hit).all()
    # per-ray ranges: any hit of the ray's (listed) hits inside its range
    lo, hi = ranges(np.random.default_rng(4), n, 0.5)
    occ = tracer.occluded(o, d, lo, hi)
    ref_ray, *_ = all_hits(tree.world(tree.triangles), o, d, lo, hi)
    expected = np.zeros(n, bool)
    expected[ref_ray] = True
    assert (occ != expected).mean() <= 0.002
    # image-shaped rays keep their shape
    assert tracer.occluded(o[:60].reshape(6, 10, 3), d[:60].reshape(6, 10, 3)).shape == (6, 10)


@pytest.mark.parametrize("packet", [None, 1])
def test_directions_too_short_to_invert_miss(runtime, teapot_tree, packet):
    """A direction whose largest component's float32 inverse overflows (every component
    below about 2^-128) misses, as a zero one does, in every query and path, and the
    other rays' answers are those of the same rays alone. Scaled by 1e-40, such rays
    crashed the process in packet programs: a wide walk's slab tests, NaN on every
    axis, took its nodes' empty slots for met and read a leaf at a garbage address.
    (tests/test_runtimes.py: rays just above that bound keep their hits.)"""
    tree = teapot_tree
    o, d = random_rays(tree, 64, seed=11)
    d = d / np.linalg.norm(d, axis=1)[:, None]
    tiny = d.copy()
    tiny[::3] *= 1e-40                   # every component subnormal in float32
    tiny[1::6] *= 1e-39
    mixed = d.copy()
    mixed[::4, 0] = 2.0 ** -120          # one component a normal number: a ray
    mixed[::4, 1:] *= 1e-40
    kw = {} if packet is None else {"packet": packet}
    tracer = Tracer(tree, device=runtime.spec, **kw)
    gone = np.zeros(len(d), bool)
    gone[::3] = gone[1::6] = True
    alone = tracer.trace(o[~gone], d[~gone])
    hits = tracer.trace(o, tiny)
    assert not hits.hit[gone].any()
    np.testing.assert_array_equal(hits.t[~gone], alone.t)
    np.testing.assert_array_equal(hits.prim[~gone], alone.prim)
    assert not tracer.occluded(o, tiny)[gone].any()
    assert not tracer.count(o, tiny)[gone].any()
    lists = tracer.intersections(o, tiny)
    assert not np.isin(np.flatnonzero(gone), lists.ray).any()
    np.testing.assert_array_equal(tracer.count(o, tiny)[~gone], tracer.count(o[~gone], d[~gone]))
    tracer.trace(o, mixed)              # answers of their own; no crash
    tracer.count(o, mixed)


def test_occluded_stops_at_any_hit_in_packets_and_lanes(runtime, teapot_tree):
    """occluded with one t range for all is trace's traversal stopping at the first hit
    it finds (ANY_HIT; rays that share no path through the wide nodes): rays from one
    origin as an image, given (H, W, 3) and flat, rays in split planes and random rays,
    in packets of each width, answer trace's hit."""
    tree = teapot_tree
    eye, image = eye_image(tree, runtime.small(96, 8))
    flat = image.reshape(-1, 3)
    o_r, d_r = random_rays(tree, runtime.small(2001, 61), seed=14)
    o_s, d_s = split_plane_rays(tree, runtime.small(500, 30), seed=15)
    packets = [1] if runtime.simulator else [1, *PACKETS]
    for packet in packets:
        tracer = Tracer(tree, device=runtime.spec, packet=packet)
        tracer._poison_outputs = True
        for t_min, t_max in ((0.0, np.inf), (0.5, 1.2)):
            for o, d in ((eye, image), (eye, flat), (o_r, d_r), (o_s, d_s)):
                want = tracer.trace(o, d, t_min, t_max).hit
                assert np.array_equal(tracer.occluded(o, d, t_min, t_max), want), packet
        # (the image looks at the teapot: some of its rays hit)
        assert tracer.occluded(eye, image).any()


@pytest.mark.parametrize("where", ["near", "far"])
def test_image_rays_read_as_given_answer_as_float32_copies(runtime, where, monkeypatch):
    """An image's rays are read by the query kernels as the caller gave them (float64 or
    float32, (N, 3) or one (3,) origin, a t range a ray or one for all; RAYS_WORLD),
    converted as the host converts them: count, crossings and every hit's t, u, v and
    triangle equal those of the same rays in reverse order (float32 copies made on the
    host), at scale 1 and for a tree far from the origin at a scale that is not 1
    (SCALE), and in launches of a few rows (taken in an order through the world box)."""
    v, f = real_mesh_arrays("teapot.obj")
    if where == "far":
        v = v * 2.0 ** 48 + np.array([3e15, -7e14, 1.5e15])     # beyond 2^40: scaled
    tree = build(v, f)
    tracer = Tracer(tree, device=runtime.spec)
    if tracer.packet == 1 or not tracer._rays_in_kernel:
        pytest.skip("image rays are walked in blocks by packet programs on CPUs")
    eye, image = eye_image(tree, 40)
    back = slice(None, None, -1)
    lo_box, hi_box = tree.world_box()
    lens = eye + 1e-3 * (hi_box - lo_box) * np.random.default_rng(6).random(image.shape)
    for o_given, d_given in ((eye, image), (lens, image),
                             (lens.astype(np.float32), image.astype(np.float32))):
        given = query_rays.QueryRays(tracer, o_given, d_given, 0.0, np.inf)
        rays = query_rays.as_image(tracer, given, o_given, d_given)
        assert rays.world and rays.image_w == 40
        d_flat = d_given.reshape(-1, 3)
        o_flat = np.broadcast_to(o_given, d_given.shape).reshape(-1, 3)
        lo, hi = ranges(np.random.default_rng(7), len(d_flat), 0.5)
        for t_min, t_max in ((0.0, np.inf), (lo.reshape(40, 40), hi.reshape(40, 40))):
            flat_lo = np.ravel(t_min) if np.ndim(t_min) else t_min
            flat_hi = np.ravel(t_max) if np.ndim(t_max) else t_max
            rev = (lambda a: a[back] if np.ndim(a) else a)
            assert np.array_equal(tracer.count(o_given, d_given, t_min, t_max).reshape(-1),
                                  tracer.count(o_flat[back], d_flat[back], rev(flat_lo),
                                               rev(flat_hi))[back])
            got = tracer.intersections(o_given, d_given, t_min, t_max)
            want = tracer.intersections(o_flat[back], d_flat[back], rev(flat_lo), rev(flat_hi))
            order = np.concatenate([np.arange(want.offsets[i], want.offsets[i + 1])
                                    for i in range(len(d_flat))[back]]).astype(np.int64)
            assert np.array_equal(got.counts.reshape(-1), want.counts[back])
            for name in ("t", "u", "v", "prim"):
                assert np.array_equal(getattr(got, name), getattr(want, name)[order]), name
    # unrefined, a hit's t is the float32 test's, which any other rounding of a ray
    # changes
    raw = Tracer(tree, device=runtime.spec, refine=False)
    got = raw.intersections(lens, image)
    want = raw.intersections(lens.reshape(-1, 3)[back], image.reshape(-1, 3)[back])
    assert np.array_equal(np.sort(got.t), np.sort(want.t))
    # launches of 3 rows: a launch's rays are no whole image, and each is taken in an
    # order of its own (forced here: ordered rays are left as they are), its keys
    # computed over the world box
    want = tracer.count(np.broadcast_to(eye, image.shape).reshape(-1, 3)[back],
                        image.reshape(-1, 3)[back])[back]
    monkeypatch.setattr(tracer, "_launch_size", lambda widths, *a, **k: 120)
    taken = force_ray_order(monkeypatch, query_rays)
    monkeypatch.setattr(kray_order, "unordered", lambda *a, **k: True)
    assert np.array_equal(tracer.count(eye, image).reshape(-1), want)
    assert any(t is not None for t in taken)


def test_hit_rows_on_the_device_are_numpys(runtime, teapot_tree):
    """intersections' rows gathered from the first pass's slots by kernels/hit_rows.cl
    equal numpy's take: rays with no hit, with several, runs that reach past the slots
    (read as the last one, as numpy's "clip"), first as uint32 (list_first's) and as an
    int64 view that does not start on a page (list_rays' offsets), counts that are not
    multiples of the work size; poisoned outputs."""
    tracer = Tracer(teapot_tree, device=runtime.spec)
    tracer._poison_outputs = True
    rng = np.random.default_rng(41)
    n, n_slots = runtime.small(5003, 77), runtime.small(9000, 150)
    counts = np.where(rng.random(n) < 0.6, 0, rng.integers(1, 6, n)).astype(np.int64)
    first = rng.integers(0, n_slots, n).astype(np.uint32)
    first[-3:] = n_slots - 2                   # runs past the end
    counts[-3:] = 5
    slots = (rng.random(n_slots).astype(np.float32), rng.random((n_slots, 2)).astype(np.float32),
             rng.integers(0, 1 << 30, n_slots).astype(np.uint32))
    offsets = hit_lists._offsets(counts)
    wide = np.concatenate([[7], first.astype(np.int64)])
    for f in (first, wide[1:]):
        got = hit_lists._rows_on_device(tracer, counts, offsets, f, slots)
        want = hit_lists._rows_on_host(tracer, counts, offsets, f, slots)
        assert all(np.array_equal(a, b) for a, b in zip(got, want))
    none = np.zeros(n, np.int64)
    assert [len(a) for a in hit_lists._rows_on_device(tracer, none, hit_lists._offsets(none), first,
                                                  slots)] == [0, 0, 0]


def test_intersections_match_brute_force(runtime, teapot_tree, monkeypatch):
    tree = teapot_tree
    n = runtime.small(2003, 41)
    o, d, tracer = poisoned_case(runtime, tree, n, seed=5)
    hits = tracer.intersections(o, d)
    assert hits.offsets[0] == 0 and hits.offsets[-1] == len(hits.t) and len(hits) == n
    same_ray = hits.ray[1:] == hits.ray[:-1]
    # sorted by t, ties by input id, each triangle once per ray
    step = np.diff(hits.t)[same_ray]
    assert (step >= 0).all()
    assert (np.diff(hits.prim.astype(np.int64))[same_ray][step == 0] > 0).all()
    # against every hit in float64, on the input triangles
    tri = tree.world(tree.triangles)
    by_id = np.empty_like(tri)
    by_id[tree.tri_ids] = tri
    ref_ray, ref_prim, ref_t, _, _ = all_hits(by_id, o, d)
    mine = set(zip(hits.ray.tolist(), hits.prim.tolist()))
    ref = set(zip(ref_ray.tolist(), ref_prim.tolist()))
    differ = np.array(sorted(mine ^ ref), dtype=np.int64).reshape(-1, 2)
    if len(differ):
        # only rays that graze an edge of the triangle in question, within rounding
        r, p = differ[:, 0], differ[:, 1]
        t_p = np.array([hits.t[(hits.ray == a) & (hits.prim == b)][0] if (a, b) in mine else
                        ref_t[(ref_ray == a) & (ref_prim == b)][0] for a, b in differ])
        near = edge_distance(by_id[p], o[r], d[r]) <= graze_tolerance(tree, by_id[p], o[r], d[r], t_p, "world")
        assert near.all(), differ[~near][:5]
        assert len(differ) <= max(2, 0.002 * len(ref))
    both = sorted(mine & ref)
    a = {k: i for i, k in enumerate(zip(hits.ray.tolist(), hits.prim.tolist()))}
    b = {k: i for i, k in enumerate(zip(ref_ray.tolist(), ref_prim.tolist()))}
    t_mine = hits.t[[a[k] for k in both]]
    t_ref = ref_t[[b[k] for k in both]]
    assert np.allclose(t_mine, t_ref, rtol=RTOL_T, atol=0)

    # max_hits=k: the first k of the whole list; k = 1 is trace's nearest hit
    for k in (1, 2):
        few = tracer.intersections(o, d, max_hits=k)
        counts = np.minimum(hits.counts, k)
        assert (few.counts == counts).all()
        keep = np.arange(len(hits.t)) - np.repeat(hits.offsets[:-1], hits.counts) < np.repeat(counts, hits.counts)
        assert (few.prim == hits.prim[keep]).all() and (few.t == hits.t[keep]).all()
    nearest = tracer.trace(o, d)
    first = tracer.intersections(o, d, max_hits=1)
    assert (first.counts == nearest.hit).all()
    assert (first.prim == nearest.prim[nearest.hit]).all()
    assert (first.t == nearest.t[nearest.hit]).all()

    # rays that all miss: no hit, nothing read back (the slots are read as far as the
    # first pass's hits go)
    away = tracer.intersections(o + 1e3 * d, d)
    assert away.offsets.tolist() == [0] * (n + 1) and len(away.t) == 0 and len(away) == n

    # the first pass's slots a ray (the rays with more listed again), the rays it
    # takes at once and the rays a launch takes (each launch's hits written from its
    # own counter, list_first) change nothing
    assert (hits.counts > 1).any()
    for guess, chunk, launch in ((1, 1 << 20, None), (2, 97, None), (4, 1 << 20, 37)):
        monkeypatch.setattr(hit_lists, "GUESS_HITS", guess)
        monkeypatch.setattr(hit_lists, "GUESS_CHUNK", chunk)       # in parts of 97 rays
        if launch:
            monkeypatch.setattr(tracer, "_launch_size", lambda widths, *a, **k: launch)
        again = tracer.intersections(o, d)
        for name in ("offsets", "t", "prim", "u", "v"):
            assert np.array_equal(getattr(again, name), getattr(hits, name)), (guess, name)
        few = tracer.intersections(o, d, max_hits=3)
        counts = np.minimum(hits.counts, 3)
        keep = np.arange(len(hits.t)) - np.repeat(hits.offsets[:-1], hits.counts) < np.repeat(counts, hits.counts)
        assert (few.counts == counts).all() and (few.prim == hits.prim[keep]).all()


def test_nearest_hits_end_their_walks_and_keep_the_whole_lists_first(runtime, teapot_tree,
                                                                     monkeypatch):
    """max_hits=k ends a ray's walk once its k slots are taken and the k-th hit is
    final (kd_list_done): the answer is still the whole list's first k, bit for bit, for
    an image's rays (packets), random rays (lanes), rays in the tree's split planes and
    the rays with more hits than the first pass's slots (listed again to their count),
    at each packet width; but where hits tie within float32 rounding at the k-th place
    (rays through an edge of two triangles), which the slots keep follows the walk's
    float32 t as trace's hit does, and the whole list orders them by their refined t.
    max_hits=1 is trace's hit."""
    tree = teapot_tree
    eye, image = eye_image(tree, runtime.small(48, 8))
    o_r, d_r = random_rays(tree, runtime.small(1500, 41), seed=23)
    o_s, d_s = split_plane_rays(tree, runtime.small(400, 30), seed=24)
    cases = [(eye, image.reshape(-1, 3)), (o_r, d_r), (o_s, d_s)]
    for packet in [1] if runtime.simulator else [1, *PACKETS]:
        tracer = Tracer(tree, device=runtime.spec, packet=packet)
        tracer._poison_outputs = True
        for o, d in cases:
            whole = tracer.intersections(o, d)
            assert (whole.counts > 3).any()
            for k, guess in ((1, 4), (3, 4), (3, 1), (6, 2)):
                monkeypatch.setattr(hit_lists, "GUESS_HITS", guess)
                few = tracer.intersections(o, d, max_hits=k)
                counts = np.minimum(whole.counts, k)
                rank = np.arange(len(whole.t)) - np.repeat(whole.offsets[:-1], whole.counts)
                keep = rank < np.repeat(counts, whole.counts)
                assert np.array_equal(few.counts, counts), (packet, k, guess)
                other = few.prim != whole.prim[keep]
                assert other.mean() <= 0.05, (packet, k, guess)   # edges: split planes
                assert np.allclose(few.t[other], whole.t[keep][other], rtol=1e-6, atol=0)
                for name in ("t", "prim", "u", "v"):
                    assert np.array_equal(getattr(few, name)[~other],
                                          getattr(whole, name)[keep][~other]), (packet, k, name)
                if k == 1:
                    hit = tracer.trace(o, d)
                    assert np.array_equal(few.prim, hit.prim[hit.hit])
                    assert np.array_equal(few.t, hit.t[hit.hit])


def test_rays_of_other_dtypes_refine_as_float64(runtime, teapot_tree):
    """Rays given as float16 or integers are the float64 rays of the same values: trace
    refines its hits from those (as the queries do), so its t, u and v are float64's bit
    for bit and max_hits=1 is its hit."""
    tracer = Tracer(teapot_tree, device=runtime.spec)
    o, d = random_rays(teapot_tree, runtime.small(4000, 40), seed=31)
    d16 = d.astype(np.float16)
    for oo, dd in ((o.astype(np.float16), d16), (np.round(o).astype(np.int32), d16),
                   (o, np.round(d * 8).astype(np.int16))):
        hit = tracer.trace(oo, dd)
        assert hit.hit.sum() > len(d) // 10
        exact = tracer.trace(oo.astype(np.float64), dd.astype(np.float64))
        for name in ("t", "prim", "u", "v", "normal"):
            assert np.array_equal(getattr(hit, name), getattr(exact, name)), name
        first = tracer.intersections(oo, dd, max_hits=1)
        for name in ("t", "prim", "u", "v"):
            assert np.array_equal(getattr(first, name), getattr(hit, name)[hit.hit]), name


def test_counts_are_exact_through_vertices_and_edges(runtime):
    """A ray into a convex closed mesh through any vertex or edge crosses it exactly
    twice; from inside, once; a ray grazing it (in a face's plane) an even number."""
    for v, f in (icosphere(2), grid_cube(2)):
        tree = build(v, f)
        tracer = Tracer(tree, device=runtime.spec)
        targets = np.concatenate([v, edge_midpoints(v, f)])
        if runtime.simulator:
            targets = targets[::max(1, len(targets) // 40)]
        # from outside, radially through the target and on through the centre
        c = tracer.count(3 * targets, -targets)
        assert (c == 2).all(), (c != 2).sum()
        # from the centre out through it
        assert (tracer.count(np.zeros(3), targets) == 1).all()
        # from a corner outside, through it (two crossings, or zero grazing)
        corner = np.array([5.0, 4.0, 3.0])
        c = tracer.count(corner, targets - corner)
        assert ((c == 2) | (c == 0)).all()
        # the count's rule in float64 agrees
        if not runtime.simulator:
            ref_ray, *_ = all_hits(v[f], np.broadcast_to(corner, targets.shape), targets - corner,
                                   crossing=True)
            assert (np.bincount(ref_ray, minlength=len(targets)) % 2 == c % 2).all()
    # axis-parallel rays along the grid cube's grid lines: in its faces' planes and
    # the tree's split planes
    v, f = grid_cube(2)
    tracer = Tracer(build(v, f), device=runtime.spec)
    g = np.arange(-2, 3, dtype=float)
    y, z = np.meshgrid(g, g, indexing="ij")
    o = np.stack([np.full(y.size, -5.0), y.ravel(), z.ravel()], axis=1)
    for axis in range(3):
        oo = np.roll(o, axis, axis=1)
        dd = np.roll(np.array([1.0, 0, 0]), axis)
        c = tracer.count(oo, np.broadcast_to(dd, oo.shape))
        interior = (np.abs(oo) < 2).sum(axis=1) == 2     # the other two coordinates inside
        assert (c[interior] == 2).all()
        assert (c % 2 == 0).all()


def test_count_parity_on_fandisk(runtime):
    v, f = real_mesh_arrays("fandisk.obj")
    tree = build(v, f)
    tracer = Tracer(tree, device=runtime.spec)
    rng = np.random.default_rng(7)
    lo, hi = v.min(axis=0), v.max(axis=0)
    n = runtime.small(60, 6)
    origins = lo + rng.random((n, 3)) * (hi - lo)
    # the reference's inside test: a generic direction, float64
    generic = rng.normal(size=(n, 3))
    ref_ray, *_ = all_hits(v[f], origins, generic, crossing=True)
    inside = np.bincount(ref_ray, minlength=n) % 2 == 1
    assert (tracer.count(origins, generic) % 2 == inside).all()
    # rays from each origin through vertices: the same parity
    targets = v[rng.choice(len(v), runtime.small(50, 5), replace=False)]
    o = np.repeat(origins, len(targets), axis=0)
    d = np.tile(targets, (n, 1)) - o
    c = tracer.count(o, d)
    assert (c % 2 == np.repeat(inside, len(targets))).all()


def test_contains_through_more_shells_than_the_kernel_keeps(runtime):
    """Points in spatial order (SORT_FROM or more) inside 34 nested cubes: rays from the
    innermost cross every shell, more than a ray's ids the kernel keeps (KD_SEEN), and
    are counted again from the list; the parity of the shells around each point."""
    v, f = grid_cube(1)
    k = 34
    shells = build(np.concatenate([v * (1 + 0.1 * i) for i in range(k)]),
                   np.concatenate([f + i * len(v) for i in range(k)]))
    tracer = Tracer(shells, device=runtime.spec)
    rng = np.random.default_rng(22)
    n = krays.SORT_FROM + 333
    p = np.concatenate([rng.uniform(-4.5, 4.5, (n - 50, 3)), rng.uniform(-0.9, 0.9, (50, 3))])
    around = (np.abs(p).max(axis=1)[:, None] < 1 + 0.1 * np.arange(k)).sum(axis=1)
    assert (around == k).sum() >= 50
    assert (tracer.contains(p) == (around % 2 == 1)).all()


def test_contains_and_windings_of_more_points_than_a_part(monkeypatch):
    """More points than POINT_CHUNK (2^30: the point order's uint32) are answered a part
    at a time, each part in its own spatial order: the same answers as at once."""
    mesh = load(SCENES / "sphere.obj")
    tracer = Tracer(build(mesh.vertices, mesh.faces))
    p = np.random.default_rng(4).uniform(-1.5, 1.5, (3 * krays.SORT_FROM + 17, 3))
    inside, windings = tracer.contains(p), krays.crossing_windings(tracer, p)
    assert 0 < inside.sum() < len(p)
    monkeypatch.setattr(krays, "POINT_CHUNK", krays.SORT_FROM + 5)
    assert krays.point_chunk(tracer) == krays.SORT_FROM + 5
    np.testing.assert_array_equal(tracer.contains(p), inside)
    np.testing.assert_array_equal(krays.crossing_windings(tracer, p), windings)
    assert tracer.contains(p.reshape(1, -1, 3)).shape == (1, len(p))
    # a device whose largest buffer or memory holds fewer points takes fewer a part
    from types import SimpleNamespace
    monkeypatch.setattr(krays, "POINT_CHUNK", 1 << 30)
    for alloc, memory, zero_copy, want in (
            (24 * 1000, 1 << 40, False, 1000), (1 << 40, 320 * 1000, False, 1000),
            (1 << 40, 320 * 1000, True, 1 << 30), (1 << 44, 1 << 46, False, 1 << 30)):
        device = SimpleNamespace(max_mem_alloc_size=alloc, global_mem_size=memory)
        assert krays.point_chunk(SimpleNamespace(device=device, _zero_copy=zero_copy)) == want


def test_contains_on_grids_through_vertices(runtime):
    """Points on a grid through every vertex of the grid cube and of a sphere, against
    the exact half-space test of a convex mesh; points on the cube's surface answer as
    if moved along their direction (contains_directions)."""
    v, f = grid_cube(2)
    tracer = Tracer(build(v, f), device=runtime.spec)
    # points taken as they come, and (from SORT_FROM on) in spatial order, each octant
    # of the box one run of one direction
    for step in (1.0,) if runtime.simulator else (0.5, 0.25):
        g = np.arange(-3, 3 + step, step)
        p = np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3)
        direction = krays.contains_directions(tracer, p)
        assert (np.abs(direction) == krays.CONTAINS_DIRECTION).all()
        assert (np.sign(direction) == np.where(p >= 0, 1, -1)).all()   # the box's centre: 0
        rays, order = krays._contains_rays(tracer, p)
        assert (order is None) == (len(p) < krays.SORT_FROM)
        assert np.array_equal(rays.d, direction if order is None else direction[order])
        moved = p + 1e-6 * direction
        assert (tracer.contains(p) == (np.abs(moved) < 2).all(axis=1)).all()
    # the scene's sphere: convex, so inside = behind every face's plane
    mesh = load(SCENES / "sphere.obj")
    tracer = Tracer(build(mesh.vertices, mesh.faces), device=runtime.spec)
    tri = mesh.vertices[mesh.faces]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    lo, hi = mesh.vertices.min(axis=0), mesh.vertices.max(axis=0)
    rng = np.random.default_rng(8)
    scaled = mesh.vertices[:, None, :] * np.array([0.5, 0.999, 1.001, 2])[None, :, None]
    q = np.concatenate([lo + rng.random((runtime.small(20000, 200), 3)) * (hi - lo) * 1.2 - 0.1 * (hi - lo),
                        scaled.reshape(-1, 3)])
    side = np.einsum("pfk,fk->pf", q[:, None, :] - tri[None, :, 0], normal)
    clear = (np.abs(side).min(axis=1) > 1e-9) | (side.max(axis=1) < 0)
    expected = (side < 0).all(axis=1)
    assert (tracer.contains(q)[clear] == expected[clear]).all()
    assert tracer.contains(q.reshape(-1, 2, 3)[:3]).shape == (3, 2)


def test_queries_do_not_depend_on_work_sizes_or_packets(runtime, teapot_tree, monkeypatch):
    """Work sizes, rays a work-item, and packet programs (a leaf tested a packet's
    width of triangles at a time, PoCL's plain vector operations too) give the same
    answers bit for bit, per-ray trace included, and so do the rays taken in an order
    (kdray.ray_order)."""
    tree = teapot_tree
    o, d = random_rays(tree, runtime.small(777, 33), seed=9)
    lo, hi = ranges(np.random.default_rng(10), len(o), 0.5)

    def answers(tracer):
        listed = tracer.intersections(o, d)
        near = tracer.trace(o, d, lo, hi)
        return (tracer.occluded(o, d), tracer.count(o, d), listed.offsets, listed.prim,
                listed.t, listed.u, near.t, near.prim, near.u, near.normal)

    want = answers(Tracer(tree, device=runtime.spec, packet=1))
    # rays a work-item (RUN_CPU): 3 walks one by one in packet programs too; 21 walks as
    # packets and through the wide nodes (kd_wide_walks), an odd one left
    options = [dict(packet=1, local_size=1, batch_size=1, run=3),
               dict(packet=1, local_size=4, batch_size=4, run=3)]
    if not runtime.simulator:
        options += [dict(packet=p, run=r) for p in PACKETS for r in (3, 21)]
        options.append(dict(packet=PACKETS[0], plain_vector_ops=True, run=21))
    for opts in options:
        monkeypatch.setattr(query_rays, "RUN_CPU", opts.pop("run"))
        plain = opts.pop("plain_vector_ops", False)
        other = Tracer(tree, device=runtime.spec, **opts)
        other._plain_vector_ops = plain or other._plain_vector_ops
        for a, b in zip(answers(other), want):
            assert np.array_equal(a, b), opts
    # rays in no order of their own taken in one (kdray.ray_order, forced here for a
    # small tree): each ray's answers read and written through it
    import kdray.ray_order as ray_order
    monkeypatch.setattr(ray_order, "ORDER_FROM", 1)
    monkeypatch.setattr(ray_order, "ORDER_TREE_BYTES", 0)
    monkeypatch.setattr(query_rays, "RUN_CPU", 21)
    assert ray_order.unordered(o, d, *teapot_tree.world_box())
    for packet in [1] + ([] if runtime.simulator else list(PACKETS)):
        other = Tracer(tree, device=runtime.spec, packet=packet)
        other._poison_outputs = True
        for a, b in zip(answers(other), want):
            assert np.array_equal(a, b), ("ordered", packet)


def far_corner(v, f):
    """(v, f) with a small triangle added far out at (40, 40, 40), so that the scene's box
    is 20 times the mesh's: its rays' packets then share paths (kd_alone's spread)."""
    tip = np.array([[40.0, 40.0, 40.0], [40.5, 40.0, 40.0], [40.0, 40.5, 40.0]])
    return np.concatenate([v, tip]), np.concatenate([f, len(v) + np.arange(3)[None]])


def test_packets_that_share_paths_walk_as_their_rays_alone(runtime, teapot_tree):
    """Rays that share their paths walk as packets (queries.cl, kd_packet_walk: one node
    step for a packet's lanes, a leaf's triangles against all of them, those no lane can
    hit culled): a camera's rays with per-ray ranges, and the parallel rays of
    `contains`, answer count, intersections, occluded and trace as one-ray programs do,
    bit for bit; and rays through every vertex and edge midpoint of closed meshes, in
    packets, cross exactly twice."""
    if runtime.simulator:
        pytest.skip("a simulator runs no packet programs")
    tree = teapot_tree
    # an image whose sides are no multiple of a packet's block (kd_block_rays' edges)
    camera_o, camera_d = Tracer(tree, device=runtime.spec).camera_rays(camera_for(tree, 61, 37))
    camera_d = camera_d.reshape(-1, 3)
    lo, hi = tree.world_box()
    rng = np.random.default_rng(12)
    # parallel rays from points on a small patch each, the patches spread over the box
    patch = np.repeat(lo + (hi - lo) * rng.random((97, 3)), 16, axis=0)
    parallel_o = patch + 0.01 * (hi - lo) * rng.random(patch.shape)
    parallel_d = np.broadcast_to(krays.CONTAINS_DIRECTION.astype(np.float64), parallel_o.shape)
    for o, d in ((camera_o, camera_d), (parallel_o, parallel_d)):
        t_lo, t_hi = ranges(np.random.default_rng(13), len(d), 2.0)

        def answers(tracer, o, d):
            listed = tracer.intersections(o, d)
            crossed = tracer.intersections(o, d, max_hits=2)
            near = tracer.trace(o, d, t_lo, t_hi)
            return [np.asarray(a).reshape(-1) for a in (
                tracer.count(o, d), tracer.count(o, d, t_lo, t_hi),
                tracer.occluded(o, d, t_lo, t_hi), listed.offsets, listed.prim, listed.t,
                listed.u, crossed.offsets, crossed.prim, near.t, near.prim, near.u)]

        want = answers(Tracer(tree, device=runtime.spec, packet=1), o, d)
        assert want[0].sum() > 100
        # the camera's rays also as the image they are: walked in blocks of pixels
        shaped = [(o, d)] + ([(o[0], d.reshape(37, 61, 3))] if o is camera_o else [])
        for packet in PACKETS:
            for spread in (None, -1.0):          # as packets; every packet alone
                tracer = Tracer(tree, device=runtime.spec, packet=packet)
                tracer._alone_spread = spread
                for oo, dd in shaped:
                    for a, b in zip(answers(tracer, oo, dd), want):
                        assert np.array_equal(a, b), (packet, spread, dd.shape)

    # (N, 3) rays that are an image, from IMAGE_SEARCH_MIN_RAYS on, are found to be one
    tracer = Tracer(tree, device=runtime.spec)
    o, d = tracer.camera_rays(camera_for(tree, 512, 256))
    rays = query_rays.QueryRays(tracer, o, d, 0.0, np.inf)
    assert query_rays.as_image(tracer, rays, o, d).image_w == 512
    one = Tracer(tree, device=runtime.spec, packet=1)
    assert np.array_equal(tracer.count(o, d), one.count(o, d))

    for v, f in (icosphere(3), grid_cube(6)):
        targets = np.concatenate([v, edge_midpoints(v, f)])
        targets = targets[spatial_order(targets, v.min(axis=0), v.max(axis=0))]  # near together
        tracer = Tracer(build(*far_corner(v, f)), device=runtime.spec)
        o, d = 3 * targets, -targets
        # from outside through the target and the centre, stopping before the far tip
        assert (tracer.count(o, d, t_max=4.5) == 2).all()
        # along one direction through each target: 0 or 2, the float64 rule's parity
        direction = np.array([0.31, 0.52, 0.79])
        o, d = targets - 30 * direction, np.broadcast_to(direction, targets.shape)
        c = tracer.count(o, d, t_max=60.0)
        ref_ray, *_ = all_hits(v[f], o, d, t_max=60.0, crossing=True)
        assert ((c == 0) | (c == 2)).all()
        assert (np.bincount(ref_ray, minlength=len(c)) % 2 == c % 2).all()


def test_packet_walks_on_every_runtime(runtime):
    """The queries' packet walks (kd_packet_walk, an image's blocks, the cull) and wide
    walks (kd_wide_walks: rays from scattered points in all directions, a k-nearest
    list pruned by its last slot), and a render's packets through the wide nodes, at
    packets of 8 on every runtime, a simulator's included (a small image of the
    sphere, a few scattered rays): the answers of one ray at a time, bit for bit."""
    mesh = load(SCENES / "sphere.obj")
    tree = build(mesh.vertices, mesh.faces)
    one = Tracer(tree, device=runtime.spec, packet=1)
    camera = camera_for(tree, 16, 12)
    o, d = one.camera_rays(camera)
    d = d.reshape(12, 16, 3)
    lo, hi = ranges(np.random.default_rng(14), d.size // 3, 3.0)
    o_s, d_s = random_rays(tree, runtime.small(997, 45), seed=15, inside=0.6)

    def answers(tracer):
        image = tracer.render(camera, aovs="depth,id")
        listed = tracer.intersections(o[0], d)
        near = tracer.trace(o[0], d, lo, hi)
        scattered = tracer.intersections(o_s, d_s)
        nearest = tracer.intersections(o_s, d_s, max_hits=1)
        return (tracer.count(o[0], d), tracer.occluded(o[0], d, lo, hi), listed.offsets,
                listed.prim, listed.t, near.t, near.prim, tracer.count(o_s, d_s),
                scattered.offsets, scattered.prim, scattered.t, nearest.offsets,
                nearest.prim, tracer.contains(o_s), image["depth"], image["id"])

    want = answers(one)
    assert want[0].sum() > 50 and want[7].sum() > 10
    for a, b in zip(answers(Tracer(tree, device=runtime.spec, packet=8)), want):
        assert np.array_equal(a, b)


@pytest.mark.parametrize("packet", [1, None], ids=["one ray", "lanes"])
def test_a_corrupt_tree_is_reported_not_walked_on(runtime, teapot_tree, packet):
    """A walk that needs more stack than the tree's depth allows, or visits more leaves
    than the tree has nodes (what a corrupt tree does), stops with an error from count
    and intersections where the rays walk the k-d tree one by one. In packet programs
    only packets walk the k-d tree, and a packet that meets either bound hands its rays
    to the wide nodes (a BVH the Tracer makes from the triangles, kdray/wide.py), which
    answer as a sound tree's would. occluded takes trace's traversal, which keeps to
    its bounds."""
    if packet is None and runtime.simulator:
        pytest.skip("a simulator runs no packet programs")
    o, d = random_rays(teapot_tree, runtime.small(300, 40), seed=13)
    t_max = np.full(len(o), np.inf)
    sound = Tracer(teapot_tree, device=runtime.spec, packet=packet)
    for corrupt in ("packet_stack_size", "_n_nodes"):
        tracer = Tracer(teapot_tree, device=runtime.spec, packet=packet)
        setattr(tracer, corrupt, 2)
        if tracer.packet == 1:
            for query in (tracer.count, tracer.intersections):
                with pytest.raises(KdrayError, match="corrupt"):
                    query(o, d, t_max=t_max)
            continue
        # rays from one point in directions close together walk as packets first
        o1 = np.broadcast_to(o[0], o.shape)
        d1 = d[0] + 0.01 * d
        for oo, dd in ((o, d), (o1, d1)):
            assert np.array_equal(tracer.count(oo, dd, t_max=t_max),
                                  sound.count(oo, dd, t_max=t_max))
            a = tracer.intersections(oo, dd, t_max=t_max)
            b = sound.intersections(oo, dd, t_max=t_max)
            assert np.array_equal(a.counts, b.counts) and np.array_equal(a.prim, b.prim)


def test_many_hits_a_ray_are_counted_exactly(tracers):
    """More distinct hits than the kernel keeps (KD_SEEN)."""
    k = 80
    z = np.arange(k, dtype=float)
    v = np.concatenate([np.stack([np.full(k, -1.0), np.full(k, -1.0), z], 1),
                        np.stack([np.full(k, 2.0), np.full(k, -1.0), z], 1),
                        np.stack([np.full(k, -1.0), np.full(k, 2.0), z], 1)])
    f = np.stack([np.arange(k), np.arange(k) + k, np.arange(k) + 2 * k], 1)
    tracer = tracers(build(v, f))
    o = np.array([[0.1, 0.2, -1.0], [0.1, 0.2, 100.0]])
    d = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0]])
    assert tracer.count(o, d).tolist() == [k, k]
    assert tracer.count(o, d, 0.0, 40.5).tolist() == [40, 20]       # z < 40.5, z > 59.5
    hits = tracer.intersections(o, d)
    assert hits.counts.tolist() == [k, k]
    assert hits.prim[:k].tolist() == list(range(k))


@pytest.mark.parametrize("packet", [1, None], ids=["one ray", "lanes"])
def test_more_crossings_than_kept_ids_count_by_the_crossing_rule(tracers, packet):
    """A ray with more crossings than count_rays keeps hits of (KD_SEEN) is counted
    under the count's rule: through 20 nested grid cubes along an axis, each face
    crossed at a vertex that 4 to 6 triangles share (and on the diagonal, at edges two
    share), 40 crossings, where every triangle hit would be many more; as few as 10
    cubes (20 crossings) agree. The listing that mends a lost count (kd_count_hit)
    lists crossings however many slots it has."""
    v, f = grid_cube(1)
    vs, fs = [], []
    for k in range(1, 21):
        fs.append(f + len(v) * len(vs))
        vs.append(v * k)
    tracer = tracers(build(np.concatenate(vs), np.concatenate(fs)), packet=packet)
    tracer._alone_spread = -1.0               # lanes: the wide walk
    o = np.array([[-50.0, 0.0, 0.0], [0.0, -50.0, 0.0], [-50.0, -50.0, 0.0], [0.0, 0.0, 0.0]])
    d = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    assert tracer.count(o, d).tolist() == [40, 40, 40, 20]
    assert tracer.count(o, d, t_max=np.array([50.0, 50.0, 50.0, 10.5])).tolist() == [20, 20, 20, 10]
    hits = tracer.intersections(o, d)
    assert np.all(np.diff(hits.offsets)[:3] > 40)    # every triangle hit: more
    # the listing that mends such counts lists crossings, whatever room it is given
    # (the count's first pass may find a triangle once a leaf that holds a copy)
    rays = query_rays.QueryRays(tracer, o, d, 0.0, np.inf)
    for caps in (60, 200):
        crossed, _ = hit_lists.list_hits(tracer, rays, caps, crossing=True)
        assert np.diff(crossed.offsets).tolist() == [40, 40, 40, 20]
        assert np.all(np.isin(crossed.prim, hits.prim))
    # a first pass's few private slots (list_first) keep the nearest crossings, and
    # mark every ray as having more
    few, more = hit_lists.list_hits(tracer, rays, query_rays.LIST_SLOTS, crossing=True)
    k = query_rays.LIST_SLOTS
    assert np.diff(few.offsets).tolist() == [k] * 4 and more.all()
    for i in range(4):
        t, prim = crossed.of(i)
        assert np.array_equal(few.of(i)[1], prim[:k]) and np.array_equal(few.of(i)[0], t[:k])


def test_far_reaching_triangles_give_every_query_the_same_hits(runtime):
    """Triangles that reach far along a ray next to its hit's t (a ground plane under a
    point close above it, a point on a triangle leaving it) have their hits decided by
    t in double (REFINE): occluded is still trace's hit, and count still at most the
    hits intersections lists (one t a triangle under both rules), with ranges that end
    at the hit's t, just before and just after it, and from t = 0 off the surface."""
    n = runtime.small(2000, 24)
    rng = np.random.default_rng(21)
    quad = np.array([[0, 1, 2], [0, 2, 3]])
    for side in (2.0, 2e4, 2e6):
        h = side / 2
        tracer = Tracer(build(np.array([[-h, -h, 0], [h, -h, 0], [h, h, 0], [-h, h, 0]]), quad),
                        device=runtime.spec)
        tracer._poison_outputs = True
        o = np.column_stack([rng.uniform(-0.3, 0.3, (n, 2)), rng.uniform(1e-4, 1e-2, n)])
        d = rng.normal(size=(n, 3))
        d[:, 2] = -np.abs(d[:, 2]) - 0.05
        t_hit = -o[:, 2] / d[:, 2]
        assert tracer.trace(o, d).hit.all()
        for lo, hi in ((0.0, t_hit), (0.0, t_hit * (1 + 1e-7)), (0.0, t_hit * (1 - 1e-7)),
                       (t_hit, np.inf), (t_hit * (1 - 1e-7), np.inf)):
            hit = tracer.trace(o, d, lo, hi).hit
            assert np.array_equal(tracer.occluded(o, d, lo, hi), hit)
            listed = tracer.intersections(o, d, lo, hi)
            assert np.array_equal(listed.counts > 0, hit)
            assert (tracer.count(o, d, lo, hi) <= listed.counts).all()
    # from points on an icosphere's triangles, leaving them: a triangle's own hit at a
    # t of its float32 copy's rounding (about 1e-9) or none, alike for every query
    v, f = icosphere(2)
    tracer = Tracer(build(v, f), device=runtime.spec)
    w = rng.dirichlet(np.ones(3), n)
    tri = v[f[rng.integers(0, len(f), n)]]
    o = np.einsum("nk,nkj->nj", w, tri)
    d = rng.normal(size=(n, 3))
    hits = tracer.trace(o, d)
    assert np.array_equal(tracer.occluded(o, d), hits.hit)
    assert np.array_equal(tracer.intersections(o, d, max_hits=1).counts > 0, hits.hit)


def test_double_precision_and_scale(tracers):
    """Far from the origin and at tiny scales the queries answer as at home."""
    v, f = icosphere(1)
    rng = np.random.default_rng(10)
    p = rng.uniform(-1.5, 1.5, size=(500, 3))
    d = rng.normal(size=(500, 3))
    home = tracers(build(v, f))
    want = home.contains(p), home.count(p, d)
    for scale, shift in ((1e-20, 0.0), (1.0, 1e6), (1e20, 3e21)):
        tracer = tracers(build(v * scale + shift, f, keep_double=True))
        assert (tracer.contains(p * scale + shift) == want[0]).mean() > 0.99
        assert (tracer.count(p * scale + shift, d) == want[1]).mean() > 0.99
        hits = tracer.intersections(p * scale + shift, d, precision="double")
        assert hits.t.dtype == np.float64
        assert (hits.counts >= want[1]).all()
        step = np.diff(hits.t)[hits.ray[1:] == hits.ray[:-1]]
        assert (step >= 0).all()


def test_lists_are_the_same_whoever_gathers_their_rows(monkeypatch, tracers, teapot_tree):
    """A list's rows are gathered by numpy below DEVICE_ROWS_FROM hits and by
    hit_rows.cl from there (on a CPU): the same Intersections either way."""
    tracer = tracers(teapot_tree)
    rng = np.random.default_rng(8)
    lo, hi = teapot_tree.world_box()
    n = 3001
    o = lo + (hi - lo) * rng.random((n, 3))
    d = rng.normal(size=(n, 3))
    runs = []
    for least in (hit_lists.DEVICE_ROWS_FROM, 0, 1 << 62):
        monkeypatch.setattr(hit_lists, "DEVICE_ROWS_FROM", least)
        runs.append(tracer.intersections(o, d))
    assert runs[0].offsets[-1] > 0
    for other in runs[1:]:
        for name in ("offsets", "t", "prim", "u", "v"):
            assert np.array_equal(getattr(runs[0], name), getattr(other, name)), name


def test_number_ranges_are_checked_as_arrays_are():
    """check_ranges takes two numbers by a path of its own (most calls give numbers):
    the same answers and the same errors as the same values given a ray each."""
    from kdray.query_rays import check_ranges
    n = 4
    cases = [(0.0, np.inf), (-0.0, 0.0), (2.0, 2.0), (np.inf, np.inf), (1, 2), (np.float32(0.5), 3),
             (-1.0, 2.0), (2.0, 1.0), (np.nan, 1.0), (0.0, np.nan), (-np.inf, 0.0)]
    for a, b in cases:
        try:
            lo, hi, step = check_ranges(a, b, n)
            got = (float(lo), float(hi), step)
        except KdrayError as e:
            got = str(e)
        try:
            lo, hi, step = check_ranges(np.full(n, a, np.float64), np.full(n, b, np.float64), n)
            want = (float(lo[0]), float(hi[0]), 0)
        except KdrayError as e:
            want = str(e)
        assert got == want, (a, b)


def test_bad_input_is_refused(tracers, teapot_tree):
    tracer = tracers(teapot_tree)
    o, d = np.zeros((4, 3)), np.ones((4, 3))
    bad = [dict(t_min=-1.0), dict(t_min=2.0, t_max=1.0), dict(t_min=np.nan),
           dict(t_max=np.ones(3)), dict(t_min=np.array([0, 0, 3.0, 0]), t_max=np.full(4, 2.0))]
    for kw in bad:
        for query in (tracer.occluded, tracer.count, tracer.intersections):
            with pytest.raises(KdrayError):
                query(o, d, **kw)
    for m in (0, -1, 1.5, True, np.int8(0)):
        with pytest.raises(KdrayError):
            tracer.intersections(o, d, max_hits=m)
    # numpy's integers as Python's, and any int however large: every hit at most
    v = np.array([[-1, -1, 0], [1, -1, 0], [0, 1, 0]], float)
    stack = tracers(build(np.concatenate([v + [0, 0, z] for z in range(12)]),
                          np.arange(36).reshape(12, 3)))
    up = np.array([[0.0, 0.0, -1.0]]), np.array([[0.0, 0.0, 1.0]])
    for m in (np.int8(2), np.uint8(2), np.int32(2)):
        assert stack.intersections(*up, max_hits=m).prim.tolist() == [0, 1]
    assert stack.intersections(*up, max_hits=10**30).prim.tolist() == list(range(12))
    for points in (np.array([[0, 0, np.nan]]), np.zeros((3, 2)), np.array([["a", "b", "c"]]),
                   np.array([[np.inf, 0, 0]])):
        with pytest.raises(KdrayError):
            tracer.contains(points)
    with pytest.raises(KdrayError):
        tracer.count(np.zeros((3, 3)), np.ones((4, 3)))
    # rays that cannot be traced have no hit, as in trace
    odd = np.array([[0, 0, 0], [np.nan, 0, 0], [0, 0, np.inf]], float)
    dd = np.array([[0, 0, 0], [1, 0, 0], [1, 0, 0]], float)
    assert not tracer.occluded(odd, dd).any()
    assert (tracer.count(odd, dd) == 0).all()
    assert (tracer.intersections(odd, dd).counts == 0).all()
    assert tracer.contains(np.zeros((0, 3))).shape == (0,)


def test_contains_command(tmp_path, capsys):
    from helpers import run
    points = np.array([[0.0, 0.0, 0.0], [5.0, 5.0, 5.0], [0.5, 0.2, 0.1]])
    np.save(tmp_path / "p.npy", points)
    np.savetxt(tmp_path / "p.txt", points)
    for source in ("p.npy", "p.txt"):
        code, out, _ = run(capsys, "contains", SCENES / "sphere.obj", "--points", tmp_path / source,
                           "-o", tmp_path / "in.npy")
        assert code == 0 and "2 of 3 points inside" in out
        assert np.load(tmp_path / "in.npy").tolist() == [True, False, True]
    # any length: the direction alone counts (float32 holds neither 1e-46 nor 1e39)
    for direction in ("1,0,0", "1e-46,0,0", "1e39,1e30,0"):
        code, _, _ = run(capsys, "contains", SCENES / "sphere.obj", "--points",
                         tmp_path / "p.npy", "-o", tmp_path / "c.npy", "--count", direction)
        assert code == 0 and np.load(tmp_path / "c.npy").tolist() == [1, 0, 1], direction
    np.save(tmp_path / "bad.npy", np.zeros((3, 2)))
    np.save(tmp_path / "nan.npy", np.array([[0.0, 0.0, 0.0], [np.nan, 0.0, 0.0]]))
    for argv in (("--points", tmp_path / "bad.npy", "-o", tmp_path / "x.npy"),
                 ("--points", tmp_path / "nan.npy", "-o", tmp_path / "x.npy"),
                 ("--points", tmp_path / "nan.npy", "-o", tmp_path / "x.npy", "--count", "1,0,0"),
                 ("--points", tmp_path / "none.npy", "-o", tmp_path / "x.npy"),
                 ("--points", tmp_path / "p.npy", "-o", tmp_path / "p.npy"),
                 ("--points", tmp_path / "p.npy", "-o", tmp_path / "x.npy", "--count", "0,0,0")):
        code, _, err = run(capsys, "contains", SCENES / "sphere.obj", *argv)
        assert code == 1 and err.count("\n") == 1 and err.startswith("kdray: error:")
    assert np.load(tmp_path / "p.npy").shape == (3, 3)          # the input is kept


def test_cast_command_moves_origins_off_the_triangles_they_leave(tmp_path, capsys):
    """A rays .npz file's `prim` names the triangle each origin lies on: its ray leaves
    it (kdray.offset_origins). From float64 points on a closed sphere's triangles,
    rays leaving along their outward normals hit nothing with it; without it some hit
    the triangle they start on. A bad prim names the file."""
    from helpers import run
    from kdray.spawn import offset_origins
    mesh = load(SCENES / "sphere.obj")
    tree = build(mesh.vertices, mesh.faces)
    tri = mesh.vertices[mesh.faces]
    rng = np.random.default_rng(8)
    prim = rng.integers(0, len(tri), 400)
    w = rng.dirichlet(np.ones(3), len(prim))
    o = np.einsum("nk,nkc->nc", w, tri[prim])
    d = np.cross(tri[prim, 1] - tri[prim, 0], tri[prim, 2] - tri[prim, 0])
    d *= np.sign(np.einsum("ij,ij->i", d, o))[:, None]        # outward: the sphere's centre 0
    np.savez(tmp_path / "left.npz", origins=o, directions=d, prim=prim)
    np.savez(tmp_path / "plain.npz", origins=o, directions=d)
    np.savez(tmp_path / "bad.npz", origins=o, directions=d, prim=prim + len(tri))
    np.savez(tmp_path / "float.npz", origins=o, directions=d, prim=prim.astype(float))
    got = {}
    for name in ("left", "plain"):
        code, _, err = run(capsys, "cast", SCENES / "sphere.obj", "--rays", tmp_path / f"{name}.npz",
                           "-o", tmp_path / f"{name}_out.npz", "--query", "nearest")
        assert code == 0, err
        with np.load(tmp_path / f"{name}_out.npz") as f:
            got[name] = f["prim"]
    assert (got["left"] == MISS).all() and (got["plain"] == prim).sum() > 40
    want = Tracer(tree).trace(offset_origins(tree, o, prim, d), d)
    np.testing.assert_array_equal(got["left"], want.prim)
    for name in ("bad", "float"):
        code, _, err = run(capsys, "cast", SCENES / "sphere.obj", "--rays", tmp_path / f"{name}.npz",
                           "-o", tmp_path / "x.npz")
        assert code == 1 and err.startswith(f"kdray: error: {tmp_path / name}.npz: "), err


def test_cast_command(tmp_path, capsys):
    """`kdray cast` writes what the Tracer's queries give for the rays of a file (each
    layout of the file), the nearest hits matching the float64 oracle, and refuses bad
    files and options with one line."""
    from helpers import run
    mesh = load(SCENES / "sphere.obj")
    tree = build(mesh.vertices, mesh.faces)
    tracer = Tracer(tree)
    o, d = random_rays(tree, 301, seed=5)
    lo, hi = ranges(np.random.default_rng(6), len(d), 1.0)
    np.save(tmp_path / "r.npy", np.concatenate([o, d], axis=1))
    np.savetxt(tmp_path / "r.txt", np.concatenate([o, d], axis=1), fmt="%.17g")
    np.savez(tmp_path / "r.npz", origins=o, directions=d, t_min=lo, t_max=hi)

    def cast(source, query, *more):
        out = tmp_path / f"{query}.npz"
        code, said, err = run(capsys, "cast", SCENES / "sphere.obj", "--rays", tmp_path / source,
                              "-o", out, "--query", query, *more)
        assert code == 0 and said.startswith(f"wrote {out} (301 rays, "), err
        with np.load(out) as f:
            return {k: f[k] for k in f.files}

    for source, t in (("r.npy", {}), ("r.txt", {}), ("r.npz", {"t_min": lo, "t_max": hi})):
        got = cast(source, "nearest")
        want = tracer.trace(o, d, **t)
        for k in ("t", "prim", "u", "v", "normal", "object"):
            np.testing.assert_array_equal(got[k], getattr(want, k))
        assert cast(source, "any")["occluded"].tolist() == tracer.occluded(o, d, **t).tolist()
        assert cast(source, "count")["count"].tolist() == tracer.count(o, d, **t).tolist()
        got, want = cast(source, "all"), tracer.intersections(o, d, **t)
        for k in ("offsets", "ray", "t", "prim", "u", "v", "object"):
            np.testing.assert_array_equal(got[k], getattr(want, k))
    ray, prim, t, _, _ = all_hits(tree.world(tree.triangles.reshape(-1, 3, 3)), o, d, lo, hi)
    first = np.full(len(d), np.inf)
    np.minimum.at(first, ray, t)
    got = cast("r.npz", "nearest", "--precision", "double")
    assert got["t"].dtype == np.float64
    assert np.allclose(got["t"], first, rtol=RTOL_T, equal_nan=False)
    double = Tracer(build(mesh.vertices, mesh.faces, keep_double=True))
    assert cast("r.npz", "any", "--precision", "double")["occluded"].tolist() \
        == double.occluded(o, d, lo, hi, precision="double").tolist()
    assert cast("r.npz", "count", "--precision", "double")["count"].tolist() \
        == double.count(o, d, lo, hi, precision="double").tolist()
    got = cast("r.npy", "all", "--max-hits", "1", "--t-max", "2.5")
    want = tracer.intersections(o, d, t_max=2.5, max_hits=1)
    np.testing.assert_array_equal(got["t"], want.t)
    assert (np.diff(got["offsets"]) <= 1).all()

    np.save(tmp_path / "bad.npy", np.zeros((3, 5)))
    np.savez(tmp_path / "bad.npz", origins=o, directions=d[:, :2])
    np.savez(tmp_path / "extra.npz", origins=o, directions=d, weights=lo)
    np.savez(tmp_path / "short.npz", origins=o, directions=d, t_max=hi[:-1])
    for argv in (("--rays", tmp_path / "bad.npy"), ("--rays", tmp_path / "bad.npz"),
                 ("--rays", tmp_path / "extra.npz"), ("--rays", tmp_path / "short.npz"),
                 ("--rays", tmp_path / "none.npz"),
                 ("--rays", tmp_path / "r.npy", "--query", "all", "--max-hits", "0")):
        code, _, err = run(capsys, "cast", SCENES / "sphere.obj", *argv, "-o", tmp_path / "x.npz")
        assert code == 1 and err.count("\n") == 1 and err.startswith("kdray: error:"), argv
    # a rays file's bad values name the file, bad options' values do not
    np.savez(tmp_path / "nan.npz", origins=o, directions=d, t_min=np.full(len(d), np.nan))
    np.savez(tmp_path / "crossed.npz", origins=o, directions=d, t_min=hi + 1, t_max=hi)
    for name in ("nan.npz", "crossed.npz"):
        code, _, err = run(capsys, "cast", SCENES / "sphere.obj", "--rays", tmp_path / name,
                           "-o", tmp_path / "x.npz")
        assert code == 1 and err.startswith(f"kdray: error: {tmp_path / name}: "), err
    code, _, err = run(capsys, "cast", SCENES / "sphere.obj", "--rays", tmp_path / "r.npy",
                       "--t-min", "nan", "-o", tmp_path / "x.npz")
    assert code == 1 and err == "kdray: error: t_min and t_max must not be NaN\n"
    for argv in (("--rays", tmp_path / "r.npz", "--t-max", "1"),
                 ("--rays", tmp_path / "r.npy", "--max-hits", "2"),
                 ("--rays", tmp_path / "r.npy", "--query", "count", "--precision", "half")):
        code, _, err = run(capsys, "cast", SCENES / "sphere.obj", *argv, "-o", tmp_path / "x.npz")
        assert code == 2 and "Error:" in err, argv
    code, _, err = run(capsys, "cast", SCENES / "sphere.obj", "--rays", tmp_path / "r.npy",
                       "-o", tmp_path / "r.npy")
    assert code == 1 and err.count("\n") == 1
    assert np.load(tmp_path / "r.npy").shape == (301, 6)          # the input is kept
    assert not (tmp_path / "x.npz").exists()


def test_ranges_a_ray_through_trace_packets(runtime, teapot_tree):
    """Rays with a range a ray (an image from one eye, flat and (H, W, 3), from eyes
    spread over a patch, and from random points, which share no path) are traced in
    trace_rays' packets, each lane over its own range: every output bit for bit what
    each ray gets from a number, at each packet width; occluded with a range a ray is
    that trace's hit."""
    tree = teapot_tree
    lo, hi = tree.world_box()
    side = runtime.small(64, 8)
    eye, image = eye_image(tree, side)
    n = side * side
    rng = np.random.default_rng(21)
    eyes = eye + 1e-3 * (hi - lo) * rng.random((n, 3))
    scattered = lo + (hi - lo) * rng.random((n, 3))
    pairs = [(0.0, np.inf), (0.75, 1.05), (0.0, 0.85), (0.9, 0.9)]
    which = rng.integers(0, len(pairs), n)
    t_lo = np.array([pairs[i][0] for i in which])
    t_hi = np.array([pairs[i][1] for i in which])
    names = ("t", "prim", "u", "v", "normal")
    flat = image.reshape(-1, 3)
    for packet in [1, *PACKETS]:
        tracer = Tracer(tree, device=runtime.spec, packet=packet)
        tracer._poison_outputs = True
        for o in (eye, eyes, scattered):
            got = tracer.trace(o, flat, t_lo, t_hi)
            assert got.hit.any() and not got.hit.all()
            for i, (a, b) in enumerate(pairs):
                want = tracer.trace(o, flat, a, b)
                part = which == i
                for name in names:
                    assert np.array_equal(getattr(got, name)[part],
                                          getattr(want, name)[part]), (packet, i, name)
            occ = tracer.occluded(o, flat, t_lo, t_hi)
            assert np.array_equal(occ, got.hit), packet
        shaped = tracer.trace(eye, image, t_lo, t_hi, outputs=())
        assert shaped.t.shape == (side, side)
        assert np.array_equal(shaped.prim.ravel(), tracer.trace(eye, image.reshape(-1, 3),
                                                                t_lo, t_hi).prim)


def test_trace_takes_a_t_range_a_ray(runtime, teapot_tree):
    """Per-ray t_min, t_max give each ray the hit a number would: bit for bit, t, u, v,
    normal and prim, whichever of three ranges a ray has."""
    tree = teapot_tree
    n = runtime.small(1501, 37)
    o, d, tracer = poisoned_case(runtime, tree, n, seed=11)
    pairs = [(0.0, np.inf), (0.2, 0.7), (0.45, 3.0)]
    which = np.random.default_rng(12).integers(0, len(pairs), n)
    lo = np.array([pairs[i][0] for i in which])
    hi = np.array([pairs[i][1] for i in which])
    got = tracer.trace(o, d, lo, hi)
    for i, (a, b) in enumerate(pairs):
        want = tracer.trace(o, d, a, b)
        m = which == i
        for name in ("t", "prim", "u", "v", "normal"):
            assert np.array_equal(getattr(got, name)[m], getattr(want, name)[m]), name
    # rays in the tree's split planes (both children over one range: no early stop)
    o2, d2 = split_plane_rays(tree, runtime.small(600, 30), seed=13)
    want = tracer.trace(o2, d2)
    got2 = tracer.trace(o2, d2, np.zeros(len(o2)), np.inf)
    assert want.hit.sum() > 0
    for name in ("t", "prim", "u", "v", "normal"):
        assert np.array_equal(getattr(got2, name), getattr(want, name)), name
    # outputs left out, image-shaped rays, a range of the wrong length
    few = tracer.trace(o, d, lo, hi, outputs=())
    assert few.u is None and few.normal is None and np.array_equal(few.prim, got.prim)
    shaped = tracer.trace(o[:20].reshape(4, 5, 3), d[:20].reshape(4, 5, 3), lo[:20], hi[:20])
    assert shaped.t.shape == (4, 5) and np.array_equal(shaped.prim.ravel(), got.prim[:20])
    # ranges shaped as the rays less their last axis: the same as flat
    o45, d45, lo45, hi45 = (a[:20].reshape(4, 5, -1).squeeze(-1) if a.ndim == 1
                            else a[:20].reshape(4, 5, 3) for a in (o, d, lo, hi))
    grid = tracer.trace(o45, d45, lo45, hi45)
    assert np.array_equal(grid.t, shaped.t) and np.array_equal(grid.prim, shaped.prim)
    assert np.array_equal(tracer.occluded(o45, d45, lo45, hi45), shaped.hit)
    assert np.array_equal(tracer.count(o45, d45, lo45, hi45),
                          tracer.count(o[:20], d[:20], lo[:20], hi[:20]).reshape(4, 5))
    listed = tracer.intersections(o45, d45, lo45, hi45)
    flat = tracer.intersections(o[:20], d[:20], lo[:20], hi[:20])
    assert np.array_equal(listed.prim, flat.prim)
    with pytest.raises(KdrayError):
        tracer.trace(o, d, lo[:-1], hi)
    for wrong in (lo45.T, lo[:20].reshape(2, 10), lo[:20].reshape(4, 5, 1)):
        for query in (tracer.trace, tracer.occluded, tracer.count, tracer.intersections):
            with pytest.raises(KdrayError):
                query(o45, d45, wrong, hi45)


@pytest.mark.parametrize("packet", [None, 1])
def test_counts_past_the_kept_ids_are_exact(runtime, packet):
    """A ray through 100 stacked copies of a quad (away from its diagonal) crosses it
    100 times, more than the kernel keeps hits of: a wide walk (packet programs) meets
    each triangle once and counts them as it goes, a k-d walk keeps the greatest hits
    counted or, where they come too far out of their (t, id) order (these tie in t),
    lists them again; both exact, and equal to intersections' lists."""
    quad = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    copies = 100
    v = np.tile(quad, (copies, 1))
    f = (np.arange(copies)[:, None, None] * 4 + np.array([[0, 1, 2], [0, 2, 3]])).reshape(-1, 3)
    kw = {} if packet is None else {"packet": packet}
    tracer = Tracer(build(v, f), device=runtime.spec, **kw)
    rng = np.random.default_rng(8)
    n = runtime.small(300, 20)
    xy = 0.05 + 0.9 * rng.random((n, 2))
    xy[:, 1] = np.where(np.abs(xy[:, 0] - xy[:, 1]) < 0.01, xy[:, 1] + 0.02, xy[:, 1])
    o = np.column_stack([xy, -np.ones(n)])
    d = np.tile([0.0, 0.0, 1.0], (n, 1))
    assert (tracer.count(o, d) == copies).all()
    assert (np.diff(tracer.intersections(o, d).offsets) == copies).all()


@pytest.mark.parametrize("walk", ["one ray", "packets", "wide"])
def test_long_lists_through_copies_are_each_triangle_once(runtime, walk):
    """Rays through 40 stacked quads that k-d splits cut into copies (small triangles
    scattered among them put the planes there), some along the stack, some on a split
    plane, some across it: every triangle hit is listed once, in (t, input id) order,
    as the float64 brute force lists them, however the rays walk (a k-d walk lone or
    as packets meets a quad in every leaf that holds it; a wide walk once), and a
    k-nearest list is the whole list's start. (A copy is found next to its twin, by its
    own t: kd_list_hit.)"""
    rng = np.random.default_rng(31)
    k = 40
    quad = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    v = np.concatenate([quad + [0, 0, z] for z in np.arange(k) + 0.5])
    f = (np.arange(k)[:, None, None] * 4 + np.array([[0, 1, 2], [0, 2, 3]])).reshape(-1, 3)
    m = runtime.small(600, 120)
    centre = rng.uniform([0.02, 0.02, 0.0], [0.98, 0.98, k], (m, 1, 3))
    small = (centre + rng.normal(0.0, 0.01, (m, 3, 3))).reshape(-1, 3)
    v = np.concatenate([v, small])
    f = np.concatenate([f, len(quad) * k + np.arange(3 * m).reshape(-1, 3)])
    tree = build(v, f, K_T=10)                      # a fine tree: quads in many leaves
    kw = {"packet": 1} if walk == "one ray" else {}
    tracer = Tracer(tree, device=runtime.spec, **kw)
    tracer._alone_spread = {"one ray": None, "packets": 1e30, "wide": -1.0}[walk]
    tracer._poison_outputs = True
    n = runtime.small(300, 40)
    xy = rng.uniform(0.05, 0.95, (n, 2))
    xy[::3, 0] = small[rng.integers(0, len(small), len(xy[::3])), 0]   # on a split plane
    o = np.column_stack([xy, np.full(n, -1.0)])
    d = np.tile([0.0, 0.0, 1.0], (n, 1))
    d[1::4, :2] = rng.normal(0.0, 0.02, (len(d[1::4]), 2))             # across the planes
    hits = tracer.intersections(o, d)
    ref_ray, ref_prim, ref_t, _, _ = all_hits(v[f], o, d)
    assert np.array_equal(hits.offsets, np.concatenate([[0], np.cumsum(np.bincount(ref_ray, minlength=n))]))
    assert np.array_equal(hits.prim, ref_prim)
    assert np.allclose(hits.t, ref_t, rtol=RTOL_T, atol=0)
    along = np.ones(n, bool)
    along[1::4] = False
    assert (hits.counts[along] >= k).all()          # every quad, each once
    # counts find their copies too (kd_count_hit), of every hit and of crossings
    rays = query_rays.QueryRays(tracer, o, d, 0.0, np.inf)
    assert np.array_equal(krays._counts(tracer, rays, False), hits.counts)
    crossed = all_hits(v[f], o, d, crossing=True)[0]
    assert np.array_equal(tracer.count(o, d), np.bincount(crossed, minlength=n))
    for cap in (3, 50):
        few = tracer.intersections(o, d, max_hits=cap)
        keep = np.arange(len(hits.t)) - np.repeat(hits.offsets[:-1], hits.counts) < cap
        assert np.array_equal(few.prim, hits.prim[keep]) and np.array_equal(few.t, hits.t[keep])


@pytest.mark.parametrize("packet", [1, None], ids=["one ray", "packets"])
def test_counts_take_no_memory_for_their_hits(tracers, monkeypatch, packet):
    """Rays that meet more triangles than the kernel keeps ids of in a k-d walk are
    counted by listing their hits, a group of rays at a time that fits in memory: a
    count whose hits would not fit at once (here 20,000 rays x 100 quads, 40 MB of
    lists, with 12 MB available) is still counted, exactly, with no error."""
    import kdray.host
    k = 100
    quad = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    v = np.concatenate([quad + [0, 0, z] for z in range(k)])
    f = (np.arange(k)[:, None, None] * 4 + np.array([[0, 1, 2], [0, 2, 3]])).reshape(-1, 3)
    tracer = tracers(build(v, f), packet=packet)
    tracer._alone_spread = 1e30                       # packets: the k-d walk
    rng = np.random.default_rng(4)
    n = 20000
    xy = rng.uniform(0.05, 0.95, (n, 2))
    xy[:, 1] = np.where(np.abs(xy[:, 0] - xy[:, 1]) < 0.02, 0.5 * xy[:, 1], xy[:, 1])
    o = np.column_stack([xy, np.full(n, -1.0)])
    d = np.tile([0.0, 0.0, 1.0], (n, 1))
    for module in (kdray.host, krays):
        monkeypatch.setattr(module, "available_memory", lambda: 12 << 20)
    assert (tracer.count(o, d) == k).all()
    assert (tracer.count(o, d, t_max=np.where(np.arange(n) % 2, 50.5, np.inf)) ==
            np.where(np.arange(n) % 2, 50, k)).all()          # t = z + 1 < 50.5
    with pytest.raises(KdrayError, match="list fewer rays"):
        tracer.intersections(o, d)                    # the lists themselves do not fit


@pytest.mark.parametrize("walk", ["one ray", "packets"])
def test_counts_of_hits_out_of_order_are_mended(runtime, walk):
    """A k-d walk keeps the KD_SEEN greatest hits it has counted, (t, input id), to find
    copies by (kd_count_hit). 40 nested cubes in one leaf, tested outermost first,
    give a ray from the centre its crossings from the last: after the 32nd each comes
    before all those kept, its count is lost and mended by listing (a winding left to
    the generalized winding number); tested innermost first, it counts as it goes.
    Both exact, as the float64 brute force has them."""
    v, f = grid_cube(1)
    sizes = np.arange(1, 41) * 0.026
    rng = np.random.default_rng(12)
    n = runtime.small(64, 16)
    o = rng.uniform(-1e-3, 1e-3, (n, 3))
    d = np.tile([0.31, 0.52, 0.79], (n, 1))
    if walk == "packets":
        d[:, 0] = np.where(np.arange(n) % 2, 0.02, -0.02)   # two octants: the k-d walk
    for outer_first in (True, False):
        order = sizes[::-1] if outer_first else sizes
        vs = np.concatenate([v * s for s in order])
        fs = np.concatenate([f + len(v) * i for i in range(len(order))])
        tree = build(vs, fs, K_T=1e9)                       # one leaf, in input order
        assert tree.stats()["nodes"] == 1
        kw = {"packet": 1} if walk == "one ray" else {}
        tracer = Tracer(tree, device=runtime.spec, **kw)
        tracer._alone_spread = 1e30 if walk == "packets" else None   # k-d packets
        rays = query_rays.QueryRays(tracer, o, d, 0.0, np.inf)
        counts, raw = query_rays.count_pass(tracer, rays, True)
        assert len(raw) == (n if outer_first else 0)
        if walk == "packets" and tracer.packet > 1:
            # the same rays alone (Tracer._packet_rules reach the queries' programs):
            # the wide walk meets each triangle once and keeps no hits
            tracer._alone_spread = -1.0
            assert len(query_rays.count_pass(tracer, rays, True)[1]) == 0
            tracer._alone_spread = 1e30
        if not outer_first:
            assert (counts == 40).all()
        assert (tracer.count(o, d) == 40).all()
        ref_ray, ref_prim, _, _, _ = all_hits(vs[fs], o, d)
        hits = tracer.intersections(o, d)
        assert np.array_equal(hits.ray, ref_ray) and np.array_equal(hits.prim, ref_prim)
        if walk == "one ray":
            w = krays.crossing_windings(tracer, o[:4])
            assert (w == (krays.WINDING_RAW if outer_first else 40)).all()
            assert tracer.occupancy(o[:4]).all()


def test_a_copy_met_after_its_twin_was_dropped_is_not_counted_twice(runtime):
    """A hand-made tree split at x = 0: a large triangle (id 0) in both leaves, hit in
    the first; the second leaf's 33 triangles, all hit after it and tested before its
    copy there, push it out of the hits the count keeps (KD_SEEN): its copy then comes
    at or before the greatest dropped, the count is lost and mended by listing, not
    counted twice."""
    big = [[-1.5, -5.0, -4.0], [-1.5, 5.0, -4.0], [0.5, 0.0, 4.0]]    # x = -0.5 + z / 4
    small = [[[x, -1.0, -1.0], [x, 1.0, -1.0], [x, 0.0, 1.0]] for x in 0.1 + 0.01 * np.arange(33)]
    tris = np.array([big] + small, dtype=np.float32)
    m = len(tris)
    nodes = np.concatenate([layout.make_interior([0], [0.0], [2]), layout.make_leaf([1], [0]),
                            layout.make_leaf([m], [1])])
    flat = tris.reshape(-1, 3)
    tree = KdTree(nodes=nodes, leaf_tris=np.array([0] + list(range(1, m)) + [0], dtype=np.uint32),
                  triangles=tris, tri_ids=np.arange(m, dtype=np.uint32), origin=np.zeros(3),
                  bounds=np.stack([flat.min(0), flat.max(0)]), n_input_tris=m, depth=1,
                  params=BuildParams(K_T=15.0, max_depth=4))
    tree.validate()
    tracer = Tracer(tree, device=runtime.spec, packet=1)
    o, d = np.array([[-2.0, 0.1, 0.2]]), np.array([[1.0, 0.0, 0.0]])
    rays = query_rays.QueryRays(tracer, o, d, 0.0, np.inf)
    counts, raw = query_rays.count_pass(tracer, rays, False)
    assert raw.tolist() == [0]
    assert tracer.count(o, d).tolist() == [m]
    assert tracer.intersections(o, d).prim.tolist() == list(range(m))
