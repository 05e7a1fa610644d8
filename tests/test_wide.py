"""Wide nodes (kdray/wide.py: an 8-wide BVH) and the walk of rays that share no path
through them (kernels/wide.cl): the records hold every triangle once in boxes that hold
them, the splits are the cheapest, and the walk's hits are one ray a work-item's bit
for bit, at any offset and scale, in a t range and for any hit."""
import numpy as np
import pytest

import trees
from helpers import check_hits, grid_cube, icosphere, random_rays, real_mesh_arrays, soup
from kdray import layout
from kdray.builder import build
from kdray.wide import (EMPTY, LEAF, LEAF_ALIGN, MAX_DEPTH, STACK_GROUPS, WIDE_WORDS, WIDTH,
                        stack_groups, wide_nodes)
from small_trees import single_leaf_tree


_TREES = {}


def _tree(name):
    """A tree by name (made once): SAH over a real mesh, deep median splits of a soup,
    a cube whose vertices and edges lie in its split planes, one leaf; and the
    icosphere at the origin, 1e6 away, at 1e-6 and 1e6 of its size (with its arrays)."""
    if name not in _TREES:
        if name == "teapot":
            _TREES[name] = build(*real_mesh_arrays("teapot.obj"))
        elif name == "soup, median 18 deep":
            _TREES[name] = trees.split_tree(*soup(11, m=400), max_depth=18, leaf_size=3)
        elif name == "cube":
            _TREES[name] = build(*grid_cube(3))
        elif name == "one leaf":
            _TREES[name] = single_leaf_tree(np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]]], float))
        elif name == "one place":          # every split's cost the same
            t = np.tile(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float), (3000, 1))
            _TREES[name] = build(t, np.arange(len(t)).reshape(-1, 3))
        else:
            scale, offset = {"far": (1.0, 1e6), "tiny": (1e-6, 0.0), "huge": (1e6, 0.0)}[name]
            v, f = icosphere(2)
            v = v * scale + offset
            _TREES[name] = (build(v, f), v, f)
    return _TREES[name]


def _unpack(records):
    """(boxes (m, 6, 8) float32, child (m, 8): a wide node's index or a leaf's first
    copy, kind (m, 8): 0 (a wide node), LEAF | n_prims (a leaf) or EMPTY, orders (m, 8,
    8) slots), decoding the child words."""
    m = len(records)
    boxes = records[:, :6 * WIDTH].view(np.float32).reshape(m, 6, WIDTH)
    word = records[:, 6 * WIDTH:7 * WIDTH].astype(np.int64)
    leaf = (word & LEAF != 0) & (word != EMPTY)
    child = np.where(leaf, (word & ((1 << 27) - 1)) * LEAF_ALIGN, word)
    kind = np.where(word == EMPTY, EMPTY, np.where(leaf, LEAF | ((word >> 27 & 15) + 1), 0))
    words = records[:, 7 * WIDTH:].astype(np.int64)
    orders = (words[:, :, None] >> (3 * np.arange(WIDTH))) & 7
    return boxes, child, kind.astype(np.uint32), orders


@pytest.mark.parametrize("name", ["teapot", "soup, median 18 deep", "cube", "one leaf",
                                  "one place"])
