"""Datasets: many views of many scenes, one EXR file per view.

    jobs = [Job(scene="bunny.obj", cameras="transforms.json", output="out/bunny")]
    jobs = read_jobs("jobs.jsonl")                    # kdray batch JOBS
    reports = run(jobs, workers=2)                    # [JobReport], one per job

A job renders every view of its camera file (kdray.camera_files: nerfstudio, COLMAP,
JSON lists) of one scene to OUTPUT/<view name>.exr (and OUTPUT/<view name>.png with
`preview`). The rules a run keeps:

- **Set-up once.** A process loads a scene, gets its tree from the tree cache
  (kdray.cache) or builds it, and uploads it once for all its views; every scene of
  a process shares one OpenCL context and its compiled programs (`Tracer.with_tree`).
- **Resume.** Every file is written atomically (kdray.files), so a file that exists
  is whole: a run started again renders only the views whose files are missing
  (`overwrite` renders them all). Temporary files that a killed process left are
  removed.
- **Faults.** A job whose scene or camera file fails, or a view that fails, is
  reported in its JobReport with the reason; the run goes on with the others.
- **Scale-out.** `workers=N` runs the views on a local Dask cluster of N worker
  processes, `scheduler=ADDRESS` on an existing one (dask.distributed, the optional
  extra kdray[dask]); with neither, in this process. Each worker keeps its scenes
  and Tracers across tasks (a WorkerPlugin). A scene's tree is built by one task
  into the tree cache, which every worker then reads, so the cache folder must be
  shared between the machines of a cluster (it is, on one machine). A worker that
  dies is replaced by Dask and its tasks are run again; the views it wrote are kept.
  The bytes of every file are those of a run in one process.

Bad input is refused before anything is written (`read_jobs`, `check_outputs`):
unknown keys, missing fields or scene files, two jobs writing one folder, an output
that is a file or cannot be written.
"""
import collections
import concurrent.futures
import contextlib
import dataclasses
import logging
import math
import numbers
import os
import sys
import time
import warnings
from pathlib import Path

from .errors import DatasetError, KdrayError, MeshError, OutputError, ParameterError
from .render import DEFAULT_AOVS, parse_aovs
from .tree import BuildParams
from .validate import check_bool, parse_json, read_text, whole_or_none

log = logging.getLogger(__name__)

MAX_JOBS = 1_000_000
"""A jobs file of more lines than this is refused (a run keeps every job in memory)."""

WRITES_WAITING = 1
"""Views whose files wait to be written while the next view traces, at most: writing
(EXR compression) takes longer than tracing a view, so it runs on a thread beside it;
each waiting view holds its images in memory."""

SCENES_KEPT = 2
"""Scenes a process keeps uploaded (the most recently used): a worker that takes the
views of two scenes in turn does not load and upload them again and again."""

TEST_KILL_ENV = "KDRAY_TEST_KILL_WORKER"
"""Test-only hook: when this names a file that does not exist yet, the next process
that writes a view under Dask creates it, leaves a half-written temporary file as a
killed write would, and exits at once (tests/test_dataset.py kills a worker this way)."""


# -- jobs --------------------------------------------------------------------------------

@dataclasses.dataclass(frozen=True)
class Job:
    """One scene and its views.

    scene : path of a mesh file (kdray.load)
    cameras : path of a camera file (kdray.camera_files.read_cameras)
    output : path of the folder the views are written to (created when missing)
    aovs : AOV names (kdray.render.AOVS), or one comma-separated string
    preview : also write OUTPUT/<name>.png
    precision : "single" or "double" (see Tracer.render)
    params : kdray.BuildParams of the tree
    source : where the job was read from, for messages (read_jobs: "JOBS, line N"),
        or None; not compared
    """

    scene: Path
    cameras: Path
    output: Path
    aovs: tuple = DEFAULT_AOVS
    preview: bool = False
    precision: str = "single"
    params: BuildParams = BuildParams()
    source: str = dataclasses.field(default=None, compare=False)

    def __post_init__(self):
        # the one check of a job's fields, for read_jobs and the Python API alike:
        # types are kept, never converted
        for name in ("scene", "cameras", "output"):
            value = getattr(self, name)
            if not isinstance(value, (str, os.PathLike)) or not os.fspath(value):
                raise DatasetError(f"{name} must be a path, got {value!r}")
            if "\0" in os.fspath(value):
                raise DatasetError(f"{name} {os.fspath(value)!r}: a path cannot hold a NUL byte")
            object.__setattr__(self, name, Path(value))
        object.__setattr__(self, "aovs", parse_aovs(self.aovs))
        if not isinstance(self.preview, bool):
            raise DatasetError(f"preview must be true or false, got {self.preview!r}")
        if self.precision not in ("single", "double"):
            raise DatasetError(f"precision must be 'single' or 'double', got {self.precision!r}")
        if not isinstance(self.params, BuildParams):
            raise DatasetError(f"params must be a kdray.BuildParams, got {self.params!r}")
        # its values checked as kdray.build checks them, now, not in run() as a failed job
        object.__setattr__(self, "params", check_params(dataclasses.asdict(self.params)))

    def files(self, name):
        """The files of view `name`: [OUTPUT/name.exr] (+ OUTPUT/name.png)."""
        exr = self.output / f"{name}.exr"
        return [exr, exr.with_suffix(".png")] if self.preview else [exr]


