"""Hostile inputs on every surface (issue 53): each failure found is refused with one
line `kdray: error: ...` and exit code 1 (the API: a KdrayError), never a traceback or
a numpy warning, before any work, and no file is changed.

The shared places these tests reach: kdray.files.check_output (output paths),
kdray.validate (JSON, float32 ranges), kdray.camera (every camera's values and
sides), kdray.lidar (specs, poses, scan memory), kdray.dataset.Job and read_jobs
(jobs), kdray.builder.check_params (build parameters).
"""
import io
import json
import os
import shutil
import stat
import subprocess
import sys
import threading
import warnings
from pathlib import Path

import numpy as np
import pytest

import kdray
from helpers import run
from kdray.errors import (CameraError, DatasetError, KdrayError, MeshError, OutputError,
                          ParameterError, TreeFileError)

SCENE = Path(__file__).resolve().parent.parent / "scenes" / "cornell.obj"
CAMERA = {"width": 16, "height": 12, "eye": [0, 0.5, 1.85], "target": [0, 0.5, 0]}
POSE = [[1, 0, 0, 0], [0, -1, 0, 0.5], [0, 0, -1, 1.85], [0, 0, 0, 1]]
LIDAR = {"channels": 4, "fov_up": 10, "fov_down": -10, "columns": 16, "max_range": 50}
DEEP = "[" * 50000 + "]" * 50000
DIGITS = "9" * 5000


@pytest.fixture
def folder(tmp_path, monkeypatch):
    """A working folder holding the scene (c.obj), a camera, a pose, a lidar spec and
    an existing out.exr; the current folder."""
    monkeypatch.chdir(tmp_path)
    shutil.copy(SCENE, "c.obj")
    Path("cam.json").write_text(json.dumps(CAMERA))
    Path("pose.txt").write_text("\n".join(" ".join(map(str, row)) for row in POSE))
    Path("lidar.json").write_text(json.dumps(LIDAR))
    Path("out.exr").write_bytes(b"an existing output")
    return tmp_path


def snapshot(root):
    """Every file under root (symlinks as their targets' names) -> its bytes."""
    files = {}
    for p in sorted(Path(root).rglob("*")):
        if p.is_symlink():
            files[p] = ("link", os.readlink(p))
        elif p.is_file():
            files[p] = p.read_bytes()
    return files


def refused(capsys, folder, *argv, words=()):
    """Run `kdray argv` with numpy's warnings as errors: exit code 1, exactly one stderr
    line starting `kdray: error:` holding `words`, no traceback, and no file under
    `folder` changed, made or removed."""
    before = snapshot(folder)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        code, out, err = run(capsys, *argv)
    lines = err.splitlines()
    assert code == 1, (code, out, err)
    assert len(lines) == 1 and lines[0].startswith("kdray: error: "), err
    assert "Traceback" not in err
    for w in words:
        assert w in err, (w, err)
    assert snapshot(folder) == before
    return err


# -- pipes --------------------------------------------------------------------------------

def feed(path, data):
    """A FIFO made at path, which a thread fills with the bytes `data` (a shell's pipe)."""
    os.mkfifo(path)
    threading.Thread(target=Path(path).write_bytes, args=(data,), daemon=True).start()


def npy_bytes(array):
    buffer = io.BytesIO()
    np.save(buffer, array)
    return buffer.getvalue()


