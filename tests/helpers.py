"""What the tests share: the vendored meshes and the project's scenes, the float64
oracle checks of traced hits, ray sets, and running the CLI. Test files import this
module (and tests/trees.py), never each other; fixtures live in conftest.py."""
import gzip
import tempfile
from pathlib import Path

import numpy as np

import trees
from kdray import layout
from kdray.cli import main
from kdray.layout import MISS
from kdray.reference import brute_force

ROOT = Path(__file__).resolve().parents[1]
MESHES = ROOT / "tests" / "data" / "meshes"
"""The real meshes the tests use, gzipped OBJ files (provenance: its README.md)."""
SCENES = ROOT / "scenes"

_UNPACKED = Path(tempfile.mkdtemp(prefix="kdray-meshes-"))


def real_mesh(name):
    """Path of the real mesh `name` ("teapot.obj", ...): tests/data/meshes/<name>.gz,
    unpacked once per session into a temporary folder (kdray.load and the CLI read it
    like any mesh file)."""
    path = _UNPACKED / name
    if not path.exists():
        with gzip.open(MESHES / f"{name}.gz", "rb") as src:
            path.write_bytes(src.read())
    return path


def real_mesh_arrays(name):
    """(vertices (n,3) float64, faces (m,3) int64) of a real mesh (`real_mesh`), loaded by
    kdray.load."""
    from kdray.load import load
    m = load(real_mesh(name))
    return m.vertices, m.faces


def run(capsys, *argv):
    """Run `kdray argv...`; returns (exit code, stdout, stderr)."""
    try:
        main(list(map(str, argv)))
        code = 0
    except SystemExit as e:
        code = e.code
    out = capsys.readouterr()
    return code, out.out, out.err


# -- the float64 oracle ------------------------------------------------------------------

RTOL_T = 1e-5           # relative t error against float64
GRAZE_ULPS = 64         # how near an edge a graze passes: float32 ulps of the magnitudes involved
MAX_GRAZE = 0.002       # fraction of rays allowed to graze an edge differently


def random_rays(tree, n, seed, inside=0.25):
    """Rays in world coordinates: most from outside the scene towards points in its box,
    a fraction `inside` from points in the box in random directions."""
    rng = np.random.default_rng(seed)
    lo, hi = tree.world_box()
    c, r = 0.5 * (lo + hi), np.linalg.norm(hi - lo)
    n_in = int(n * inside)
    o = np.concatenate([c + rng.normal(size=(n - n_in, 3)) * r,
                        lo + rng.random((n_in, 3)) * (hi - lo)])
    target = lo + rng.random((n, 3)) * (hi - lo)
    d = np.concatenate([target[: n - n_in] - o[: n - n_in], rng.normal(size=(n_in, 3)) * r])
    d *= rng.uniform(0.1, 10.0, size=(n, 1))          # t is in units of |d|
    return o, d


def reference(tree, o, d, t_min=0.0, t_max=np.inf, frame="world"):
    """brute_force on the tree's own triangles, prim mapped to input ids.

    frame="world": world coordinates, float64 ray origins as given.
    frame="tree": relative to the tree's origin, with the ray origins rounded to float32
        as the tracer rounds them: exactly the tracer's input, for rays whose exact
        position matters (in split planes, on faces).
    Returns (t, prim int64 -1 on miss, u, v, triangles in input order, origins), the
    last two in the frame used."""
    if frame == "world":
        tri = tree.world(tree.triangles)
        by_id = trees.world_triangles(tree)
    else:
        tri = tree.triangles.astype(np.float64)
        by_id = trees.world_triangles(tree) - tree.origin
        by_id[tree.tri_ids] = tri
        assert tree.scale == 1.0, "frame='tree' compares t in the tree's units"
        o = (o - tree.origin).astype(np.float32).astype(np.float64)
        d = np.asarray(d).astype(np.float32).astype(np.float64)
    ref = brute_force(tri, o, d, t_min, t_max)
    prim = np.where(ref.prim >= 0, tree.tri_ids[np.maximum(ref.prim, 0)].astype(np.int64), -1)
    return ref.t, prim, ref.u, ref.v, by_id, o