JOB_KEYS = ("scene", "cameras", "output", "aovs", "preview", "precision", "build")
"""The keys of a jobs file's line; scene, cameras and output are required."""

BUILD_KEYS = tuple(f.name for f in dataclasses.fields(BuildParams))


def read_jobs(path):
    """Jobs from a JSON-lines file: one object a line with the keys of JOB_KEYS, e.g.

        {"scene": "bunny.obj", "cameras": "bunny/transforms.json", "output": "out/bunny",
         "aovs": "depth,normal,id", "preview": true, "build": {"K_T": 170}}

    Blank lines are skipped. Relative paths are relative to the file's folder. Raises
    DatasetError (line number and reason) for a line that is not a JSON object, an
    unknown key, a missing field, a scene or camera file that does not exist, or two
    jobs with one output folder; nothing is read beyond the first error.
    """
    path = Path(path)
    text = read_text(path, f"jobs file {path}", DatasetError)
    lines = [(i + 1, line) for i, line in enumerate(text.splitlines()) if line.strip()]
    if not lines:
        raise DatasetError(f"jobs file {path} holds no jobs")
    if len(lines) > MAX_JOBS:
        raise DatasetError(f"jobs file {path} holds {len(lines):,} jobs; at most {MAX_JOBS:,}")
    jobs = []
    for number, line in lines:
        where = f"{path}, line {number}"
        data = parse_json(line, where, DatasetError)
        try:
            jobs.append(dataclasses.replace(_job(data, path.parent), source=where))
        except KdrayError as e:
            raise DatasetError(f"{where}: {e}") from None
    check_jobs(jobs)
    check_outputs(jobs, make=False)
    return jobs


def _job(data, base):
    if not isinstance(data, dict):
        raise DatasetError(f"expected a JSON object with {', '.join(JOB_KEYS[:3])}, "
                           f"got {type(data).__name__}")
    unknown = sorted(set(data) - set(JOB_KEYS))
    if unknown:
        raise DatasetError(f"unknown key {', '.join(map(repr, unknown))}; "
                           f"the keys are {', '.join(JOB_KEYS)}")
    missing = [k for k in JOB_KEYS[:3] if k not in data]
    if missing:
        raise DatasetError(f"missing {', '.join(map(repr, missing))}")
    paths = {}
    for key in JOB_KEYS[:3]:
        if not isinstance(data[key], str) or not data[key]:
            raise DatasetError(f"{key!r} must be a path, got {data[key]!r}")
        paths[key] = base / data[key]
    build = data.get("build", {})
    if not isinstance(build, dict):
        raise DatasetError(f"'build' must be an object of {', '.join(BUILD_KEYS)}")
    unknown = sorted(set(build) - set(BUILD_KEYS))
    if unknown:
        raise DatasetError(f"unknown build parameter {', '.join(map(repr, unknown))}; "
                           f"they are {', '.join(BUILD_KEYS)}")
    preview = data.get("preview", False)
    if not isinstance(preview, bool):
        raise DatasetError(f"'preview' must be true or false, got {preview!r}")
    aovs = data.get("aovs", ",".join(DEFAULT_AOVS))
    if not (isinstance(aovs, str) or (isinstance(aovs, list) and all(isinstance(a, str) for a in aovs))):
        raise DatasetError(f"'aovs' must be a list of names or a comma-separated string, got {aovs!r}")
    return Job(scene=paths["scene"], cameras=paths["cameras"], output=paths["output"], aovs=aovs,
               preview=preview, precision=data.get("precision", "single"),
               params=check_params(build))


