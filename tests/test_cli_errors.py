"""Every way a user can be wrong ends in one sentence on stderr and exit 1 (2 for
usage errors), never a traceback, and never a written file."""
import os

import pytest

from helpers import SCENES
from helpers import run

SCENE = SCENES / "cornell.obj"


def assert_one_line_error(code, err, *words, exit_code=1):
    assert code == exit_code, err
    assert "Traceback" not in err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 or exit_code == 2, err
    for w in words:
        assert w.lower() in err.lower(), (w, err)


@pytest.mark.parametrize("args, words", [
    (["--aov", "depth,colour"], ["colour", "valid"]),
    (["--aov", ","], ["no aov"]),
    (["--eye", "0,0,3", "--target", "0,0,0", "--fov", "0"], ["fov", "180"]),
    (["--eye", "0,0,3", "--target", "0,0,0", "--fov", "180"], ["fov", "180"]),
    (["--eye", "0,0,3", "--target", "0,0,0", "--fov", "-5"], ["fov"]),
    (["--eye", "1,2,3", "--target", "1,2,3"], ["same point"]),
    (["--eye", "0,3,0", "--target", "0,0,0", "--up", "0,1,0"], ["up", "parallel"]),
    (["--eye", "0,0,3", "--target", "0,0,0", "--up", "0,0,0"], ["up"]),
])
def test_bad_camera_and_aov_options(capsys, tmp_path, args, words):
    out = tmp_path / "o.exr"
    code, _, err = run(capsys, "render", SCENE, "-o", out, *args)
    assert_one_line_error(code, err, *words)
    assert not out.exists()


@pytest.mark.parametrize("content, words", [
    ("{not json", ["json"]),
    ('{"width": 4, "height": 3}', ["pose"]),
    ('{"width": 4, "height": 3, "eye": [0,0,1], "target": [0,0,1]}', ["same point"]),
    ('{"width": -4, "height": 3, "eye": [0,0,1], "target": [0,0,0]}', ["width"]),
    ('{"width": 4, "height": 3, "K": [[1,0,0],[0,1,0]], "cam_to_world": [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}', ["K"]),
])
def test_malformed_camera_file(capsys, tmp_path, content, words):
    cam = tmp_path / "cam.json"
    cam.write_text(content)
    code, _, err = run(capsys, "render", SCENE, "-o", tmp_path / "o.exr", "--camera", cam)
    assert_one_line_error(code, err, "cam.json", *words)


@pytest.mark.parametrize("content, words", [
    ("1 2 3", ["16 numbers", "pose.txt"]),
    ("2 0 0 0  0 1 0 0  0 0 1 0  0 0 0 1", ["rotation"]),
    ("a b c d e f g h i j k l m n o p", ["pose"]),
])
def test_malformed_pose_file(capsys, tmp_path, content, words):
    pose = tmp_path / "pose.txt"
    pose.write_text(content)
    code, _, err = run(capsys, "render", SCENE, "-o", tmp_path / "o.exr",
                       "--intrinsics", "100,100,32,24", "--pose", pose)
    assert_one_line_error(code, err, *words)


def test_intrinsics_without_pose_is_a_usage_error(capsys, tmp_path):
    code, _, err = run(capsys, "render", SCENE, "-o", tmp_path / "o.exr", "--intrinsics", "1,1,1,1")
    assert code == 2 and "--pose" in err


def test_missing_output_folder(capsys, tmp_path):
    code, _, err = run(capsys, "render", SCENE, "-o", tmp_path / "nope" / "o.exr")
    assert_one_line_error(code, err, "does not exist")


def test_unwritable_output_folder(capsys, tmp_path, monkeypatch):
    ro = tmp_path / "ro"
    ro.mkdir(mode=0o500)
    real_access = os.access       # root may write anywhere: pretend to be a plain user
    monkeypatch.setattr(os, "access", lambda p, mode: False if str(p) == str(ro) else real_access(p, mode))
    code, _, err = run(capsys, "render", SCENE, "-o", ro / "o.exr")
    assert_one_line_error(code, err, "not writable")


def test_output_onto_input(capsys, tmp_path):
    scene = tmp_path / "s.obj"
    scene.write_bytes(SCENE.read_bytes())
    code, _, err = run(capsys, "render", scene, "-o", scene)
    assert_one_line_error(code, err, "overwrite the input")
    assert scene.read_bytes() == SCENE.read_bytes()
    code, _, err = run(capsys, "render", scene, "-o", tmp_path / "o.exr", "--preview", scene)
    assert_one_line_error(code, err, "overwrite the input")


@pytest.mark.parametrize("argv, option", [
    (["build", SCENE, "--dump", ""], "--dump"),
    (["build", ""], "SCENE"),
    (["render", SCENE, "--cameras", ""], "--cameras"),
    (["render", SCENE, "--tree", ""], "--tree"),
    (["render", SCENE, "--camera", ""], "--camera"),
    (["render", SCENE, "--pose", "", "--intrinsics", "100,100,8,8"], "--pose"),
    (["render", SCENE, "-o", ""], "--output"),
    (["cast", SCENE, "--rays", "", "-o", "x.npz"], "--rays"),
    (["bench", SCENE, "--csv", ""], "--csv"),
    (["batch", ""], "JOBS"),
])
def test_an_empty_path_is_a_usage_error(capsys, tmp_path, monkeypatch, argv, option):
    """An empty path names no file: refused as a usage error, never taken for an option
    not given (--dump "" once printed the statistics and wrote nothing, --cameras ""
    rendered one framing image)."""
    monkeypatch.chdir(tmp_path)
    code, out, err = run(capsys, *argv)
    assert_one_line_error(code, err, option, "empty path", exit_code=2)
    assert out == "" and os.listdir(tmp_path) == []


