"""Tracing time of the working tree's kdray against an earlier commit's, in turns: the
way to measure a change to the kernels or the Tracer on a machine whose speed drifts
(+-10-20 % over minutes here, more than most changes).

usage: python bench/ab_trace.py [--base HEAD] [--work COMMIT] [--meshes bunny,bunny-1.6M]
                                [--rounds 15] [--pairs 1] [--size 1024] [--packet 8]
                                [--incoherent [--rays 100000]] [--queries]

The base commit's `kdray/` and `kernels/` are exported (git archive) into a temporary
folder, and with --work another commit's too (so that a past change can be measured
against its parent: --base C~1 --work C); without it "work" is the working tree.
For each mesh the working tree builds the tree once and saves it (tree file version
1, which both must read); then two worker processes, one per version, load it, make
a Tracer (with --packet, of that packet width: 8 stands for an AVX2 CPU's packets on
one with AVX-512) and warm up. Each round asks each worker for four timed calls in
turns, the order of the workers reversed every other round and every call 0.1 s
after the one before: `render` (depth only), `render` (the default AOVs), `trace`
(numpy to numpy, the camera's 1024 x 1024 rays in row-major order, which a kdray
with kdray.ray_grid traces as an image) and `trace HxW`
(the same rays shaped (1024, 1024, 3), t and prim only; NaN for a kdray without
image-shaped rays). With --incoherent, three more: `trace` of --rays (100,000) rays in
random directions from the centre of the tree's box and from random points in it
(bench_incoherent.py's rays), and `trace spread`, the camera's rays from origins spread
over 1e-4 of the box's diagonal (a lens's or a projector's: coherent packets of
several origins; t and prim). With --queries, seven more, the queries (kdray.rays)
on the same rays: `count`, `intersections` and `occluded` of the camera's rays,
`count random` and `occluded random` of the rays from random points, and `contains`
and `distance random` (the point query) of those points (NaN for a kdray without
them). Separate processes, so each version has its own memory layout
and OpenCL context. Prints each version's median times, wall and CPU (the worker
process's, all its threads), the medians of the rounds' ratios (working tree / base:
< 1 means faster) and whether the two gave bit-identical images and hits.

A pair of processes can keep a bias of its own for all its rounds (presumably where
the arrays and the compiled kernels happen to lie in memory; an A/A comparison of
one commit against itself gave 0.94-1.11 in one pair). --pairs K starts K pairs one
after the other, each for --rounds rounds, and prints each pair's median ratio
beside the median over all rounds: pairs that disagree by more than the change
measured mean that the change is not shown.
"""
import argparse
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, HERE)
from ab_build import git_export  # noqa: E402

ENVIRON = dict(os.environ)
"""The environment as this process started, before it imported kdray (which sets
variables for the CPU runtimes, `kdray.runtimes.thread_binding`): each worker starts
from it, so that its own kdray sets what it sets."""

CALLS = ("render depth", "render default", "trace", "trace HxW")
INCOHERENT = ("random centre", "random points", "trace spread")
QUERIES = ("count", "intersections", "count random", "contains", "occluded",
           "occluded random", "distance random")


