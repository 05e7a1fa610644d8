"""Build time of the working tree's kdray against an earlier commit's, in turns in one
process: the way to measure a change to the builder on a machine whose speed drifts
(seen here: +-20 % over minutes, so that two separate runs of the same code differ
more than most changes do).

usage: python bench/ab_build.py [--base HEAD] [--meshes bunny,bunny-1.6M] [--rounds 20]
                                [--threads 2] [--processes]

The base commit's `kdray/` is exported (git archive) into a temporary folder as the
package `kdray_base` (kdray imports itself relatively, so it runs under that name);
its numba functions compile there on the first build (about half a minute). After a
warm-up build with each, each round builds the mesh once with each, the order
reversed every other round (`timing.round_robin`). Prints,
per mesh, the median and fastest wall time and the median CPU time of each, the
median of the rounds' time ratios (working tree / base: < 1 means faster), and
whether the two trees are byte-identical.

--processes: each round builds in two new processes instead, one per version (the
order reversed every other round), each making a warm-up build and then three timed
ones (the fastest counts), and prints their page faults too. Slower, but it sees
changes in memory use: in one process the two builders share malloc's free memory,
so that one's page faults can become the other's reuse (in one process, ratios of
successive commits did not compose: 608072e against e9152e8 measured 0.93 at 1.6M,
where the commits between had measured 0.93 x 0.99 x 0.97 x 0.97 = 0.87).
"""
import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, HERE)


def git_export(commit, folder, paths):
    """git archive `commit`'s `paths` (folders of the repository) into folder."""
    archive = subprocess.run(["git", "-C", ROOT, "archive", commit, *paths], check=True,
                             capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", folder], input=archive, check=True)


def export_base(commit, folder):
    """git archive `commit`'s kdray/ into folder/kdray_base; returns folder."""
    git_export(commit, folder, ["kdray"])
    os.rename(os.path.join(folder, "kdray"), os.path.join(folder, "kdray_base"))
    return folder


def child(who, path, threads):
    """One process's builds of the mesh at `path` (npz) with `who` (kdray or
    kdray_base): print {"wall": fastest of three, "cpu": its CPU seconds, "faults":
    its minor page faults} as JSON."""
    import importlib
    build = importlib.import_module(who).build
    data = np.load(path)
    v, f = data["vertices"], data["faces"]
    build(v, f, threads=threads)
    best = None
    for _ in range(3):
        r0, t0 = resource.getrusage(resource.RUSAGE_SELF), time.perf_counter()
        build(v, f, threads=threads)
        wall = time.perf_counter() - t0
        r1 = resource.getrusage(resource.RUSAGE_SELF)
        run = dict(wall=wall, cpu=r1.ru_utime + r1.ru_stime - r0.ru_utime - r0.ru_stime,
                   faults=r1.ru_minflt - r0.ru_minflt)
        if best is None or wall < best["wall"]:
            best = run
    print(json.dumps(best))


def in_processes(name, folder, rounds, threads):
    """--processes: rounds of one new process per version; prints as main does."""
    from meshes import mesh as bench_mesh
    m = bench_mesh(name)
    path = os.path.join(folder, "mesh.npz")
    np.savez(path, vertices=m.vertices, faces=m.faces)
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([folder, ROOT]))
    runs = {"base": [], "work": []}
    for r in range(rounds):
        for who in (("base", "work") if r % 2 == 0 else ("work", "base")):
            module = "kdray_base" if who == "base" else "kdray"
            cmd = [sys.executable, __file__, "--child", module, path]
            if threads is not None:
                cmd += ["--threads", str(threads)]
            out = subprocess.run(cmd, check=True, capture_output=True, text=True, env=env).stdout
            runs[who].append(json.loads(out.splitlines()[-1]))
    for who, label in (("base", "base"), ("work", "working tree")):
        wall = np.array([x["wall"] for x in runs[who]])
        print(f"{name:<12} {who:<5} ({label}): wall median {np.median(wall):.4f} s, fastest "
              f"{wall.min():.4f} s, cpu median {np.median([x['cpu'] for x in runs[who]]):.4f} s, "
              f"page faults median {int(np.median([x['faults'] for x in runs[who]]))}")
    ratio = [w["wall"] / b["wall"] for w, b in zip(runs["work"], runs["base"])]
    cpu = [w["cpu"] / b["cpu"] for w, b in zip(runs["work"], runs["base"])]
    print(f"{name:<12} work / base: wall {np.median(ratio):.3f}, cpu {np.median(cpu):.3f} "
          f"(medians of {rounds} rounds of new processes)", flush=True)


def main():
    if len(sys.argv) > 1 and sys.argv[1] == "--child":
        threads = int(sys.argv[5]) if len(sys.argv) > 5 else None
        return child(sys.argv[2], sys.argv[3], threads)
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", default="HEAD", help="commit to compare with (default HEAD)")
    ap.add_argument("--meshes", default="bunny,bunny-1.6M")
    ap.add_argument("--rounds", type=int, default=20)
    ap.add_argument("--threads", type=int, default=None, help="build threads (default: all CPUs)")
    ap.add_argument("--processes", action="store_true",
                    help="each build in a new process (sees memory effects; slower)")
    args = ap.parse_args()

    from meshes import mesh as bench_mesh
    with tempfile.TemporaryDirectory() as tmp:
        sys.path.insert(0, export_base(args.base, tmp))
        if args.processes:
            for name in args.meshes.split(","):
                in_processes(name, tmp, args.rounds, args.threads)
            return
        import kdray
        import kdray_base
        from timing import median_ratio, round_robin
        for name in args.meshes.split(","):
            m = bench_mesh(name)
            build = {who: (lambda f=f: f(m.vertices, m.faces, threads=args.threads))
                     for who, f in (("base", kdray_base.build), ("work", kdray.build))}
            wall, cpu, trees = round_robin(build, args.rounds)
            same = trees["base"].to_bytes() == trees["work"].to_bytes()
            del trees
            for who in build:
                print(f"{name:<12} {who:<5} ({args.base if who == 'base' else 'working tree'}): "
                      f"wall median {np.median(wall[who]):.4f} s, fastest {wall[who].min():.4f} s, "
                      f"cpu median {np.median(cpu[who]):.4f} s")
            print(f"{name:<12} work / base: wall {median_ratio(wall['work'], wall['base']):.3f}, "
                  f"cpu {median_ratio(cpu['work'], cpu['base']):.3f} (medians of {args.rounds} "
                  f"rounds); trees {'identical' if same else 'DIFFER'}", flush=True)

if __name__ == "__main__":
    main()