@pytest.mark.parametrize("run", [4, 8, 16])
def test_wide_nodes_hold_each_triangle_once_in_boxes_that_hold_them(name, run):
    """Every triangle the tree lists is copied once into one leaf of at most TRI_BLOCK
    triangles, which starts on a multiple of `run` and of LEAF_ALIGN after first_copy
    and is padded to the next such multiple (-1); a leaf's box is its triangles' box
    exactly, a wide child's box holds its children's boxes; children come after their
    parent (no cycle), no deeper than `levels`, within the BVH's depth bound even where
    every split costs the same (every triangle in one place); empty slots hold an empty
    box; and each octant's order lists every child once, then the empty slots."""
    tree = _tree(name)
    first_copy = 48
    align = max(run, LEAF_ALIGN)         # a leaf's start and padding
    records, levels, copies = wide_nodes(tree, run, first_copy)
    assert records.dtype == np.uint32 and records.shape[1] == WIDE_WORDS
    boxes, child, kind, orders = _unpack(records)
    listed = np.unique(tree.leaf_tris)
    assert sorted(copies[copies >= 0].tolist()) == listed.tolist()       # each once
    is_leaf = (kind & LEAF).astype(bool) & (kind != EMPTY)
    is_node = kind == 0
    tris = tree.triangles.astype(np.float64)
    covered = np.zeros(len(copies), bool)
    for j, i in zip(*np.nonzero(is_leaf)):
        at, n = int(child[j, i]) - first_copy, int(kind[j, i] & ~np.uint32(LEAF))
        assert at % run == 0 and (at + first_copy) % LEAF_ALIGN == 0 and 1 <= n <= layout.TRI_BLOCK
        assert not covered[at:at + n].any()
        end = -(-(at + n) // align) * align
        covered[at:end] = True
        assert np.all(copies[at:at + n] >= 0)
        assert np.all(copies[at + n:end] == -1)                         # the padding
        t = tris[copies[at:at + n]]
        assert np.array_equal(boxes[j, :3, i], t.min(axis=(0, 1)))
        assert np.array_equal(boxes[j, 3:, i], t.max(axis=(0, 1)))
    assert covered.all()                                                 # no stray copy
    for j, i in zip(*np.nonzero(is_node)):
        c = child[j, i]
        assert c > j
        inside = kind[c] != EMPTY
        assert np.all(boxes[c, :3][:, inside] >= boxes[j, :3, i][:, None])
        assert np.all(boxes[c, 3:][:, inside] <= boxes[j, 3:, i][:, None])
    empty = np.broadcast_to((kind == EMPTY)[:, None], (len(kind), 3, WIDTH))
    assert np.all(np.isposinf(boxes[:, :3][empty])) and np.all(np.isneginf(boxes[:, 3:][empty]))
    # the wide depth: children after parents, so one pass from the root gives each depth
    wide_depth = np.zeros(len(records), np.int64)
    for j in range(len(records)):
        wide_depth[child[j][is_node[j]]] = wide_depth[j] + 1
    assert wide_depth.max() + 1 <= levels <= MAX_DEPTH + 1
    assert levels <= stack_groups(levels) in STACK_GROUPS
    for octant in range(8):
        for j in range(len(records)):
            n_kids = int(np.count_nonzero(kind[j] != EMPTY))
            order = orders[j, octant]
            assert sorted(order.tolist()) == list(range(WIDTH))
            assert set(order[:n_kids].tolist()) == set(np.flatnonzero(kind[j] != EMPTY).tolist())


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_wide_children_gather_at_the_least_area(seed):
    """wide_children on a binary BVH of 1-triangle leaves over random triangles: every
    leaf is one node's child once, each node's children are a cut of its binary
    subtree, and the nodes' total area is the least of every gathering, found here by
    trying every cut of at most 8 children below every node."""
    from functools import lru_cache
    from kdray.builder.bvh import sah_bvh, wide_children
    rng = np.random.default_rng(seed)
    t = (rng.random((23, 1, 3)) * 10 + rng.random((23, 3, 3))).astype(np.float32)
    boxes = np.concatenate([t.min(axis=1), t.max(axis=1)], axis=1)
    order = np.stack([np.argsort(boxes[:, a] + boxes[:, 3 + a], kind="stable") for a in range(3)])
    left, right, first, count, depth, box = sah_bvh(boxes, order.astype(np.int64), 1, 48, 1 << 30)
    kids, wide, wdepth = wide_children(left, right, box, 8)
    def area(n):
        e = box[n, 3:].astype(np.float64) - box[n, :3]
        return float(e[0] * e[1] + e[1] * e[2] + e[2] * e[0])

    def cuts(n):
        """Every set of at most 8 nodes that n's subtree can be opened into."""
        out = [(n,)]
        if left[n] >= 0:
            out += [a + b for a in cuts(left[n]) for b in cuts(right[n]) if len(a) + len(b) <= 8]
        return out

    @lru_cache(None)
    def least(b):
        """The least total area of the wide nodes of b's subtree, b a node's root."""
        return area(b) + min(sum(least(c) for c in a + c2 if left[c] >= 0)
                             for a in cuts(left[b]) for c2 in cuts(right[b])
                             if len(a) + len(c2) <= 8)

    # the root of each wide node: the binary node whose children's cut its kids are
    root_of = {0: 0}
    for w in range(len(kids)):
        for i in np.flatnonzero(wide[w] >= 0):
            root_of[int(wide[w, i])] = int(kids[w, i])
    listed = np.sort(kids[kids >= 0][left[kids[kids >= 0]] < 0])
    assert listed.tolist() == np.flatnonzero(left < 0).tolist()           # each leaf once
    for w in range(len(kids)):
        got = tuple(sorted(kids[w][kids[w] >= 0].tolist()))
        r = root_of[w]
        assert got in {tuple(sorted(a + b)) for a in cuts(left[r]) for b in cuts(right[r])
                       if len(a) + len(b) <= 8}
        for i in np.flatnonzero(wide[w] >= 0):
            assert wide[w, i] > w and wdepth[wide[w, i]] == wdepth[w] + 1
    total = sum(area(root_of[w]) for w in range(len(kids)))
    assert total == pytest.approx(least(0), rel=1e-12)


@pytest.mark.parametrize("name", ["teapot", "soup, median 18 deep", "one place"])
def test_bvh_subtrees_on_threads_are_the_one_thread_build(name, monkeypatch):
    """sah_bvh with its subtrees on 2 and 3 threads (from any size here) gives the one
    thread's arrays, node for node, and its triangles in the same order; and the same
    BVH, numbered otherwise, as the build of one pass (each node's triangles and box)."""
    from kdray.builder import bvh
    monkeypatch.setattr(bvh, "PARALLEL_FROM", 0)
    tree = _tree(name)
    t = tree.triangles.astype(np.float32)
    boxes = np.concatenate([t.min(axis=1), t.max(axis=1)], axis=1)
    start = np.stack([np.argsort(boxes[:, a] + boxes[:, 3 + a], kind="stable")
                      for a in range(3)]).astype(np.int64)
    got = {}
    for threads in (1, 2, 3):
        order = start.copy()
        got[threads] = (order, bvh.sah_bvh(boxes, order, 16, MAX_DEPTH, 512, threads))
    for threads in (2, 3):
        assert np.array_equal(got[threads][0], got[1][0])
        for a, b in zip(got[threads][1], got[1][1]):
            assert np.array_equal(a, b)
    monkeypatch.setattr(bvh, "PARALLEL_FROM", 1 << 40)
    order = start.copy()
    one = bvh.sah_bvh(boxes, order, 16, MAX_DEPTH, 512, 2)
    assert np.array_equal(order, got[1][0])

    def nodes(arrays):
        left, right, first, count, depth, box = arrays
        return sorted((int(f), int(c), int(d), tuple(b.tolist()))
                      for f, c, d, b in zip(first, count, depth, box))
    assert nodes(one) == nodes(got[1][1])


def test_bvh_splits_are_the_cheapest_at_block_multiples():
    """sah_bvh on a row of unit boxes along x, one of them far away: the root's split
    leaves the far one alone with the blocks it must share (the cost's minimum,
    computed here), and every left child holds whole blocks."""
    from kdray.builder.bvh import sah_bvh
    n, block = 70, 16
    lo = np.stack([np.arange(n, dtype=np.float32), np.zeros(n, np.float32),
                   np.zeros(n, np.float32)], 1)
    lo[-1, 0] = 1000.0
    boxes = np.concatenate([lo, lo + 1], axis=1)
    order = np.stack([np.argsort(boxes[:, a] + boxes[:, 3 + a], kind="stable") for a in range(3)])
    left, right, first, count, depth, box = sah_bvh(boxes, order.astype(np.int64), block, 48,
                                                    1 << 30)
    assert len(left) == 2 * (-(-n // block)) - 1
    assert np.all(count[left[left >= 0]] % block == 0)

    def cost(k):
        def a(b):
            e = b[3:] - b[:3]
            return e[0] * e[1] + e[1] * e[2] + e[2] * e[0]
        x = np.concatenate([boxes[:k, :3].min(0), boxes[:k, 3:].max(0)])
        y = np.concatenate([boxes[k:, :3].min(0), boxes[k:, 3:].max(0)])
        return a(x) * -(-k // block) + a(y) * -(-(n - k) // block)
    best = min(range(block, n, block), key=cost)
    assert count[left[0]] == best == 64
    assert np.array_equal(box[0], np.concatenate([boxes[:, :3].min(0), boxes[:, 3:].max(0)]))


@pytest.mark.parametrize("name", ["far", "tiny", "huge"])
def test_wide_walk_equals_single_rays_at_any_offset_and_scale(name, tracers):
    """Rays that share no path (every packet traced alone: random origins, and rays
    aimed exactly at every vertex and edge midpoint from random points, and
    axis-parallel ones through vertices) walk the wide nodes: bit for bit one ray a
    work-item's hits (the random ones the oracle's), in a t range given as numbers, without refinement,
    and for any hit (occluded) the same rays' hit or miss."""
    tree, v, f = _tree(name)
    rng = np.random.default_rng(41)
    lo, hi = tree.world_box()
    size = np.max(hi - lo)
    o1, d1 = random_rays(tree, 1501, seed=42, inside=0.5)
    targets = np.concatenate([v, 0.5 * (v[f[:, 0]] + v[f[:, 1]])])
    o2 = lo + (hi - lo) * rng.uniform(-0.5, 1.5, (len(targets), 3))
    d2 = targets - o2
    o3 = v - np.array([2 * size, 0, 0])
    d3 = np.tile([1.0, 0.0, 0.0], (len(v), 1))
    o = np.concatenate([o1, o2, o3])
    d = np.concatenate([d1, d2, d3])
    d /= np.linalg.norm(d, axis=1)[:, None]        # t in units of the scene's size
    single = tracers(tree, packet=1)
    packed = tracers(tree)
    if packed.packet == 1:
        pytest.skip("no packets on this device")
    packed._alone_spread = -1.0               # every packet alone: the wide walk
    packed._poison_outputs = True
    for t_min, t_max in [(0.3 * size, 1.7 * size), (0.0, np.inf)]:
        a = single.trace(o, d, t_min=t_min, t_max=t_max)
        b = packed.trace(o, d, t_min=t_min, t_max=t_max)
        for field in ("t", "prim", "u", "v", "normal"):
            assert np.array_equal(getattr(a, field), getattr(b, field), equal_nan=True), field
        assert np.array_equal(packed.occluded(o, d, t_min=t_min, t_max=t_max), a.hit)
        n = len(o1)                 # the oracle's tolerance is for rays that graze by chance
        check_hits(b[:n], tree, o[:n], d[:n], t_min=t_min, t_max=t_max)
    assert 0.2 * len(d) < np.count_nonzero(b.hit) < 0.95 * len(d)
    raw = tracers(tree, refine=False)
    raw._alone_spread = -1.0
    c = tracers(tree, packet=1, refine=False).trace(o, d)
    assert np.array_equal(raw.trace(o, d).prim, c.prim)


def test_wide_nodes_are_made_by_the_first_call_and_follow_the_tree(tracers):
    """A Tracer with packets makes no wide nodes until its first render, trace or
    query, which makes them, their leaves' copies appended to the triangle buffers
    (their bytes join device_bytes); images and hits are one ray a work-item's;
    `with_tree` traces the new tree's, not the old one's."""
    from kdray import Camera, Tracer
    tree = _tree("teapot")
    other = _tree("soup, median 18 deep")
    lo, hi = tree.world_box()
    camera = Camera.frame(lo, hi, 16, 12)
    o, d = random_rays(tree, 301, seed=43)
    want_image = tracers(tree, packet=1).render(camera, aovs="depth,normal,id")
    want_hits = tracers(tree, packet=1).trace(o, d)
    for call in ("render", "trace"):
        tr = Tracer(tree)
        if tr.packet == 1:
            pytest.skip("no packets on this device")
        tr._alone_spread = -1.0
        before = tr.device_bytes
        assert tr._wide_nodes is None
        image = tr.render(camera, aovs="depth,normal,id") if call == "render" else None
        assert (tr._wide_nodes is not None) == (call == "render")
        hits = tr.trace(o, d)
        n_kd = layout.n_device_triangles(tree.nodes, tr.packet)
        first_copy = layout.TRI_BLOCK * layout.n_triangle_blocks(n_kd)
        records, _, copies = wide_nodes(tree, tr.packet, first_copy)
        added = (records.nbytes + 36 * layout.TRI_BLOCK * layout.n_triangle_blocks(len(copies))
                 + 4 * (first_copy - n_kd + len(copies)))
        assert tr.device_bytes == before + added
        image = tr.render(camera, aovs="depth,normal,id") if image is None else image
        for name in want_image:
            assert np.array_equal(image[name], want_image[name], equal_nan=True), name
        for field in ("t", "prim", "u", "v"):
            assert np.array_equal(getattr(want_hits, field), getattr(hits, field)), field
    swapped = tr.with_tree(other)
    o, d = random_rays(other, 301, seed=44)
    want = tracers(other, packet=1).trace(o, d)
    got = swapped.trace(o, d)
    for field in ("t", "prim", "u", "v"):
        assert np.array_equal(getattr(want, field), getattr(got, field)), field


def _blocks_in_one_octant(d, packet):
    """(one, mixed): how many of an (H, W, 3) image's packets of 4 x packet / 4 pixels
    have directions in one octant, and how many do not (the k-d walk's)."""
    h, w = d.shape[:2]
    rows = packet // 4
    s = np.signbit(d[: h - h % rows, : w - w % 4])
    s = s.reshape(h // rows, rows, w // 4, 4, 3)
    one = (s == s[:, :1, :, :1]).all(axis=(1, 3, 4))
    return int(one.sum()), int((~one).sum())


@pytest.mark.parametrize("name", ["teapot", "cube", "far", "tiny"])
def test_packets_of_one_octant_walk_the_wide_nodes_as_their_rays_alone(name, tracers):
    """Packets of an image's pixels whose directions share an octant walk the wide nodes
    as one (wide.cl, kd_packet_wide_traverse), the others the k-d tree: every hit is one
    ray a work-item's bit for bit, for a camera's rays from one eye (blocks on the
    view's axes mixed), from an eye spread over a lens, through every vertex of a cube
    whose vertices lie on its split planes, in t ranges as numbers and a ray each,
    without refinement, for any hit; at any offset and scale; and a render's."""
    from kdray import Camera
    tree = _tree(name)
    tree = tree[0] if isinstance(tree, tuple) else tree
    lo, hi = tree.world_box()
    c, size = 0.5 * (lo + hi), np.max(hi - lo)
    if name == "cube":
        # a pinhole on the z axis through the grid points of the front face (z = 3):
        # pixel (i, j) aims at (i / 8 - 3, j / 8 - 3, 3), every vertex a pixel's
        g = np.arange(49) / 8.0 - 3.0
        target = np.stack(np.meshgrid(g, g, [3.0], indexing="ij"), -1)[:, :, 0]
        eye = np.array([0.3, 0.55, 11.0])
        o, d = eye, target - eye
    else:
        # the view's axes through the box's centre: blocks there are mixed
        camera = Camera.look_at(c + np.array([0.0, 0.0, 1.2 * size]), c, up=(0, 1, 0),
                                fov_deg=50, width=97, height=81)
        o, d = camera.rays()
        o, d = o[0], d.reshape(81, 97, 3)
    single = tracers(tree, packet=1)
    packed = tracers(tree)
    if packed.packet == 1:
        pytest.skip("no packets on this device")
    one, mixed = _blocks_in_one_octant(d, packed.packet)
    assert one > 3 * mixed > 0, (one, mixed)
    rng = np.random.default_rng(47)
    lens = o + 1e-4 * size * rng.uniform(-1, 1, d.shape)      # origins spread a little
    t_lo = rng.uniform(0, 1.5, d.size // 3) * size
    t_hi = t_lo + rng.uniform(0, 2, d.size // 3) * size
    packed._poison_outputs = True
    for oo in (o, lens):
        for t_min, t_max in ((0.0, np.inf), (0.2 * size, 1.1 * size), (t_lo, t_hi)):
            a = single.trace(oo, d, t_min=t_min, t_max=t_max)
            b = packed.trace(oo, d, t_min=t_min, t_max=t_max)
            for field in ("t", "prim", "u", "v", "normal"):
                assert np.array_equal(getattr(a, field), getattr(b, field),
                                  equal_nan=True), field
            assert np.array_equal(packed.occluded(oo, d, t_min=t_min, t_max=t_max), a.hit)
    assert 0.1 * a.hit.size < np.count_nonzero(single.trace(o, d).hit)
    raw = tracers(tree, refine=False)
    one_raw = tracers(tree, packet=1, refine=False)
    assert np.array_equal(raw.trace(o, d).prim, one_raw.trace(o, d).prim)
    if name != "cube":
        image = packed.render(camera, aovs="depth,normal,id,bary")
        want = single.render(camera, aovs="depth,normal,id,bary")
        for k in want:
            assert np.array_equal(image[k], want[k], equal_nan=True), k


def test_renders_keep_to_the_k_d_tree_where_the_wide_nodes_do_not_fit(tracers, monkeypatch):
    """Where the wide nodes do not fit beside the tree (DeviceError from the size check,
    made before any buffer changes), renders keep to the k-d tree's packets, with the
    same images, and do not try again; traces with packets, which need them, raise."""
    from kdray import Camera, Tracer
    from kdray.errors import DeviceError
    tree = _tree("teapot")
    tr = Tracer(tree)
    if tr.packet == 1:
        pytest.skip("no packets on this device")
    check = tr._check_fits
    tried = []

    def no_room(sizes):
        if "wide nodes" in sizes:
            tried.append(1)
            raise DeviceError("the wide nodes do not fit (test)")
        return check(sizes)

    monkeypatch.setattr(tr, "_check_fits", no_room)
    before = tr.device_bytes
    lo, hi = tree.world_box()
    camera = Camera.frame(lo, hi, 40, 30)
    want = tracers(tree, packet=1).render(camera, aovs="depth,normal,id")
    for _ in range(2):
        image = tr.render(camera, aovs="depth,normal,id")
        for k in want:
            assert np.array_equal(image[k], want[k], equal_nan=True), k
    assert tr._wide_nodes is None and tr.device_bytes == before and len(tried) == 1
    assert tr.compile(("depth",)) is tr
    o, d = random_rays(tree, 101, seed=45)
    with pytest.raises(DeviceError):
        tr.trace(o, d)


def test_stack_groups():
    """Programs are compiled for a few stack depths of wide nodes: the fewest that hold
    a walk, any tree's at most (MAX_DEPTH + 1 levels)."""
    assert STACK_GROUPS == tuple(sorted(STACK_GROUPS)) and STACK_GROUPS[-1] == MAX_DEPTH + 1
    for levels in range(1, MAX_DEPTH + 2):
        g = stack_groups(levels)
        assert g >= levels and all(h < levels for h in STACK_GROUPS if h < g)
