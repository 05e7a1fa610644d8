"""Error against run time: kdray's settings beside Open3D and embreex on the same rays.

usage: python bench/bench_error.py [SCENE...] [--size 512x512] [--repeat 5] [--sample 10000]
                                   [--settings kdray,kdray:K_T=15,open3d,embreex]
                                   [--offset D] [--device SPEC] [--plot PNG] [--csv CSV]

`kdray bench` (kdray.bench.run) with two more settings:
    open3d    Open3D's RaycastingScene (numpy rays to numpy hits, the tensor
              conversion included; float32 world coordinates)
    embreex   trimesh's embreex front end (numpy to numpy, hit points refined in
              float64 by trimesh, no normals: the float64 normal of its triangle)
(bench/peers.py). The default SCENEs are scenes/cornell.obj, scenes/sphere.obj and the
Stanford bunny (tests/data/meshes); the default settings are kdray.bench's and Open3D
and embreex where installed (pip install -e '.[bench]'; Open3D also needs the system's
libusb-1.0: `make bench-deps`). `--offset D` moves scene and camera by D along (1,1,1):
Open3D and embreex then get float32 world coordinates, as their users would give them.
`--plot` draws the depth error's 99th percentile against Mrays/s (matplotlib).
"""
import argparse
import contextlib
import math
import os
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, HERE)

from kdray import bench  # noqa: E402  (kdray before open3d: kdray.runtimes and TBB)
from kdray.errors import KdrayError, OutputError, ParameterError  # noqa: E402
from peers import PEERS, Peer, installed  # noqa: E402

PROG = "bench_error"
DEFAULT_SCENES = (os.path.join(ROOT, "scenes", "cornell.obj"),
                  os.path.join(ROOT, "scenes", "sphere.obj"),
                  os.path.join(ROOT, "tests", "data", "meshes", "stanford-bunny.obj.gz"))
INSTALL = "pip install -e '.[bench]'"


def parse_settings(text):
    """(settings, notes): kdray.bench settings and Peers. None: kdray.bench's defaults
    and the peers that are installed (notes name those left out); a peer named
    explicitly that is not installed is an error."""
    if text is None:
        notes = [f"{name} is not installed: left out ({INSTALL})"
                 for name in PEERS if not installed(name)]
        names = list(bench.DEFAULT_SETTINGS) + [name for name in PEERS if installed(name)]
        return [parse_setting(name) for name in names], notes
    names = [s.strip() for s in text.split(",") if s.strip()]
    if not names:
        raise ParameterError("--settings names no setting")
    return [parse_setting(name) for name in names], []


def parse_setting(name):
    head, *parts = name.split(":")
    if head in PEERS:
        if parts:
            raise ParameterError(f"setting {name!r}: {head} takes no options")
        if not installed(head):
            raise ParameterError(f"setting {name!r}: {head} is not installed ({INSTALL})")
        return Peer(head)
    if head != "kdray":
        raise ParameterError(f"unknown setting {name!r}: expected kdray[:KEY=VALUE...], "
                             f"{' or '.join(PEERS)}")
    return bench.parse_setting(name)


