"""Work sizes and devices: packets or single rays, local size, batch and group count,
on one OpenCL device or several, timed side by side (round robin), for the defaults of
`kdray.work_sizes.default_work_sizes` and the orders of `kdray.device.CPU_RUNTIME_ORDER`.

usage: python bench/tune_work_sizes.py [--device intel] [--meshes bunny,bunny-1.6M]
                                       [--size 1024] [--repeat 7] [--configs ...]
       python bench/tune_work_sizes.py --configs intel:default,pocl:default

For each mesh, one Tracer per configuration "[DEVICE:]PxL/B/G" (P rays a work-item, L
work-items a group, batches of B rays, G groups; "default" is the device's default;
DEVICE, if given, replaces --device) on the same tree; the first configuration is the
reference. Each round times `render` (depth only) and `trace` (the camera's rays, numpy to
numpy, float64) of every configuration once, in turns (timing.round_robin), and
the table gives the medians and each one's time relative to the first (< 1: faster).
Every configuration's depth image must equal the first's bit for bit.
"""
import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from meshes import mesh as bench_mesh  # noqa: E402

import kdray  # noqa: E402
from timing import round_robin  # noqa: E402

CONFIGS = ("default", "1x8/64/8", "1x16/256/8", "1x32/512/8", "1x64/1024/8", "1x64/256/16",
           "1x128/1024/4", "8x1/64/8", "8x4/256/8", "8x8/512/8", "8x16/1024/8", "8x32/2048/4")


def parse(config, device):
    """"[DEVICE:]PxL/B/G" or "[DEVICE:]default" -> dict of Tracer keywords."""
    if ":" in config:
        device, config = config.split(":", 1)
    if config == "default":
        return dict(device=device)
    pl, batch, groups = config.split("/")
    packet, local = pl.split("x")
    return dict(device=device, packet=int(packet), local_size=int(local),
                batch_size=int(batch), groups=int(groups))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default=None)
    parser.add_argument("--meshes", default="bunny,bunny-1.6M")
    parser.add_argument("--size", type=int, default=1024)
    parser.add_argument("--repeat", type=int, default=7)
    parser.add_argument("--configs", default=",".join(CONFIGS))
    args = parser.parse_args()
    configs = args.configs.split(",")
    for name in args.meshes.split(","):
        m = bench_mesh(name)
        tree = kdray.build(m.vertices, m.faces)
        lo, hi = tree.world_box()
        c, r = 0.5 * (lo + hi), 0.5 * float(np.linalg.norm(hi - lo))
        camera = kdray.Camera.look_at(c + np.array([0.0, 0.2, 2.2]) * r, c, (0, 1, 0), fov_deg=40,
                                      width=args.size, height=args.size)
        tracers = {cfg: kdray.Tracer(tree, **parse(cfg, args.device)) for cfg in configs}
        default = tracers[configs[0]]
        print(f"\n## {name}: {len(m.faces):,} triangles, {args.size}x{args.size} rays, "
              f"the first: {default.device.name.strip()} ({default.device.platform.name.strip()}) "
              f"{default.packet}x{default.local_size}/{default.batch_size}/{default.groups}", flush=True)
        o, d = default.camera_rays(camera)
        o, d = np.ascontiguousarray(o, dtype=np.float64), np.ascontiguousarray(d, dtype=np.float64)
        fns = {}
        for cfg, tr in tracers.items():
            fns[f"{cfg} render"] = lambda tr=tr: tr.render(camera, aovs=("depth",))["depth"]
            fns[f"{cfg} trace"] = lambda tr=tr: tr.trace(o, d).t
        wall, _, results = round_robin(fns, args.repeat)
        base = results[f"{configs[0]} render"]
        width = max(14, max(len(cfg) for cfg in configs))
        print(f"{'config':<{width}} {'render s':>9} {'x first':>9} {'trace s':>9} {'x first':>9}")
        for cfg in configs:
            assert np.array_equal(results[f"{cfg} render"], base), cfg
            rs, ts = np.median(wall[f"{cfg} render"]), np.median(wall[f"{cfg} trace"])
            rr = np.median(np.asarray(wall[f"{cfg} render"]) / wall[f"{configs[0]} render"])
            tt = np.median(np.asarray(wall[f"{cfg} trace"]) / wall[f"{configs[0]} trace"])
            print(f"{cfg:<{width}} {rs:>9.4f} {rr:>9.3f} {ts:>9.4f} {tt:>9.3f}", flush=True)


if __name__ == "__main__":
    main()
