"""`kdray bench` (the table, the CSV, one-line errors) and bench/bench_error.py, its
comparison with Open3D and embreex (the plot), small and fast."""
import csv
import os
import subprocess
import sys
import time

import numpy as np
import pytest

from kdray import bench
from kdray.errors import ParameterError
from helpers import ROOT, SCENES, run

sys.path.insert(0, str(ROOT / "bench"))
import bench_error  # noqa: E402
import timing  # noqa: E402

SMALL = ["--size", "48x32", "--repeat", "1", "--sample", "300"]


def check_table_and_csv(out, csv_path, settings):
    lines = [line for line in out.splitlines() if not line.startswith("#")]
    header = lines[0].split()
    for col in ("scene", "tris", "setting", "build", "trace", "Mrays/s", "disagree", "prim!=",
                "p99", "max"):
        assert col in header, col
    assert len(lines) == 1 + len(settings) and all(line.split()[0] == "sphere" for line in lines[1:])
    with open(csv_path, newline="") as f:
        rows = list(csv.DictReader(f))
    assert [r["setting"] for r in rows] == settings
    assert set(rows[0]) == set(bench.COLUMNS)
    for r in rows:
        assert float(r["trace_s"]) > 0 and float(r["mrays_s"]) > 0
    return rows


def test_bench_table_csv(capsys, tmp_path, monkeypatch):
    csv_path = tmp_path / "b.csv"
    code, out, err = run(capsys, "bench", SCENES / "sphere.obj", *SMALL,
                         "--settings", "kdray,kdray:stack=1", "--csv", csv_path)
    assert code == 0, err
    assert out.startswith("# 48x32 primary rays")
    for r in check_table_and_csv(out, csv_path, ["kdray", "kdray:stack=1"]):
        assert int(r["disagree"]) == 0
        assert float(r["depth_p99"]) < 1e-5
        assert float(r["normal_max_deg"]) < 1e-2
    # written atomically: a write that fails part way keeps the file that was there
    from kdray import bench
    from kdray.errors import OutputError
    before = csv_path.read_bytes()
    real, written = csv.DictWriter.writerow, []

    def fail(self, row):                         # the disk fills after 10 rows
        written.append(row)
        if len(written) > 10:
            raise OSError(28, "No space left on device")
        return real(self, row)
    monkeypatch.setattr(csv.DictWriter, "writerow", fail)
    with pytest.raises(OutputError, match="No space left"):
        bench.write_csv([{k: 1.0 for k in bench.COLUMNS}] * 50, csv_path)
    assert csv_path.read_bytes() == before and len(list(tmp_path.iterdir())) == 1
    monkeypatch.undo()
    # numpy's numbers are written as numbers (repr would write np.float64(0.25))
    row = {k: np.float64(0.25) for k in bench.COLUMNS}
    row.update(scene="s", setting="kdray", tris=np.int64(12), disagree=np.int64(3))
    bench.write_csv([row], csv_path)
    with open(csv_path, newline="") as f:
        (got,) = list(csv.DictReader(f))
    assert got["trace_s"] == "0.25" and got["tris"] == "12" and got["disagree"] == "3"
    # an empty --csv is refused as any empty output path is, before any work
    code, out, err = run(capsys, "bench", SCENES / "sphere.obj", *SMALL, "--csv", "")
    assert code == 2 and "'--csv': an empty path names no file" in err and out == ""


def test_bench_offset_far_from_origin():
    rows = bench.run([SCENES / "sphere.obj"], size=(24, 16), repeat=1, sample=200,
                     settings="kdray", offset=1e5)
    assert rows[0]["disagree"] == 0 and rows[0]["depth_p99"] < 1e-5


def test_a_scenes_figures_do_not_depend_on_the_scenes_before_it():
    """Each scene's rays are sampled from the seed alone: the sphere's row is the same
    after the cornell box as on its own (it was another sample, depth p99 2x apart)."""
    keys = ("disagree", "prim_diff", "depth_p99", "depth_max", "normal_p99_deg",
            "normal_max_deg")
    kw = dict(size=(48, 32), repeat=1, sample=300, settings="kdray,kdray:refine=0")
    alone = bench.run([SCENES / "sphere.obj"], **kw)
    after = bench.run([SCENES / "cornell.obj", SCENES / "sphere.obj"], **kw)[2:]
    assert [[r[k] for k in keys] for r in alone] == [[r[k] for k in keys] for r in after]


def test_bench_without_a_scene_says_what_to_pass(capsys):
    code, out, err = run(capsys, "bench", *SMALL)
    assert code == 2 and out == ""
    assert "name one or more mesh files" in err and "SCENE" in err, err
    with pytest.raises(ParameterError, match="no scene given"):
        bench.run([], settings="kdray")


@pytest.mark.parametrize("settings, words", [
    ("kdray,fast", "unknown setting 'fast'"),
    ("kdray:K_T", "'K_T' is not KEY=VALUE"),
    ("kdray:stack=x", "stack must be an integer"),
    ("open3d", "bench/bench_error.py"),
    ("kdray:refine=2", "refine must be 0 or 1"),
    ("kdray:refine=-1", "refine must be 0 or 1"),
])
def test_bench_bad_setting_is_one_line(capsys, settings, words):
    code, out, err = run(capsys, "bench", SCENES / "sphere.obj", *SMALL, "--settings", settings)
    assert code == 1 and out == ""
    assert err.count("\n") == 1 and err.startswith("kdray: error:") and words in err, err