def worker(tree_path, size, out_path, packet=0, n_rays=100_000):
    """Serve timed calls on stdin ("render depth", ...): print each one's seconds.
    Writes the outputs of one call of each to out_path (npz) first. packet: the
    Tracer's packet width, 0 for the device's default; n_rays: the incoherent sets'
    rays."""
    import kdray
    tree = kdray.KdTree.load(tree_path)
    # (a base commit may predate KdTree.world_box; scale-1 trees need no scale)
    lo, hi = tree.origin + tree.bounds.astype(np.float64)
    camera = kdray.Camera.frame(lo, hi, size, size)
    o, d = camera.rays()
    tracer = kdray.Tracer(tree, packet=packet or None)
    from bench_incoherent import ray_sets, spread_origins
    (oc, dc), (op, dp) = ray_sets(tree, n_rays).values()
    shape = (size, size, 3)
    spread = spread_origins(o, lo, hi, 1e-4)
    calls = {"render depth": lambda: tracer.render(camera, aovs=("depth",)),
             "render default": lambda: tracer.render(camera),
             "trace": lambda: tracer.trace(o, d),
             "trace HxW": lambda: tracer.trace(o.reshape(shape), d.reshape(shape), outputs=()),
             "random centre": lambda: tracer.trace(oc, dc),
             "random points": lambda: tracer.trace(op, dp),
             "trace spread": lambda: tracer.trace(spread, d, outputs=())}
    queries = {}
    if hasattr(tracer, "count"):          # a kdray with the ray queries
        calls.update({"count": lambda: tracer.count(o, d),
                      "intersections": lambda: tracer.intersections(o, d),
                      "count random": lambda: tracer.count(op, dp),
                      "contains": lambda: tracer.contains(op),
                      "occluded": lambda: tracer.occluded(o, d),
                      "occluded random": lambda: tracer.occluded(op, dp),
                      "distance random": lambda: tracer.distance(op)})
        listed = calls["intersections"]()
        queries = {k: calls[k]() for k in QUERIES if k != "intersections"}
        queries.update({"intersections offsets": listed.offsets,
                        "intersections prim": listed.prim})
    else:
        calls.update({k: (lambda: None) for k in QUERIES})
    images = calls["render default"]()
    hits = calls["trace"]()
    incoherent = {k: calls[k]().prim for k in INCOHERENT}
    calls["render depth"]()
    try:
        calls["trace HxW"]()
    except kdray.KdrayError:               # a kdray before image-shaped rays: not timed
        calls["trace HxW"] = lambda: None
    np.savez(out_path, **{f"render {k}": v for k, v in images.items()},
             **{f"trace {k}": getattr(hits, k) for k in ("t", "prim", "u", "v", "normal")},
             **{f"{k} prim": v for k, v in incoherent.items()}, **queries)
    print("ready", flush=True)
    for line in sys.stdin:
        t0, c0 = time.perf_counter(), time.process_time()
        ran = calls[line.strip()]() is not None
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        print(f"{wall} {cpu}" if ran else "nan nan", flush=True)


def start_workers(name, folder, tree_path, base_root, work_root, size, packet=0,
                  n_rays=100_000):
    """{"base": (process, outputs npz path), "work": ...}: one ready worker per version."""
    workers = {}
    for who, root in (("base", base_root), ("work", work_root)):
        env = dict(ENVIRON, PYTHONPATH=root)
        out = os.path.join(folder, f"{name}-{who}.npz")
        env["PYTHONPATH"] += os.pathsep + HERE          # bench_incoherent's rays
        p = subprocess.Popen([sys.executable, __file__, "--worker", tree_path, str(size), out,
                              str(packet), str(n_rays)],
                             stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=env,
                             cwd=root)
        if p.stdout.readline().strip() != "ready":
            raise SystemExit(f"the {who} worker failed to start")
        workers[who] = (p, out)
    return workers


def timed_rounds(workers, rounds, calls=CALLS):
    """{(who, call): (rounds, 2) seconds, wall and the worker's CPU time (all its
    threads)}: every call of both workers, in turns."""
    from timing import ROUND_ROBIN_PAUSE
    seconds = {(who, c): [] for who in workers for c in calls}
    for r in range(rounds):
        for who in (("base", "work") if r % 2 == 0 else ("work", "base")):
            p = workers[who][0]
            for c in calls:
                time.sleep(ROUND_ROBIN_PAUSE)
                p.stdin.write(c + "\n")
                p.stdin.flush()
                seconds[who, c].append([float(x) for x in p.stdout.readline().split()])
    for p, _ in workers.values():
        p.stdin.close()
        p.wait()
    return {k: np.array(v) for k, v in seconds.items()}


