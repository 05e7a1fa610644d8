"""Embree 3's C++ API as a ray caster for the bench/ scripts: bench/embree_anchor.cpp,
compiled here with the system's g++ against Debian's libembree-dev and libtbb-dev
(`make bench-deps` installs them where it may), run as a server process.

    anchor = EmbreeAnchor.start(mesh)     # None, with anchor_missing() saying why
    anchor.rays(o, d, t_min, t_max)       # float32 copies, written once
    anchor.trace1()                       # rtcIntersect1, TBB's threads: seconds
    anchor.trace16(w, h)                  # rtcIntersect16 on 4 x 4 tiles: seconds
    anchor.occluded1()                    # rtcOccluded1: (seconds, rays occluded)
    t, prim = anchor.hits()               # float32 t (+inf miss), int64 prim (-1)

The program is compiled once per source and CPU (-O3 -march=native) into
~/.cache/kdray-bench. Embree is left at its defaults (scene flags, build quality,
every core), as its users get it.

    python bench/embree_anchor.py --meshes bunny,bunny-1.6M,spot

prints Embree's statistics of the tree it builds over each mesh (rtcNewDevice's
"verbose=3": its kind, nodes, leaves, SAH; BENCHMARKS.md, "Incoherent rays").
"""
import hashlib
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

import numpy as np

SOURCE = Path(__file__).with_name("embree_anchor.cpp")
CACHE = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "kdray-bench"
HEADER = Path("/usr/include/embree3/rtcore.h")


def anchor_missing():
    """Why the anchor cannot run here (a line), or None."""
    if shutil.which("g++") is None:
        return "no g++"
    if not HEADER.exists():
        return "no Embree 3 headers (apt-get install libembree-dev libtbb-dev; make bench-deps)"
    return None


def _binary():
    """The compiled anchor's path, compiling it when its source changed."""
    key = hashlib.sha256(SOURCE.read_bytes()).hexdigest()[:16]
    path = CACHE / f"embree_anchor-{key}"
    if not path.exists():
        CACHE.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp")
        subprocess.run(["g++", "-O3", "-march=native", "-std=c++17", str(SOURCE), "-o", str(tmp),
                        "-lembree3", "-ltbb"], check=True)
        tmp.replace(path)
    return path


class EmbreeAnchor:
    """A running bench/embree_anchor.cpp over one mesh (see the module's docstring)."""

    def __init__(self, proc, folder, build_s):
        self.proc, self.folder, self.build_s = proc, folder, build_s
        self.n = 0

    @classmethod
    def start(cls, mesh, config=None):
        """The anchor over mesh (.vertices (V, 3), .faces (F, 3)), its scene built; None
        when it cannot run here (anchor_missing says why). config: Embree's device
        string (its messages go to this process's stderr)."""
        if anchor_missing():
            return None
        folder = Path(tempfile.mkdtemp(prefix="kdray-embree-"))
        scene = folder / "scene.bin"
        v = np.ascontiguousarray(mesh.vertices, np.float32)
        f = np.ascontiguousarray(mesh.faces, np.uint32)
        scene.write_bytes(np.array([len(v), len(f)], np.uint32).tobytes() + v.tobytes() + f.tobytes())
        proc = subprocess.Popen([str(_binary()), str(scene), *([config] if config else [])],
                                stdin=subprocess.PIPE,
                                stdout=subprocess.PIPE, text=True, bufsize=1)
        ready = proc.stdout.readline().split()
        if ready[:1] != ["ready"]:
            proc.kill()
            raise RuntimeError(f"embree_anchor did not start: {ready}")
        return cls(proc, folder, float(ready[1]))

    def _ask(self, line):
        self.proc.stdin.write(line + "\n")
        self.proc.stdin.flush()
        reply = self.proc.stdout.readline().split()
        if reply[:1] != ["ok"]:
            raise RuntimeError(f"embree_anchor: {line}: {' '.join(reply)}")
        return reply[1:]

    def rays(self, o, d, t_min=0.0, t_max=np.inf):
        """Rays o, d (N, 3) (one origin (3,) is repeated), t_min, t_max scalars: float32."""
        d = np.asarray(d, np.float64).reshape(-1, 3)
        o = np.broadcast_to(np.asarray(o, np.float64).reshape(-1, 3), d.shape)
        q = np.empty((len(d), 8), np.float32)
        q[:, 0:3], q[:, 3], q[:, 4:7], q[:, 7] = o, t_min, d, t_max
        path = self.folder / "rays.bin"
        path.write_bytes(q.tobytes())
        self.n = len(d)
        self._ask(f"rays {path} {self.n}")

    def trace1(self):
        """rtcIntersect1 on every ray; its seconds (no Python inside)."""
        return float(self._ask("trace1")[0])

    def occluded1(self):
        """rtcOccluded1 on every ray: (seconds, rays occluded); the hits() of the last
        trace are left as they are."""
        seconds, count = self._ask("occluded1")
        return float(seconds), int(count)

    def trace16(self, width, height):
        """rtcIntersect16 on the rays as a height x width image in 4 x 4 tiles; seconds."""
        return float(self._ask(f"trace16 {width} {height}")[0])

    def hits(self):
        """The last trace's (t float32 (N,), +inf on a miss; prim int64 (N,), -1 on a miss)."""
        path = self.folder / "hits.bin"
        self._ask(f"dump {path}")
        raw = np.fromfile(path, np.float32, count=self.n), np.fromfile(
            path, np.int32, count=self.n, offset=4 * self.n)
        return raw[0], raw[1].astype(np.int64)

    def close(self):
        if self.proc.poll() is None:
            self.proc.stdin.write("quit\n")
            self.proc.stdin.close()
            self.proc.wait(timeout=30)
        shutil.rmtree(self.folder, ignore_errors=True)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def main():
    import argparse
    import re
    import sys
    sys.path.insert(0, str(Path(__file__).parent))
    from meshes import mesh
    ap = argparse.ArgumentParser(description="Embree's statistics of its tree over meshes")
    ap.add_argument("--meshes", default="bunny,bunny-1.6M,spot")
    args = ap.parse_args()
    if anchor_missing():
        sys.exit(f"embree_anchor: {anchor_missing()}")
    for name in args.meshes.split(","):
        print(f"== {name}", flush=True)
        with tempfile.TemporaryFile("w+") as log:
            err = os.dup(2)
            os.dup2(log.fileno(), 2)            # the child's stderr: Embree's statistics
            try:
                EmbreeAnchor.start(mesh(name), config="verbose=3").close()
            finally:
                os.dup2(err, 2)
                os.close(err)
            log.seek(0)
            for line in log:
                if re.match(r"\s*(building|finished|primitives|total +: sah|getAABBNodes|leaves |"
                            r"histogram|intersector1)", line):
                    print(line.rstrip())


if __name__ == "__main__":
    main()