def size(text):
    try:
        w, h = (int(x) for x in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT, e.g. 512x512, got {text!r}")
    if w < 1 or h < 1:
        raise argparse.ArgumentTypeError(f"width and height must be at least 1, got {w}x{h}")
    return w, h


@contextlib.contextmanager
def step(what):
    """Progress on stderr when it is a terminal."""
    live = sys.stderr.isatty()
    if live:
        print(f"{PROG}: {what}...", end="", file=sys.stderr, flush=True)
    t0 = time.perf_counter()
    try:
        yield
    finally:
        if live:
            print(f"\r{PROG}: {what} ({time.perf_counter() - t0:.2f} s)", file=sys.stderr)


def plot(rows, path, x="mrays_s"):
    """Depth error p99 (log) against Mrays/s (or trace_s): one colour per scene, one
    marker per setting. Returns None, or a note when matplotlib is not installed."""
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return f"matplotlib is not installed: {path} not written ({INSTALL})"
    scenes = list(dict.fromkeys(r["scene"] for r in rows))
    settings = list(dict.fromkeys(r["setting"] for r in rows))
    markers = "os^vD<>pP*Xh"
    colours = plt.get_cmap("tab10")
    floor = 1e-17                                 # log axis: an exact 0 is drawn here
    fig, ax = plt.subplots(figsize=(8, 5.5))
    for r in rows:
        y = r["depth_p99"]
        if not math.isfinite(y):
            continue
        ax.scatter(r[x], max(y, floor), color=colours(scenes.index(r["scene"]) % 10),
                   marker=markers[settings.index(r["setting"]) % len(markers)], s=50)
    ax.set_yscale("log")
    ax.set_xlabel("Mrays/s (numpy rays to numpy hits)" if x == "mrays_s" else "trace seconds")
    ax.set_ylabel("relative depth error, 99th percentile")
    ax.set_title("kdray, Open3D and embreex: error against speed")
    ax.grid(True, which="both", alpha=0.3)
    from matplotlib.lines import Line2D
    handles = [Line2D([], [], color=colours(i % 10), marker="o", ls="", label=s) for i, s in enumerate(scenes)]
    handles += [Line2D([], [], color="grey", marker=markers[i % len(markers)], ls="", label=s)
                for i, s in enumerate(settings)]
    ax.legend(handles=handles, fontsize=8, loc="best")
    fig.tight_layout()
    try:
        fig.savefig(path, dpi=120)
    except OSError as e:
        raise OutputError(f"{path}: cannot write the plot ({e.strerror or e})") from None
    finally:
        plt.close(fig)
    return None


def main(argv=None):
    ap = argparse.ArgumentParser(prog=PROG, description=__doc__.splitlines()[0])
    ap.add_argument("scenes", nargs="*", metavar="SCENE",
                    help="mesh files (default: cornell, sphere and the Stanford bunny)")
    ap.add_argument("--size", type=size, default=(512, 512), help="rays: WIDTHxHEIGHT (512x512)")
    ap.add_argument("--repeat", type=int, default=5, help="warm runs timed, the median counts (5)")
    ap.add_argument("--sample", type=int, default=10000,
                    help="random rays checked against the float64 reference (10000)")
    ap.add_argument("--settings", default=None,
                    help="comma-separated: kdray[:KEY=VALUE...] (K_T, K_I, empty_bonus, "
                         "max_depth, leaf_size, stack, local, batch), open3d, embreex "
                         f"(default: {','.join(bench.DEFAULT_SETTINGS)}, open3d and embreex "
                         "if installed)")
    ap.add_argument("--offset", type=float, default=0.0,
                    help="move scene and camera by D along (1,1,1) (precision far from the origin)")
    ap.add_argument("--device", default=None, help="OpenCL device, PYOPENCL_CTX syntax")
    ap.add_argument("--plot", default=None, help="PNG plot of depth error against Mrays/s")
    ap.add_argument("--csv", default=None, help="also write the table as CSV")
    args = ap.parse_args(argv)
    try:
        for path in (args.plot, args.csv):
            folder = os.path.dirname(os.path.abspath(path)) if path else None
            if folder and not os.path.isdir(folder):
                raise OutputError(f"{path}: the folder {folder} does not exist")
        settings, notes = parse_settings(args.settings)
        for note in notes:
            print(f"{PROG}: note: {note}", file=sys.stderr)
        rows = bench.run(args.scenes or DEFAULT_SCENES, size=args.size, repeat=args.repeat,
                         sample=args.sample, settings=settings, device=args.device,
                         offset=args.offset, step=step)
        print(bench.header(args.size, args.repeat, args.sample, args.offset))
        print(bench.format_table(rows), flush=True)
        if args.csv:
            bench.write_csv(rows, args.csv)
        if args.plot:
            note = plot(rows, args.plot)
            print(f"{PROG}: note: {note}" if note else f"{PROG}: wrote {args.plot}", file=sys.stderr)
    except KdrayError as e:
        print(f"{PROG}: error: {e}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
