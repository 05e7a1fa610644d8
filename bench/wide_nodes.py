"""Wide nodes collapsed from the k-d tree, traced one ray at a time: an experiment for
the incoherent rays of issue 51, against `Tracer.trace` on the same rays, in turns.

usage: python bench/wide_nodes.py [--meshes bunny,bunny-1.6M] [--kinds uniform,centre,ao]
                                  [--width 8] [--interleave 2] [--rays 1048576]
                                  [--rounds 3] [--repeat 5] [--sorted] [--ordered]

The k-d tree's walk takes most of an incoherent ray's time (BENCHMARKS.md, "Incoherent
rays"): 18 node steps and 4 leaves a bunny ray from a random point. Here each node of
the k-d tree that starts a wide node takes as children its subtree's nodes 3 levels
down (--width 8) or 4 (--width 16), empty leaves left out, each with the box of its
triangles clipped to its cell (`wide_nodes`); bench/wide_nodes.cl tests a ray against
all the children's boxes in one vector step, keeps the nearest first and skips what
it enters beyond its best hit, and tests leaves with kdray's own kd_ray_leaf.
--interleave R rays a work-item take their steps in turns (2: each in a struct of its
own, whose state the compiler keeps in registers; more: an array of them). --direct:
a node's nearest child is taken next without the stack. --ordered (8 children): each
wide node also holds, for each octant of directions, the order in which such rays meet
its children's cells (disjoint k-d cells, so the order is front to back for every ray
of the octant); the hit children are pushed in it with no compare and no branch, and
each slab's near and far planes are picked by the direction's signs instead of a min
and a max.

The script checks that every ray's hit triangle is trace's (prints the mismatches:
they must be 0), prints the wide nodes and leaves a ray visits, then the time of the
wide kernel (float32 rays relative to the tree in, t and input id out) against
`Tracer.trace(o, d, outputs=())` (float64 rays in), median of --repeat calls each way
in --rounds rounds. trace orders incoherent rays through trees of 16 MiB and more
(kdray.ray_order); this kernel takes them as they come, unless --sorted sorts them on
the host in kdray.ray_order's order (octant, the cell where a ray enters the box) for
both.
"""
import argparse
import os
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.dirname(HERE))

from meshes import mesh as load_mesh  # noqa: E402

import kdray  # noqa: E402
from kdray import layout, ray_input  # noqa: E402

LEAF = 0x80000000
EMPTY = 0xFFFFFFFF
LEVELS = {8: 3, 16: 4}


def content_boxes(nodes, tris, cells):
    """(lo, hi) (n, 3) float32: each node's triangles' box clipped to its cell (cells:
    node_boxes), from the device's nodes and triangle copies; +inf/-inf where empty."""
    n = len(nodes)
    leaf = layout.is_leaf(nodes)
    count = layout.n_prims(nodes).astype(np.int64)
    first = layout.leaf_offset(nodes).astype(np.int64)
    above = layout.above_child(nodes).astype(np.int64)
    lo = np.full((n, 3), np.inf, np.float32)
    hi = np.full((n, 3), -np.inf, np.float32)
    t_lo, t_hi = tris.min(axis=1), tris.max(axis=1)
    for i in np.flatnonzero(leaf & (count > 0)):
        lo[i] = np.maximum(t_lo[first[i]:first[i] + count[i]].min(axis=0), cells[i, 0])
        hi[i] = np.minimum(t_hi[first[i]:first[i] + count[i]].max(axis=0), cells[i, 1])
    for i in np.flatnonzero(~leaf)[::-1]:          # children have larger indices
        lo[i] = np.minimum(lo[i + 1], lo[above[i]])
        hi[i] = np.maximum(hi[i + 1], hi[above[i]])
    return lo, hi


def octant_order(root, depth, leaf, axis, above, kids):
    """The slots of `kids` (root's subtree nodes `depth` levels down, in their order) in
    the order rays of each octant (bit a: the direction's axis a negative) meet their
    cells: (8,) uint32, 3 bits a slot, the nearest lowest; slots past len(kids) after."""
    words = np.zeros(8, np.uint32)
    for octant in range(8):
        seq = []

        def walk(k, level):
            if k in kids and (leaf[k] or level == depth):
                seq.append(kids.index(k))
                return
            if leaf[k]:
                return                                   # an empty leaf, left out
            near, far = k + 1, above[k]
            if octant >> int(axis[k]) & 1:
                near, far = far, near
            walk(near, level + 1)
            walk(far, level + 1)

        walk(root, 0)
        assert sorted(seq) == list(range(len(kids)))
        seq += range(len(kids), 8)
        words[octant] = sum(j << (3 * i) for i, j in enumerate(seq))
    return words