def test_npy_and_npz_inputs_are_read_from_pipes(capsys, folder):
    """A .npy points file and .npy and .npz rays files that are pipes are read as the
    same files are (docs/interface.md: "files and pipes are read"); a pipe's .npy whose
    header claims more than it holds is refused, not allocated."""
    points = np.array([[0.1, 0.5, 0.1], [0.5, 0.5, 0.5], [5.0, 5.0, 5.0]])
    np.save("p.npy", points)
    feed("pipe.npy", npy_bytes(points))
    assert run(capsys, "contains", "c.obj", "--points", "p.npy", "-o", "a.npy")[0] == 0
    assert run(capsys, "contains", "c.obj", "--points", "pipe.npy", "-o", "b.npy")[0] == 0
    assert np.array_equal(np.load("a.npy"), np.load("b.npy"))
    rays = np.concatenate([points, np.tile([[0.0, 0.0, 1.0]], (3, 1))], axis=1)
    np.save("r.npy", rays)
    os.remove("pipe.npy")
    feed("pipe.npy", npy_bytes(rays))
    np.savez("r.npz", origins=rays[:, :3], directions=rays[:, 3:])
    buffer = io.BytesIO()
    np.savez(buffer, origins=rays[:, :3], directions=rays[:, 3:])
    feed("pipe.npz", buffer.getvalue())
    Path("R.NPY").write_bytes(npy_bytes(rays))       # the extension in any case
    for source, out in (("r.npy", "c.npz"), ("pipe.npy", "d.npz"), ("pipe.npz", "e.npz"),
                        ("R.NPY", "g.npz")):
        assert run(capsys, "cast", "c.obj", "--rays", source, "-o", out)[0] == 0
    for out in ("d.npz", "e.npz", "g.npz"):
        with np.load("c.npz") as a, np.load(out) as b:
            assert all(np.array_equal(a[k], b[k]) for k in a.files)
    claim = io.BytesIO()
    np.lib.format.write_array_header_1_0(claim, {"descr": "<f8", "fortran_order": False,
                                                 "shape": (10 ** 12, 3)})
    claim = claim.getvalue() + points.tobytes()
    os.remove("pipe.npy")
    feed("pipe.npy", claim)
    refused(capsys, folder, "contains", "c.obj", "--points", "pipe.npy", "-o", "f.npy",
            words=["cannot be read as a .npy file", "needs"])


def test_outputs_that_are_pipes_are_refused(capsys, folder):
    """-o naming a FIFO (or a device) is refused before any work: kdray writes a file
    whole and renames it over the name, which would replace the node (as root,
    /dev/null itself)."""
    Path("pts.txt").write_text("0.1 0.5 0.1\n")
    os.mkfifo("o.npy")
    refused(capsys, folder, "contains", "c.obj", "--points", "pts.txt", "-o", "o.npy",
            words=["-o o.npy: is a device, a pipe or a socket, not a file"])
    assert stat.S_ISFIFO(os.stat("o.npy").st_mode)


def test_python_writers_refuse_pipes(folder):
    """The library's own writers (a tree file, a camera file, a lidar's points) refuse
    a FIFO as the CLI does, and leave it a FIFO: a file renamed over it would replace
    it (as root, /dev/null itself)."""
    os.mkfifo("node")
    mesh = kdray.load("c.obj")
    tree = kdray.build(mesh.vertices, mesh.faces)
    camera = kdray.Camera.look_at(CAMERA["eye"], CAMERA["target"], (0, 1, 0), 60, 16, 12)
    images = kdray.Tracer(tree).scan(kdray.Lidar.from_dict(LIDAR), np.array(POSE, float))
    for write in (lambda: tree.save("node"), lambda: camera.to_json("node"),
                  lambda: kdray.lidar.write_points_ply("node", images)):
        with pytest.raises(OutputError, match="node: it is a device, a pipe"):
            write()
        assert stat.S_ISFIFO(os.stat("node").st_mode)


# -- outputs: collisions, folders, names -------------------------------------------------

@pytest.mark.parametrize("preview", ["out.exr", "./out.exr", "sub/../out.exr", "link.exr"])
def test_render_preview_equal_to_output(capsys, folder, preview):
    os.mkdir("sub")
    os.symlink("out.exr", "link.exr")
    refused(capsys, folder, "render", "c.obj", "--size", "8x6", "-o", "out.exr",
            "--preview", preview, words=["--preview", "one would replace the other"])


def test_render_preview_through_a_dangling_symlink(capsys, folder):
    os.symlink("new.exr", "dangling.png")
    refused(capsys, folder, "render", "c.obj", "--size", "8x6", "-o", "new.exr",
            "--preview", "dangling.png", words=["one would replace the other"])


@pytest.mark.parametrize("argv, words", [
    (["--camera", "cam.json", "-o", "cam.json"], ["-o cam.json", "overwrite the input"]),
    (["--camera", "cam.json", "-o", "./cam.json"], ["overwrite the input cam.json"]),
    (["--intrinsics", "8,8,4,3", "--pose", "pose.txt", "-o", "pose.txt"], ["overwrite"]),
    (["-o", "out.exr", "--preview", "c.obj"], ["--preview c.obj", "overwrite the input"]),
])
def test_render_output_equal_to_an_input(capsys, folder, argv, words):
    refused(capsys, folder, "render", "c.obj", "--size", "8x6", *argv, words=words)


