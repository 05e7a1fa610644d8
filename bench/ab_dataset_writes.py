"""What writing a view's files beside the next view's trace, and OpenEXR's thread pool,
each give a dataset run: 60 views of the bunny at 640 x 480 (depth, normal, id) through
kdray.dataset.run, with OpenEXR compressing on 0 or 2 threads and dataset.WRITES_WAITING
0 (write, then trace the next view) or 1 (write beside it); 3 rounds, median views/s.

    .venv/bin/python bench/ab_dataset_writes.py
"""
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import kdray  # noqa: E402
import kdray.images  # noqa: E402
from kdray import dataset  # noqa: E402
from bench_dataset import orbit_cameras, write_camera_list  # noqa: E402
from meshes import FILES, MESHES  # noqa: E402

VIEWS = 60


def main():
    import OpenEXR
    work = Path(tempfile.mkdtemp(prefix="kdray-ab-writes-"))
    mesh_path = MESHES / f"{FILES['bunny']}.gz"
    m = kdray.load(mesh_path)
    cams = write_camera_list(work / "c.json", orbit_cameras(kdray.build(m.vertices, m.faces),
                                                            VIEWS, 640, 480))
    kdray.images.compress_on_threads = lambda n=None: None      # the rounds set it
    rates = {}
    for _ in range(3):
        for threads in (0, 2):
            for waiting in (0, 1):
                OpenEXR.set_global_thread_count(threads)
                dataset.WRITES_WAITING = waiting
                out = work / "out"
                shutil.rmtree(out, ignore_errors=True)
                t0 = time.perf_counter()
                report = dataset.run([dataset.Job(scene=mesh_path, cameras=cams, output=out,
                                                  aovs=("depth", "normal", "id"))])[0]
                assert report.ok and report.rendered == VIEWS
                rates.setdefault((threads, waiting), []).append(VIEWS / (time.perf_counter() - t0))
    for (threads, waiting), r in rates.items():
        print(f"OpenEXR threads {threads}, views waiting to be written {waiting}: "
              f"{np.median(r):.1f} views/s ({', '.join(f'{x:.1f}' for x in r)})")
    shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