def test_bench_missing_scene_is_one_line(capsys, tmp_path):
    code, out, err = run(capsys, "bench", tmp_path / "nope.obj", *SMALL, "--settings", "kdray")
    assert code == 1 and err.count("\n") == 1 and "no such file" in err, err


def test_errors_and_angles():
    ref_t = np.array([1.0, 2.0, np.inf, 4.0])
    ref_prim = np.array([0, 1, -1, 2])
    n = np.tile([0.0, 0.0, 1.0], (4, 1))
    e = bench.errors([1.0, 2.0 * (1 + 1e-6), 3.0, np.inf], [0, 1, 5, -1], n, ref_t, ref_prim, n)
    assert e["disagree"] == 2 and e["prim_diff"] == 0
    assert e["depth_max"] == pytest.approx(1e-6)
    assert e["normal_max_deg"] == 0.0
    a = bench.angle_deg([[1.0, 0.0, 0.0]], [[np.cos(1e-9), np.sin(1e-9), 0.0]])
    assert a[0] == pytest.approx(np.degrees(1e-9), rel=1e-6)
    tri = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]]], dtype=float)
    assert bench.unit_normals(tri).tolist() == [[0.0, 0.0, 1.0]]


def test_bench_takes_another_method():
    # kdray.bench.run measures any object with `name` and `hits` on the same rays:
    # here one that misses every ray, with no normals of its own.
    class Blind:
        name = "blind"

        def hits(self, mesh, o, d, repeat):
            return 0.0, 1.0, np.full(len(o), np.inf), np.full(len(o), -1), None
    rows = bench.run([SCENES / "sphere.obj"], size=(24, 16), repeat=1, sample=200,
                     settings=["kdray", Blind()])
    assert [r["setting"] for r in rows] == ["kdray", "blind"]
    assert rows[0]["disagree"] == 0 and rows[1]["disagree"] > 0


# -- bench/bench_error.py ----------------------------------------------------------------

@pytest.mark.parametrize("settings, words", [
    ("kdray,fast", "unknown setting 'fast': expected kdray[:KEY=VALUE...], open3d or embreex"),
    ("kdray:stack=x", "stack must be an integer"),
    ("open3d:K_T=1", "takes no options"),
    ("embreex:x", "takes no options"),
])
def test_bench_error_bad_setting_is_one_line(capsys, settings, words):
    code = bench_error.main([str(SCENES / "sphere.obj"), *SMALL, "--settings", settings])
    out, err = capsys.readouterr()
    assert code == 1 and out == ""
    assert err.count("\n") == 1 and err.startswith("bench_error: error:") and words in err, err


def test_bench_error_default_settings_name_the_missing_peers(monkeypatch):
    monkeypatch.setattr(bench_error, "installed", lambda name: name == "embreex")
    settings, notes = bench_error.parse_settings(None)
    assert [s.name for s in settings] == [*bench.DEFAULT_SETTINGS, "embreex"]
    assert [n.split(" ")[0] for n in notes] == ["open3d", "mitsuba"]
    assert all(" is not installed" in n for n in notes)
    with pytest.raises(ParameterError, match="open3d is not installed"):
        bench_error.parse_settings("kdray,open3d")


def test_bench_error_default_scenes_exist():
    for path in bench_error.DEFAULT_SCENES:
        assert os.path.isfile(path), path


def test_bench_error_script_table_csv_plot(tmp_path):
    # The script as `make bench` runs it, in its own process, with the peers installed.
    pytest.importorskip("matplotlib")
    settings = ["kdray"] + [name for name in ("open3d", "embreex") if bench_error.installed(name)]
    csv_path, png_path = tmp_path / "b.csv", tmp_path / "b.png"
    p = subprocess.run([sys.executable, str(ROOT / "bench" / "bench_error.py"),
                        str(SCENES / "sphere.obj"), *SMALL, "--settings", ",".join(settings),
                        "--csv", str(csv_path), "--plot", str(png_path)],
                       capture_output=True, text=True, cwd=tmp_path, timeout=300)
    assert p.returncode == 0, p.stderr
    rows = check_table_and_csv(p.stdout, csv_path, settings)
    for r in rows:
        assert int(r["disagree"]) == 0 and float(r["depth_p99"]) < 1e-5
    assert png_path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert f"bench_error: wrote {png_path}" in p.stderr


def test_plot_without_matplotlib_is_a_note(monkeypatch, tmp_path):
    monkeypatch.setitem(sys.modules, "matplotlib", None)      # import matplotlib -> ImportError
    rows = [dict(zip(bench.COLUMNS, ("s", 1, "kdray", 0.1, 0.1, 1.0, 0, 0, 1e-7, 1e-7, 0.0, 0.0)))]
    note = bench_error.plot(rows, tmp_path / "p.png")
    assert "matplotlib is not installed" in note and not (tmp_path / "p.png").exists()


def test_round_robin_turns_and_pauses():
    # A warm-up call each, then rounds in alternating order; every call after a pause.
    calls, starts = [], []

    def make(name):
        def fn():
            calls.append(name)
            starts.append(time.perf_counter())
            return len(calls)
        return fn
    wall, cpu, results = timing.round_robin({"a": make("a"), "b": make("b")}, 3, pause=0.02)
    assert calls == ["a", "b", "a", "b", "b", "a", "a", "b"]
    assert min(np.diff(starts)) >= 0.02
    assert results == {"a": 7, "b": 8}
    assert wall["a"].shape == cpu["b"].shape == (3,)
    assert timing.median_ratio([2.0, 4.0, 3.0], [1.0, 1.0, 2.0]) == 2.0
