"""kdray finds a working device whatever was imported before it: Open3D bundles an older
TBB under the name Intel's CPU runtime needs (libtbb.so.12), so kdray registers its own
copy of the runtime that loads its TBB under another name (kdray.runtimes). Here: the
in-place renaming of a shared object's names, the copy's folder, and Open3D imported
before kdray in a fresh process."""
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from kdray import runtimes

ROOT = Path(__file__).resolve().parents[1]
INTEL = runtimes.intel_library()
needs_intel = pytest.mark.skipif(
    not sys.platform.startswith("linux") or not INTEL.is_file(),
    reason="needs Intel's CPU runtime from its wheel (Linux x86-64)")


def _strings(path):
    return runtimes.dynamic_strings(Path(path).read_bytes())


# ---------------------------------------------------------------- renaming in place

@pytest.fixture
def shared_object(tmp_path):
    """A copy of a shared object this interpreter loads (the _ctypes extension: it needs
    libffi and libc) and its dynamic strings."""
    import _ctypes
    if not sys.platform.startswith("linux"):
        pytest.skip("ELF shared objects: Linux")
    path = tmp_path / "module.so"
    shutil.copy(_ctypes.__file__, path)
    return path, _strings(path)


def test_rename_needed_in_place(shared_object):
    path, before = shared_object
    old = next(s for tag, s in before if tag == "NEEDED" and s.startswith("libffi"))
    size = path.stat().st_size
    runtimes.rename_dynamic(path, "NEEDED", old, "libkd.so")          # shorter is allowed
    after = _strings(path)
    assert after == [(tag, "libkd.so" if (tag, s) == ("NEEDED", old) else s) for tag, s in before]
    assert path.stat().st_size == size


def test_rename_refusals(shared_object, monkeypatch):
    path, before = shared_object
    old = next(s for tag, s in before if tag == "NEEDED")
    data = path.read_bytes()
    with pytest.raises(ValueError, match="longer"):
        runtimes.rename_dynamic(path, "NEEDED", old, old + "x")
    with pytest.raises(ValueError, match="no NEEDED entry"):
        runtimes.rename_dynamic(path, "NEEDED", "libnothing.so.1", "libx.so")
    with pytest.raises(ValueError, match="no SONAME entry"):
        runtimes.rename_dynamic(path, "SONAME", old, "libx.so")       # an extension has none
    # a name stored as the tail of this one (as linkers may) would be renamed with it
    uses = runtimes._string_uses

    def sharing(elf, strtab, entries):
        start = next(v for t, v in entries if t == 1)                 # the first NEEDED
        return uses(elf, strtab, entries) + [start + 3]
    monkeypatch.setattr(runtimes, "_string_uses", sharing)
    with pytest.raises(ValueError, match="shares the bytes"):
        runtimes.rename_dynamic(path, "NEEDED", old, "libx.so")
    assert path.read_bytes() == data
    with pytest.raises(ValueError, match="not a 64-bit little-endian ELF"):
        runtimes.dynamic_strings(b"#!/bin/sh\n" + bytes(64))


# ---------------------------------------------------------------- kdray's copy of the runtime

@pytest.fixture
def fake_prefix(tmp_path):
    """A lib folder holding links to every file of this environment's lib folder (the
    runtime, its TBB and the rest), to make copies in without touching the environment."""
    lib = tmp_path / "lib"
    lib.mkdir()
    for entry in os.scandir(INTEL.parent):
        if entry.is_file() and not entry.name.startswith("."):
            os.symlink(os.path.realpath(entry.path), lib / entry.name)
    return lib


