"""Where a kernel's time goes, instruction by instruction, on a CPU runtime that
compiles kernels in memory (Intel's): `perf record` samples of renders or traces,
mapped onto the kernel's machine code, which is copied out of the process at the end.

usage (Linux `perf` and binutils' `objdump`):
    .venv/bin/python bench/profile_kernel.py [--mesh bunny] [--call render]
        [--seconds 8] [--out /tmp/kdray-profile]

The script runs itself under `perf record -F 2000` (--child), warms the Tracer up,
calls `render` (depth only), `render-default` (the default AOVs), `trace` (the
framing camera's (N, 3) float64 rays, t and prim) or `trace-miss` (the same rays
turned to miss the tree's box, from origins five times farther out: what a trace
pays to read its rays and write its hits, with no traversal) or `trace-uniform`
(2^18 incoherent rays: origins uniform in the box, random directions) or `count` (the
camera's rays' crossing counts, kdray.rays) or `count-uniform` and `occluded-uniform`
(those queries of the incoherent rays) for --seconds, and
copies every
executable anonymous mapping of the process (where Intel's runtime puts compiled
kernels: perf sees them only as "[JIT]" addresses) to --out. It then counts the
samples that fall in each mapping, disassembles the busiest one (objdump), and
writes:

  annotated.txt   every instruction of that mapping with its sample count
  windows.txt     the share of samples in each 256-byte window (over 0.5 %)

and prints the windows and the 30 busiest instructions. A sample lands on the
instruction after the one that stalled (skid), so read the counts in context; match
code to source by its landmarks (the node step's `vdivps`, the triangle test's three
`vcmpeqps` against zero, `vgatherdps` for a leaf's triangles gathered ray by ray).
PoCL's kernels are shared objects instead, which `perf report` names itself
(BENCHMARKS.md, "Timing in turns").
"""
import argparse
import collections
import os
import re
import shutil
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)


def child(args):
    """Run the calls for --seconds, then copy the executable anonymous mappings."""
    from meshes import framed
    import numpy as np
    import kdray
    _, tree, camera, o, d = framed(args.mesh, args.size)
    tracer = kdray.Tracer(tree)
    if args.call == "trace-miss":
        lo, hi = tree.world_box()
        centre = (lo + hi) / 2
        o = o + 5 * (o - centre)
        d = np.ascontiguousarray((o[0] - centre) + (d - d.mean(axis=0)))
    if args.call.endswith("-uniform"):
        lo, hi = (np.asarray(x, dtype=np.float64) for x in tree.world_box())
        rng = np.random.default_rng(1)
        o, d = lo + (hi - lo) * rng.random((1 << 18, 3)), rng.normal(size=(1 << 18, 3))
    trace = lambda: tracer.trace(o, d, outputs=())  # noqa: E731
    call = {"render": lambda: tracer.render(camera, aovs=("depth",)),
            "render-default": lambda: tracer.render(camera),
            "trace": trace, "trace-miss": trace, "trace-uniform": trace,
            "count": lambda: tracer.count(o, d), "count-uniform": lambda: tracer.count(o, d),
            "occluded-uniform": lambda: tracer.occluded(o, d),
            "contains-uniform": lambda: tracer.contains(o),
            "intersections": lambda: tracer.intersections(o, d)}[args.call]
    call()
    call()
    start, calls = time.perf_counter(), 0
    while time.perf_counter() - start < args.seconds:
        call()
        calls += 1
    print(f"{calls} calls, {1e3 * (time.perf_counter() - start) / calls:.2f} ms each")
    os.makedirs(args.out, exist_ok=True)
    with open("/proc/self/maps") as f, open("/proc/self/mem", "rb") as mem:
        for line in f:
            fields = line.split()
            if len(fields) != 5 or "x" not in fields[1]:
                continue                  # named mappings (files, [vdso]) are not JIT code
            lo, hi = (int(x, 16) for x in fields[0].split("-"))
            try:
                mem.seek(lo)
                data = mem.read(hi - lo)
            except OSError:
                continue
            with open(os.path.join(args.out, f"code_{lo:x}.bin"), "wb") as out:
                out.write(data)


