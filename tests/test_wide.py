"""Wide nodes (kdray/wide.py) and the walk of rays that share no path through them
(kernels/wide.cl): the records hold every leaf once with its triangles' box, each
octant's order is front to back, and the walk's hits are one ray a work-item's bit for
bit, at any offset and scale, in a t range and for any hit."""
import numpy as np
import pytest

import trees
from helpers import check_hits, grid_cube, icosphere, random_rays, real_mesh_arrays, soup
from kdray import layout
from kdray.builder import build
from kdray.wide import EMPTY, LEAF, WIDE_WORDS, WIDTH, wide_nodes
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
        else:
            scale, offset = {"far": (1.0, 1e6), "tiny": (1e-6, 0.0), "huge": (1e6, 0.0)}[name]
            v, f = icosphere(2)
            v = v * scale + offset
            _TREES[name] = (build(v, f), v, f)
    return _TREES[name]


def _unpack(records):
    """(boxes (m, 6, 8) float32, child (m, 8), kind (m, 8), orders (m, 8, 8) slots)."""
    m = len(records)
    boxes = records[:, :6 * WIDTH].view(np.float32).reshape(m, 6, WIDTH)
    child = records[:, 6 * WIDTH:7 * WIDTH].astype(np.int64)
    kind = records[:, 7 * WIDTH:8 * WIDTH]
    words = records[:, 8 * WIDTH:].astype(np.int64)
    orders = (words[:, :, None] >> (3 * np.arange(WIDTH))) & 7
    return boxes, child, kind, orders


@pytest.mark.parametrize("name", ["teapot", "soup, median 18 deep", "cube", "one leaf"])
def test_wide_nodes_hold_each_leaf_once_in_front_to_back_order(name):
    """Every leaf with triangles is one wide node's child exactly once (empty leaves
    none's), with the box of its triangles clipped to its cell (recomputed here leaf by
    leaf); a wide child's box holds its children's; children come after their parent
    (no cycle) no deeper than `levels`; and each octant's order lists the children
    first, then the empty slots, each child's cell before the next one's along some
    axis in the octant's direction (so every ray of the octant meets them in that
    order)."""
    tree = _tree(name)
    dev_nodes = layout.device_nodes(tree, 8)
    records, levels = wide_nodes(tree, dev_nodes)
    assert records.dtype == np.uint32 and records.shape[1] == WIDE_WORDS
    boxes, child, kind, orders = _unpack(records)
    nodes = tree.nodes
    leaf = layout.is_leaf(nodes)
    count = layout.n_prims(nodes)
    cells = tree.node_boxes().astype(np.float64)
    # the k-d node each slot stands for: a leaf by its first device triangle, a wide node
    # by its root (the interior nodes 0, 3, 6, ... levels deep, in index order)
    by_offset = {int(layout.leaf_offset(dev_nodes)[i]): i for i in np.flatnonzero(leaf & (count > 0))}
    depth = tree._topology()[0]
    roots = np.flatnonzero(~leaf & (depth % 3 == 0)) if not leaf[0] else np.array([0])
    assert len(records) == len(roots)
    is_leaf = (kind & LEAF).astype(bool) & (kind != EMPTY)
    is_node = kind == 0
    kd = np.where(is_node, roots[np.minimum(child, len(roots) - 1)], -1)
    for j, i in zip(*np.nonzero(is_leaf)):
        kd[j, i] = by_offset[int(child[j, i])]
    seen = kd[is_leaf]
    assert sorted(seen.tolist()) == sorted(by_offset.values())        # each leaf once
    assert np.all(count[seen] == (kind[is_leaf] & ~np.uint32(LEAF)))
    for j, i in zip(*np.nonzero(is_leaf)):
        n = kd[j, i]
        first = layout.leaf_offset(nodes)[n]
        t = tree.triangles[tree.leaf_tris[first:first + count[n]]].astype(np.float64)
        lo = np.maximum(t.min(axis=(0, 1)), cells[n, 0])
        hi = np.minimum(t.max(axis=(0, 1)), cells[n, 1])
        assert np.array_equal(boxes[j, :3, i], lo) and np.array_equal(boxes[j, 3:, i], hi)
    for j, i in zip(*np.nonzero(is_node)):
        c = child[j, i]
        assert c > j
        inside = (kind[c] != EMPTY) & (boxes[c, 0] <= boxes[c, 3])
        assert np.all(boxes[c, :3][:, inside] >= boxes[j, :3, i][:, None])
        assert np.all(boxes[c, 3:][:, inside] <= boxes[j, 3:, i][:, None])
    assert np.all(np.isposinf(boxes[:, :3][np.broadcast_to((kind == EMPTY)[:, None], (len(kind), 3, WIDTH))]))
    # the wide depth: children after parents, so one pass from the root gives each depth
    wide_depth = np.zeros(len(records), np.int64)
    for j in range(len(records)):
        wide_depth[child[j][is_node[j]]] = wide_depth[j] + 1
    assert wide_depth.max() + 1 <= levels
    for octant in range(8):
        up = np.array([not octant >> a & 1 for a in range(3)])
        for j in range(len(records)):
            n_kids = int(np.count_nonzero(kind[j] != EMPTY))
            order = orders[j, octant]
            assert sorted(order.tolist()) == list(range(WIDTH))
            assert set(order[:n_kids].tolist()) == set(np.flatnonzero(kind[j] != EMPTY).tolist())
            for x in range(n_kids):
                for y in range(x + 1, n_kids):
                    a, b = cells[kd[j, order[x]]], cells[kd[j, order[y]]]
                    assert np.any(np.where(up, a[1] <= b[0], a[0] >= b[1])), (j, octant)


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


def test_wide_nodes_are_made_by_the_first_trace_and_follow_the_tree(tracers):
    """A render makes no wide nodes; the first trace makes them (their bytes join
    device_bytes); `with_tree` traces the new tree's, not the old one's."""
    from kdray import Camera, Tracer
    tree = _tree("teapot")
    other = _tree("soup, median 18 deep")
    tr = Tracer(tree)
    if tr.packet == 1:
        pytest.skip("no packets on this device")
    tr._alone_spread = -1.0
    before = tr.device_bytes
    lo, hi = tree.world_box()
    tr.render(Camera.frame(lo, hi, 16, 12), aovs="depth")
    assert tr._wide_nodes is None and tr.device_bytes == before
    o, d = random_rays(tree, 301, seed=43)
    tr.trace(o, d)
    assert tr.device_bytes == before + wide_nodes(tree, layout.device_nodes(tree, tr.packet))[0].nbytes
    swapped = tr.with_tree(other)
    o, d = random_rays(other, 301, seed=44)
    want = tracers(other, packet=1).trace(o, d)
    got = swapped.trace(o, d)
    for field in ("t", "prim", "u", "v"):
        assert np.array_equal(getattr(want, field), getattr(got, field)), field
