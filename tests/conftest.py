"""Shared fixtures: a random generator, the session's Tracers, and the OpenCL
implementations the kernel tests run on. What tests share besides fixtures is in
tests/helpers.py."""
import dataclasses
import os
import tempfile
from pathlib import Path

import numpy as np
import pytest


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


@pytest.fixture(scope="session")
def tracers():
    """tracers(tree, **options) -> the session's Tracer of `tree` with those options, on
    the default device: made once per (tree, options), so that contexts, uploads and
    programs are made once. Options given as None are left out (the Tracer's default)."""
    from kdray.trace import Tracer
    made = {}

    def get(tree, **options):
        options = {k: v for k, v in options.items() if v is not None}
        key = (id(tree), tuple(sorted(options.items())))
        if key not in made:
            made[key] = (tree, Tracer(tree, **options))   # the tree kept alive: ids stay unique
        return made[key][1]

    yield get
    made.clear()


# -- the OpenCL implementations the kernel tests run on ----------------------------------
#
# Tests that take the `runtime` fixture run once on each OpenCL implementation that
# works here (PoCL, Intel's CPU runtime, Oclgrind, a GPU's driver: the first working
# device of each), the others on kdray's default device (PYOPENCL_CTX chooses another).
# KDRAY_TEST_RUNTIMES (comma-separated implementation names, e.g. "pocl,oclgrind")
# narrows the set. Oclgrind simulates a device and checks every access: its tests keep
# their cases small, and anything it reports (invalid accesses, data races, work-group
# divergence at barriers) fails the test. Its check of uninitialised values
# (OCLGRIND_UNINITIALIZED) is off: Oclgrind 21.10 crashes in it on kdray's kernels; so
# is its check of API calls (OCLGRIND_CHECK_API), which flags pyopencl's query of an
# NVIDIA-only device property.

_OCLGRIND_LOG = Path(tempfile.mkdtemp(prefix="kdray-oclgrind-")) / "oclgrind.log"
# read by Oclgrind when it starts, so before any test lists the OpenCL platforms; one log
# a process, as pytest-xdist's workers (`make test`) inherit the controller's environment
# and a report must fail the test that caused it, not a neighbour's
if "OCLGRIND_LOG" not in os.environ or os.environ.get("PYTEST_XDIST_WORKER"):
    os.environ["OCLGRIND_LOG"] = str(_OCLGRIND_LOG)
os.environ.setdefault("OCLGRIND_DATA_RACES", "1")


@dataclasses.dataclass(frozen=True)
class Runtime:
    """One OpenCL implementation to test on: name ("pocl", "intel", "oclgrind", ...),
    spec (the --device string of its first working device), description, simulator
    (bool: keep the case small)."""
    name: str
    spec: str
    description: str
    simulator: bool

    def small(self, n_cpu, n_simulator):
        """A case size: n_simulator on a simulator, else n_cpu."""
        return n_simulator if self.simulator else n_cpu


_RUNTIMES = None
_OUTCOMES = {}           # test id -> ((name, description), "passed" | "failed" | "skipped")


def runtimes():
    """[Runtime] of every OpenCL implementation that works here (its devices' probes),
    narrowed by KDRAY_TEST_RUNTIMES; found once per session."""
    global _RUNTIMES
    if _RUNTIMES is None:
        from kdray import device
        found = {}
        try:
            entries = device.working_devices(include_simulators=True)
        except device.DeviceError:
            entries = []
        for spec, dev, name in entries:
            found.setdefault(name, Runtime(name, spec, device.describe(dev), device.is_simulator(dev)))
        wanted = os.environ.get("KDRAY_TEST_RUNTIMES", "").strip()
        if wanted:
            names = [w.strip() for w in wanted.split(",") if w.strip()]
            found = {n: found[n] for n in names if n in found}
        _RUNTIMES = list(found.values())
    return _RUNTIMES


def pytest_generate_tests(metafunc):
    if "runtime" in metafunc.fixturenames:
        present = runtimes()
        metafunc.parametrize("runtime", present or [None], ids=[r.name for r in present] or ["none"],
                             indirect=True)


def pytest_configure(config):
    config.addinivalue_line(
        "markers", "slow_on_simulator(**params): the cases with these parameters are `slow` "
        "on a simulator (pytest_collection_modifyitems)")


@pytest.hookimpl(tryfirst=True)       # before `-m "not slow"` deselects
def pytest_collection_modifyitems(items):
    """`@pytest.mark.slow_on_simulator(scene="soup")`: the test's cases with those
    parameters are long checks (`slow`) on a simulator, where another case of the test
    (the same contract, on the same simulator) stays in `make test`."""
    for item in items:
        rt = getattr(item, "callspec", None) and item.callspec.params.get("runtime")
        if not (isinstance(rt, Runtime) and rt.simulator):
            continue
        for mark in item.iter_markers("slow_on_simulator"):
            if all(item.callspec.params.get(k) == v for k, v in mark.kwargs.items()):
                item.add_marker(pytest.mark.slow)


