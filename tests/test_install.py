"""`pip install kdray` resolves on every platform we support, with the OpenCL runtime
each one can have.

pyproject.toml picks the OpenCL runtimes by environment markers: PoCL has wheels for
Linux x86-64 only, Intel's CPU runtime for Linux x86-64 and Windows x86-64; macOS uses
Apple's OpenCL and Linux aarch64 a system ICD, so they get pyopencl alone. Those
machines are not here, so each platform is checked in two steps:

- test_markers evaluates each requirement's marker in the platform's marker
  environment (packaging.markers) and compares the packages selected with the
  expected ones. No network; always runs.
- test_resolves asks pip to resolve the requirements so selected against the package
  index as the platform would see it: wheels only, chosen by the platform's tags
  (--platform, --python-version of this interpreter, --implementation cp), in a dry
  run whose --report lists what would be installed. It checks that the resolution
  succeeds and holds the platform's OpenCL runtimes and no others. Skipped when the
  package index cannot be reached.

A limit of pip: --platform changes the tags of the wheels pip accepts, not the
environment markers, which it evaluates against the running interpreter. So the
top-level requirements are passed with their markers removed (test_markers has
evaluated them for the target), and the markers of the dependencies of our
dependencies are evaluated as for this machine, not for the target.
"""
import json
import subprocess
import sys
from pathlib import Path

import pytest
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    tomllib = pytest.importorskip(
        "tomli", reason="reading pyproject.toml needs tomllib (Python 3.11+) or tomli")

PYPROJECT = Path(__file__).resolve().parents[1] / "pyproject.toml"
PYTHON = f"{sys.version_info.major}.{sys.version_info.minor}"


def manylinux(arch):
    """The tags of a Linux with glibc 2.28 (pip does not expand manylinux_2_28 to the
    older manylinux_2_x tags itself; manylinux2014 it expands to 2010 and 1)."""
    return [f"manylinux_2_{minor}_{arch}" for minor in range(28, 16, -1)] + [f"manylinux2014_{arch}"]


# name: (marker environment, pip --platform tags, OpenCL runtime packages expected)
PLATFORMS = {
    "linux-x86_64": (
        dict(sys_platform="linux", platform_system="Linux", os_name="posix", platform_machine="x86_64"),
        manylinux("x86_64"),
        {"pocl-binary-distribution", "intel-opencl-rt", "intel-cmplr-lib-rt"}),
    "win-amd64": (
        dict(sys_platform="win32", platform_system="Windows", os_name="nt", platform_machine="AMD64"),
        ["win_amd64"],
        {"intel-opencl-rt", "intel-cmplr-lib-rt"}),
    "macos-arm64": (
        dict(sys_platform="darwin", platform_system="Darwin", os_name="posix", platform_machine="arm64"),
        ["macosx_11_0_arm64"],  # pip adds the older macOS versions' tags itself
        set()),
    "macos-x86_64": (
        dict(sys_platform="darwin", platform_system="Darwin", os_name="posix", platform_machine="x86_64"),
        ["macosx_10_15_x86_64"],
        set()),
    "linux-aarch64": (
        dict(sys_platform="linux", platform_system="Linux", os_name="posix", platform_machine="aarch64"),
        manylinux("aarch64"),
        set()),
}

OPENCL_RUNTIMES = {"pocl-binary-distribution", "intel-opencl-rt", "intel-cmplr-lib-rt"}
# on every platform
COMMON = {"numpy", "numba", "pyopencl", "trimesh", "openimageio", "openexr", "click"}


def dependencies():
    with open(PYPROJECT, "rb") as f:
        return [Requirement(s) for s in tomllib.load(f)["project"]["dependencies"]]


def selected(environment):
    """The requirements of [project] dependencies whose markers hold in `environment`
    (the keys it does not set, python_version among them, are this interpreter's)."""
    return [r for r in dependencies() if r.marker is None or r.marker.evaluate(environment)]


def names(requirements):
    return {canonicalize_name(r.name) for r in requirements}


@pytest.mark.parametrize("platform", PLATFORMS)
def test_markers(platform):
    """Each platform gets the common dependencies and exactly its OpenCL runtimes."""
    environment, _, runtimes = PLATFORMS[platform]
    assert names(selected(environment)) == COMMON | runtimes


def test_intel_packages_from_one_release():
    """Intel's OpenCL runtime and the compiler library it loads are pinned to the same
    release series: libintelocl needs the libimf/libsvml of its own release."""
    specifiers = {str(r.specifier) for r in dependencies()
                  if canonicalize_name(r.name) in ("intel-opencl-rt", "intel-cmplr-lib-rt")}
    assert len(specifiers) == 1, specifiers
    (specifier,) = specifiers
    assert specifier.startswith("==") and specifier.endswith(".*"), specifier


def pip(*args, timeout):
    return subprocess.run([sys.executable, "-m", "pip", *args],
                          capture_output=True, text=True, timeout=timeout)


@pytest.fixture(scope="module")
def index():
    """Skips the resolution tests when the package index cannot be reached: one query
    for pyopencl's versions, with a short network timeout and no retries."""
    try:
        result = pip("index", "versions", "pyopencl", "--timeout", "10", "--retries", "0",
                     timeout=60)
    except subprocess.TimeoutExpired:
        pytest.skip("package index: no answer to `pip index versions pyopencl` in 60 s")
    if result.returncode != 0:
        last = (result.stderr.strip().splitlines() or ["(no message)"])[-1]
        pytest.skip(f"package index not reachable: `pip index versions pyopencl` says {last!r}")


@pytest.mark.parametrize("platform", PLATFORMS)
def test_resolves(platform, index, tmp_path):
    """pip finds wheels for the platform's selected requirements and everything they
    need (dependencies of dependencies: see the module's docstring), and the resolution
    holds exactly the platform's OpenCL runtimes."""
    environment, tags, runtimes = PLATFORMS[platform]
    requirements = selected(environment)
    for r in requirements:
        r.marker = None  # pip would evaluate it for this machine, not for the target
    report = tmp_path / "report.json"
    platforms = [arg for tag in tags for arg in ("--platform", tag)]
    result = pip("install", "--dry-run", "--quiet", "--ignore-installed", "--only-binary=:all:",
                 *platforms, "--python-version", PYTHON, "--implementation", "cp",
                 "--target", str(tmp_path / "target"), "--report", str(report),
                 *map(str, requirements), timeout=600)
    assert result.returncode == 0, result.stderr
    installed = {canonicalize_name(item["metadata"]["name"])
                 for item in json.loads(report.read_text())["install"]}
    assert names(requirements) <= installed
    assert installed & OPENCL_RUNTIMES == runtimes