def test_scan_points_and_output_collide(capsys, folder):
    refused(capsys, folder, "scan", "c.obj", "--lidar", "lidar.json", "--pose", "pose.txt",
            "-o", "out.exr", "--points", "./out.exr", words=["--points", "replace"])
    refused(capsys, folder, "scan", "c.obj", "--lidar", "lidar.json", "--pose", "pose.txt",
            "-o", "lidar.json", words=["overwrite the input lidar.json"])


@pytest.mark.parametrize("argv", [
    ["scan", "c.obj", "--lidar", "lidar.json", "--pose", "pose.txt", "-o", "new.exr",
     "--points", "sub"],
    ["build", "c.obj", "--dump", "sub"],
    ["render", "c.obj", "--size", "8x6", "-o", "new.exr", "--preview", "sub"],
    ["bench", "c.obj", "--size", "4x4", "--csv", "sub"],
])
def test_every_output_option_refuses_a_folder_in_one_line(capsys, folder, argv):
    os.mkdir("sub")
    refused(capsys, folder, *argv, words=["sub: is a folder"])


def test_bench_csv_equal_to_a_scene(capsys, folder):
    refused(capsys, folder, "bench", "c.obj", "--size", "4x4", "--csv", "c.obj",
            words=["--csv c.obj", "overwrite the input c.obj"])


@pytest.mark.parametrize("command", [
    ["render", "c.obj", "--size", "8x6"],
    ["contains", "c.obj", "--points", "pts.txt"],
    ["cast", "c.obj", "--rays", "rays.txt"],
    ["points", "c.obj", "--points", "pts.txt"],
    ["sdf", "c.obj", "--resolution", "4"],
    ["scan", "c.obj", "--lidar", "lidar.json", "--pose", "pose.txt"],
])
@pytest.mark.parametrize("output", [".", "sub/", "sub/" + "y" * 242 + ".exr"])
def test_outputs_that_cannot_be_written_are_refused_first(capsys, folder, command, output):
    """A folder (existing or not) or a name whose temporary file's name is too long (242
    + 14 bytes): refused before any work, exit 1 and one line, by every command."""
    os.mkdir("sub")
    Path("pts.txt").write_text("0 0.5 0\n")
    Path("rays.txt").write_text("0 0.5 3 0 0 -1\n")
    before = snapshot(folder)
    for path in (output, output.rstrip("/")):
        code, _, err = run(capsys, *command, "-o", path)
        assert code == 1 and err.count("\n") == 1, err
        assert "is a folder" in err or "255" in err, err
    assert snapshot(folder) == before


def test_longest_output_name_is_written(capsys, folder):
    """The check counts the temporary's 14 bytes: a name of 241 bytes is written."""
    name = "z" * 237 + ".exr"
    code, _, err = run(capsys, "render", "c.obj", "--size", "4x3", "-o", name)
    assert code == 0, err
    assert Path(name).is_file()


def test_view_name_checked_on_the_temporary_name(capsys, folder):
    """A view name of 238 bytes passes `<name>.exr` (242) but not its temporary (256):
    refused before any rendering; 237 bytes is rendered."""
    Path("long.json").write_text(json.dumps([dict(CAMERA, name="v" * 238)]))
    refused(capsys, folder, "render", "c.obj", "--cameras", "long.json", "-o", "views",
            words=["256 bytes", "255"])
    Path("ok.json").write_text(json.dumps([dict(CAMERA, name="v" * 237, width=4, height=3)]))
    code, _, err = run(capsys, "render", "c.obj", "--cameras", "ok.json", "-o", "views")
    assert code == 0, err
    assert Path("views", "v" * 237 + ".exr").is_file()


def test_batch_jobs_writing_one_folder_through_a_symlink(capsys, folder):
    Path("cams.json").write_text(json.dumps([dict(CAMERA, name="a")]))
    os.mkdir("real")
    os.symlink("real", "link")
    jobs = [{"scene": "c.obj", "cameras": "cams.json", "output": o} for o in ("real", "link")]
    Path("jobs.jsonl").write_text("\n".join(map(json.dumps, jobs)) + "\n")
    refused(capsys, folder, "batch", "jobs.jsonl", words=["lines 1 and 2 both write"])


