"""Where `Tracer.trace`'s time goes beside `render`'s on the same rays: the order the
rays come in, their type, a shared origin and the double-precision refinement, each
timed in turns against the others.

usage: python bench/trace_costs.py [--meshes bunny,bunny-1.6M] [--size 1024]
                                   [--repeat 7] [--device intel]

For each mesh, the framing camera's rays (`Camera.rays`: float64 origins and
directions, row-major pixels) are traced as:

  render depth         Tracer.render(camera, ["depth"]): the same rays, made on the
                       device, in packets of 4 x 2 (AVX2) or 4 x 4 pixels
  render depth id      the same with the ids, which a trace always stores
  trace rows f64       Tracer.trace(o, d, outputs=()) with its search for an image
                       off (kdray.ray_grid): packets of consecutive rays
  trace image found    the same call as it is: bench_trace.py's; the rays are found
                       to be an image and traced in render's blocks
  trace image given    the same rays shaped (size, size, 3): no search
  image one origin     the same with the camera's eye (3,) for every ray
  image one origin f32 ... and float32 directions: the render's rays but for their
                       reading, conversion and ids
  grid_width           the search alone (ray_grid.grid_width, as `trace` calls it):
                       in a round robin its samples miss the cache, as in a trace
  trace blocks f64     the same rays reordered into render's blocks of 4 x 2 or 4 x 4
                       pixels first (the reordering is not timed): the cost of a
                       caller's row order
  trace rows f32       float32 copies of o and d: the cost of reading float64
  trace one origin     the camera's eye (3,) for every ray, float64 directions
  trace no refine      a Tracer(refine=False): t, u, v not recomputed in double
  render no refine     the same for render

all in one round robin (`timing.round_robin`), medians of --repeat rounds, each also
as the median ratio to "trace rows f64" and to "render depth". The "trace ..." rows
but "trace image found" trace their (N, 3) rays in the order given (`rows`); the
"image ..." rows in render's blocks. Every variant's t equals the plain trace's for
the rays it shares bit for bit, except those without refinement and with float32
directions.
"""
import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from meshes import framed  # noqa: E402
from timing import median_ratio, round_robin  # noqa: E402

import kdray  # noqa: E402
from kdray.ray_grid import grid_width  # noqa: E402


def block_order(size, w=4, h=2):
    """Indices of a size x size row-major image's pixels in blocks of w x h, the blocks
    row-major (size a multiple of both)."""
    return np.arange(size * size).reshape(size // h, h, size // w, w).transpose(0, 2, 1, 3).reshape(-1)


def rows(tracer, o, d):
    """t of the rays traced in packets of consecutive rays: Tracer._trace, which
    `trace` calls after its search for an image in (N, 3) rays (kdray.ray_grid)."""
    return tracer._trace(o, d, outputs=())[0].t


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--meshes", default="bunny,bunny-1.6M")
    ap.add_argument("--size", type=int, default=1024)
    ap.add_argument("--repeat", type=int, default=7)
    ap.add_argument("--device", default=None)
    args = ap.parse_args()
    for name in args.meshes.split(","):
        m, tree, camera, o, d = framed(name, args.size)
        tracer = kdray.Tracer(tree, device=args.device)
        # blocks of 4 x packet / 4 pixels: the packets render_camera makes
        order = block_order(args.size, 4, max(tracer.packet // 4, 1))
        ob, db = np.ascontiguousarray(o[order]), np.ascontiguousarray(d[order])
        image = (args.size, args.size, 3)
        o32, d32 = o.astype(np.float32), d.astype(np.float32)
        plain = kdray.Tracer(tree, device=args.device, refine=False)
        d32_image = d32.reshape(image)
        calls = {"render depth": lambda: tracer.render(camera, ["depth"])["depth"].ravel(),
                 "render depth id": lambda: tracer.render(camera, ["depth", "id"])["depth"].ravel(),
                 "trace rows f64": lambda: rows(tracer, o, d),
                 "trace image found": lambda: tracer.trace(o, d, outputs=()).t,
                 "trace image given": lambda: tracer.trace(o.reshape(image), d.reshape(image),
                                                           outputs=()).t.ravel(),
                 "image one origin": lambda: tracer.trace(camera.eye, d.reshape(image),
                                                          outputs=()).t.ravel(),
                 "image one origin f32": lambda: tracer.trace(camera.eye, d32_image,
                                                              outputs=()).t.ravel(),
                 "grid_width": lambda: grid_width(o, d, min_rows=max(tracer.packet // 4, 1)),
                 "trace blocks f64": lambda: rows(tracer, ob, db),
                 "trace rows f32": lambda: rows(tracer, o32, d32),
                 "trace one origin": lambda: rows(tracer, camera.eye, d),
                 "trace no refine": lambda: rows(plain, o, d),
                 "render no refine": lambda: plain.render(camera, ["depth"])["depth"].ravel()}
        seconds, _, results = round_robin(calls, args.repeat)
        t = results["trace rows f64"]
        same = {"trace blocks f64": np.array_equal(results["trace blocks f64"], t[order]),
                "trace image found": np.array_equal(results["trace image found"], t),
                "trace image given": np.array_equal(results["trace image given"], t),
                "image one origin": np.array_equal(results["image one origin"], t),
                "trace one origin": np.array_equal(results["trace one origin"], t)}
        print(f"## {name}: {len(m.faces):,} triangles, {args.size}x{args.size} rays, "
              f"{tracer.device.name.strip()} ({tracer.device.platform.name.strip()}), "
              f"packets of {tracer.packet}")
        print(f"{'call':<20} {'ms':>7} {'x trace rows f64':>17} {'x render':>9}  same t")
        for call, s in seconds.items():
            ratio = median_ratio(s, seconds["trace rows f64"])
            to_render = median_ratio(s, seconds["render depth"])
            print(f"{call:<20} {np.median(s) * 1e3:>7.2f} {ratio:>17.3f} {to_render:>9.3f}  "
                  f"{same.get(call, '')}", flush=True)


if __name__ == "__main__":
    main()