def check_params(build):
    """BuildParams from a dict of its fields, checked as `kdray.build` checks them
    (ParameterError), without building."""
    from .builder import check_params as _check
    return _check(**build)


def check_jobs(jobs):
    """DatasetError for jobs whose scene or camera file does not exist, or two jobs
    that write one output folder; each job named by its source (a jobs file's "JOBS,
    line N"), else "job N"."""
    where = _job_names(jobs)
    for i, job in enumerate(jobs):
        for what in ("scene", "cameras"):
            p = getattr(job, what)
            try:
                found = p.exists()
            except OSError as e:                # a name too long, ...: exists() raises
                raise DatasetError(f"{where[i]}: the {what} file {p} cannot be used "
                                   f"({e.strerror or e})") from None
            if not found:
                raise DatasetError(f"{where[i]}: the {what} file {p} does not exist")
    check_distinct_outputs(jobs)


def _job_names(jobs):
    """Each job's name in messages: its source (a jobs file's "JOBS, line N"), else
    "job N"."""
    return [job.source or f"job {i + 1}" for i, job in enumerate(jobs)]


def check_distinct_outputs(jobs):
    """DatasetError for two jobs that write one output folder (symlinks resolved)."""
    where = _job_names(jobs)
    seen = {}
    for i, job in enumerate(jobs):
        key = os.path.normcase(os.path.realpath(job.output))
        if key in seen:
            first, _, line = where[seen[key]].rpartition("line ")
            both = (f"{first}lines {line} and {where[i].rpartition('line ')[2]}" if first
                    else f"{where[seen[key]]} and {where[i]}")
            raise DatasetError(f"{both} both write to {job.output}; give each job its own "
                               "output folder")
        seen[key] = i


def missing_views(job, views, overwrite=False):
    """The views of `job` to render: those whose files are not all there (as files: a
    folder of a file's name is not one), or all with overwrite."""
    return [v for v in views if overwrite or not all(f.is_file() for f in job.files(v.name))]


def check_outputs(jobs, make=True):
    """Check every job's output folder, then (make) create them: OutputError when one is
    a file, or it or the folder it would be made in cannot be written, or making one
    fails, named by the job's source where it has one (a jobs file's "JOBS, line N").
    Nothing is created when any fails: the folders made before a failure are
    removed. Returns {job index: the folders made for it, deepest first} (made)."""
    def error(i, message):
        named = jobs[i].source
        return OutputError(f"{named}: {message}" if named else message)
    for i, job in enumerate(jobs):
        out = job.output
        try:                                    # exists() raises for a name too long
            if out.exists() and not out.is_dir():
                raise error(i, f"{out}: is a file, not a folder (the output of {job.scene.name})")
            existing = out
            while not existing.exists():
                existing = existing.parent
        except OSError as e:
            raise error(i, f"{out}: cannot be used ({e.strerror or e})") from None
        if not existing.is_dir():
            raise error(i, f"{out}: cannot be made, {existing} is a file")
        if not os.access(existing, os.W_OK | os.X_OK):
            raise error(i, f"{out}: {'the folder' if existing == out else existing} is not writable")
    if not make:
        return {}
    made, made_by = [], {}                      # the folders made, deepest last
    for i, job in enumerate(jobs):
        missing = [f for f in (job.output, *job.output.parents) if not f.exists()]
        try:
            job.output.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            for folder in reversed(made):       # what the checks let through: undone
                with contextlib.suppress(OSError):
                    folder.rmdir()
            raise error(i, f"{job.output}: cannot be made ({e.strerror or e})") from None
        made.extend(reversed(missing))
        made_by[i] = missing
    return made_by


def _remove_made_if_empty(reports, made_by):
    """The folders check_outputs made (made_by) for jobs that failed before rendering
    a view, removed where they are still empty, deepest first: a failed job leaves no
    folder it made (a parent another job made or filled stays)."""
    for i, report in enumerate(reports):
        if report.ok or report.rendered:
            continue
        for folder in made_by.get(i, ()):
            try:
                folder.rmdir()
            except OSError:                     # not empty: it and its parents stay
                break


# -- what a run did ------------------------------------------------------------------------

STEPS = ("load", "tree", "device", "compile", "trace", "write")
"""The steps timed per job: load the mesh, build the tree (or read it from the cache),
create the Tracer (context and upload), compile the kernels, trace the views, write
the files. Under Dask each is summed over the workers that did it."""


