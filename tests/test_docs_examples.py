"""Every Python example in README.md and docs/ runs, and prints what its comments say.

A file's examples run in order in one namespace, as a reader takes them, in a folder
holding the repository's scenes/ and the files the examples name as a user's own
(part.stl, os1-128.json, bunny.obj, transforms.json, out.exr). The inputs an example
only sketches (`tracer`, `points`, `origins`, `pose`, ...) are given as data, never
modules, so that an example missing an import fails. A line `print(...)  # expected`
must print `expected`, numbers compared as written ("..." stands for more digits,
blanks inside numpy's brackets ignored).
"""
import contextlib
import io
import json
import os
import re
from pathlib import Path

import numpy as np
import pytest

import kdray
from kdray.images import write_exr
from kdray.lidar import Lidar

ROOT = Path(__file__).resolve().parent.parent
DOCS = [ROOT / "README.md"] + sorted((ROOT / "docs").glob("*.md"))
BLOCK = re.compile(r"^```python\n(.*?)^```", re.S | re.M)


def python_blocks(path):
    """[(line, code)] of the ```python blocks of a Markdown file."""
    text = path.read_text()
    return [(text[:m.start()].count("\n") + 1, m.group(1)) for m in BLOCK.finditer(text)]


def printed_claims(code):
    """[(line in the block, expected text)] of its `print(...)  # expected` lines."""
    claims = []
    for k, line in enumerate(code.splitlines(), 1):
        m = re.match(r"\s*print\(.*\)\s+#\s*(.+)$", line)
        if m:
            claims.append((k, m.group(1).strip()))
    return claims


def same_print(got, expected):
    """Whether a printed line matches a comment's claim (blanks after "[" and before
    "]" and runs of blanks ignored; "..." matches more digits)."""
    def norm(s):
        s = re.sub(r"\s+", " ", s.strip())
        return re.sub(r"\[ ", "[", re.sub(r" \]", "]", s))
    pattern = re.escape(norm(expected)).replace(re.escape("..."), r"\d*")
    return re.fullmatch(pattern, norm(got)) is not None


def inputs(folder):
    """The files and the names the examples take as a user's own: cornell's tree and
    Tracer, points in and around it, rays, a light and a lidar pose inside the box."""
    import shutil
    import trimesh
    (folder / "scenes").symlink_to(ROOT / "scenes")
    trimesh.creation.box(extents=(1, 1, 1)).export(folder / "part.stl")
    shutil.copy(ROOT / "scenes" / "sphere.obj", folder / "bunny.obj")
    lidar = Lidar(elevations=np.linspace(10, -10, 8), columns=64, max_range=50.0)
    (folder / "os1-128.json").write_text(lidar.to_json())
    camera = kdray.Camera.look_at(eye=(0, 0, 4), target=(0, 0, 0), width=32, height=24)
    opengl = camera.cam_to_world @ np.diag([1.0, -1.0, -1.0, 1.0])  # nerfstudio's axes
    K = camera.K
    (folder / "transforms.json").write_text(json.dumps({
        "fl_x": K[0, 0], "fl_y": K[1, 1], "cx": K[0, 2], "cy": K[1, 2], "w": 32, "h": 24,
        "frames": [{"file_path": "images/front.png", "transform_matrix": opengl.tolist()}]}))
    mesh = kdray.load(ROOT / "scenes" / "cornell.obj")
    tree = kdray.build(mesh.vertices, mesh.faces)
    tracer = kdray.Tracer(tree)
    view = kdray.Camera.from_json(ROOT / "scenes" / "cornell.json")
    write_exr(folder / "out.exr", tracer.render(view, aovs="depth,id"), camera=view)
    rng = np.random.default_rng(0)
    points = rng.uniform(-1.2, 1.2, size=(257, 3)) + [0, 0.5, 0]
    origins = np.tile([0.0, 0.5, 0.0], (101, 1))
    directions = rng.normal(size=(101, 3))
    pose = np.eye(4)
    pose[:3, 3] = (0, 0.5, 0)
    return {"tree": tree, "tracer": tracer, "points": points, "origins": origins,
            "directions": directions, "light": np.array([0.0, 0.95, 0.0]), "pose": pose}


# cornell, the examples' `tracer`, is open: the parity example warns as it should
@pytest.mark.filterwarnings("ignore::kdray.points.OpenMeshWarning")
@pytest.mark.parametrize("doc", [p for p in DOCS if python_blocks(p)],
                         ids=lambda p: p.relative_to(ROOT).as_posix())
def test_examples_run_and_print_what_they_say(doc, tmp_path, monkeypatch, brute_trees):
    monkeypatch.chdir(tmp_path)
    namespace = inputs(tmp_path)
    for line, code in python_blocks(doc):
        out = io.StringIO()
        where = f"{doc.name}, the example at line {line}"
        try:
            with contextlib.redirect_stdout(out):
                exec(compile(code, where, "exec"), namespace)
        except Exception as e:
            pytest.fail(f"{where}: {type(e).__name__}: {e}")
        printed, lines = out.getvalue().splitlines(), code.splitlines()
        for k, expected in printed_claims(code):
            # line k prints the n-th line of output, n the prints above it (one line each)
            n = sum(bool(re.match(r"\s*print\(", text)) for text in lines[:k - 1])
            assert n < len(printed), f"{where}: no output for line {k}"
            assert same_print(printed[n], expected), (
                f"{where}, line {k}: printed {printed[n]!r}, the comment says {expected!r}")


def test_claims_are_checked():
    """The comparison itself: a stale number fails, digits past "..." pass."""
    assert same_print("[1.8881779       inf] [        17 4294967295]",
                      "[1.888... inf] [17 4294967295]")
    assert not same_print("[1.8881779       inf] [        17 4294967295]",
                          "[1.888... inf] [24 4294967295]")
    assert same_print("(480, 640) (480, 640, 3) uint32", "(480, 640) (480, 640, 3) uint32")
    assert not same_print("[[320. 241.]] [1.85]", "[[320. 240.]] [1.85]")
    assert printed_claims("x = 1\nprint(x)   # 1\nprint(2)\n") == [(2, "1")]