def wide_nodes(tree, packet, width, ordered=False):
    """The wide nodes of `tree` for a Tracer of packets of `packet`: (m * 8 * width,)
    float32, node j's record at j * 8 * width: the children's min x, y, z and max x, y, z
    (6 rows of `width` floats), then as uint32 each child's index (a wide node's, or its
    leaf's first triangle copy) and kind (0: a wide node, LEAF | n_prims, EMPTY)."""
    nodes, tris, _ = layout.device_triangles(tree, packet)
    leaf = layout.is_leaf(nodes)
    count = layout.n_prims(nodes).astype(np.int64)
    first = layout.leaf_offset(nodes).astype(np.int64)
    above = layout.above_child(nodes).astype(np.int64)
    axis = layout.split_axis(nodes)
    extra = 8 if ordered else 0
    lo, hi = content_boxes(nodes, tris, tree.node_boxes().astype(np.float32))
    records = []

    def build(root):
        index = len(records)
        records.append(None)
        kids = [root]
        for _ in range(LEVELS[width]):
            kids = [c for k in kids for c in ((k,) if leaf[k] else (k + 1, above[k]))]
        kids = [c for c in kids if not (leaf[c] and count[c] == 0)]
        rec = np.zeros(8 * width + extra, np.float32)
        words = rec.view(np.uint32)
        rec[:3 * width], rec[3 * width:6 * width] = np.inf, -np.inf
        words[7 * width:8 * width] = EMPTY
        for j, c in enumerate(kids):
            rec[j:3 * width:width] = lo[c]
            rec[3 * width + j:6 * width:width] = hi[c]
            if leaf[c]:
                words[6 * width + j], words[7 * width + j] = first[c], LEAF | count[c]
            else:
                words[6 * width + j], words[7 * width + j] = build(c), 0
        if ordered:
            words[8 * width:] = octant_order(root, LEVELS[width], leaf, axis, above, kids)
        records[index] = rec
        return index

    build(0)
    return np.concatenate(records)


def sort_rays(o, d, tree):
    """o, d in kdray.ray_order's order (octant, then the Morton code of the cell of a
    16^3 grid where the ray enters the box), sorted on the host: what trace_rays reads
    its rays in through trees of 16 MiB and more."""
    from kdray.ray_order import ray_keys
    lo, hi = tree.world_box()
    order = np.argsort(ray_keys(o, d, lo, hi), kind="stable")
    return np.ascontiguousarray(o[order]), np.ascontiguousarray(d[order])


def rays_of(kind, tree, n, rng, mesh=None):
    """(o, d) (n, 3) float64 of a kind: uniform, centre or ao (bench_embree's)."""
    lo, hi = tree.world_box()
    d = rng.normal(size=(n, 3))
    if kind == "uniform":
        return rng.uniform(lo, hi, (n, 3)), d
    if kind == "centre":
        return np.broadcast_to(0.5 * (lo + hi), (n, 3)).copy(), d
    if kind == "ao":
        from bench_embree import AO_OFFSET, ao_rays
        return ao_rays(mesh, n, rng, AO_OFFSET * np.linalg.norm(np.subtract(hi, lo)))
    raise SystemExit(f"unknown kind {kind!r}: uniform, centre or ao")


