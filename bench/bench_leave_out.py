"""What leaving out unneeded work saves: outputs, stack, degenerate triangles.

usage: python bench/bench_leave_out.py [--mesh bunny] [--size 1024] [--repeat 7]

1. Outputs. `Tracer.render` compiles a kernel with only the outputs the AOVs need and
   allocates only their buffers. For each AOV set: the kernel outputs compiled in,
   device and host bytes per pixel, and the warm render time (median of --repeat);
   the saving of an AOV set is its time and bytes against computing everything
   (depth, normal, bary, id).
2. Stack. The stack is sized from the tree's depth (depth + 1 entries) instead of the
   largest depth a file may hold (64): private memory per work-item and render time,
   single rays (short-stack ring, 12 bytes an entry) and packets (100 bytes an entry).
3. Degenerate triangles. The mesh with 20 % zero-area triangles added (half with a
   repeated vertex index, half with a copy of a vertex at a new index) builds the same tree as the clean mesh (nodes and
   references equal); the cost of finding them is the builder's prepare step.
(Culling to the view frustum, `kdray render --cull`, is measured in BENCHMARKS.md.)
"""
import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from meshes import mesh as bench_mesh  # noqa: E402

import kdray  # noqa: E402
from kdray.bench import timed  # noqa: E402
from kdray.layout import OUTPUT_WIDTH  # noqa: E402
from kdray.render import host_bytes_per_pixel, kernel_outputs  # noqa: E402

AOV_SETS = [("depth",), ("depth", "normal"), ("depth", "bary"), ("depth", "id"),
            ("depth", "normal", "bary", "id"), ("distance",), ("position",)]


def outputs(tracer, camera, repeat):
    print("\n## outputs (AOV sets)")
    print(f"{'AOVs':<28} {'kernel outputs':<18} {'device B/px':>11} {'host B/px':>9} {'render s':>9}")
    full = None
    for aovs in AOV_SETS:
        s = timed(lambda: tracer.render(camera, aovs=aovs), repeat)[0]
        outs = kernel_outputs(aovs)
        device = sum(OUTPUT_WIDTH[o][0] * 4 for o in outs)
        host = host_bytes_per_pixel(aovs)
        if len(aovs) == 4:
            full = (s, device)
        print(f"{','.join(aovs):<28} {' '.join(outs):<18} {device:>11} {host:>9} {s:>9.4f}", flush=True)
    return full


def stack(tree, camera, repeat):
    print("\n## stack size")
    print(f"{'kernel':<8} {'entries':>7} {'private B':>9} {'render s':>9}")
    chosen = kdray.trace.default_stack_size(tree)
    for packet, entry_bytes in ((1, 12), (8, 100)):
        for size in (chosen, 64):
            if packet == 1:
                tracer = kdray.Tracer(tree, packet=1, stack_size=size)
            else:
                tracer = kdray.Tracer(tree, packet=8)
                tracer.packet_stack_size = size
            s = timed(lambda: tracer.render(camera, aovs=("depth",)), repeat)[0]
            kind = "packet" if packet == 8 else "single"
            print(f"{kind:<8} {size:>7} {size * entry_bytes:>9} {s:>9.4f}", flush=True)


def degenerate(m, repeat):
    print("\n## degenerate triangles")
    rng = np.random.default_rng(0)
    n = len(m.faces) // 5
    pick = rng.choice(len(m.faces), n)
    zero_area = m.faces[pick].copy()
    zero_area[: n // 2, 2] = zero_area[: n // 2, 1]                 # a repeated index
    v = m.vertices
    verts = np.concatenate([v, v[zero_area[n // 2:, 0]]])           # a copied vertex
    zero_area[n // 2:, 2] = len(v) + np.arange(n - n // 2)
    faces = np.concatenate([m.faces, zero_area])
    clean = kdray.build(m.vertices, m.faces)
    s_clean = timed(lambda: kdray.build(m.vertices, m.faces), repeat)[0]
    dirty = kdray.build(verts, faces)
    s_dirty = timed(lambda: kdray.build(verts, faces), repeat)[0]
    same = (np.array_equal(clean.nodes, dirty.nodes) and np.array_equal(clean.leaf_tris, dirty.leaf_tris)
            and np.array_equal(clean.triangles, dirty.triangles))
    left = dirty.n_input_tris - len(dirty.tri_ids)
    print(f"clean mesh:   {len(m.faces):>9} triangles, build {s_clean:.3f} s")
    print(f"with {n} zero-area added: {len(faces):>9} triangles, {left} left out, build {s_dirty:.3f} s, "
          f"tree identical: {same}, ids point into the input: "
          f"{bool(np.all(dirty.tri_ids < len(m.faces)))}")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--mesh", default="bunny")
    ap.add_argument("--size", type=int, default=1024)
    ap.add_argument("--repeat", type=int, default=7)
    args = ap.parse_args()
    m = bench_mesh(args.mesh)
    tree = kdray.build(m.vertices, m.faces)
    lo, hi = tree.world_box()
    camera = kdray.Camera.frame(lo, hi, args.size, args.size)
    tracer = kdray.Tracer(tree)
    print(f"# {args.mesh}: {len(m.faces)} triangles, {args.size}x{args.size}, tree depth {tree.depth}, "
          f"{tracer.device.name.strip()}, packet {tracer.packet}")
    outputs(tracer, camera, args.repeat)
    stack(tree, camera, args.repeat)
    degenerate(m, max(1, args.repeat // 2))


if __name__ == "__main__":
    main()
