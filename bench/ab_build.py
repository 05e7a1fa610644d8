"""Build time of the working tree's kdray against an earlier commit's, in turns in one
process: the way to measure a change to the builder on a machine whose speed drifts
(seen here: +-20 % over minutes, so that two separate runs of the same code differ
more than most changes do).

usage: python bench/ab_build.py [--base HEAD] [--meshes bunny,bunny-1.6M] [--rounds 20]
                                [--threads 2]

The base commit's `kdray/` is exported (git archive) into a temporary folder as the
package `kdray_base` (kdray imports itself relatively, so it runs under that name);
its numba functions compile there on the first build (about half a minute). Each
round builds the mesh once with each, the order reversed every other round. Prints,
per mesh, the median and fastest wall time and the median CPU time of each, the
median of the rounds' time ratios (working tree / base: < 1 means faster), and
whether the two trees are byte-identical.
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


def export_base(commit, folder):
    """git archive `commit`'s kdray/ into folder/kdray_base; returns folder."""
    archive = subprocess.run(["git", "-C", ROOT, "archive", commit, "kdray"], check=True,
                             capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", folder], input=archive, check=True)
    os.rename(os.path.join(folder, "kdray"), os.path.join(folder, "kdray_base"))
    return folder


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", default="HEAD", help="commit to compare with (default HEAD)")
    ap.add_argument("--meshes", default="bunny,bunny-1.6M")
    ap.add_argument("--rounds", type=int, default=20)
    ap.add_argument("--threads", type=int, default=None, help="build threads (default: all CPUs)")
    args = ap.parse_args()

    from meshes import mesh as bench_mesh
    with tempfile.TemporaryDirectory() as tmp:
        sys.path.insert(0, export_base(args.base, tmp))
        import kdray
        import kdray_base
        builds = {"base": kdray_base.build, "work": kdray.build}
        for name in args.meshes.split(","):
            m = bench_mesh(name)
            trees = {who: build(m.vertices, m.faces, threads=args.threads)
                     for who, build in builds.items()}      # compile, warm up
            same = trees["base"].to_bytes() == trees["work"].to_bytes()
            del trees
            wall = {who: [] for who in builds}
            cpu = {who: [] for who in builds}
            order = list(builds)
            for r in range(args.rounds):
                for who in (order if r % 2 == 0 else order[::-1]):
                    t0, c0 = time.perf_counter(), time.process_time()
                    builds[who](m.vertices, m.faces, threads=args.threads)
                    wall[who].append(time.perf_counter() - t0)
                    cpu[who].append(time.process_time() - c0)
            for who in order:
                w = np.array(wall[who])
                print(f"{name:<12} {who:<5} ({args.base if who == 'base' else 'working tree'}): "
                      f"wall median {np.median(w):.4f} s, fastest {w.min():.4f} s, "
                      f"cpu median {np.median(cpu[who]):.4f} s")
            ratio = np.array(wall["work"]) / np.array(wall["base"])
            cpu_ratio = np.array(cpu["work"]) / np.array(cpu["base"])
            print(f"{name:<12} work / base: wall {np.median(ratio):.3f}, cpu {np.median(cpu_ratio):.3f} "
                  f"(medians of {args.rounds} rounds); trees {'identical' if same else 'DIFFER'}",
                  flush=True)


if __name__ == "__main__":
    main()
