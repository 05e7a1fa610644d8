"""Cold start: the time of a first `kdray render` on a fresh install, step by step,
and of the runs after it, when the on-disk caches are warm.

    .venv/bin/python bench/bench_cold.py                       # scenes/cornell.obj, 640x480
    .venv/bin/python bench/bench_cold.py scenes/sphere.obj --warm 5

Each run is `python -X importtime -m kdray.cli -v render SCENE` in a fresh process.
"Cold" runs get empty caches of their own: numba's compiled builder (NUMBA_CACHE_DIR;
about 20 s to compile on 2 cores), PoCL's compiled kernels (POCL_CACHE_DIR) and
everything under XDG_CACHE_HOME (pyopencl's and pytools' caches). "Warm" runs then
reuse those caches. Python's bytecode (.pyc) and the operating system's file cache
stay as they are: a fresh `pip install` writes the .pyc of its packages, and nothing
here may drop the file cache of a shared machine.

The split comes from `kdray -v`'s step timings: load (reading the mesh, with trimesh's
import), build (numba's import and its compile or cache load, then the build), device
(pyopencl's import, context, upload), kernel compile (building the program and the
first launch on one pixel, where PoCL compiles the kernel again for its work-group
size), trace, write (with OpenImageIO's import). "start-up" is from the process's start
to the command (`kdray -v` logs it): the interpreter and `import kdray.cli` (numpy,
click); "exit" is the rest of the wall time (starting the process, releasing the
OpenCL context, the interpreter's shutdown). "all imports" is the sum of
-X importtime's top-level imports, which are spread over the steps above.
"""
import argparse
import datetime
import os
import platform
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

STEPS = (("start-up", "start-up"), ("load", "loading"), ("build", "building"),
         ("device", "setting up the device"), ("kernel compile", "compiling the kernels"),
         ("trace", "tracing"), ("write", "writing"))


def run_once(scene, size, env, out):
    """One `kdray -v render` in a fresh process: {row: seconds}, and the top imports."""
    cmd = [sys.executable, "-X", "importtime", "-m", "kdray.cli", "-v", "render", str(scene),
           "--size", size, "-o", str(out)]
    started = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=ROOT)
    wall = time.perf_counter() - started
    if proc.returncode != 0:
        tail = "\n".join(line for line in proc.stderr.splitlines() if "import time:" not in line)
        raise SystemExit(f"kdray render failed ({proc.returncode}):\n{tail[-2000:]}")
    steps = None
    imports = {}
    for line in proc.stderr.splitlines():
        m = re.match(r"import time:\s+\d+ \|\s+(\d+) \|( *)(\S+)", line)
        if m:
            if len(m.group(2)) == 1:          # a top-level import (not nested in another)
                name = m.group(3).split(".")[0]
                imports[name] = imports.get(name, 0.0) + int(m.group(1)) * 1e-6
        elif line.startswith("kdray: start-up"):
            steps = dict((k, float(v)) for k, v in re.findall(r"(.+?) (\d+\.\d+) s(?:, |$)", line[7:]))
    if steps is None:
        raise SystemExit("no step timings in kdray -v's output")
    row = {}
    for name, prefix in STEPS:
        row[name] = sum(v for k, v in steps.items() if k.startswith(prefix))
    row["exit"] = wall - sum(steps.values())
    row["total (wall)"] = wall
    row["all imports"] = sum(imports.values())
    return row, imports


def cpu_name():
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown CPU"


def opencl_name():
    try:
        from kdray.device import choose_device
        d = choose_device(None)
        return f"{d.name.strip()}, {d.platform.version.split(' Linux')[0].strip()}"
    except Exception as e:  # the table is still useful without it
        return f"unknown OpenCL device ({e})"


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("scene", nargs="?", default=str(ROOT / "scenes" / "cornell.obj"))
    parser.add_argument("--size", default="640x480")
    parser.add_argument("--cold", type=int, default=1, help="cold runs, each with new empty caches")
    parser.add_argument("--warm", type=int, default=3, help="warm runs after the first cold one")
    args = parser.parse_args()

    cold, warm, top = [], [], {}
    with tempfile.TemporaryDirectory(prefix="kdray-cold-") as tmp:
        tmp = Path(tmp)
        envs = []
        for i in range(args.cold):
            caches = tmp / f"caches{i}"
            env = dict(os.environ, NUMBA_CACHE_DIR=str(caches / "numba"),
                       POCL_CACHE_DIR=str(caches / "pocl"), XDG_CACHE_HOME=str(caches / "xdg"))
            env.pop("POCL_KERNEL_CACHE", None)
            env.pop("PYOPENCL_NO_CACHE", None)
            envs.append(env)
            row, top = run_once(args.scene, args.size, env, tmp / "out.exr")
            cold.append(row)
        for _ in range(args.warm):
            warm.append(run_once(args.scene, args.size, envs[0], tmp / "out.exr")[0])

    names = [name for name, _ in STEPS] + ["exit", "total (wall)", "all imports"]
    scene = os.path.relpath(args.scene, ROOT)
    print(f"### Cold start of `kdray render` ({datetime.date.today().isoformat()})\n")
    print(f"{cpu_name()}, {os.cpu_count()} cores, {opencl_name()}; Python {platform.python_version()}.")
    print(f"`{scene}` at {args.size}. Command (from the repository root):\n")
    print("```\n.venv/bin/python bench/bench_cold.py "
          + " ".join(sys.argv[1:]) + "\n```\n")
    print(f"Each run: `python -X importtime -m kdray.cli -v render {scene} --size {args.size}` in a "
          f"fresh process. Cold: empty numba, PoCL and XDG (pyopencl) caches"
          + (f" (median of {args.cold})" if args.cold > 1 else "")
          + f"; warm: the same caches filled, median of {args.warm}. Seconds.\n")
    print("| step | cold | warm |")
    print("|---|---:|---:|")
    for name in names:
        c = statistics.median(r[name] for r in cold)
        w = statistics.median(r[name] for r in warm) if warm else float("nan")
        print(f"| {name} | {c:.2f} | {w:.2f} |")
    biggest = sorted(top.items(), key=lambda kv: -kv[1])[:6]
    print("\nLargest top-level imports (cold run): "
          + ", ".join(f"{k} {v:.2f} s" for k, v in biggest) + ".")


if __name__ == "__main__":
    main()
