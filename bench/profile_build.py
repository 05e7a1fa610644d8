"""Where a build's time goes, by numba function: builds under `perf record` with a perf
map of kdray's compiled functions, so that `perf report` names them.

usage (Linux `perf`, e.g. Debian's linux-perf):
    NUMBA_CACHE_DIR=$(mktemp -d) perf record -F 4000 -o perf.data \\
        .venv/bin/python bench/profile_build.py --mesh bunny --builds 200 --threads 1
    perf report -i perf.data --time 40%-100% --no-children --sort symbol

A fresh NUMBA_CACHE_DIR makes numba compile in this process (functions loaded from
its cache keep no symbol table); `--time 40%-100%` leaves the compile out of the report.
LLVM inlines small callees into their callers, so a name covers what it inlined.
After the first build the map /tmp/perf-PID.map lists every compiled function of
kdray.build (perf reads it for JIT code).
"""
import argparse
import os
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)


def write_perf_map(prefix="kdray"):
    """Write /tmp/perf-PID.map (start, size, name) for the numba functions compiled in
    this process by modules whose name starts with `prefix`; returns how many."""
    from numba.core.registry import CPUDispatcher
    entries = {}
    for name, module in list(sys.modules.items()):
        if not name.startswith(prefix):
            continue
        for obj in list(vars(module).values()):
            if not isinstance(obj, CPUDispatcher):
                continue
            for cres in obj.overloads.values():
                library = cres.library
                for fn in library._final_module.functions:
                    if not fn.is_declaration:
                        address = library.get_pointer_to_function(fn.name)
                        if address:
                            entries[address] = fn.name
    starts = sorted(entries)
    with open(f"/tmp/perf-{os.getpid()}.map", "w") as f:
        for i, start in enumerate(starts):
            size = starts[i + 1] - start if i + 1 < len(starts) else 4096
            f.write(f"{start:x} {min(size, 1 << 20):x} {entries[start]}\n")
    return len(starts)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mesh", default="bunny")
    ap.add_argument("--builds", type=int, default=200)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--leaf-size", type=int, default=0,
                    help="build parameter (e.g. 64: nodes of up to 64 triangles are leaves; "
                         "the difference to 0 is what the small nodes cost)")
    args = ap.parse_args()
    import kdray
    from meshes import mesh as bench_mesh
    m = bench_mesh(args.mesh)
    kw = dict(threads=args.threads, leaf_size=args.leaf_size)
    kdray.build(m.vertices, m.faces, **kw)
    print(f"perf map: {write_perf_map()} functions", flush=True)
    t0 = time.perf_counter()
    for _ in range(args.builds):
        kdray.build(m.vertices, m.faces, **kw)
    print(f"{args.mesh}: {(time.perf_counter() - t0) / args.builds:.4f} s a build")


if __name__ == "__main__":
    main()