def test_a_view_that_would_overwrite_its_camera_file(folder):
    from kdray.dataset import Job, plan
    Path("a.exr").write_text(json.dumps([dict(CAMERA, name="a")]))    # a camera list
    [(report, todo)] = plan([Job("c.obj", "a.exr", ".")])
    assert todo == [] and "would overwrite the cameras file" in report.errors[0]


def test_nul_byte_in_a_batch_output(capsys, folder):
    Path("cams.json").write_text(json.dumps([dict(CAMERA, name="a")]))
    job = {"scene": "c.obj", "cameras": "cams.json", "output": "o\u0000x"}
    Path("jobs.jsonl").write_text(json.dumps(job) + "\n")
    refused(capsys, folder, "batch", "jobs.jsonl", words=["line 1", "NUL byte"])


def test_a_newline_in_a_message_stays_on_one_line(capsys, folder):
    refused(capsys, folder, "render", "no\nsuch.obj", "-o", "x.exr", words=["no\\nsuch.obj"])


# -- JSON: nesting, huge integers, keys given twice ----------------------------------------

def _jobs_line(build):
    return '{"scene": "c.obj", "cameras": "cam.json", "output": "o", "build": ' + build + '}\n'


@pytest.mark.parametrize("value, words", [
    (DEEP, ["JSON nested more than 32 deep (JSON_MAX_DEPTH)"]),
    (DIGITS, ["an integer of 5000 digits", "309"]),
    ("9" * 400, ["an integer of 400 digits"]),          # past float64: OverflowError before
    ('{"a": 1, "a": 2}', ['the key "a" is given twice in one object']),   # the last won
])
@pytest.mark.parametrize("surface", ["camera", "cameras", "lidar", "batch"])
def test_json_that_python_cannot_take(capsys, folder, surface, value, words):
    if surface in ("camera", "cameras"):
        Path("bad.json").write_text('{"width": 16, "height": 12, "eye": [0, 0.5, 1.85], '
                                    '"target": [0, 0.5, 0], "fov": ' + value + '}')
        option = "--camera" if surface == "camera" else "--cameras"
        argv = ["render", "c.obj", option, "bad.json", "-o", "o.exr" if option == "--camera" else "o"]
    elif surface == "lidar":
        Path("bad.json").write_text(json.dumps(LIDAR)[:-1] + ', "horizontal_fov": ' + value + '}')
        argv = ["scan", "c.obj", "--lidar", "bad.json", "--pose", "pose.txt", "-o", "s.exr"]
    else:
        Path("bad.json").write_text(_jobs_line('{"K_T": ' + value + '}'))
        argv = ["batch", "bad.json"]
    refused(capsys, folder, *argv, words=words)


def test_json_readers_refuse_depth_and_digits_through_the_api(folder):
    from kdray.camera_files import read_cameras
    from kdray.dataset import read_jobs
    Path("deep.json").write_text(DEEP)
    for reader, error in ((kdray.Camera.from_json, CameraError), (read_cameras, CameraError),
                          (kdray.Lidar.from_json, ParameterError), (read_jobs, DatasetError)):
        with pytest.raises(error, match="nested more than 32 deep"):
            reader("deep.json")
    Path("shallow.json").write_text("[" * 33 + "]" * 33)       # under Python's limit
    with pytest.raises(CameraError, match="nested more than 32 deep"):
        kdray.Camera.from_json("shallow.json")


def test_object_names_nested_deeply_in_a_tree_file():
    from kdray.layout import decode_names
    with pytest.raises(TreeFileError, match="not UTF-8 JSON"):
        decode_names(DEEP.encode())


# -- values no camera or lidar has ----------------------------------------------------------

def _camera_file(K=((30, 0, 8), (0, 30, 6), (0, 0, 1)), translation=(0, 0.5, 1.85), **more):
    pose = [row[:] for row in POSE]
    for k in range(3):
        pose[k][3] = translation[k]
    return json.dumps({"width": 16, "height": 12, "K": [list(r) for r in K],
                       "cam_to_world": pose, **more})