def plane_hit(tri, o, d):
    """Ray/plane intersection of each ray with its triangle's plane, float64:
    (t, barycentrics (k, 3) of v0, v1, v2), without edge tests."""
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    n = np.cross(e1, e2)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.einsum("ij,ij->i", tri[:, 0] - o, n) / np.einsum("ij,ij->i", d, n)
        p = o + t[:, None] * d - tri[:, 0]
        nn = np.einsum("ij,ij->i", n, n)
        b1 = np.einsum("ij,ij->i", np.cross(p, e2), n) / nn
        b2 = np.einsum("ij,ij->i", np.cross(e1, p), n) / nn
    return t, np.stack([1 - b1 - b2, b1, b2], axis=1)


def edge_distance(tri, o, d):
    """(k,) distance between each ray's line and the nearest edge of its triangle: how far
    the ray must move to change whether it hits (independent of the angle it meets the
    plane at). tri (k,3,3), o, d (k,3)."""
    u = d / np.linalg.norm(d, axis=1, keepdims=True)

    def perp(x):
        return x - np.einsum("ij,ij->i", x, u)[:, None] * u
    dist = np.full(len(o), np.inf)
    for a, c in ((0, 1), (1, 2), (2, 0)):
        wp, ep = perp(tri[:, a] - o), perp(tri[:, c] - tri[:, a])
        ee = np.einsum("ij,ij->i", ep, ep)
        s = np.clip(-np.einsum("ij,ij->i", wp, ep) / np.where(ee > 0, ee, 1.0), 0, 1)
        dist = np.minimum(dist, np.linalg.norm(wp + s[:, None] * ep, axis=1))
    return dist


def graze_tolerance(tree, tri, o, d, t_p, frame):
    """(k,) how near an edge a ray may pass and still be a float32 graze: GRAZE_ULPS float32
    ulps of the largest coordinate involved (ray origin, hit point, vertices), measured in
    the tree's frame. A barycentric tolerance would not do: at a grazing angle a rounding
    of the ray moves the plane's hit point along the plane by 1/cos of the angle."""
    shift = tree.origin if frame == "world" else 0.0
    mags = [np.linalg.norm(o - shift, axis=1), np.linalg.norm(o + t_p[:, None] * d - shift, axis=1),
            np.abs(tri - (shift if np.ndim(shift) == 0 else shift[None, None])).max(axis=(1, 2))]
    return GRAZE_ULPS * 2.0 ** -24 * np.max(mags, axis=0)


def check_hits(hits, tree, o, d, t_min=0.0, t_max=np.inf, max_graze=MAX_GRAZE, frame="world",
               rtol=RTOL_T):
    """Assert that `hits` agree with the oracle (t and barycentric points to `rtol`
    relative, at most `max_graze` of the rays grazing an edge differently); return the
    number of rays that hit."""
    t_ref, p_ref, u_ref, v_ref, world, o = reference(tree, o, d, t_min, t_max, frame)
    ours = np.where(hits.prim == MISS, -1, hits.prim.astype(np.int64))
    hit, ref_hit = ours >= 0, p_ref >= 0
    # miss values
    assert np.all(np.isposinf(hits.t[~hit]))
    assert np.all(hits.u[~hit] == 0) and np.all(hits.v[~hit] == 0)
    assert np.all(hits.normal[~hit] == 0)
    assert np.all((hits.t[hit] > t_min) & (hits.t[hit] < t_max))

    same = hit & ref_hit & (ours == p_ref)
    # t: relative error rtol, plus (for rays starting next to a surface) the float32
    # rounding of coordinates, 1e-6 of the scene's size along the ray
    scale = np.linalg.norm(tree.bounds[1].astype(np.float64) - tree.bounds[0])
    err = np.abs(hits.t[same] - t_ref[same])
    allowed = rtol * t_ref[same] + 1e-6 * scale / np.linalg.norm(d[same], axis=1)
    assert np.all(err <= allowed), f"t error {np.max(err / t_ref[same]):.3g}"
    # barycentrics: the points they give agree to 1e-5 of the scene's size (as t does)
    tri = world[ours[same]]

    def point(u, v):
        u, v = u.astype(np.float64)[:, None], v.astype(np.float64)[:, None]
        return (1 - u - v) * tri[:, 0] + u * tri[:, 1] + v * tri[:, 2]
    err = np.linalg.norm(point(hits.u[same], hits.v[same]) - point(u_ref[same], v_ref[same]), axis=1)
    assert err.size == 0 or err.max() <= rtol * scale, f"barycentric error {err.max() / scale:.3g}"
    # normals: float64 (v1 - v0) x (v2 - v0) of the hit triangle
    n64 = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n64 /= np.linalg.norm(n64, axis=1, keepdims=True)
    assert np.allclose(hits.normal[same], n64, atol=1e-5)

    # both hit, different triangles: a tie (ours is hit, nearly, at the same t), or one
    # of the two grazes an edge and the other is the hit behind it
    diff = np.flatnonzero(hit & ref_hit & (ours != p_ref))
    n_diff_grazes = 0
    def gap(prims, rays):
        """(distance from the ray's line to the triangle, 0 when the line passes through it;
        distance to its nearest edge; tolerance for a float32 graze; plane t)."""
        tri = world[prims]
        t_p, b = plane_hit(tri, o[rays], d[rays])
        edge = edge_distance(tri, o[rays], d[rays])
        outside = np.where(b.min(axis=1) >= 0, 0.0, edge)
        return outside, edge, graze_tolerance(tree, tri, o[rays], d[rays], t_p, frame), t_p

    if len(diff):
        out_ours, edge_ours, tol, t_p = gap(ours[diff], diff)
        assert np.all(out_ours <= tol), "a different, non-touching triangle"
        tie = np.isclose(t_p, t_ref[diff], rtol=rtol)
        _, edge_ref, tol_ref, _ = gap(p_ref[diff], diff)
        graze = np.where(t_p < t_ref[diff], edge_ours <= tol, edge_ref <= tol_ref)
        assert np.all(tie | graze), "a different triangle at another t"
        n_diff_grazes = int(np.count_nonzero(~tie))
    # one hit, the other missed: only a ray grazing an edge
    only_ours = np.flatnonzero(hit & ~ref_hit)
    only_ref = np.flatnonzero(~hit & ref_hit)
    if len(only_ours):
        _, edge, tol, _ = gap(ours[only_ours], only_ours)
        assert np.all(edge <= tol), "hit where the oracle sees none"
    if len(only_ref):
        _, edge, tol, _ = gap(p_ref[only_ref], only_ref)
        assert np.all(edge <= tol), f"missed {len(only_ref)} rays the oracle hits squarely"
    grazes = len(only_ours) + len(only_ref) + n_diff_grazes
    assert grazes <= max_graze * len(o) + 1, f"{grazes} grazing disagreements"
    return int(hit.sum())