def compare(name, folder, base_root, work_root, rounds, size, pairs=1, calls=CALLS, packet=0,
            n_rays=100_000):
    """Both versions on one mesh, in turns, in `pairs` pairs of fresh processes one
    after the other; prints the medians and ratios. Every pair's outputs are compared
    (each process computes its own). packet: the Tracers' packet width (0: default)."""
    import kdray
    from meshes import mesh as bench_mesh
    from timing import median_ratio
    m = bench_mesh(name)
    tree_path = os.path.join(folder, f"{name}.kdtree")
    kdray.build(m.vertices, m.faces).save(tree_path)
    same = True
    runs = []
    for _ in range(pairs):
        workers = start_workers(name, folder, tree_path, base_root, work_root, size, packet,
                                n_rays)
        a, b = (np.load(workers[who][1]) for who in ("base", "work"))
        same &= sorted(a.files) == sorted(b.files) and all(
            np.array_equal(a[k], b[k], equal_nan=True) for k in a.files)
        runs.append(timed_rounds(workers, rounds, calls))
    for c in calls:
        base = np.concatenate([s["base", c] for s in runs])
        work = np.concatenate([s["work", c] for s in runs])
        for k, what in enumerate(("wall", "cpu")):
            each = ""
            if pairs > 1:
                each = ", pairs " + " ".join(
                    f"{median_ratio(s['work', c][:, k], s['base', c][:, k]):.3f}" for s in runs)
            print(f"{name:<12} {c:<15} {what:<4} base {np.median(base[:, k]):.4f} s, work "
                  f"{np.median(work[:, k]):.4f} s, work / base "
                  f"{median_ratio(work[:, k], base[:, k]):.3f} "
                  f"(median of {len(base)} rounds{each})", flush=True)
    print(f"{name:<12} outputs {'identical' if same else 'DIFFER'}", flush=True)


def main():
    if len(sys.argv) > 1 and sys.argv[1] == "--worker":
        return worker(sys.argv[2], int(sys.argv[3]), sys.argv[4], int(sys.argv[5]),
                      int(sys.argv[6]))
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", default="HEAD", help="commit to compare with (default HEAD)")
    ap.add_argument("--work", default=None, help="commit to measure (default: the working tree)")
    ap.add_argument("--meshes", default="bunny,bunny-1.6M")
    ap.add_argument("--rounds", type=int, default=15, help="rounds a pair of processes")
    ap.add_argument("--pairs", type=int, default=1,
                    help="pairs of worker processes, one after the other (default 1)")
    ap.add_argument("--size", type=int, default=1024)
    ap.add_argument("--packet", type=int, default=0,
                    help="the Tracers' packet width: 1, 8 or 16 (default: the device's)")
    ap.add_argument("--rays", type=int, default=100_000,
                    help="rays in each --incoherent set (default 100,000)")
    ap.add_argument("--incoherent", action="store_true",
                    help="also time --rays rays in random directions (two sets)")
    ap.add_argument("--queries", action="store_true",
                    help="also time the queries (count, intersections, contains, occluded, "
                         "distance)")
    args = ap.parse_args()
    calls = CALLS + (INCOHERENT if args.incoherent else ()) + (QUERIES if args.queries else ())
    sys.path.insert(0, ROOT)
    with tempfile.TemporaryDirectory() as tmp:
        roots = {}
        for who, commit in (("base", args.base), ("work", args.work)):
            roots[who] = ROOT
            if commit is not None:
                roots[who] = os.path.join(tmp, who)
                os.mkdir(roots[who])
                git_export(commit, roots[who], ["kdray", "kernels"])
        for name in args.meshes.split(","):
            compare(name, tmp, roots["base"], roots["work"], args.rounds, args.size,
                    args.pairs, calls, args.packet, args.rays)


if __name__ == "__main__":
    main()