@dataclasses.dataclass
class JobReport:
    """What a run did for one job: views in the camera file, views rendered, views
    skipped (already there), seconds per step (STEPS), tree_cached (True: read from
    the cache, False: built, None: not needed: no view to render, or the scene kept
    from an earlier job of the run in the process that rendered it), errors (one line
    each; empty: success)."""

    job: Job
    views: int = 0
    rendered: int = 0
    skipped: int = 0
    seconds: dict = dataclasses.field(default_factory=lambda: dict.fromkeys(STEPS, 0.0))
    tree_cached: object = None
    errors: list = dataclasses.field(default_factory=list)

    @property
    def ok(self):
        return not self.errors

    def add(self, seconds):
        for k, v in seconds.items():
            self.seconds[k] += v

    def summary(self):
        """One line: views, and the time of each step."""
        if self.ok and not self.rendered:
            return f"{self.job.scene.name}: {self.views} views, all there already"
        tree = {None: "", True: " (cache)", False: " (built)"}[self.tree_cached]
        steps = ", ".join(f"{k} {v:.2f} s{tree if k == 'tree' else ''}"
                          for k, v in self.seconds.items())
        status = "" if self.ok else f"; FAILED: {self.errors[0]}" + (
            f" (and {len(self.errors) - 1} more)" if len(self.errors) > 1 else "")
        return (f"{self.job.scene.name}: {self.rendered} of {self.views} views rendered, "
                f"{self.skipped} already there; {steps}{status}")


# -- one process's scenes --------------------------------------------------------------------

