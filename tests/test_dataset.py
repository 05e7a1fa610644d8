"""Datasets (kdray.dataset, kdray.cache, `kdray render --cameras`, `kdray batch`): the
files of a run of many views equal single renders; resume; faults; the tree cache;
Dask workers, one of them killed."""
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from kdray import dataset
from kdray.cache import TreeCache, tree_key
from kdray.dataset import Job, Progress, read_jobs, run
from kdray.errors import DatasetError, OutputError
from kdray.images import read_exr, read_object_names
from kdray.load import load
from kdray.tree import BuildParams
from helpers import real_mesh, run as run_cli

SIZE = (40, 30)


def orbit(path, n, radius=3.0, names=True):
    """A JSON list of n look-at cameras round the teapot (kdray camera files)."""
    cams = []
    for i in range(n):
        a = 2 * math.pi * i / n
        cam = {"width": SIZE[0], "height": SIZE[1], "eye": [radius * math.cos(a), 1.5, radius * math.sin(a)],
               "target": [0, 0.5, 0], "fov": 40}
        if names:
            cam["name"] = f"view{i:02d}"
        cams.append(cam)
    path.write_text(json.dumps(cams))
    return path


@pytest.fixture
def cache_dir(tmp_path, monkeypatch):
    folder = tmp_path / "cache"
    monkeypatch.setenv("KDRAY_CACHE_DIR", str(folder))
    return folder


@pytest.fixture
def teapot_job(tmp_path):
    return Job(scene=real_mesh("teapot.obj"), cameras=orbit(tmp_path / "cams.json", 5),
               output=tmp_path / "out", aovs="depth,normal,id")


def files(folder):
    """{name: bytes} of the visible files of a folder."""
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if not p.name.startswith(".")}


def test_cameras_equal_single_renders(capsys, tmp_path, cache_dir):
    cams = orbit(tmp_path / "cams.json", 4)
    code, out, err = run_cli(capsys, "render", real_mesh("teapot.obj"), "--cameras", cams,
                             "-o", tmp_path / "views", "--aov", "depth,normal,bary,id")
    assert code == 0, err
    assert "4 of 4 views rendered" in out
    for i, cam in enumerate(json.loads(cams.read_text())):
        single = tmp_path / f"single{i}.json"
        single.write_text(json.dumps({k: v for k, v in cam.items() if k != "name"}))
        code, _, err = run_cli(capsys, "render", real_mesh("teapot.obj"), "--camera", single,
                               "-o", tmp_path / "single.exr", "--aov", "depth,normal,bary,id")
        assert code == 0, err
        many, one = read_exr(tmp_path / "views" / f"{cam['name']}.exr"), read_exr(tmp_path / "single.exr")
        assert many.keys() == one.keys()
        for k in one:
            assert np.array_equal(many[k], one[k], equal_nan=True), (i, k)
        assert (tmp_path / "views" / f"{cam['name']}.exr").read_bytes() == (tmp_path / "single.exr").read_bytes()
        assert np.count_nonzero(one["id"] != 0xFFFFFFFF) > 100


def test_render_many_and_with_tree_equal_render(tracers):
    import kdray
    a = kdray.load(real_mesh("teapot.obj"))
    b = kdray.load(real_mesh("fandisk.obj"))
    tree_a, tree_b = kdray.build(a.vertices, a.faces), kdray.build(b.vertices, b.faces)
    tracer = tracers(tree_a)
    cams = [kdray.Camera.frame(*t.world_box(), *SIZE) for t in (tree_a, tree_b)]
    many = list(tracer.render_many(cams[:1] * 2, "depth,id"))
    assert len(many) == 2 and all(np.array_equal(m["id"], many[0]["id"]) for m in many)
    other = tracer.with_tree(tree_b)
    assert other.context is tracer.context and other._programs is tracer._programs
    fresh = kdray.Tracer(tree_b).render(cams[1], "depth,normal,id")
    shared = other.render(cams[1], "depth,normal,id")
    for k in fresh:
        assert np.array_equal(fresh[k], shared[k])
    assert np.array_equal(tracer.render(cams[0], "id")["id"], many[0]["id"])   # the first is intact