# -- ray sets and cameras -------------------------------------------------------------

def soup(seed, m=300):
    """Random triangles of mixed sizes in the unit cube, with duplicates (exact ties)
    and a few triangles sharing edges."""
    rng = np.random.default_rng(seed)
    centers = rng.random((m, 1, 3))
    size = 10.0 ** rng.uniform(-2.5, -0.5, size=(m, 1, 1))
    tri = centers + rng.normal(size=(m, 3, 3)) * size
    tri[-10:] = tri[:10]                                  # duplicates: exact ties
    tri[-20:-10, 0], tri[-20:-10, 1] = tri[:10, 1], tri[:10, 0]   # shared edges
    return tri.reshape(-1, 3), np.arange(3 * m).reshape(m, 3)


def split_plane_rays(tree, n, seed):
    """Rays lying in split planes of the tree (o[axis] == split, d[axis] = +-0), and rays
    crossing a split plane exactly where they start (o[axis] == split, d[axis] != 0)."""
    rng = np.random.default_rng(seed)
    inner = np.flatnonzero(~layout.is_leaf(tree.nodes))
    nodes = rng.choice(inner, size=n)
    axis = layout.split_axis(tree.nodes[nodes]).astype(np.int64)
    split = layout.split(tree.nodes[nodes]).astype(np.float64)
    boxes = tree.node_boxes().astype(np.float64)
    lo, hi = boxes[nodes, 0], boxes[nodes, 1]
    o_rel = lo + rng.random((n, 3)) * (hi - lo)
    o_rel[np.arange(n), axis] = split                      # exactly representable: float32
    target = lo + rng.random((n, 3)) * (hi - lo)
    d = target - o_rel
    in_plane = rng.random(n) < 0.7
    d[np.arange(n), axis] = np.where(in_plane, np.where(rng.random(n) < 0.5, 0.0, -0.0),
                                     d[np.arange(n), axis])
    # in-plane rays start back along the ray, outside the node (still in the plane);
    # the others start on the plane, inside the node
    o_rel[in_plane] -= 2.0 * d[in_plane]
    zero = np.all(d == 0, axis=1)
    d[zero, (axis[zero] + 1) % 3] = 1.0
    d /= np.linalg.norm(d, axis=1, keepdims=True)          # (keeps the zeros' signs)
    return o_rel.astype(np.float32).astype(np.float64) + tree.origin, d