def test_missing_and_bad_scene(capsys, tmp_path):
    code, _, err = run(capsys, "render", tmp_path / "none.obj", "-o", tmp_path / "o.exr")
    assert_one_line_error(code, err, "none.obj", "no such file")
    bad = tmp_path / "bad.ply"
    bad.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 99999999\n")
    code, _, err = run(capsys, "render", bad, "-o", tmp_path / "o.exr")
    assert_one_line_error(code, err, "bad.ply")


def test_debug_shows_the_traceback(capsys, tmp_path):
    with pytest.raises(Exception):
        from kdray.cli import main
        main(["--debug", "render", str(tmp_path / "none.obj")])


def test_absurd_size_is_refused_before_allocating(capsys, tmp_path, monkeypatch):
    # 4 GiB available, as on a small machine: a machine with 128 GiB would render 60000^2
    monkeypatch.setattr("kdray.host.available_memory", lambda: 4 * 2**30)
    code, _, err = run(capsys, "render", SCENE, "-o", tmp_path / "o.exr", "--size", "60000x60000")
    assert_one_line_error(code, err, "GiB", "4.0 GiB are available")
    code, _, err = run(capsys, "render", SCENE, "-o", tmp_path / "o.exr", "--size", "20000x20000")
    assert_one_line_error(code, err, "GiB", "4.0 GiB are available")
    code, _, err = run(capsys, "render", SCENE, "-o", tmp_path / "o.exr", "--size", "100000x100000")
    assert_one_line_error(code, err, "at most 65536 (MAX_SIDE)")   # every camera's limit
    assert not (tmp_path / "o.exr").exists()


def test_mesh_problems_name_the_file(capsys, tmp_path):
    degenerate = tmp_path / "flat.obj"
    degenerate.write_text("v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\nf 1 1 2\n")
    code, _, err = run(capsys, "render", degenerate, "-o", tmp_path / "o.exr")
    assert_one_line_error(code, err, "flat.obj", "no triangles left")
    out_of_range = tmp_path / "oor.obj"
    out_of_range.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n")
    code, _, err = run(capsys, "build", out_of_range)
    assert_one_line_error(code, err, "oor.obj", "does not exist")
    points = tmp_path / "points.ply"
    import numpy as np
    import trimesh
    trimesh.PointCloud(np.random.default_rng(0).random((10, 3))).export(points)
    code, _, err = run(capsys, "render", points, "-o", tmp_path / "o.exr")
    assert_one_line_error(code, err, "points.ply", "no triangles")
    # a device or a pipe is not a mesh file (their size reads 0: once "is empty")
    fifo = tmp_path / "mesh.obj"
    os.mkfifo(fifo)
    for scene in ("/dev/zero", fifo):
        code, _, err = run(capsys, "build", scene)
        assert_one_line_error(code, err, str(scene), "a device or a pipe")


def test_no_opencl_platform_says_how_to_get_one(capsys, tmp_path, monkeypatch):
    import pyopencl
    monkeypatch.setattr(pyopencl, "get_platforms", lambda: [])
    code, _, err = run(capsys, "render", SCENE, "-o", tmp_path / "o.exr")
    assert_one_line_error(code, err, "no OpenCL platform", "pip install pocl-binary-distribution")
    code, _, err = run(capsys, "devices")
    assert_one_line_error(code, err, "pocl-binary-distribution")


def test_device_choice(capsys, tmp_path, monkeypatch):
    monkeypatch.setenv("PYOPENCL_CTX", "7:0")
    code, _, err = run(capsys, "render", SCENE, "-o", tmp_path / "o.exr")
    assert_one_line_error(code, err, "no OpenCL platform 7")
    code, _, err = run(capsys, "render", SCENE, "-o", tmp_path / "o.exr", "--device", "nosuchvendor")
    assert_one_line_error(code, err, "nosuchvendor")
    monkeypatch.delenv("PYOPENCL_CTX")
    code, out, err = run(capsys, "devices")
    assert code == 0 and "--device 0:0" in out and "default:" in out


def test_an_existing_tree_file_survives_a_failed_write(tmp_path, monkeypatch):
    from small_trees import two_leaf_tree
    from kdray import files
    path = tmp_path / "t.kdt"
    two_leaf_tree().save(path)
    before = path.read_bytes()

    def fail(*args):
        raise KeyboardInterrupt
    monkeypatch.setattr(files.os, "fsync", fail)
    with pytest.raises(KeyboardInterrupt):
        two_leaf_tree().save(path)
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["t.kdt"]


def test_progress_only_on_a_terminal(capsys, tmp_path, monkeypatch):
    import sys
    code, out, err = run(capsys, "build", SCENES / "sphere.obj")
    assert code == 0 and err == ""                     # not a terminal: quiet
    monkeypatch.setattr(sys.stderr, "isatty", lambda: True, raising=False)
    code, out, err = run(capsys, "build", SCENES / "sphere.obj")
    assert code == 0 and "building the tree of 1,280 triangles" in err