def test_resume_renders_only_what_is_missing(teapot_job, cache_dir):
    cache = TreeCache(cache_dir)
    reference = run([teapot_job], cache=cache)[0]
    assert reference.ok and reference.rendered == 5 and reference.tree_cached is False
    full = files(teapot_job.output)
    assert len(full) == 5
    # an interrupted run: Ctrl-C after two views, and a write that a kill -9 cut short
    for p in teapot_job.output.iterdir():
        p.unlink()

    class Interrupt(Progress):
        def view(self, job, name, seconds):
            super().view(job, name, seconds)
            if self.done == 2:
                raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run([teapot_job], cache=cache, progress=Interrupt(0, live=False))
    # the views reported, and at most the one whose write was under way
    kept = sorted(files(teapot_job.output))
    assert kept in (["view00.exr", "view01.exr"], ["view00.exr", "view01.exr", "view02.exr"])
    (teapot_job.output / ".view03.exr.1234abcd.tmp").write_bytes(b"half")
    again = run([teapot_job], cache=cache)[0]
    assert again.ok and (again.rendered, again.skipped) == (5 - len(kept), len(kept))
    assert again.tree_cached is True               # the first run filled the cache
    assert files(teapot_job.output) == full
    assert sorted(p.name for p in teapot_job.output.iterdir()) == sorted(full)   # no .tmp left
    # everything there: nothing to do, no scene loaded
    done = run([teapot_job])[0]
    assert (done.rendered, done.skipped) == (0, 5) and done.seconds["load"] == 0
    over = run([teapot_job], overwrite=True)[0]
    assert over.rendered == 5 and files(teapot_job.output) == full


def write_jobs(path, jobs):
    path.write_text("".join(json.dumps(j) + "\n" for j in jobs))
    return path