def report(args, perf_data):
    """Samples per mapping; the busiest mapping annotated."""
    script = subprocess.run(["perf", "script", "-i", perf_data, "-F", "ip"],
                            capture_output=True, text=True, check=True).stdout
    ips = collections.Counter(int(x, 16) for x in script.split())
    total = sum(ips.values())
    regions = []
    for name in os.listdir(args.out):
        m = re.fullmatch(r"code_([0-9a-f]+)\.bin", name)
        if m:
            lo = int(m.group(1), 16)
            regions.append((lo, lo + os.path.getsize(os.path.join(args.out, name)), name))
    counts = {r: sum(n for ip, n in ips.items() if r[0] <= ip < r[1]) for r in regions}
    if not counts or max(counts.values()) == 0:
        sys.exit("no samples fell in an executable anonymous mapping (not Intel's runtime?)")
    lo, hi, name = max(counts, key=counts.get)
    inside = counts[(lo, hi, name)]
    print(f"{total} samples; {inside} ({100 * inside / total:.1f} %) in {name} "
          f"({hi - lo} bytes), the kernels' code")
    dis = subprocess.run(["objdump", "-D", "-b", "binary", "-m", "i386:x86-64",
                          f"--adjust-vma={lo:#x}", os.path.join(args.out, name)],
                         capture_output=True, text=True, check=True).stdout
    rows = []
    for line in dis.splitlines():
        m = re.match(r"\s*([0-9a-f]+):\s", line)
        rows.append((ips.get(int(m.group(1), 16), 0) if m else 0, line))
    with open(os.path.join(args.out, "annotated.txt"), "w") as f:
        f.writelines(f"{n:6d} {line}\n" for n, line in rows)
    windows = collections.Counter()
    for ip, n in ips.items():
        if lo <= ip < hi:
            windows[(ip - lo) // 256] += n
    lines = [f"{256 * w:6x} {100 * n / inside:5.1f} %" for w, n in sorted(windows.items())
             if n > 0.005 * inside]
    with open(os.path.join(args.out, "windows.txt"), "w") as f:
        f.write("\n".join(lines) + "\n")
    print("offset  share of the kernels' samples (256-byte windows over 0.5 %)")
    print("\n".join(lines))
    print("busiest instructions (samples, address, bytes, instruction):")
    for n, line in sorted(rows, key=lambda r: -r[0])[:30]:
        print(f"{n:6d} {line.strip()}")
    print(f"annotated listing: {os.path.join(args.out, 'annotated.txt')}")


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--mesh", default="bunny")
    p.add_argument("--call", default="render", choices=("render", "render-default", "trace", "trace-miss",
                                                    "trace-uniform", "count", "count-uniform",
                                                    "occluded-uniform", "contains-uniform", "intersections"))
    p.add_argument("--size", type=int, default=1024)
    p.add_argument("--seconds", type=float, default=8.0)
    p.add_argument("--out", default="/tmp/kdray-profile")
    p.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = p.parse_args()
    if args.child:
        return child(args)
    for tool in ("perf", "objdump"):
        if shutil.which(tool) is None:
            sys.exit(f"{tool} is not installed")
    shutil.rmtree(args.out, ignore_errors=True)
    os.makedirs(args.out)
    perf_data = os.path.join(args.out, "perf.data")
    subprocess.run(["perf", "record", "-q", "-F", "2000", "-o", perf_data, sys.executable,
                    os.path.abspath(__file__), "--child", "--mesh", args.mesh, "--call",
                    args.call, "--size", str(args.size), "--seconds", str(args.seconds),
                    "--out", args.out], check=True)
    report(args, perf_data)


if __name__ == "__main__":
    main()