@pytest.mark.parametrize("text, words", [
    (_camera_file(K=((1e308, 0, 8), (0, 1e308, 6), (0, 0, 1))), ["K holds 1e+308", "float32"]),
    (_camera_file(K=((30, 0, 1e300), (0, 30, 6), (0, 0, 1))), ["K holds 1e+300", "float32"]),
    (_camera_file(K=((1e-300, 0, 8), (0, 1e-300, 6), (0, 0, 1))), ["K's inverse"]),
    (_camera_file(translation=(1e39, 0, 0)), ["translation of cam_to_world holds 1e+39"]),
    (_camera_file(translation=(0, 1e300, 0)), ["translation of cam_to_world holds 1e+300"]),
    (json.dumps(dict(CAMERA, width=100000)), ["width", "at most 65536 (MAX_SIDE)"]),
    (json.dumps(dict(CAMERA, width=640.0)), ["width", "got 640.0"]),
    (json.dumps(dict(CAMERA, fov="40")), ["fov must be a number"]),
    (json.dumps(dict(CAMERA, eye=[1e300, 0, 0])), ["eye holds 1e+300"]),
])
def test_camera_files_with_values_no_camera_has(capsys, folder, text, words):
    Path("bad.json").write_text(text)
    refused(capsys, folder, "render", "c.obj", "--camera", "bad.json", "-o", "o.exr",
            words=["camera file bad.json", *words])


@pytest.mark.parametrize("argv, words", [
    (["--intrinsics", "1e308,1e308,8,6", "--pose", "pose.txt"], ["K holds 1e+308"]),
    (["--eye", "1e39,0,0", "--target", "0,0,0"], ["eye holds 1e+39"]),
    (["--eye", "1e300,0,0", "--target", "0,0,0"], ["eye holds 1e+300"]),
    (["--eye", "0,0,1", "--target", "0,0,0", "--up", "1e300,0,0"], ["up holds 1e+300"]),
    (["--size", "100000x2"], ["at most 65536 (MAX_SIDE)"]),
])
def test_camera_options_with_values_no_camera_has(capsys, folder, argv, words):
    refused(capsys, folder, "render", "c.obj", *argv, "-o", "o.exr", words=words)


@pytest.mark.parametrize("t", ["1e39", "1e300"])
@pytest.mark.parametrize("command", ["render", "scan"])
def test_poses_beyond_float32(capsys, folder, t, command):
    Path("far.txt").write_text(f"1 0 0 {t}\n0 1 0 0\n0 0 1 0\n0 0 0 1\n")
    if command == "render":
        argv = ["render", "c.obj", "--intrinsics", "8,8,4,3", "--pose", "far.txt", "-o", "o.exr"]
    else:
        argv = ["scan", "c.obj", "--lidar", "lidar.json", "--pose", "far.txt", "-o", "o.exr"]
    refused(capsys, folder, *argv, words=["pose in far.txt", "float32"])


def test_one_side_limit_for_every_camera():
    from kdray.camera import MAX_SIDE
    from kdray.camera_files import MAX_SIDE as FILES_MAX_SIDE
    assert FILES_MAX_SIDE is MAX_SIDE
    for make in (lambda: kdray.Camera(MAX_SIDE + 1, 2, np.eye(3), np.eye(4)),
                 lambda: kdray.Camera.look_at((0, 0, 1), (0, 0, 0), width=MAX_SIDE + 1),
                 lambda: kdray.Camera.panorama(np.eye(4), 2, MAX_SIDE + 1)):
        with pytest.raises(CameraError, match="MAX_SIDE"):
            make()
    kdray.Camera(MAX_SIDE, 1, np.eye(3), np.eye(4))


# -- memory --------------------------------------------------------------------------------

def test_scan_at_the_documented_limits_is_refused_with_the_amount(capsys, folder, monkeypatch):
    monkeypatch.setattr("kdray.host.available_memory", lambda: 4 * 2**30)
    Path("big.json").write_text(json.dumps(dict(LIDAR, channels=1024, columns=65536)))
    refused(capsys, folder, "scan", "c.obj", "--lidar", "big.json", "--pose", "pose.txt",
            "-o", "s.exr", words=["1024 x 65536 beams needs about 8.8 GiB", "4.0 GiB"])
    lidar = kdray.Lidar.from_json("big.json")
    with pytest.raises(KdrayError, match="8.8 GiB"):
        lidar.directions()                # the first large array of Tracer.scan


def _stacked_planes(n_planes, keep_double=False):
    """A Tracer of n_planes unit squares at z = 0, 1, ..., and rays up through them all
    (more hits a ray than intersections' first pass lists)."""
    corners = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float64)
    v = np.concatenate([np.column_stack([corners, np.full(4, z)]) for z in range(n_planes)])
    f = np.concatenate([np.array([[0, 1, 2], [0, 2, 3]]) + 4 * z for z in range(n_planes)])
    return kdray.Tracer(kdray.build(v, f, keep_double=keep_double))


