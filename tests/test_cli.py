"""The command line: output, exit codes, one-line errors."""

from kdray.tree import KdTree
from helpers import SCENES, real_mesh, run


def test_build_dump_info_check(capsys, tmp_path):
    tree_path = tmp_path / "teapot.kdt"
    code, out, err = run(capsys, "build", real_mesh("teapot.obj"), "--dump", tree_path)
    assert code == 0, err
    assert "nodes" in out and "build_seconds" in out and "refs_per_triangle" in out
    tree = KdTree.load(tree_path)
    tree.validate()
    assert tree.n_input_tris == 6320
    code, out, err = run(capsys, "info", tree_path, "--check")
    assert code == 0, err
    assert "check              ok" in out and "origin" in out


def test_info_check_names_the_file_it_refuses(capsys, tmp_path, monkeypatch):
    """A tree file that loads but fails the full validation (a triangle moved within the
    bounds: only --check sees it) is refused naming the file, as the loader's errors."""
    from kdray.errors import TreeError
    tree_path = tmp_path / "t.kdt"
    assert run(capsys, "build", SCENES / "cornell.obj", "--dump", tree_path)[0] == 0

    def broken(self, *args, **kwargs):
        raise TreeError("triangle 5 (input id 5) is not listed in a leaf")
    monkeypatch.setattr(KdTree, "validate", broken)
    code, _, err = run(capsys, "info", tree_path, "--check")
    assert code == 1 and err == f"kdray: error: {tree_path}: triangle 5 (input id 5) is not " \
        f"listed in a leaf\n", err


def test_build_options_reach_the_builder(capsys, tmp_path):
    tree_path = tmp_path / "t.kdt"
    code, _, err = run(capsys, "build", real_mesh("teapot.obj"), "--dump", tree_path,
                       "--max-depth", "5", "--k-i", "40", "--empty-bonus", "1")
    assert code == 0, err
    p = KdTree.load(tree_path).params
    assert (p.max_depth, p.K_I, p.empty_bonus) == (5, 40.0, 1.0)


def test_help_documents_every_build_option(capsys):
    code, out, _ = run(capsys, "build", "--help")
    assert code == 0
    for opt in ("--dump", "--k-t", "--k-i", "--empty-bonus", "--max-depth", "--leaf-size"):
        assert opt in out


def test_errors_are_one_line(capsys, tmp_path):
    code, out, err = run(capsys, "build", tmp_path / "missing.obj")
    assert code == 1 and err.count("\n") == 1 and "missing.obj" in err and "Traceback" not in err
    bad = tmp_path / "bad.kdt"
    bad.write_bytes(b"KDRAYTRE" + bytes(300))
    code, out, err = run(capsys, "info", bad)
    assert code == 1 and err.count("\n") == 1 and "bad.kdt" in err


def test_usage_errors_exit_2(capsys):
    code, _, err = run(capsys, "build", "--no-such-option", "x.obj")
    assert code == 2
    code, _, err = run(capsys, "render", "x.obj", "--size", "0x10")
    assert code == 2


def test_dump_onto_the_input_is_refused(capsys, tmp_path):
    src = tmp_path / "m.obj"
    src.write_bytes(real_mesh("teapot.obj").read_bytes())
    code, _, err = run(capsys, "build", src, "--dump", src)
    assert code == 1 and "overwrite the input" in err
    assert src.read_bytes()[:2] != b"KD"


def test_render_writes_the_camera_into_the_exr(capsys, tmp_path):
    """The EXR of `kdray render` names its camera: read_camera gives back the camera of
    the --camera file exactly, and OpenImageIO reads the standard worldToCamera."""
    import numpy as np
    import OpenImageIO as oiio
    from kdray.camera import Camera
    from kdray.images import exr_camera_matrices, read_camera, read_exr
    camera = Camera.look_at((0.3, 1.1, 3.9), (0.0, 1.0, 0.0), fov_deg=41.0, width=40, height=30)
    camera.to_json(tmp_path / "cam.json")
    out = tmp_path / "cornell.exr"
    code, printed, err = run(capsys, "render", SCENES / "cornell.obj", "--camera",
                             tmp_path / "cam.json", "-o", out, "--aov", "depth,id")
    assert code == 0, err
    assert "(40x30, depth, id, " in printed and "of 1200 pixels hit" in printed   # the file's size
    assert read_camera(out) == Camera.from_json(tmp_path / "cam.json")
    assert set(read_exr(out)) == {"depth", "id"}
    spec = oiio.ImageInput.open(str(out)).spec()
    stored = np.array(spec.getattribute("worldToCamera"), dtype=np.float64).reshape(4, 4)
    assert np.allclose(stored, exr_camera_matrices(camera)[0], rtol=1e-6, atol=1e-6)
