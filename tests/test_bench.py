"""`kdray bench`: the table, the CSV, the plot and one-line errors (small and fast)."""
import csv
import time

import numpy as np
import pytest

from kdray import bench
from test_cli import run
from conftest import SCENES

SMALL = ["--size", "48x32", "--repeat", "1", "--sample", "300"]


def test_bench_table_csv_plot(capsys, tmp_path):
    csv_path, png_path = tmp_path / "b.csv", tmp_path / "b.png"
    code, out, err = run(capsys, "bench", SCENES / "sphere.obj", *SMALL,
                         "--settings", "kdray,kdray:stack=1", "--csv", csv_path, "--plot", png_path)
    assert code == 0, err
    lines = [line for line in out.splitlines() if not line.startswith("#")]
    header = lines[0].split()
    for col in ("scene", "tris", "setting", "build", "trace", "Mrays/s", "disagree", "prim!=",
                "p99", "max"):
        assert col in header, col
    assert len(lines) == 3 and all(line.split()[0] == "sphere" for line in lines[1:])
    with open(csv_path, newline="") as f:
        rows = list(csv.DictReader(f))
    assert [r["setting"] for r in rows] == ["kdray", "kdray:stack=1"]
    assert set(rows[0]) == set(bench.COLUMNS)
    for r in rows:
        assert int(r["disagree"]) == 0
        assert float(r["depth_p99"]) < 1e-5
        assert float(r["normal_max_deg"]) < 1e-2
        assert float(r["trace_s"]) > 0 and float(r["mrays_s"]) > 0
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        assert not png_path.exists() and "matplotlib" in err
    else:
        assert png_path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_bench_offset_far_from_origin():
    rows, _ = bench.run([SCENES / "sphere.obj"], size=(24, 16), repeat=1, sample=200,
                        settings="kdray", offset=1e5)
    assert rows[0]["disagree"] == 0 and rows[0]["depth_p99"] < 1e-5


@pytest.mark.parametrize("settings, words", [
    ("kdray,fast", "unknown setting 'fast'"),
    ("kdray:K_T", "'K_T' is not KEY=VALUE"),
    ("kdray:stack=x", "stack must be an integer"),
    ("open3d:K_T=1", "takes no options"),
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


def test_plot_without_matplotlib_is_a_note(monkeypatch, tmp_path):
    import sys
    monkeypatch.setitem(sys.modules, "matplotlib", None)      # import matplotlib -> ImportError
    rows = [dict(zip(bench.COLUMNS, ("s", 1, "kdray", 0.1, 0.1, 1.0, 0, 0, 1e-7, 1e-7, 0.0, 0.0)))]
    note = bench.plot(rows, tmp_path / "p.png")
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
    wall, cpu, results = bench.round_robin({"a": make("a"), "b": make("b")}, 3, pause=0.02)
    assert calls == ["a", "b", "a", "b", "b", "a", "a", "b"]
    assert min(np.diff(starts)) >= 0.02
    assert results == {"a": 7, "b": 8}
    assert wall["a"].shape == cpu["b"].shape == (3,)
    assert bench.median_ratio([2.0, 4.0, 3.0], [1.0, 1.0, 2.0]) == 2.0
