"""The command line: output, exit codes, one-line errors."""

from kdray.tree import KdTree
from helpers import real_mesh, run


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
