"""`kdray setup` leaves nothing for the default render (`make render`) to compile, nor
for a default render of meshes whose trees are of other sizes.

Checked from a fresh environment: numba's and pyopencl's caches (NUMBA_CACHE_DIR,
XDG_CACHE_HOME) and PoCL's (POCL_CACHE_DIR) in an empty temporary folder, `kdray setup`,
then the default render. The render must not say that it compiles the tree builder,
and must add no file to those caches (a compiled numba function or OpenCL program is
a new file there).
"""
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
KDRAY = [sys.executable, "-m", "kdray.cli"]


def _files(folder):
    return {p.relative_to(folder) for p in Path(folder).rglob("*") if p.is_file()}


@pytest.mark.slow     # compiles the whole tree builder from nothing (numba): 25-30 s on 2 cores
def test_default_render_compiles_nothing_after_setup(tmp_path):
    caches = tmp_path / "caches"
    env = dict(os.environ, NUMBA_CACHE_DIR=str(caches / "numba"),
               XDG_CACHE_HOME=str(caches / "xdg"), POCL_CACHE_DIR=str(caches / "pocl"),
               KDRAY_CACHE_DIR=str(caches / "trees"))
    env.pop("NUMBA_DISABLE_JIT", None)

    def kdray(*args):
        proc = subprocess.run(KDRAY + [str(a) for a in args], cwd=ROOT, env=env,
                              capture_output=True, text=True, timeout=600)
        assert proc.returncode == 0, proc.stderr
        return proc

    kdray("setup")
    numba = _files(caches / "numba")
    assert numba                              # the set-up's cache is where we look
    (tmp_path / "out").mkdir()
    before = {p for p in _files(caches) if not p.name.startswith("tempfile")}  # PoCL's temporaries
    render = kdray("render", "scenes/cornell.obj", "--camera", "scenes/cornell.json",
                   "-o", tmp_path / "out" / "cornell.exr",
                   "--preview", tmp_path / "out" / "cornell.png")
    assert "compiling the tree builder" not in render.stderr       # builder.COMPILING
    after = {p for p in _files(caches) if not p.name.startswith("tempfile")}
    assert after == before, f"the render compiled: {sorted(map(str, after - before))}"
    assert (tmp_path / "out" / "cornell.exr").is_file()
    # trees of other depths and wide levels (the bunny: 20 deep, 6 levels of wide
    # nodes; fandisk 14 and 5; a 1280-triangle sphere 7 and 3) share the programs that
    # setup compiled (work_sizes.STACK_SIZES, wide.STACK_GROUPS)
    for scene in ("tests/data/meshes/stanford-bunny.obj.gz", "tests/data/meshes/fandisk.obj.gz",
                  "scenes/sphere.obj"):
        kdray("render", scene, "--size", "64x48", "-o", tmp_path / "out" / "mesh.exr")
        now = {p for p in _files(caches) if not p.name.startswith("tempfile")}
        assert now == before, f"rendering {scene} compiled: {sorted(map(str, now - before))}"