class WideKernel:
    """The wide kernel of one Tracer on one set of rays; call() -> (t, input id)."""

    def __init__(self, tracer, width, interleave, o, d, count=False, direct=False,
                 ordered=False):
        import pyopencl as cl
        self.tracer, self.interleave, self.n = tracer, interleave, len(d)
        records = wide_nodes(tracer.tree, tracer.packet, width, ordered)
        self.n_wide = len(records) // (8 * width + (8 if ordered else 0))
        defines = {"W_N": width, "W_R": interleave, "PACKET": tracer.packet,
                   "PACKET_STACK_SIZE": tracer.packet_stack_size,
                   "STACK_SIZE": tracer.stack_size}
        if tracer.refine:
            defines["REFINE"] = None      # kd_ray_leaf's test as trace_rays takes it
        if count:
            defines["W_COUNT"] = None
        if direct:
            defines["W_DIRECT"] = None
        if ordered:
            defines["W_ORDER"] = None
        entry = tracer._built(os.path.join(HERE, "wide_nodes.cl"), defines, ("wide_trace",))
        self.kernel = entry["wide_trace"]
        o32, d32 = ray_input.rays32(o, d, 1, tracer._origin, tracer._scale)
        mf, ctx = cl.mem_flags, tracer.context
        self.wide = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=records)
        self.o = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=np.ascontiguousarray(o32))
        self.d = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=np.ascontiguousarray(d32))
        self.t = np.empty(self.n, np.float32)
        self.ids = np.empty(self.n, np.uint32)
        self.t_buf = cl.Buffer(ctx, mf.WRITE_ONLY, self.t.nbytes)
        self.id_buf = cl.Buffer(ctx, mf.WRITE_ONLY, self.ids.nbytes)

    def __call__(self):
        import pyopencl as cl
        q, tr = self.tracer.queue, self.tracer
        items = -(-self.n // self.interleave)
        self.kernel(q, (-(-items // 16) * 16,), (16,), self.wide, tr._tris, tr._tri_ids,
                    tr._bounds, self.o, self.d, np.uint32(self.n), self.t_buf, self.id_buf)
        cl.enqueue_copy(q, self.t, self.t_buf)
        cl.enqueue_copy(q, self.ids, self.id_buf)
        q.finish()
        return self.t, self.ids


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--meshes", default="bunny,bunny-1.6M")
    p.add_argument("--kinds", default="uniform,centre")
    p.add_argument("--width", type=int, default=8, choices=(8, 16))
    p.add_argument("--interleave", type=int, default=2)
    p.add_argument("--rays", type=int, default=1 << 20)
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--repeat", type=int, default=5)
    p.add_argument("--direct", action="store_true",
                   help="a node's nearest child taken next without the stack (W_DIRECT)")
    p.add_argument("--ordered", action="store_true",
                   help="hit children pushed in their octant's order, near and far planes "
                        "chosen by the direction's signs (W_ORDER; --width 8)")
    p.add_argument("--sorted", action="store_true",
                   help="rays sorted on the host first in kdray.ray_order's order, for both")
    args = p.parse_args()
    for name in args.meshes.split(","):
        m = load_mesh(name)
        tree = kdray.build(m.vertices, m.faces)
        tracer = kdray.Tracer(tree)
        for kind in args.kinds.split(","):
            o, d = rays_of(kind, tree, args.rays, np.random.default_rng(0), m)
            if args.sorted:
                o, d = sort_rays(o, d, tree)
            wide = WideKernel(tracer, args.width, args.interleave, o, d, direct=args.direct,
                              ordered=args.ordered)
            _, ids = wide()
            hits = tracer.trace(o, d, outputs=())
            bad = int(np.count_nonzero(ids != hits.prim))
            visits = WideKernel(tracer, args.width, args.interleave, o, d, count=True,
                                direct=args.direct, ordered=args.ordered)()[0]
            visits = visits.astype(np.int64)
            print(f"{name} {kind}: {wide.n_wide} wide nodes of {args.width}, "
                  f"{(visits % 1000).mean():.2f} of them and {(visits // 1000).mean():.2f} "
                  f"leaves a ray; hit triangles unlike trace's: {bad} of {len(ids)}")
            ratios = []
            for _ in range(args.rounds):
                a, b = [], []
                for _ in range(args.repeat):
                    t0 = time.perf_counter()
                    wide()
                    a.append(time.perf_counter() - t0)
                    t0 = time.perf_counter()
                    tracer.trace(o, d, outputs=())
                    b.append(time.perf_counter() - t0)
                ratios.append(np.median(a) / np.median(b))
                print(f"  wide {1e3 * np.median(a):.1f} ms, trace {1e3 * np.median(b):.1f} ms, "
                      f"wide / trace {ratios[-1]:.3f}")
            print(f"  median wide / trace: {np.median(ratios):.3f}")


if __name__ == "__main__":
    main()
