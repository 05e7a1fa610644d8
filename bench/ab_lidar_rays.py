"""Where a lidar scan's rays are made, in turns in one process: the render kernel from
the Lidar's float32 direction map (Tracer.scan) against float64 beams made on the host
and traced by trace_rays (the path of precision="double", without its float64 t), in rows
of consecutive beams or (image_w) in blocks of 4 azimuth steps x 2 or 4 beams: 128 x 2048
beams from inside the 1.6M-triangle bunny, 10 rounds.

    .venv/bin/python bench/ab_lidar_rays.py
"""
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import kdray  # noqa: E402
from kdray.lidar import scan_images  # noqa: E402
from meshes import mesh  # noqa: E402
from timing import median_ratio, round_robin  # noqa: E402


def main():
    m = mesh("bunny-1.6M")
    tree = kdray.build(m.vertices, m.faces)
    tracer = kdray.Tracer(tree)
    lidar = kdray.Lidar.from_dict({"channels": 128, "fov_up": 22.5, "fov_down": -22.5,
                                   "columns": 2048, "max_range": 2.5})
    lo, hi = tree.world_box()
    pose = np.eye(4)
    pose[:3, 3] = (lo + hi) / 2

    def host(image_w=0):
        origin, d = lidar.rays(pose)
        hits, _ = tracer._trace(origin, d, t_max=lidar.max_range * (1 + 2.0**-16),
                                outputs=("T", "ID"), image_w=image_w)
        return scan_images(lidar, origin, d, hits.t, hits.prim, tree.objects)

    fns = {"host float64 rays": host,
           "host rays, blocks": lambda: host(lidar.shape[1]),
           "device ray map": lambda: tracer.scan(lidar, pose)}
    wall, _, results = round_robin(fns, 10)
    for name, seconds in wall.items():
        print(f"{name:<18} {1e3 * np.median(seconds):6.1f} ms")
    for name in ("host rays, blocks", "device ray map"):
        print(f"{name} / host float64 rays time: "
              f"{median_ratio(wall[name], wall['host float64 rays']):.3f}")
    same = results["host float64 rays"]["id"] == results["device ray map"]["id"]
    print(f"same ids: {same.mean():.4f}")
    rows, blocks = results["host float64 rays"], results["host rays, blocks"]
    print("rows and blocks: range and id identical:",
          all(np.array_equal(rows[k], blocks[k], equal_nan=True) for k in ("range", "id")))


if __name__ == "__main__":
    main()