def camera_for(tree, width, height):
    """A look-at camera a little outside the scene's bounding sphere, off the axes."""
    from kdray.camera import Camera
    lo, hi = tree.world_box()
    c, r = 0.5 * (lo + hi), 0.5 * np.linalg.norm(hi - lo)
    view = np.array([0.35, 0.3, 1.0]) / np.linalg.norm([0.35, 0.3, 1.0])
    return Camera.look_at(c + 2.2 * r * view, c, up=(0, 1, 0), fov_deg=40, width=width,
                          height=height)


def assert_watertight(tracers, tree, o, d, stack_sizes, atol, label=""):
    """Rays aimed at points of a closed surface with |d| = distance: for every stack size
    (tracers: the session's `tracers` fixture), no ray leaks, t = 1 within atol, and the
    results are identical. Returns the hits."""
    base = None
    for size in stack_sizes:
        hits = tracers(tree, stack_size=size).trace(o, d)
        leaks = np.count_nonzero(hits.prim == MISS)
        assert leaks == 0, f"{leaks} of {len(d)} rays leaked (stack {size}, {label})"
        assert np.allclose(hits.t, 1.0, atol=atol)
        if base is None:
            base = hits
        assert np.array_equal(hits.prim, base.prim) and np.array_equal(hits.t, base.t)
    return base


# -- closed meshes whose vertices and edges rays can be aimed at exactly ----------------

def icosphere(subdivisions=2):
    """A closed, consistently oriented sphere of 20 * 4^s triangles (vertices shared)."""
    t = (1 + 5 ** 0.5) / 2
    v = [(-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0), (0, -1, t), (0, 1, t), (0, -1, -t),
         (0, 1, -t), (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1)]
    f = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4),
         (11, 10, 2), (10, 7, 6), (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8),
         (3, 8, 9), (4, 9, 5), (2, 4, 11), (6, 2, 10), (8, 6, 7), (9, 8, 1)]
    v = [np.array(p, float) / np.linalg.norm(p) for p in v]
    for _ in range(subdivisions):
        mid, faces = {}, []

        def m(a, b):
            key = (min(a, b), max(a, b))
            if key not in mid:
                p = v[a] + v[b]
                v.append(p / np.linalg.norm(p))
                mid[key] = len(v) - 1
            return mid[key]
        for a, b, c in f:
            ab, bc, ca = m(a, b), m(b, c), m(c, a)
            faces += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
        f = faces
    return np.array(v), np.array(f, dtype=np.int64)


def grid_cube(n=3):
    """The cube [-n, n]^3 made of 2 triangles per unit square, every vertex on the integer
    grid, outward normals: the k-d tree's planes go through its vertices and edges."""
    verts, faces, index = [], [], {}

    def vid(p):
        if p not in index:
            index[p] = len(verts)
            verts.append(p)
        return index[p]
    for axis in range(3):
        for side in (-n, n):
            u, w = (axis + 1) % 3, (axis + 2) % 3
            for i in range(-n, n):
                for j in range(-n, n):
                    q = []
                    for a, b in ((i, j), (i + 1, j), (i + 1, j + 1), (i, j + 1)):
                        p = [0, 0, 0]
                        p[axis], p[u], p[w] = side, a, b
                        q.append(vid(tuple(p)))
                    if side < 0:
                        q = q[::-1]
                    faces += [(q[0], q[1], q[2]), (q[0], q[2], q[3])]
    return np.array(verts, float), np.array(faces, dtype=np.int64)


def edge_midpoints(v, f):
    e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    e = np.unique(e, axis=0)
    return 0.5 * (v[e[:, 0]] + v[e[:, 1]])


def force_ray_order(monkeypatch, module):
    """Make `module` (kdray.trace or kdray.query_rays) take rays in no order of their own in
    one (kdray.ray_order) however few they are and however small the tree: returns the
    list of the orders it took (None where the rays were judged in order already)."""
    import kdray.ray_order as ray_order
    taken = []

    def spy(*args):
        taken.append(ray_order.ray_order(*args))
        return taken[-1]

    monkeypatch.setattr(ray_order, "ORDER_FROM", 1)
    monkeypatch.setattr(ray_order, "DIRECTION_ORDER_FROM", 1)
    monkeypatch.setattr(ray_order, "FOLLOW_ORDER_FROM", 1)
    monkeypatch.setattr(ray_order, "ORDER_TREE_BYTES", 0)
    monkeypatch.setattr(module, "ray_order", spy)
    return taken