def test_intersections_count_every_list_they_make(monkeypatch):
    """intersections checks the memory of each array that grows with the hits before
    making it, so that a total the first checks let through (20 bytes a hit) ends in
    a KdrayError, not numpy's MemoryError: the whole list with the relisted rays' hits
    put in place (and their index), the lists of several launches joined, and the
    float64 answers (about 84 bytes a hit). It counted the first two only. (One ray
    in 30 starts high, its 4 hits all listed by the first pass: where every ray is
    listed again, that list is the whole one, and no other is made.)"""
    tracer = _stacked_planes(40, keep_double=True)
    rng = np.random.default_rng(3)
    n = 300
    high = np.arange(n) % 30 == 0
    o = np.column_stack([0.05 + 0.9 * rng.random((n, 2)), np.where(high, 35.5, -0.5)])
    d = np.tile([0.0, 0.0, 1.0], (n, 1))
    hits = tracer.intersections(o, d)
    assert len(hits.t) == 40 * n - 36 * 10               # 11,640: every plane once a ray
    # room for the listing passes (under 20 bytes a hit), not for the whole list's
    monkeypatch.setattr("kdray.host.available_memory", lambda: 40 * n * 22 + n * 200)
    with pytest.raises(KdrayError, match="11,640 hits of 300 rays needs about .*max_hits"):
        tracer.intersections(o, d)
    monkeypatch.setattr("kdray.host.available_memory", lambda: 40 * n * 60 + n * 200)
    assert len(tracer.intersections(o, d).t) == 40 * n - 36 * 10
    with pytest.raises(KdrayError, match="hits of 300 rays in double precision needs about"):
        tracer.intersections(o, d, precision="double")


def test_double_render_counts_its_float64_images(monkeypatch):
    """render(precision="double") checks the memory of its float64 part (the camera's
    float64 rays, t and uv, the images) before the kernel's: it checked the kernel's
    float32 images only, and ended in numpy's MemoryError where those fit."""
    from kdray import render as _render
    tracer = _stacked_planes(2, keep_double=True)
    cam = kdray.Camera.frame(*tracer.tree.world_box(), width=64, height=48)
    single = 64 * 48 * _render.host_bytes_per_pixel(("depth", "id"))
    monkeypatch.setattr("kdray.host.available_memory", lambda: 2 * single)
    tracer.render(cam, aovs="depth,id")
    with pytest.raises(KdrayError, match="a 64x48 render of depth, id in double precision"):
        tracer.render(cam, aovs="depth,id", precision="double")


def test_available_memory_under_an_address_space_limit():
    """RLIMIT_AS (ulimit -v) bounds what a check_host_memory allows."""
    code = ("import resource; resource.setrlimit(resource.RLIMIT_AS, (3 << 30, 3 << 30)); "
            "from kdray.host import available_memory; print(available_memory())")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout
    assert 0 < int(out) < 3 << 30


# -- types are kept ------------------------------------------------------------------------

def test_batch_build_parameter_given_as_a_string(capsys, folder):
    Path("jobs.jsonl").write_text(_jobs_line('{"K_I": "20"}'))
    refused(capsys, folder, "batch", "jobs.jsonl", words=["K_I must be a number, got '20'"])


@pytest.mark.parametrize("params, words", [
    ({"K_T": "20"}, "K_T must be a number, got '20'"),
    ({"K_I": True}, "K_I must be a number, got True"),
    ({"max_depth": 3.0}, "max_depth must be a whole number"),
    ({"leaf_size": 10**30}, "leaf_size must be from 0 to 4294967295"),
    ({"K_I": 10**400}, "K_I must be finite"),
])
def test_build_parameters_keep_their_types(params, words):
    v, f = [[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]]
    with pytest.raises(ParameterError, match=words) as info:
        kdray.build(v, f, **params)
    assert isinstance(info.value, ValueError)