@pytest.fixture
def runtime(request):
    """The Runtime a test runs on (see runtimes()); on Oclgrind, fails the test when
    Oclgrind reports anything while it runs."""
    rt = request.param
    if rt is None:
        pytest.skip("no working OpenCL implementation")
    log = Path(os.environ["OCLGRIND_LOG"])
    before = log.stat().st_size if log.exists() else 0
    yield rt
    if rt.name == "oclgrind" and log.exists() and log.stat().st_size > before:
        with open(log, encoding="utf-8", errors="replace") as f:
            f.seek(before)
            report = f.read()
        pytest.fail(f"Oclgrind reported:\n{report[:4000]}", pytrace=False)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    """Name the Runtime of every test that runs on one in its reports' user_properties,
    which pytest-xdist carries from its workers to the controller that prints the
    summary."""
    rt = getattr(item, "callspec", None) and item.callspec.params.get("runtime")
    tag = ("runtime", (rt.name, rt.description)) if isinstance(rt, Runtime) else None
    if tag and tag not in item.user_properties:
        item.user_properties.append(tag)
    yield


def pytest_runtest_logreport(report):
    """Record the outcome of every test that ran on a Runtime (a failure in any phase,
    such as Oclgrind's report at teardown, makes it failed)."""
    rt = dict(report.user_properties).get("runtime")
    if rt is None:
        return
    rt = tuple(rt)
    previous = _OUTCOMES.get(report.nodeid, (rt, None))[1]
    if report.failed:
        _OUTCOMES[report.nodeid] = (rt, "failed")
    elif report.skipped:
        _OUTCOMES[report.nodeid] = (rt, "skipped")
    elif report.when == "call" and previous is None:
        _OUTCOMES[report.nodeid] = (rt, "passed")


def pytest_terminal_summary(terminalreporter):
    """Which OpenCL implementations the kernel tests covered, which were not (and why),
    and the default device the other tests ran on."""
    if not _OUTCOMES:
        return
    from kdray import device
    tr = terminalreporter
    tr.section("OpenCL implementations covered")
    by_runtime = {}
    for rt, status in _OUTCOMES.values():
        by_runtime.setdefault(rt, []).append(status)
    for rt, statuses in by_runtime.items():
        counts = ", ".join(f"{statuses.count(s)} {s}" for s in ("passed", "failed", "skipped")
                           if statuses.count(s))
        tr.write_line(f"{rt[0]:<9} {counts}: {rt[1]}")
    try:
        tr.write_line(f"other kernel tests: the default device, "
                      f"{device.describe(device.choose_device(None))}")
        for line in device.list_devices():
            if "fails:" in line or line.startswith("not loaded"):
                tr.write_line(f"not covered: {line.strip()}")
    except device.DeviceError as e:
        tr.write_line(f"no default device: {e}")


# -- trimesh's trees, where their packages are missing ------------------------------

class _BoxTree:
    """rtree's Index as trimesh uses it, by brute force: `bounds` (6,) and
    `intersection(bounds (6,))` -> ids of the triangle boxes that overlap."""

    def __init__(self, triangles):
        tri = np.asarray(triangles, dtype=np.float64)
        self.lo, self.hi = tri.min(axis=1), tri.max(axis=1)
        self.bounds = np.concatenate([self.lo.min(axis=0), self.hi.max(axis=0)])

    def intersection(self, bounds):
        b = np.asarray(bounds, dtype=np.float64)
        return np.flatnonzero(((self.lo <= b[3:]) & (self.hi >= b[:3])).all(axis=1)).tolist()


class _VertexTree:
    """scipy's cKDTree as trimesh.proximity uses it, by brute force: query(points) ->
    (distance (n,), index (n,)) of each point's nearest vertex."""

    def __init__(self, points):
        self.points = np.asarray(points, dtype=np.float64)

    def query(self, q):
        q = np.asarray(q, dtype=np.float64).reshape(-1, 3)
        dist = np.linalg.norm(q[:, None, :] - self.points[None, :, :], axis=2)
        i = dist.argmin(axis=1)
        return dist[np.arange(len(q)), i], i


@pytest.fixture
def brute_trees(monkeypatch):
    """trimesh's r-tree and vertex k-d tree, by brute force where rtree or scipy is
    missing (the oracles' dependencies, not the intersector's: neither is in the test
    extra)."""
    import trimesh
    try:
        import rtree  # noqa: F401
    except ImportError:
        monkeypatch.setattr(trimesh.Trimesh, "triangles_tree",
                            property(lambda mesh: _BoxTree(mesh.triangles)))
    try:
        import scipy.spatial  # noqa: F401
    except ImportError:
        monkeypatch.setattr(trimesh.proximity, "cKDTree", _VertexTree)