def test_batch_goes_on_past_a_bad_scene(capsys, tmp_path, cache_dir):
    orbit(tmp_path / "cams.json", 3)
    (tmp_path / "broken.obj").write_text("v 0 0 0\nv 1 0 0\nf 1 2 7\n")
    teapot = real_mesh("teapot.obj").read_text().splitlines()
    faces = [i for i, line in enumerate(teapot) if line.startswith("f ")]
    half = faces[len(faces) // 2]          # the teapot's faces in two objects
    (tmp_path / "two.obj").write_text("\n".join(["o lid"] + teapot[:half] + ["o body"] + teapot[half:]))
    (tmp_path / "badcams.json").write_text("[{\"width\": 0, \"height\": 3}]")
    jobs = write_jobs(tmp_path / "jobs.jsonl", [
        {"scene": str(real_mesh("teapot.obj")), "cameras": "cams.json", "output": "a",
         "aovs": "depth,id,object"},
        {"scene": "broken.obj", "cameras": "cams.json", "output": "b"},
        {"scene": str(real_mesh("teapot.obj")), "cameras": "badcams.json", "output": "c"},
        {"scene": str(real_mesh("fandisk.obj")), "cameras": "cams.json", "output": "d",
         "aovs": ["depth"], "preview": True, "build": {"K_T": 15}},
        {"scene": "two.obj", "cameras": "cams.json", "output": "e", "aovs": "object"},
    ])
    code, out, err = run_cli(capsys, "batch", jobs)
    assert code == 1
    assert "broken.obj" in err and "badcams.json" in err
    assert err.strip().splitlines()[-1].startswith("kdray: error: 2 of 5 job(s) failed")
    assert sorted(files(tmp_path / "a")) == ["view00.exr", "view01.exr", "view02.exr"]
    assert len(files(tmp_path / "d")) == 6                       # EXR + PNG per view
    assert list(read_exr(tmp_path / "d" / "view00.exr")) == ["depth"]
    a = read_exr(tmp_path / "a" / "view00.exr")
    assert list(a) == ["depth", "id", "object"]
    assert np.array_equal(a["object"], np.where(a["id"] == 0xFFFFFFFF, 0xFFFFFFFF, 0))
    assert read_object_names(tmp_path / "a" / "view00.exr") is None       # one object: no table
    # a scene of two objects: their names in every view, through the tree cache
    seen = set()
    for i in range(3):
        seen |= set(np.unique(read_exr(tmp_path / "e" / f"view0{i}.exr")["object"]).tolist())
        assert read_object_names(tmp_path / "e" / f"view0{i}.exr") == ("lid", "body")
    assert seen == {0, 1, 0xFFFFFFFF}
    # the failed jobs leave no folder behind (the run made them, and they stayed empty)
    assert not (tmp_path / "b").exists() and not (tmp_path / "c").exists()
    # the fourth job's build parameters reach its tree: another cache entry than the first's
    teapot = load(real_mesh("teapot.obj"))
    assert TreeCache(cache_dir).load(tree_key(teapot, BuildParams())) is not None


@pytest.mark.parametrize("line, message", [
    ('{"scene": "m.obj", "cameras": "c.json", "output": "o", "colour": 1}', "unknown key 'colour'"),
    ('{"scene": "m.obj", "output": "o"}', "missing 'cameras'"),
    ('{"scene": "m.obj", "cameras": "c.json", "output": "o", "build": {"K_X": 1}}',
     "unknown build parameter 'K_X'"),
    ('{"scene": "m.obj", "cameras": "c.json", "output": "o", "build": {"K_T": -1}}', "K_T must be"),
    ('{"scene": "m.obj", "cameras": "c.json", "output": "o", "aovs": "depth,colour"}', "unknown AOV"),
    ('{"scene": "m.obj", "cameras": "c.json", "output": "o", "preview": "yes"}', "'preview' must be"),
    ('{"scene": "gone.obj", "cameras": "c.json", "output": "o"}', "gone.obj does not exist"),
    ('{"scene": "m.obj", "cameras": "c.json", "output": "o", "build": {"K_T": NaN}}', "K_T must be a positive number"),
    ('["m.obj"]', "expected a JSON object"),
    ("scene = m.obj", "not valid JSON"),
])
def test_bad_jobs_files(capsys, tmp_path, line, message):
    (tmp_path / "m.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    orbit(tmp_path / "c.json", 1)
    jobs = tmp_path / "jobs.jsonl"
    jobs.write_text(line + "\n")
    with pytest.raises(DatasetError, match=message):
        read_jobs(jobs)
    code, out, err = run_cli(capsys, "batch", jobs)
    assert code == 1 and err.count("\n") == 1 and "line 1" in err and "Traceback" not in err
    assert not (tmp_path / "o").exists()


def test_duplicate_outputs_and_output_that_is_a_file(capsys, tmp_path):
    (tmp_path / "m.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    orbit(tmp_path / "c.json", 1)
    job = {"scene": "m.obj", "cameras": "c.json", "output": "o"}
    jobs = write_jobs(tmp_path / "jobs.jsonl", [job, dict(job, output="./o/")])
    with pytest.raises(DatasetError, match="lines 1 and 2 both write to"):
        read_jobs(jobs)
    (tmp_path / "file").write_text("not a folder")
    jobs = write_jobs(tmp_path / "jobs.jsonl", [job, dict(job, output="file"),
                                                dict(job, output="file/sub")])
    code, out, err = run_cli(capsys, "batch", jobs)
    assert code == 1 and err.count("\n") == 1 and "is a file, not a folder" in err
    assert "jobs.jsonl, line 2: " in err               # where, as the file's other checks
    assert not (tmp_path / "o").exists()               # nothing made before the check
    code, out, err = run_cli(capsys, "render", tmp_path / "m.obj", "--cameras", tmp_path / "c.json",
                             "-o", tmp_path / "file")
    assert code == 1 and "is a file, not a folder" in err


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into any folder")
def test_unwritable_output(capsys, tmp_path):
    (tmp_path / "m.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    orbit(tmp_path / "c.json", 1)
    locked = tmp_path / "locked"
    locked.mkdir(mode=0o500)
    code, _, err = run_cli(capsys, "render", tmp_path / "m.obj", "--cameras", tmp_path / "c.json",
                           "-o", locked / "views")
    assert code == 1 and "not writable" in err


def test_bad_camera_file_is_one_line_and_writes_nothing(capsys, tmp_path):
    cams = tmp_path / "cams.json"
    cams.write_text("{not json")
    code, _, err = run_cli(capsys, "render", real_mesh("teapot.obj"), "--cameras", cams,
                           "-o", tmp_path / "views")
    assert code == 1 and err.count("\n") == 1 and "cams.json" in err
    assert not (tmp_path / "views").exists()
    code, _, err = run_cli(capsys, "render", real_mesh("teapot.obj"), "--cameras", cams,
                           "--eye", "0,0,3", "--target", "0,0,0")
    assert code == 2 and "--cameras cannot be combined with --eye, --target" in err
    # the views' own sizes and fields of view: one-view options would be ignored
    for more, name in ((("--size", "8x6"), "--size"), (("--fov", "30"), "--fov"),
                       (("--up", "0,0,1"), "--up"), (("--preview", "p.png"), "--preview FILE")):
        code, _, err = run_cli(capsys, "render", real_mesh("teapot.obj"), "--cameras", cams,
                               *more)
        assert code == 2 and f"--cameras cannot be combined with {name}" in err, more
    # a scene that is not there: one line, and no folder made for it
    good = tmp_path / "good.json"
    good.write_text(json.dumps([{"name": "a", "width": 4, "height": 4,
                                 "K": [[2, 0, 2], [0, 2, 2], [0, 0, 1]],
                                 "cam_to_world": np.eye(4).tolist()}]))
    code, _, err = run_cli(capsys, "render", tmp_path / "nope.obj", "--cameras", good,
                           "-o", tmp_path / "views")
    assert code == 1 and err.count("\n") == 1 and "nope.obj: no such file" in err
    assert not (tmp_path / "views").exists()


def test_tree_cache(tmp_path, caplog, monkeypatch):
    cache = TreeCache(tmp_path / "trees")
    mesh = load(real_mesh("teapot.obj"))
    built = []

    def build(m, params):
        built.append(params)
        return dataset.build_tree(m, params)

    tree, cached = cache.tree(mesh, BuildParams(), build)
    again, cached_again = cache.tree(mesh, BuildParams(), build)
    assert (cached, cached_again, len(built)) == (False, True, 1) and again == tree
    _, cached = cache.tree(mesh, BuildParams(K_T=15), build)
    assert not cached and len(built) == 2                  # parameters are in the key
    moved = type(mesh).from_arrays(mesh.vertices + 1e-9, mesh.faces, name="other.obj")
    assert tree_key(moved, BuildParams()) != tree_key(mesh, BuildParams())
    copy = tmp_path / "renamed.obj"
    copy.write_bytes(real_mesh("teapot.obj").read_bytes())
    assert tree_key(load(copy), BuildParams()) == tree_key(mesh, BuildParams())
    # a table of several objects is part of the tree, so of the key
    two = np.arange(len(mesh.faces)) % 2
    named = type(mesh).from_arrays(mesh.vertices, mesh.faces, objects=two, object_names=("a", "b"))
    other = type(mesh).from_arrays(mesh.vertices, mesh.faces, objects=two, object_names=("a", "c"))
    assert len({tree_key(m, BuildParams()) for m in (mesh, named, other)}) == 3
    tree2, _ = cache.tree(named, BuildParams(), build)
    assert cache.tree(named, BuildParams(), build)[0].object_names == ("a", "b") == tree2.object_names
    # a corrupt file is rebuilt and replaced
    path = cache.path(tree_key(mesh, BuildParams()))
    path.write_bytes(path.read_bytes()[:-5])
    tree3, cached = cache.tree(mesh, BuildParams(), build)
    assert not cached and tree3 == tree and "building it again" in caplog.text
    assert cache.load(tree_key(mesh, BuildParams())) == tree
    # a write a kill cut short leaves a temporary file: counted in the size, cleared
    from kdray.files import temporary_path
    temporary_path(path).write_bytes(b"\0" * 5000)
    trees, size = cache.usage()
    assert trees == 3 and size == 5000 + sum(f.stat().st_size for f in cache.folder.glob("??/*.kdt"))
    assert cache.clear() == (3, size) and cache.usage() == (0, 0)
    assert not list(cache.folder.iterdir())             # the emptied folders too
    # a tree that cannot be removed (an immutable folder): said, not "removed 0"
    cache.tree(mesh, BuildParams(), build)
    cache.tree(named, BuildParams(), build)
    stuck = cache.path(tree_key(mesh, BuildParams()))
    real_unlink = Path.unlink

    def refuse(self, *args, **kwargs):
        if self == stuck:
            raise PermissionError(1, "Operation not permitted")
        return real_unlink(self, *args, **kwargs)
    monkeypatch.setattr(Path, "unlink", refuse)
    with pytest.raises(OutputError, match=r"1 file\(s\) stay, .*Operation not permitted.*"
                                          r"removed 1 tree"):
        cache.clear()
    assert cache.usage()[0] == 1


def test_progress_line():
    class Terminal:
        text = ""

        def write(self, s):
            self.text += s

        def flush(self):
            pass

        def isatty(self):
            return True

    out = Terminal()
    p = Progress(10, stream=out)
    p.start -= 2.0                       # two seconds ago
    p.advance(4)
    assert "kdray: 4/10 views, 2.0 views/s, 0:03 left" in out.text
    p.close()
    assert out.text.endswith("\n")
    quiet = Terminal()
    quiet.isatty = lambda: False
    p = Progress(10, stream=quiet)
    p.advance(10)
    p.close()
    assert quiet.text == ""


def kdray_cli(*argv):
    """(exit code, stdout, stderr) of `kdray argv...` in a fresh process (logging set up
    as for a user)."""
    proc = subprocess.run([sys.executable, "-m", "kdray.cli", *map(str, argv)],
                          capture_output=True, text=True)
    return proc.returncode, proc.stdout, proc.stderr


def test_verbose_logs_a_line_per_view(tmp_path, cache_dir):
    code, out, err = kdray_cli("-v", "render", real_mesh("teapot.obj"), "--cameras",
                               orbit(tmp_path / "c.json", 3), "-o", tmp_path / "v")
    assert code == 0, err
    assert sum("kdray: teapot.obj: view0" in line for line in err.splitlines()) == 3
    code, out, err = kdray_cli("-q", "render", real_mesh("teapot.obj"), "--cameras",
                               tmp_path / "c.json", "-o", tmp_path / "v", "--overwrite")
    assert code == 0 and err == "" and "3 of 3 views rendered" in out


def test_setup_and_cache_commands(capsys, tmp_path, cache_dir, monkeypatch):
    # a --device that is not there: refused before the builder is looked at
    from kdray import builder
    compiled = builder.compiled
    monkeypatch.setattr(builder, "compiled", lambda: pytest.fail("the builder came first"))
    code, out, err = run_cli(capsys, "setup", "--device", "no-such-platform")
    assert code == 1 and out == "" and "no-such-platform" in err
    monkeypatch.setattr(builder, "compiled", compiled)
    code, out, err = run_cli(capsys, "setup")
    assert code == 0, err
    assert "tree builder: compiled" in out and "kernels: compiled for" in out
    assert "camera models: compiled" in out
    run_cli(capsys, "render", real_mesh("teapot.obj"), "--cameras", orbit(tmp_path / "c.json", 1),
            "-o", tmp_path / "v")
    code, out, _ = run_cli(capsys, "cache")
    assert code == 0 and f"{cache_dir}: 1 trees" in out
    code, out, _ = run_cli(capsys, "cache", "--clear")
    assert code == 0 and "removed 1 trees" in out
    # a cache "folder" that is a file: one line, not "0 trees"
    cache_dir.rename(tmp_path / "gone")
    cache_dir.write_text("not a folder")
    for more in ((), ("--clear",)):
        code, out, err = run_cli(capsys, "cache", *more)
        assert code == 1 and out == "" and err.count("\n") == 1 and "is a file" in err
    assert cache_dir.read_text() == "not a folder"


# -- Dask --------------------------------------------------------------------------------

def _dask_jobs(tmp_path, out):
    orbit(tmp_path / "cams.json", 7)
    return [Job(scene=real_mesh(name), cameras=tmp_path / "cams.json", output=tmp_path / out / name,
                aovs="depth,normal,id", preview=(name == "teapot.obj"))
            for name in ("teapot.obj", "fandisk.obj")]


def test_dask_workers_write_the_same_bytes(tmp_path):
    pytest.importorskip("distributed")
    cache = TreeCache(tmp_path / "cache")
    here = run(_dask_jobs(tmp_path, "here"), cache=cache)
    dask = run(_dask_jobs(tmp_path, "dask"), workers=2, cache=cache, chunk=2)
    assert all(r.ok and r.rendered == 7 for r in here + dask)
    assert all(r.tree_cached for r in dask)
    for name in ("teapot.obj", "fandisk.obj"):
        a, b = files(tmp_path / "here" / name), files(tmp_path / "dask" / name)
        assert len(a) == (14 if name == "teapot.obj" else 7) and a == b


def test_dask_worker_killed_loses_nothing(tmp_path, monkeypatch):
    pytest.importorskip("distributed")
    cache = TreeCache(tmp_path / "cache")
    marker = tmp_path / "killed"
    monkeypatch.setenv(dataset.TEST_KILL_ENV, str(marker))
    assert all(r.ok for r in run(_dask_jobs(tmp_path, "here"), cache=cache))
    assert not marker.exists()                           # the hook acts in Dask workers only
    dask = run(_dask_jobs(tmp_path, "dask"), workers=2, cache=cache, chunk=2)
    assert marker.exists()                               # a worker did die
    assert all(r.ok and r.rendered == 7 for r in dask), [r.errors for r in dask]
    for name in ("teapot.obj", "fandisk.obj"):
        folder = tmp_path / "dask" / name
        assert files(folder) == files(tmp_path / "here" / name)
        assert not [p.name for p in folder.iterdir() if p.name.startswith(".")]   # no partial file


def test_a_task_run_again_counts_the_views_it_finds(tmp_path, monkeypatch):
    """A Dask task run again (its worker died after writing some of its views) finds
    those views written and reports them (skipped), so that the job's report counts
    every view (they were dropped: "145 of 150 views rendered, 0 already there" with
    all 150 written); the run counts them rendered (test_task_results_in_the_report)."""
    from kdray.camera_files import read_cameras
    renderer = dataset.Renderer()                       # this process as the worker
    monkeypatch.setattr(dataset, "_worker_renderer", lambda: renderer)
    (job,) = _dask_jobs(tmp_path, "out")[:1]
    job.output.mkdir(parents=True)                      # as run() makes it first
    views = read_cameras(job.cameras)
    seconds, rendered, skipped, errors, done, cached = dataset._task_views(job, views[:3], False)
    assert (rendered, skipped, errors, len(done), cached) == (3, 0, [], 3, False)
    seconds, rendered, skipped, errors, done, cached = dataset._task_views(job, views[:5], False)
    assert (rendered, skipped, errors, len(done)) == (2, 3, [], 2)
    assert cached is None                               # the scene kept from the first task


def test_task_results_in_the_report(tmp_path):
    """How a Dask run takes its tasks' results into a job's report: views a task found
    written (its own attempt on a worker that died wrote them: every view a task gets
    was missing when the run began) count as rendered in this run, not as already
    there (a fresh run had said "389 of 400 views rendered, 11 already there"); a
    failure that is not a KdrayError (KilledWorker, when a job's workers keep dying)
    is one line naming the scene, however many of its tasks fail so (each had been a
    line of its own, "KilledWorker: ..." naming no scene)."""
    (job,) = _dask_jobs(tmp_path, "out")[:1]
    report = dataset.JobReport(job, views=7)
    progress = Progress(7, live=False)
    seconds = dict.fromkeys(dataset.STEPS, 0.1)
    dataset._task_done(report, "views", 4, (seconds, 1, 3, [], [("a", 0.1)], False), progress)
    assert (report.rendered, report.skipped, progress.done) == (4, 0, 4)

    class KilledWorker(Exception):
        pass
    for task in range(3):
        dataset._task_failed(report, "views", 1, KilledWorker(f"task {task}: workers died"),
                             progress)
    dataset._task_failed(report, "views", 0, OSError("a bug"), progress)
    assert report.errors == [f"{job.scene}: KilledWorker: task 0: workers died",
                             f"{job.scene}: OSError: a bug"]
    assert progress.done == 7 and not report.ok
    # a KdrayError as the worker raised it (it names its scene), once
    for _ in range(2):
        dataset._task_failed(report, "views", 0, DatasetError(f"{job.scene}: bad"), progress)
    assert report.errors[-1] == f"{job.scene}: bad" and len(report.errors) == 3


def test_run_refuses_bad_arguments_before_anything(tmp_path):
    """run()'s own arguments are checked as the command line's are, before any folder
    is made: a chunk that is not an integer >= 1 (-1 had rendered nothing and said all
    views were there; "2" raised a TypeError), an overwrite that is not True or False
    ("no" had been taken as true), two jobs that write one folder (the second had
    reported the first's views as its own)."""
    from kdray.errors import ParameterError
    jobs = _dask_jobs(tmp_path, "out")
    for chunk in (-1, 0, "2", 2.5, True):
        with pytest.raises(ParameterError, match="chunk must be None or an integer >= 1"):
            run(jobs, workers=1, chunk=chunk)
    for overwrite in ("no", 0, None):
        with pytest.raises(ParameterError, match="overwrite must be True or False"):
            run(jobs, overwrite=overwrite)
    same = [jobs[0], Job(scene=jobs[1].scene, cameras=jobs[1].cameras, output=jobs[0].output)]
    with pytest.raises(DatasetError, match="job 1 and job 2 both write to"):
        run(same)
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("text", ["{}", "not json", '{"address": 5}', "[1, 2]"])
def test_a_scheduler_file_that_is_not_one(tmp_path, text):
    """A --scheduler file with no address in it is one line, not Dask's traceback
    (AssertionError or TypeError from its reader)."""
    orbit(tmp_path / "cams.json", 1)
    jobs = write_jobs(tmp_path / "jobs.jsonl", [
        {"scene": str(real_mesh("teapot.obj")), "cameras": "cams.json", "output": "a"}])
    (tmp_path / "sched.json").write_text(text)
    code, _, err = kdray_cli("batch", jobs, "--scheduler", str(tmp_path / "sched.json"))
    assert code == 1 and len(err.strip().splitlines()) == 1, err
    assert err.startswith("kdray: error: ") and "sched.json" in err


def test_dask_worker_errors_are_one_line(tmp_path):
    """A scene that fails to load in a Dask worker is reported as in-process: one line a
    failure and the summary, no worker log or traceback (the worker's stderr is the
    command's), also while another cluster holds Dask's port 8787 (its scheduler then
    warned in four lines)."""
    import socket
    pytest.importorskip("distributed")
    orbit(tmp_path / "cams.json", 1)
    (tmp_path / "broken.obj").write_text("v 0 0 0\nv 1 0 0\nf 1 2 9\n")
    jobs = write_jobs(tmp_path / "jobs.jsonl", [
        {"scene": str(real_mesh("teapot.obj")), "cameras": "cams.json", "output": "a"},
        {"scene": "broken.obj", "cameras": "cams.json", "output": "b"}])
    with socket.socket() as held:
        try:
            held.bind(("", 8787))
            held.listen()
        except OSError:                 # held already: the case itself
            pass
        code, _, err = kdray_cli("batch", jobs, "--workers", "1", "--no-cache")
    assert code == 1
    lines = err.strip().splitlines()
    assert len(lines) == 2 and all(line.startswith("kdray: ") for line in lines), err
    assert "broken.obj" in lines[0] and lines[1].startswith("kdray: error: 1 of 2 job(s)")


def test_dask_missing_is_a_clear_error(tmp_path, monkeypatch):
    import builtins
    real_import = builtins.__import__

    def no_dask(name, *args, **kwargs):
        if name == "distributed":
            raise ImportError(name)
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_dask)
    with pytest.raises(DatasetError, match=r"pip install 'kdray\[dask\]'"):
        run(_dask_jobs(tmp_path, "x"), workers=2)


def test_output_errors_before_anything(tmp_path):
    (tmp_path / "f").write_text("")
    jobs = [Job(scene=real_mesh("teapot.obj"), cameras=orbit(tmp_path / "c.json", 1), output=tmp_path / "ok"),
            Job(scene=real_mesh("teapot.obj"), cameras=tmp_path / "c.json", output=tmp_path / "f" / "x")]
    with pytest.raises(OutputError, match="is a file"):
        run(jobs)
    assert not (tmp_path / "ok").exists()


def test_output_that_cannot_be_made_leaves_none_made(tmp_path, monkeypatch):
    """A folder whose making fails though the checks let it through (a file system's
    own refusal: /proc, a full disk) leaves none of the jobs' folders made: those made
    before it are removed (they were left)."""
    cams = orbit(tmp_path / "c.json", 1)
    jobs = [Job(scene=real_mesh("teapot.obj"), cameras=cams, output=tmp_path / "a" / "b"),
            Job(scene=real_mesh("teapot.obj"), cameras=cams, output=tmp_path / "c")]
    (tmp_path / "kept").mkdir()
    jobs.append(Job(scene=real_mesh("teapot.obj"), cameras=cams, output=tmp_path / "kept"))
    real_mkdir = Path.mkdir

    def refuse(self, *args, **kwargs):
        if self == tmp_path / "c":
            raise OSError(28, "No space left on device")
        return real_mkdir(self, *args, **kwargs)
    monkeypatch.setattr(Path, "mkdir", refuse)
    with pytest.raises(OutputError, match="c: cannot be made .No space left on device"):
        run(jobs)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.json", "kept"]
    # jobs read from a file: the message names the job's line, as read_jobs' do
    listed = write_jobs(tmp_path / "kept" / "jobs.jsonl", [
        {"scene": str(real_mesh("teapot.obj")), "cameras": str(cams), "output": str(j.output)}
        for j in jobs])
    read = read_jobs(listed)
    assert read == jobs and read[1].source == f"{listed}, line 2"
    with pytest.raises(OutputError, match=r"jobs.jsonl, line 2: .*c: cannot be made"):
        run(read)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.json", "kept"]


def test_views_whose_files_are_folders_are_not_done(tmp_path):
    """A view counts as done when its files are files: a folder of its file's name
    (nothing a run writes) is not skipped, the view fails and the others go on."""
    cams = orbit(tmp_path / "c.json", 2)
    job = Job(scene=real_mesh("teapot.obj"), cameras=cams, output=tmp_path / "out")
    (tmp_path / "out" / "view00.exr").mkdir(parents=True)
    (report,) = run([job])
    assert report.skipped == 0 and report.rendered == 1 and len(report.errors) == 1
    # named by its scene, as a job's own faults are (several jobs' views share names)
    assert report.errors[0].startswith(f"{job.scene}: view view00: ")


def test_dask_existing_scheduler(tmp_path):
    distributed = pytest.importorskip("distributed")
    cache = TreeCache(tmp_path / "cache")
    here = run(_dask_jobs(tmp_path, "here")[:1], cache=cache)
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster:
        there = run(_dask_jobs(tmp_path, "there")[:1], scheduler=cluster.scheduler_address,
                    cache=cache)
        # without a cache the workers build the tree: reported so, as in-process
        built = run(_dask_jobs(tmp_path, "built")[:1], scheduler=cluster.scheduler_address,
                    cache=None, overwrite=True)
    assert here[0].ok and there[0].ok and there[0].rendered == 7
    assert files(tmp_path / "there" / "teapot.obj") == files(tmp_path / "here" / "teapot.obj")
    assert built[0].ok and built[0].tree_cached is False and "tree" in built[0].summary()
    assert "(built)" in built[0].summary()


def test_a_scene_kept_from_an_earlier_job(tmp_path, monkeypatch):
    """A job whose scene an earlier job of the run loaded (the same mesh, parameters and
    precision) takes its Tracer as it is: no tree step of its own (tree_cached None, not
    "(built)"), and what its other AOVs need compiled under compile, not trace."""
    from kdray.trace import Tracer
    cams = orbit(tmp_path / "cams.json", 2)
    jobs = [Job(scene=real_mesh("teapot.obj"), cameras=cams, output=tmp_path / name, aovs=aovs)
            for name, aovs in (("a", "depth"), ("b", "depth,normal,bary,id"))]
    compiled = []
    real = Tracer.compile

    def compile(self, aovs=None, **kw):
        compiled.append(tuple(aovs))
        return real(self, aovs, **kw)

    monkeypatch.setattr(Tracer, "compile", compile)
    first, second = run(jobs, cache=None)
    assert first.ok and second.ok and second.rendered == 2
    assert first.tree_cached is False and "(built)" in first.summary()
    assert second.tree_cached is None and "(built)" not in second.summary()
    assert compiled[-1] == ("depth", "normal", "bary", "id")
    assert second.seconds["load"] == second.seconds["tree"] == 0 < second.seconds["compile"]


def test_unwritable_output_checked_before_anything(capsys, tmp_path, monkeypatch):
    # as root every folder is writable; the check itself is what is tested here
    (tmp_path / "m.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    orbit(tmp_path / "c.json", 1)
    locked = tmp_path / "locked"
    locked.mkdir()
    real_access = os.access
    monkeypatch.setattr(os, "access", lambda p, mode: Path(p) != locked and real_access(p, mode))
    code, _, err = run_cli(capsys, "render", tmp_path / "m.obj", "--cameras", tmp_path / "c.json",
                           "-o", locked / "views")
    assert code == 1 and err.count("\n") == 1 and f"{locked} is not writable" in err
    assert not (locked / "views").exists()


def test_builder_compiled_state(tmp_path, caplog, capsys, monkeypatch):
    from kdray import builder
    assert builder.compiled()                      # make install compiled it
    code = ("import kdray.builder as b; print(b.compiled())")
    fresh = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                           env=dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "numba")))
    assert fresh.stdout.strip() == "False", fresh.stderr   # a cache folder of nothing
    # a run that finds the builder not compiled says so before compiling it
    monkeypatch.setattr(builder, "compiled", lambda: False)
    compiled = []
    monkeypatch.setattr(builder, "compile_all", lambda: compiled.append(1))
    job = Job(scene=real_mesh("teapot.obj"), cameras=orbit(tmp_path / "c.json", 1),
              output=tmp_path / "o", aovs="depth")
    assert run([job])[0].ok and compiled == [1]
    assert builder.COMPILING in caplog.text
    # as does every other command: and compiles all of it, so that it says so once (a
    # build alone compiled only what it calls, and the next command said it again)
    caplog.clear()
    code, _, err = run_cli(capsys, "build", real_mesh("teapot.obj"))
    assert code == 0 and compiled == [1, 1]
    assert builder.COMPILING in caplog.text + err