@pytest.mark.parametrize("make, error", [
    (lambda: kdray.Camera(640.0, 480, np.eye(3), np.eye(4)), CameraError),
    (lambda: kdray.Camera("640", 480, np.eye(3), np.eye(4)), CameraError),
    (lambda: kdray.Camera.look_at((0, 0, 1), (0, 0, 0), fov_deg="40"), CameraError),
    (lambda: kdray.Camera(4, 3, [[10**400, 0, 1], [0, 1, 1], [0, 0, 1]], np.eye(4)), CameraError),
    (lambda: kdray.Lidar([0.0], 8, 10**400), ParameterError),
    (lambda: kdray.Mesh.from_arrays([[10**400, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]]), MeshError),
])
def test_api_values_of_the_wrong_type_or_range(make, error):
    with pytest.raises(error):
        make()


@pytest.mark.skipif(not os.path.exists("/dev/zero"), reason="no /dev/zero here")
@pytest.mark.parametrize("argv, words", [
    (["batch", "/dev/zero"], "jobs file /dev/zero is a device"),
    (["info", "/dev/zero"], "/dev/zero is a device"),
    (["scan", "c.obj", "--lidar", "/dev/zero", "--pose", "pose.txt", "-o", "new.exr"],
     "lidar spec /dev/zero is a device"),
    (["scan", "c.obj", "--lidar", "lidar.json", "--pose", "/dev/zero", "-o", "new.exr"],
     "/dev/zero is a device"),
    (["render", "c.obj", "--camera", "/dev/zero", "-o", "new.exr"], "/dev/zero is a device"),
    (["contains", "c.obj", "--points", "/dev/zero", "-o", "new.npy"], "/dev/zero is a device"),
])
def test_devices_as_inputs_are_refused_not_read_forever(capsys, folder, argv, words):
    refused(capsys, folder, *argv, words=[words])


def test_api_objects_of_another_class_are_type_errors():
    """A kdray object of the wrong class (a Mesh for a tree, a dict for a camera or a
    lidar) is Python's TypeError naming both, not an AttributeError from inside."""
    v, f = np.eye(3), np.array([[0, 1, 2]])
    tracer = kdray.Tracer(kdray.build(v, f))
    for call, words in ((lambda: kdray.Tracer(kdray.Mesh.from_arrays(v, f)), "KdTree, got Mesh"),
                        (lambda: tracer.render({"width": 4}), "Camera, got dict"),
                        (lambda: tracer.camera_rays(None), "Camera, got NoneType"),
                        (lambda: tracer.scan({"columns": 4}, np.eye(4)), "Lidar, got dict")):
        with pytest.raises(TypeError, match=words):
            call()


def test_api_jobs_keep_their_types():
    from kdray.dataset import Job
    for fields, words in (({"scene": 3}, "scene must be a path"),
                          ({"output": "a\0b"}, "NUL byte"),
                          ({"preview": "yes"}, "preview must be true or false"),
                          ({"params": {"K_T": 1}}, "params must be a kdray.BuildParams")):
        with pytest.raises(DatasetError, match=words):
            Job(**{"scene": "s.obj", "cameras": "c.json", "output": "o", **fields})


def test_api_flags_sizes_and_params_keep_their_types(folder):
    """Found by the docs' audit: a flag given "no" was taken for its truth, a device
    given as a number for its digits, stack sizes and sample counts of other types got
    past or failed with Python's errors, a BuildParams of strings failed only when its
    job ran, an origin of letters was numpy's error. Each is a KdrayError now, and
    kdray.DatasetError is exported as the other errors are."""
    from kdray.cull import cull_faces
    from kdray.dataset import Job
    from kdray.device import choose_device
    from kdray.sdf import sdf_grid
    mesh = kdray.load("c.obj")
    tree = kdray.build(mesh.vertices, mesh.faces)
    tracer = kdray.Tracer(tree)
    camera = kdray.Camera.look_at(CAMERA["eye"], CAMERA["target"], (0, 1, 0), 60, 16, 12)
    for call, error, words in (
            (lambda: sdf_grid(tracer, 4, occupancy="no"), KdrayError, "occupancy must be True or False"),
            (lambda: camera.rays(valid="no"), CameraError, "valid must be True or False"),
            (lambda: choose_device(2), kdray.DeviceError, "a --device string"),
            (lambda: tracer.compile(stack_sizes=("8",)), KdrayError, "stack_sizes must be some of"),
            (lambda: tracer.compile(stack_sizes=(1000,)), KdrayError, "stack_sizes must be some of"),
            (lambda: tracer.compile(stack_sizes=(0,)), KdrayError, "stack_sizes must be some of"),
            (lambda: tree.validate(coverage_samples="4"), kdray.TreeError, "coverage_samples must be"),
            (lambda: cull_faces(mesh.vertices, mesh.faces, camera, origin="x"), ParameterError,
             "origin must be 3 finite numbers"),
            (lambda: Job(scene="s.obj", cameras="c.json", output="o",
                         params=kdray.BuildParams(K_I="20")), ParameterError, "K_I must be a number"),
            (lambda: Job(scene="s.obj", cameras="c.json", output="o",
                         params=kdray.BuildParams(max_depth=3.0)), ParameterError, "max_depth")):
        with pytest.raises(error, match=words):
            call()
    assert kdray.DatasetError is DatasetError and "DatasetError" in kdray.__all__
    assert camera.rays(valid=np.bool_(True))[2].all()
    tree.validate(coverage_samples=np.int64(2))


