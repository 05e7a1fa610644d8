"""`kdray render -v`: what the render left out (degenerate and culled triangles, kernel
outputs not computed) and the stack size, on stderr; run as a real process so that
logging is set up as for a user."""
import subprocess
import sys

import kdray
from helpers import SCENES

# Two triangles facing +z at x = -2 and x = +2, and one degenerate (its vertices on a line).
OBJ = """v -2.5 -0.5 0
v -1.5 -0.5 0
v -2 0.5 0
v 1.5 -0.5 0
v 2.5 -0.5 0
v 2 0.5 0
v 0 0 0
v 1 1 0
v 2 2 0
f 1 2 3
f 7 8 9
f 4 5 6
"""


def kdray_cli(*argv):
    """(exit code, stdout, stderr) of `kdray argv...` in a fresh process."""
    proc = subprocess.run([sys.executable, "-m", "kdray.cli", *map(str, argv)],
                          capture_output=True, text=True)
    return proc.returncode, proc.stdout, proc.stderr


def test_verbose_reports_outputs_stack_and_left_out(tmp_path):
    scene = SCENES / "cornell.obj"
    code, out, err = kdray_cli("-v", "render", scene, "--size", "32x24", "--aov", "depth,normal",
                               "-o", tmp_path / "c.exr")
    assert code == 0, err
    mesh = kdray.load(scene)
    tree = kdray.build(mesh.vertices, mesh.faces)
    depth = tree.depth
    copies = len(tree.leaf_tris)
    mib = (8 * len(tree.nodes) + 40 * copies) / 2**20
    assert f"kdray: tree on the device: {mib:.1f} MiB ({len(tree.nodes)} nodes, {copies} triangle " \
           f"copies)\n" in err
    assert "kdray: triangles left out as degenerate: 0 of 32\n" in err
    assert "kdray: kernel outputs: T, NORMAL; not computed: UV, ID\n" in err
    stack = kdray.trace.default_stack_size(tree)
    assert stack >= depth + 1
    assert f"kdray: stack size: {stack} entries (tree depth {depth}; default {stack})\n" in err
    assert "--cull" not in err
    for step in ("loading", "building the tree", "setting up the device", "compiling the kernels",
                 "tracing 32x24 rays", "writing"):
        assert step in err, step
    code, out, err = kdray_cli("render", scene, "--size", "32x24", "-o", tmp_path / "c.exr")
    assert code == 0 and "left out" not in err and "kernel outputs" not in err


def test_verbose_counts_degenerate_and_culled_triangles(tmp_path):
    scene = tmp_path / "two.obj"
    scene.write_text(OBJ)
    # looks at the right triangle only: the left one is outside the view
    code, out, err = kdray_cli("-v", "render", scene, "--cull", "--eye", "2,0,3", "--target", "2,0,0",
                               "--fov", "30", "--size", "24x24", "--aov", "id",
                               "-o", tmp_path / "two.exr")
    assert code == 0, err
    assert "kdray: triangles left out as degenerate: 1 of 3\n" in err
    assert "kdray: triangles left out by --cull (outside the view): 1 of 3; 1 in the tree\n" in err
    assert "kdray: kernel outputs: ID; not computed: T, UV, NORMAL\n" in err
    assert "of 576 pixels hit" in out and " 0 of 576" not in out


def test_verbose_with_a_tree_file_and_cull_refused_with_it(tmp_path):
    scene = tmp_path / "two.obj"
    scene.write_text(OBJ)
    tree = tmp_path / "two.kdt"
    code, _, err = kdray_cli("build", scene, "--dump", tree)
    assert code == 0, err
    code, _, err = kdray_cli("-v", "render", scene, "--tree", tree, "--size", "8x8",
                             "-o", tmp_path / "two.exr")
    assert code == 0, err
    assert "kdray: the tree holds 2 of 3 input triangles" in err
    code, _, err = kdray_cli("render", scene, "--tree", tree, "--cull", "-o", tmp_path / "two.exr")
    assert code == 2 and "--cull" in err


def test_points_say_parity_on_open_meshes_once_as_a_log_line(tmp_path):
    """--sign parity on a mesh with open edges: one `kdray: ` line on stderr (none with
    -q), not Python's warning naming click's source line; as `kdray sdf` does."""
    mesh = tmp_path / "tri.obj"
    mesh.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    (tmp_path / "p.txt").write_text("0.2 0.2 1\n")
    for query in ("signed", "occupancy"):
        for quiet in ((), ("-q",)):
            code, _, err = kdray_cli(*quiet, "points", mesh, "--points", tmp_path / "p.txt",
                                     "-o", tmp_path / "o.npz", "--query", query, "--sign",
                                     "parity")
            assert code == 0 and err.splitlines() == ([] if quiet else [
                f"kdray: {mesh} has 3 open edges: --sign parity is undefined where a point's "
                "ray leaves through a hole (--sign winding is meant for such meshes)"])
