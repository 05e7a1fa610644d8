"""A call after the process has been idle, against back-to-back calls: with kdray
binding the CPU runtimes' worker threads to cores (its default,
`kdray.runtimes.thread_binding`) and without (KDRAY_BIND_THREADS=0).

usage: python bench/bench_idle.py [--mesh bunny] [--size 1024] [--calls 20] [--pairs 3]
                                  [--device intel]

Each setting runs in a fresh process (pairs of them, the order swapped every other
pair, so that the machine's drift hits both alike), which loads the mesh's tree
(built once here), makes a Tracer on --device (default: the default device) and warms
up. It then times
`--calls` calls of each kind, first back to back (pause 0), then each one 0.1 s after
the one before (pause 0.1, what bench_trace.py's round robin leaves between calls),
and prints each call's median and 90th percentile over all pairs:

  render depth     Tracer.render(camera, ["depth"]) of the framing camera
  trace t,prim     Tracer.trace(o, d, outputs=()) of the same camera's (N, 3) rays

On Intel's runtime the thread that waits for a kernel works on it beside the runtime's
worker threads; unbound, a worker woken after an idle moment can be placed on that
thread's core and share it until Linux's load balancer moves one (BENCHMARKS.md,
"Calls after an idle moment"). PoCL's workers alone run its kernels; unbound, its calls
had a long tail too.
"""
import argparse
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

ENVIRON = dict(os.environ)
"""The environment before kdray is imported here (kdray adds Intel's variables to it)."""

PAUSES = (0.0, 0.1)
CALLS = ("render depth", "trace t,prim")
SETTINGS = {"bound (default)": {}, "unbound": {"KDRAY_BIND_THREADS": "0"}}


def child(tree_path, size, n_calls, device):
    """Print one line per (call, pause): 'call|pause|seconds seconds ...'."""
    import kdray
    tree = kdray.KdTree.load(tree_path)
    lo, hi = tree.world_box()
    camera = kdray.Camera.frame(lo, hi, size, size)
    o, d = camera.rays()
    tracer = kdray.Tracer(tree, device=device or None)
    calls = {"render depth": lambda: tracer.render(camera, ["depth"]),
             "trace t,prim": lambda: tracer.trace(o, d, outputs=())}
    for fn in calls.values():
        for _ in range(3):
            fn()
    print(f"device|{tracer.device.name.strip()} ({tracer.device.platform.name.strip()})")
    for pause in PAUSES:
        for name, fn in calls.items():
            seconds = []
            for _ in range(n_calls):
                time.sleep(pause)
                t0 = time.perf_counter()
                fn()
                seconds.append(time.perf_counter() - t0)
            print(f"{name}|{pause}|{' '.join(repr(s) for s in seconds)}", flush=True)


def main():
    if len(sys.argv) > 1 and sys.argv[1] == "--child":
        return child(sys.argv[2], int(sys.argv[3]), int(sys.argv[4]), sys.argv[5])
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mesh", default="bunny")
    ap.add_argument("--size", type=int, default=1024)
    ap.add_argument("--calls", type=int, default=20, help="timed calls of each kind a process")
    ap.add_argument("--pairs", type=int, default=3)
    ap.add_argument("--device", default="", help="a --device string (default: the default device)")
    args = ap.parse_args()
    import kdray
    from meshes import mesh as bench_mesh
    m = bench_mesh(args.mesh)
    times = {(s, c, p): [] for s in SETTINGS for c in CALLS for p in PAUSES}
    device = None
    with tempfile.TemporaryDirectory() as tmp:
        tree_path = os.path.join(tmp, f"{args.mesh}.kdtree")
        kdray.build(m.vertices, m.faces).save(tree_path)
        for k in range(args.pairs):
            order = list(SETTINGS) if k % 2 == 0 else list(SETTINGS)[::-1]
            for setting in order:
                env = dict(ENVIRON, **SETTINGS[setting])
                out = subprocess.run([sys.executable, __file__, "--child", tree_path,
                                      str(args.size), str(args.calls), args.device],
                                     env=env, capture_output=True, text=True, check=True).stdout
                for line in out.splitlines():
                    call, _, rest = line.partition("|")
                    if call == "device":
                        device = rest
                        continue
                    pause, _, seconds = rest.partition("|")
                    times[setting, call, float(pause)] += [float(s) for s in seconds.split()]
    print(f"# {args.mesh}, {args.size}x{args.size} rays, {device}; {args.pairs} pairs of "
          f"processes, {args.calls} calls of each kind a process")
    print(f"{'setting':<16} {'call':<13} {'pause s':>7} {'median ms':>10} {'p90 ms':>8}")
    for setting in SETTINGS:
        for call in CALLS:
            for pause in PAUSES:
                s = np.array(times[setting, call, pause]) * 1e3
                print(f"{setting:<16} {call:<13} {pause:>7.1f} {np.median(s):>10.2f} "
                      f"{np.percentile(s, 90):>8.2f}")


if __name__ == "__main__":
    main()