def test_api_paths_with_nul_or_no_name(tmp_path):
    from kdray.camera_files import read_cameras
    from kdray.images import write_exr
    image = {"depth": np.zeros((2, 2), np.float32)}
    for call, error in ((lambda: write_exr(tmp_path / ".", image), OutputError),
                        (lambda: write_exr("a\0b.exr", image), OutputError),
                        (lambda: kdray.Camera.look_at((0, 0, 1), (0, 0, 0)).to_json("a\0b"), OutputError),
                        (lambda: kdray.KdTree.load("a\0b"), TreeFileError),
                        (lambda: read_cameras("a\0b.json"), CameraError),
                        (lambda: kdray.Lidar.from_json("a\0b.json"), ParameterError)):
        with pytest.raises(error):
            call()


def test_camera_far_from_a_tiny_scene_is_refused_by_the_render():
    """The eye relative to a tree of scale 2^-100, in its units (1e60), is beyond the
    kernels' float32: a KdrayError, no numpy warning."""
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], dtype=np.float64) * 1e-30
    tracer = kdray.Tracer(kdray.build(v, [[0, 1, 2]]))
    camera = kdray.Camera.look_at((1e30, 0, 0), (0, 0, 0), width=4, height=3)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(KdrayError, match="eye relative to the tree"):
            tracer.render(camera)


def test_lidar_far_from_a_tiny_scene_is_refused_by_the_scan():
    """The same for a scan: the lidar's position relative to a tree of scale 2^-100 is
    beyond float32 (a KdrayError, no numpy warning)."""
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], dtype=np.float64) * 1e-30
    tracer = kdray.Tracer(kdray.build(v, [[0, 1, 2]]))
    pose = np.eye(4)
    pose[0, 3] = 1e30
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(KdrayError, match="lidar's position relative to the tree"):
            tracer.scan(kdray.Lidar(np.array([10.0, 0.0, -10.0]), 8, 1e40), pose)


def test_intersections_too_many_to_list_are_refused_early(monkeypatch):
    """Rays whose lists cannot fit are refused once the hits counted so far do not
    fit (hit_lists.COUNT_FIRST, then twice as many at a time), not after counting every
    ray: here after 4 + 8 + ... + 128 = 252 of 1,000 rays (40 hits each; room for the
    first pass, which lists 8 a ray, and for the lists of 10,000 hits); it counted all
    1,000 first."""
    from kdray import hit_lists
    tracer = _stacked_planes(40)
    n = 1000
    rng = np.random.default_rng(5)
    o = np.column_stack([0.05 + 0.9 * rng.random((n, 2)), np.full(n, -0.5)])
    d = np.tile([0.0, 0.0, 1.0], (n, 1))
    counted = []
    count_pass = hit_lists.count_pass
    monkeypatch.setattr(hit_lists, "count_pass", lambda tracer, rays, crossing: (
        counted.append(rays.n), count_pass(tracer, rays, crossing))[1])
    monkeypatch.setattr(hit_lists, "COUNT_FIRST", 4)
    # 20 bytes a hit listed, 12 a ray (hit_lists.list_hits' check)
    monkeypatch.setattr("kdray.host.available_memory", lambda: 10000 * 20 + n * 12)
    with pytest.raises(KdrayError, match="10,080 hits of 252 rays counted so far needs about"):
        tracer.intersections(o, d)
    assert counted == [4, 8, 16, 32, 64, 128]