class Renderer:
    """The scenes of one process (this one, or a Dask worker) on one device: loads a
    scene, gets its tree (cache or build), uploads it, compiles, renders its views and
    writes them. Keeps the SCENES_KEPT most recent scenes and one OpenCL context.

    device : a --device spec or None; cache : a kdray.cache.TreeCache or None (build
    every time).
    """

    def __init__(self, device=None, cache=None, dask_worker=False):
        from .images import compress_on_threads
        compress_on_threads()
        self.dask_worker = dask_worker    # the test-only kill hook acts in workers only
        self.device = device
        self.cache = cache
        self._base = None                 # the first Tracer: its context serves them all
        self._scenes = {}                 # scene key -> its Tracer, the most recent last

    def scene(self, job):
        """(tracer, seconds, cached) for a job's scene: seconds of the set-up steps this
        call did, cached as JobReport.tree_cached (None for a scene already here, whose
        only step is compiling what this job's AOVs need that an earlier job's did
        not)."""
        from .load import load
        key = _scene_key(job)
        if key in self._scenes:
            tracer = self._scenes.pop(key)
            self._scenes[key] = tracer                         # most recent last
            t0 = time.perf_counter()
            tracer.compile(job.aovs, precision=job.precision)
            return tracer, {"compile": time.perf_counter() - t0}, None
        seconds = {}
        t0 = time.perf_counter()
        mesh = load(job.scene)
        seconds["load"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        tree, cached = self.tree(mesh, job.params)
        if job.precision == "double":
            tree = tree.with_double(mesh.vertices, mesh.faces)
        seconds["tree"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        if self._base is None:
            from .trace import Tracer
            tracer = self._base = Tracer(tree, device=self.device)
        else:
            tracer = self._base.with_tree(tree)
        seconds["device"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        tracer.compile(job.aovs, precision=job.precision)
        seconds["compile"] = time.perf_counter() - t0
        while len(self._scenes) >= SCENES_KEPT:
            self._scenes.pop(next(iter(self._scenes)))
        self._scenes[key] = tracer
        return tracer, seconds, cached

    def tree(self, mesh, params):
        """(tree, cached) of a loaded mesh."""
        if self.cache is None:
            return build_tree(mesh, params), False
        return self.cache.tree(mesh, params, build_tree)

    def render_views(self, job, views, overwrite=False, on_view=None):
        """Render and write `views` (kdray.camera_files.View) of `job` that are missing
        (all with overwrite). Returns (seconds, rendered, skipped, errors, tree_cached);
        on_view(name, seconds) is called after each view written. A view's files are
        written on a thread while the next view traces (WRITES_WAITING), so `seconds`'
        trace and write overlap."""
        seconds = dict.fromkeys(STEPS, 0.0)
        todo = missing_views(job, views, overwrite)
        skipped = len(views) - len(todo)
        if not todo:
            return seconds, 0, skipped, [], None
        tracer, setup, cached = self.scene(job)
        for k, v in setup.items():
            seconds[k] += v
        rendered, errors = 0, []
        pending = collections.deque()            # (view, write's future, trace seconds)

        def fault(view, e):                      # named by its scene, as a job's are
            errors.append(f"{job.scene}: view {view.name}: {e}")

        def finish(view, future, trace_seconds):
            nonlocal rendered
            try:
                write_seconds = future.result()
            except KdrayError as e:
                fault(view, e)
                return
            seconds["trace"] += trace_seconds
            seconds["write"] += write_seconds
            rendered += 1
            if on_view is not None:
                on_view(view.name, trace_seconds + write_seconds)

        # a view's files are written on a thread while the next view traces
        with concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="kdray-write") as writer:
            try:
                for view in todo:
                    t0 = time.perf_counter()
                    try:
                        images = tracer.render(view.camera, job.aovs, job.precision)
                    except KdrayError as e:
                        fault(view, e)
                        continue
                    future = writer.submit(_timed_write, job, view, images, tracer.tree,
                                           self.dask_worker)
                    pending.append((view, future, time.perf_counter() - t0))
                    while len(pending) > WRITES_WAITING or (pending and pending[0][1].done()):
                        finish(*pending.popleft())
                while pending:
                    finish(*pending.popleft())
            except BaseException:
                for _, future, _ in pending:         # a write under way still completes
                    future.cancel()
                raise
        return seconds, rendered, skipped, errors, cached


def build_tree(mesh, params):
    """The tree of a loaded mesh (kdray.Mesh) with `params`, its objects table kept."""
    from .builder import build
    try:
        tree = build(mesh.vertices, mesh.faces, **dataclasses.asdict(params))
    except KdrayError as e:
        raise type(e)(f"{mesh.name}: {e}") from None
    return tree.with_objects(mesh.objects, mesh.object_names)


def _scene_key(job):
    """What makes two jobs' scenes the same on a device: the file (path, size and
    modification time), the build parameters and the precision."""
    try:
        st = job.scene.stat()
    except OSError as e:
        raise MeshError(f"{job.scene}: cannot be read ({e.strerror or e})") from None
    return (os.path.abspath(job.scene), st.st_size, st.st_mtime_ns, job.params, job.precision)


def _timed_write(job, view, images, tree, test_kill):
    t0 = time.perf_counter()
    write_view(job, view, images, tree, test_kill)
    return time.perf_counter() - t0


def write_view(job, view, images, tree, test_kill=False):
    """Write one view's files (atomically): the EXR with the camera and the objects'
    names, and the preview."""
    from .images import write_exr, write_preview
    exr, *preview = job.files(view.name)
    if test_kill:
        _test_kill_hook(exr)
    write_exr(exr, images, camera=view.camera, object_names=tree.object_names)
    if preview:
        write_preview(preview[0], images)


def _test_kill_hook(path):
    marker = os.environ.get(TEST_KILL_ENV)
    if not marker:
        return
    try:
        fd = os.open(marker, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
    except FileExistsError:
        return
    os.close(fd)
    tmp = path.with_name(f".{path.name}.dead.tmp")
    tmp.write_bytes(b"\x76\x2f\x31\x01 half an EXR")
    os._exit(3)


def remove_stale_temporaries(job, names):
    """Remove the temporary files (.NAME.exr.*.tmp) that a killed process left beside
    the views `names` of a job; returns how many."""
    removed = 0
    if not job.output.is_dir():
        return 0
    wanted = {f.name for name in names for f in job.files(name)}
    for p in job.output.glob(".*.tmp"):
        stem = p.name[1:].rsplit(".", 2)[0]
        if stem in wanted:
            try:
                p.unlink()
                removed += 1
            except OSError:
                pass
    return removed


# -- progress ------------------------------------------------------------------------------

class Progress:
    """Views done, views per second and time left, on one line of stderr that redraws
    itself; only when stderr is a terminal and `live`. `view(job, name, seconds)`
    logs one line a view at -v (logging INFO)."""

    def __init__(self, total, live=None, stream=None):
        self.stream = stream or sys.stderr
        self.total = total
        self.done = 0
        self.start = time.perf_counter()
        self.live = (self.stream.isatty() if live is None else live) and total > 0
        self._shown = 0.0

    def view(self, job, name, seconds):
        log.info("%s: %s (%.3f s)", job.scene.name, name, seconds)
        self.advance(1)

    def advance(self, n):
        self.done += n
        now = time.perf_counter()
        if self.live and (now - self._shown > 0.1 or self.done >= self.total):
            self._shown = now
            self.stream.write("\r" + self.line(now) + "\x1b[K")
            self.stream.flush()

    def line(self, now=None):
        elapsed = (now or time.perf_counter()) - self.start
        rate = self.done / elapsed if elapsed > 0 else 0.0
        left = (self.total - self.done) / rate if rate > 0 else math.inf
        eta = _duration(left) if math.isfinite(left) else "?"
        return f"kdray: {self.done}/{self.total} views, {rate:.1f} views/s, {eta} left"

    def close(self):
        if self.live:
            self.stream.write("\n")
            self.stream.flush()


def _duration(seconds):
    s = int(round(seconds))
    return f"{s // 3600}:{s // 60 % 60:02d}:{s % 60:02d}" if s >= 3600 else f"{s // 60}:{s % 60:02d}"


# -- runs ----------------------------------------------------------------------------------

def plan(jobs, overwrite=False):
    """Read every job's cameras and see what is missing: [(report, views to render)].
    A camera file that fails is its job's error. Stale temporary files are removed."""
    from .camera_files import read_cameras
    planned = []
    for job in jobs:
        report = JobReport(job)
        try:
            views = read_cameras(job.cameras)
        except KdrayError as e:
            report.errors.append(str(e))
            planned.append((report, []))
            continue
        report.views = len(views)
        clash = _overwritten_input(job, views)
        if clash:
            report.errors.append(clash)
            planned.append((report, []))
            continue
        remove_stale_temporaries(job, [v.name for v in views])
        todo = missing_views(job, views, overwrite)
        report.skipped = len(views) - len(todo)
        planned.append((report, todo))
    return planned


def _overwritten_input(job, views):
    """Why a view's file would overwrite the job's scene or camera file, or None."""
    folder = os.path.realpath(job.output)
    for what in ("scene", "cameras"):
        source = getattr(job, what)
        path = os.path.realpath(source)
        if os.path.dirname(path) == folder:
            names = {f.name for view in views for f in job.files(view.name)}
            if os.path.basename(path) in names:
                return (f"{source}: a view's file in {job.output} would overwrite the "
                        f"{what} file")
    return None


WORKERS_PER_CPU = 4
"""Most local Dask workers (`run(workers=)`, `--workers`) a CPU this process may run on:
each worker's OpenCL runtime already uses every core (docs/datasets.md), so more
workers only share the cores, at a process and a context each; 4,097 of them on 2 cores
never finished starting."""


def check_workers(workers):
    """workers as `run` takes it: None or 0 (this process), or an integer from 1 to
    WORKERS_PER_CPU times the CPUs this process may run on; ParameterError otherwise."""
    if workers is None:
        return None
    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    most = WORKERS_PER_CPU * cpus
    if (isinstance(workers, bool) or not isinstance(workers, numbers.Integral)
            or not 0 <= workers <= most):
        raise ParameterError(f"workers must be an integer from 1 to {most} ({WORKERS_PER_CPU} "
                             f"a CPU of the {cpus} this process may run on; 0 or None: this "
                             f"process), got {workers!r:.60}")
    return int(workers)


def run(jobs, workers=None, scheduler=None, device=None, cache=None, overwrite=False,
        progress=None, chunk=None):
    """Render every job's missing views. Returns [JobReport], in the jobs' order.

    workers : None or 0 (in this process), or N >= 1: a local Dask cluster of N worker
        processes (one thread each)
    scheduler : the address of an existing Dask scheduler (instead of workers)
    device : --device spec for every process; cache : kdray.cache.TreeCache or None
    overwrite : render views whose files exist too
    progress : a Progress, or None (quiet)
    chunk : None or an integer >= 1, views per Dask task (default: enough tasks for 4
        per worker, at most 16 views each)
    Raises OutputError (before anything is written) for output folders that cannot be
    used, DatasetError for two jobs that write one folder (check_distinct_outputs),
    ParameterError for workers out of range (check_workers), an overwrite that is not
    True or False or a chunk that is not None or an integer >= 1; a failing scene,
    camera file or view is its report's error.
    """
    workers = check_workers(workers)
    overwrite = check_bool(overwrite, "overwrite", ParameterError)
    chunk = whole_or_none(chunk, "chunk", ParameterError)
    check_distinct_outputs(jobs)
    made_by = check_outputs(jobs)
    planned = plan(jobs, overwrite)
    total = sum(len(todo) for _, todo in planned)
    progress = progress or Progress(total, live=False)
    progress.total = total
    progress.live = progress.live and total > 0
    _compile_builder(any(todo for _, todo in planned))
    try:
        if workers or scheduler:
            _run_dask(planned, workers, scheduler, device, cache, overwrite, progress, chunk)
        else:
            _run_here(planned, device, cache, overwrite, progress)
    finally:
        progress.close()
    for report, todo in planned:
        remove_stale_temporaries(report.job, [v.name for v in todo])
    reports = [report for report, _ in planned]
    _remove_made_if_empty(reports, made_by)
    return reports


def _compile_builder(needed):
    """Compile the builder now when its compiled code is not on disk yet, saying so:
    once per install, before a cluster's workers would each compile it."""
    from . import builder
    if needed and not builder.compiled():
        log.warning(builder.COMPILING)
        builder.compile_all()


def _run_here(planned, device, cache, overwrite, progress):
    renderer = Renderer(device=device, cache=cache)
    for report, todo in planned:
        if not todo:
            continue
        job = report.job
        try:
            seconds, rendered, skipped, errors, cached = renderer.render_views(
                job, todo, overwrite, on_view=lambda name, s, job=job: progress.view(job, name, s))
        except Exception as e:          # a scene that fails, whatever the reason: go on
            what = str(e) if isinstance(e, KdrayError) else f"{type(e).__name__}: {e}"
            report.errors.append(what if str(job.scene) in what else f"{job.scene}: {what}")
            log.debug("%s failed", job.scene, exc_info=True)
            progress.advance(len(todo))
            continue
        report.add(seconds)
        report.rendered += rendered
        report.skipped += skipped           # written meanwhile (by another run)
        report.errors.extend(errors)
        if cached is not None:               # None: the scene kept from an earlier job
            report.tree_cached = cached
        progress.advance(len(todo) - rendered)       # failed, or written meanwhile


# -- Dask ------------------------------------------------------------------------------------

def _dask():
    try:
        import distributed
    except ImportError:
        raise DatasetError("--workers and --scheduler need Dask: pip install 'kdray[dask]'") from None
    return distributed


def _make_plugin(device, cache_folder):
    distributed = _dask()

    class KdrayWorker(distributed.WorkerPlugin):
        """Each worker's Renderer: its scenes and Tracers live as long as the worker."""
        name = "kdray"

        def __init__(self, device, cache_folder):
            self.device = device
            self.cache_folder = cache_folder
            self.renderer = None

        def setup(self, worker):
            from .cache import TreeCache
            cache = None if self.cache_folder is None else TreeCache(self.cache_folder)
            self.renderer = Renderer(device=self.device, cache=cache, dask_worker=True)

    return KdrayWorker(device, cache_folder)


def _worker_renderer():
    return _dask().get_worker().plugins["kdray"].renderer


def _task_tree(job):
    """A Dask task: the job's tree built into the cache (or read from it). Returns
    (seconds, cached)."""
    from .load import load
    renderer = _worker_renderer()
    t0 = time.perf_counter()
    mesh = load(job.scene)
    t1 = time.perf_counter()
    _, cached = renderer.tree(mesh, job.params)
    return {"load": t1 - t0, "tree": time.perf_counter() - t1}, cached


def _task_views(job, views, overwrite, _tree_done=None):
    """A Dask task: render and write some of a job's views on this worker. Returns
    (seconds, rendered, skipped, errors, [(name, seconds)], cached): skipped, the views
    whose files were there by then (a task run again after its worker died had written
    them: _run_dask counts them rendered); cached as JobReport.tree_cached for this
    worker's scene."""
    done = []
    seconds, rendered, skipped, errors, cached = _worker_renderer().render_views(
        job, views, overwrite, on_view=lambda name, s: done.append((name, s)))
    return seconds, rendered, skipped, errors, done, cached


def local_cluster(workers, quiet=False):
    """A dask.distributed LocalCluster of `workers` processes of one thread each, with
    glibc's malloc left as it is: Dask's nannies set MALLOC_TRIM_THRESHOLD_ in their
    workers, which also fixes glibc's mmap threshold, so that every image array is
    mapped and faulted in anew and a worker renders and writes at 0.6 times the speed
    (BENCHMARKS.md). quiet: the workers log nothing below CRITICAL (a task's KdrayError,
    which the caller reports in one line, is an ERROR there with its traceback)."""
    import dask
    distributed = _dask()
    # the scheduler's HTTP server (health checks; no dashboard is asked for) takes
    # another port where another cluster holds 8787, and says so in a warning of four
    # lines on the command's stderr: two runs at once are fine
    with dask.config.set({"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None}), \
            warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Port [0-9]+ is already in use")
        return distributed.LocalCluster(n_workers=int(workers), threads_per_worker=1,
                                        processes=True, dashboard_address=None,
                                        silence_logs=logging.CRITICAL if quiet
                                        else logging.ERROR)


def _task_failed(report, kind, n, e, progress):
    """A Dask task of `report`'s job failed with `e` (kind "tree" or "views", n views):
    its error into the report, once. A KdrayError as the worker raised it; anything
    else (KilledWorker: its workers kept dying; a bug) named by the job's scene and
    its type, once a type: every task of a job whose workers die fails alike, each
    naming its own task."""
    if isinstance(e, KdrayError):
        if kind == "tree" or not any(str(e) in err for err in report.errors):
            report.errors.append(str(e))
    else:
        kind_of = f"{report.job.scene}: {type(e).__name__}"
        if not any(err.startswith(kind_of + ":") for err in report.errors):
            report.errors.append(f"{kind_of}: {e}")
    if kind == "views":
        progress.advance(n)


def _task_done(report, kind, n, result, progress):
    """A Dask task's result (_task_tree's or _task_views') into `report`."""
    if kind == "tree":
        seconds, cached = result
        report.add(seconds)
        report.tree_cached = cached
        return
    seconds, rendered, skipped, errors, done, cached = result
    if report.tree_cached is None:   # without a tree task (no cache): the workers'
        report.tree_cached = cached
    report.add(seconds)
    # a task's views were all missing when the run began (plan): those it found written
    # were written in this run, by its own attempt on a worker that died
    report.rendered += rendered + skipped
    report.errors.extend(errors)
    for name, s in done:
        progress.view(report.job, name, s)
    progress.advance(n - len(done))


def _scheduler_address(path):
    """The "address" of a Dask scheduler file (`dask scheduler --scheduler-file` writes
    one: a JSON object); DatasetError for a file that is not one (Dask's own reader
    fails on them with an AssertionError or a TypeError)."""
    source = f"the Dask scheduler file {path}"
    data = parse_json(read_text(path, source, DatasetError), source, DatasetError)
    address = data.get("address") if isinstance(data, dict) else None
    if not isinstance(address, str) or not address:
        raise DatasetError(f"{source} holds no scheduler address (a JSON object with an "
                           f"\"address\" string, as `dask scheduler --scheduler-file` "
                           f"writes)")
    return address


def _run_dask(planned, workers, scheduler, device, cache, overwrite, progress, chunk):
    distributed = _dask()
    quiet = not log.isEnabledFor(logging.DEBUG)
    if quiet:                                    # Dask's own progress lines only at -vv
        logging.getLogger("distributed").setLevel(logging.ERROR)
    cluster = None
    if scheduler:
        # an address, or the file `dask scheduler --scheduler-file` writes
        address = _scheduler_address(scheduler) if os.path.isfile(scheduler) else scheduler
        try:
            client = distributed.Client(address=address, timeout="30s")
        except (OSError, TimeoutError, ValueError) as e:
            raise DatasetError(f"cannot reach the Dask scheduler {scheduler}: {e}") from None
        n_workers = max(len(client.scheduler_info().get("workers", {})), 1)
    else:
        cluster = local_cluster(workers, quiet=quiet)
        client = distributed.Client(cluster)
        n_workers = int(workers)
    try:
        client.register_plugin(_make_plugin(device, None if cache is None else str(cache.folder)))
        futures = {}
        for index, (report, todo) in enumerate(planned):
            if not todo:
                continue
            tree = None
            if cache is not None:
                tree = client.submit(_task_tree, report.job, pure=False)
                futures[tree] = (index, "tree", 0)
            size = chunk or max(1, min(16, math.ceil(len(todo) / (4 * n_workers))))
            for start in range(0, len(todo), size):
                part = todo[start:start + size]
                f = client.submit(_task_views, report.job, part, overwrite, tree, pure=False)
                futures[f] = (index, "views", len(part))
        for future in distributed.as_completed(list(futures)):
            index, kind, n = futures[future]
            try:
                result = future.result()
            except Exception as e:          # KdrayError; a worker that died too often; a bug
                _task_failed(planned[index][0], kind, n, e, progress)
                continue
            _task_done(planned[index][0], kind, n, result, progress)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