@needs_intel
def test_private_runtime_folder(fake_prefix):
    library = fake_prefix / INTEL.name
    folder, tbb = runtimes.private_folder(library)
    assert folder.parent == fake_prefix and folder.name.startswith(runtimes.PRIVATE_PREFIX)
    assert ("NEEDED", tbb) in _strings(library) and tbb.startswith("libtbb.so")
    stale = fake_prefix / f"{runtimes.PRIVATE_PREFIX}0123456789abcdef"    # an older runtime's
    stale.mkdir()
    dead = fake_prefix / f".{folder.name}.999999999.tmp"                   # a killed process's
    dead.mkdir()
    assert runtimes.private_runtime(library, create=False) is None
    copy = runtimes.private_runtime(library)
    assert copy == folder / INTEL.name and copy.is_file() and not copy.is_symlink()
    needed = [s for tag, s in _strings(copy) if tag == "NEEDED"]
    assert runtimes.PRIVATE_TBB in needed and tbb not in needed
    assert needed == [runtimes.PRIVATE_TBB if s == tbb else s
                      for tag, s in _strings(library) if tag == "NEEDED"]
    assert ("SONAME", runtimes.PRIVATE_TBB) in _strings(folder / runtimes.PRIVATE_TBB)
    # everything else is a link to the runtime's folder; no other TBB of that name
    names = set(os.listdir(folder))
    assert tbb not in names and not any(n.startswith("libintelocl.so.") for n in names)
    assert os.readlink(folder / "libcommon_clang.so") == "../libcommon_clang.so"
    assert not stale.exists() and not dead.exists()
    assert sorted(p.name for p in fake_prefix.iterdir() if p.is_dir()) == [folder.name]
    assert runtimes.private_runtime(library) == copy                   # found, not made again
    assert runtimes.registered_library(library) == copy
    # its TBB upgraded (another size or time): another folder, the old one removed
    (fake_prefix / tbb).unlink()
    shutil.copy(os.path.realpath(INTEL.parent / tbb), fake_prefix / tbb)
    newer = runtimes.private_runtime(library)
    assert newer.parent != folder and newer.is_file() and not folder.exists()


@needs_intel
def test_private_runtime_where_it_cannot_be_made(fake_prefix, monkeypatch):
    library = fake_prefix / INTEL.name
    fake_prefix.chmod(0o555)                                        # a read-only environment
    try:
        if os.access(fake_prefix, os.W_OK):                         # root writes anyway
            monkeypatch.setattr(runtimes.shutil, "copy", _disk_full)
        assert runtimes.private_runtime(library) is None
        assert runtimes.registered_library(library) == library
        assert [p.name for p in fake_prefix.iterdir() if p.is_dir()] == []
    finally:
        fake_prefix.chmod(0o755)


def _disk_full(*args, **kwargs):
    raise OSError(28, "No space left on device")


# ---------------------------------------------------------------- Open3D and kdray in one process

OPEN3D_AND_KDRAY = """
    import sys
    if sys.argv[1] == "kdray first":
        import kdray
    import open3d as o3d
    box = o3d.t.geometry.TriangleMesh.from_legacy(o3d.geometry.TriangleMesh.create_box())
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(box)
    rays = o3d.core.Tensor([[0.5, 0.5, -1, 0, 0, 1]], dtype=o3d.core.Dtype.Float32)
    print("open3d", float(scene.cast_rays(rays)["t_hit"].numpy()[0]))
    import kdray
    from kdray import device, runtimes
    print("\\n".join(device.list_devices()))
    mesh = kdray.load("scenes/sphere.obj")
    spec = "intel" if runtimes.intel_library().is_file() else None
    tracer = kdray.Tracer(kdray.build(mesh.vertices, mesh.faces), device=spec)
    camera = kdray.Camera.look_at((0, 0, 3), (0, 0, 0), width=8, height=8)
    hit = tracer.render(camera, aovs=("id",))["id"] != 0xFFFFFFFF
    print("kdray", tracer.device.platform.name.strip(), int(hit.sum()))
    print("open3d again", float(scene.cast_rays(rays)["t_hit"].numpy()[0]))
"""


@pytest.mark.parametrize("order", ["open3d first", "kdray first"])
def test_open3d_and_kdray_in_one_process(order):
    """Open3D and kdray imported in one fresh process, in either order: both work, and
    where Intel's CPU runtime is installed (on Zen 4 and Zen 5 the only CPU runtime that
    runs) kdray renders on it."""
    if subprocess.run([sys.executable, "-c", "import open3d"], capture_output=True,
                      timeout=120).returncode != 0:
        pytest.skip("Open3D is not installed (make bench-deps installs it)")
    names = set(runtimes.INTEL_AFFINITY_NAMES) | set(runtimes.POCL_AFFINITY) | {"PYOPENCL_CTX"}
    env = {k: v for k, v in os.environ.items() if k not in names}
    proc = subprocess.run([sys.executable, "-c", textwrap.dedent(OPEN3D_AND_KDRAY), order],
                          capture_output=True, text=True, cwd=ROOT, timeout=300, env=env)
    assert proc.returncode == 0, proc.stderr
    out = proc.stdout
    assert "open3d 0.99999" in out and "open3d again 0.99999" in out
    assert "not loaded" not in out and "\ndefault: --device " in out, out
    kdray_line = next(ln for ln in out.splitlines() if ln.startswith("kdray "))
    assert int(kdray_line.rsplit(None, 1)[1]) > 0
    if INTEL.is_file():
        assert kdray_line.startswith(f"kdray {runtimes.INTEL_CPU_PLATFORM} ")
