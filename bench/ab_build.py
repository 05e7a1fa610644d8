"""Build time of the working tree's kdray against an earlier commit's, in turns in one
process: the way to measure a change to the builder on a machine whose speed drifts
(seen here: +-20 % over minutes, so that two separate runs of the same code differ
more than most changes do).

usage: python bench/ab_build.py [--base HEAD] [--meshes bunny,bunny-1.6M] [--rounds 20]
                                [--threads 2]

The base commit's `kdray/` is exported (git archive) into a temporary folder as the
package `kdray_base` (kdray imports itself relatively, so it runs under that name);
its numba functions compile there on the first build (about half a minute). After a
warm-up build with each, each round builds the mesh once with each, the order
reversed every other round (`kdray.bench.round_robin`). Prints,
per mesh, the median and fastest wall time and the median CPU time of each, the
median of the rounds' time ratios (working tree / base: < 1 means faster), and
whether the two trees are byte-identical.
"""
import argparse
import os
import subprocess
import sys
import tempfile

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
        from kdray.bench import median_ratio, round_robin
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
