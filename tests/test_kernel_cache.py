"""Compiled kernels on disk: kdray relies on the OpenCL driver's cache (PoCL's here), and
keys every build by a hash of all of kernels/, so a cache can never serve a program built
from other kernels. The PoCL checks run in fresh processes with their own POCL_CACHE_DIR
(PoCL reads it once, when it starts) and count the programs PoCL compiled and wrote."""
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from kdray import device as kdevice

BUILD = """
import sys
from pathlib import Path
import kdray.device as dev
dev.KERNEL_DIR = Path(sys.argv[1])
context, _ = dev.create_context("pocl")
defines = {"STACK_SIZE": int(sys.argv[2]), "LOCAL_SIZE": 8, "BATCH_SIZE": 64, "OUT_T": None}
try:
    program = dev.build_program(context, "render.cl", defines)
except dev.KernelBuildError as e:
    print("KernelBuildError:", e)
    sys.exit(3)
print("kernels:", program.kernel_names)
"""


def _pocl_works():
    try:
        kdevice.choose_device("pocl")
    except kdevice.DeviceError:
        return False
    return True


pocl = pytest.mark.skipif(not _pocl_works(), reason="no working PoCL device")


@pytest.fixture
def kernels(tmp_path):
    """A copy of kernels/ that a test may edit."""
    folder = tmp_path / "kernels"
    shutil.copytree(kdevice.KERNEL_DIR, folder)
    return folder


def build_in_new_process(cache, kernels, stack_size=8):
    """(exit code, stdout + stderr) of building render.cl in a fresh process."""
    env = dict(os.environ, POCL_CACHE_DIR=str(cache))
    env.pop("POCL_KERNEL_CACHE", None)
    proc = subprocess.run([sys.executable, "-c", BUILD, str(kernels), str(stack_size)],
                          capture_output=True, text=True, env=env)
    return proc.returncode, proc.stdout + proc.stderr


def compiled(cache):
    """{program.bc path: modification time in ns}: the programs PoCL compiled into `cache`,
    but for the device probe's (kdray.device.probe; its folder holds `kdray_probe`)."""
    return {str(p): p.stat().st_mtime_ns for p in Path(cache).rglob("program.bc")
            if not (p.parent / "kdray_probe").exists()}


def test_kernels_hash_covers_every_file(kernels):
    base = kdevice.kernels_hash(kernels)
    assert len(base) == 16 and base == kdevice.kernels_hash(kernels)
    for name in sorted(os.listdir(kernels)):
        path = kernels / name
        data = path.read_bytes()
        path.write_bytes(data + b"\n")
        assert kdevice.kernels_hash(kernels) != base, name
        path.write_bytes(data)
    assert kdevice.kernels_hash(kernels) == base
    (kernels / "new.h").write_text("")
    assert kdevice.kernels_hash(kernels) != base
    with pytest.raises(kdevice.DeviceError):
        kdevice.kernels_hash(kernels / "missing")


def test_the_options_carry_the_hash():
    try:
        device = kdevice.choose_device(None)
    except kdevice.DeviceError:
        pytest.skip("no OpenCL device")
    options = kdevice.build_options(device, {"STACK_SIZE": 4})
    assert f"-DKDRAY_KERNELS={kdevice.kernels_hash()}" in options and "-DSTACK_SIZE=4" in options


@pocl
def test_second_build_compiles_nothing_and_a_new_define_compiles_again(tmp_path, kernels):
    cache = tmp_path / "pocl"
    code, out = build_in_new_process(cache, kernels)
    assert code == 0 and "render_camera" in out, out
    first = compiled(cache)
    assert len(first) == 1
    code, out = build_in_new_process(cache, kernels)
    assert code == 0 and "render_camera" in out, out
    assert compiled(cache) == first                 # loaded, not compiled again
    code, out = build_in_new_process(cache, kernels, stack_size=9)
    assert code == 0, out
    assert len(compiled(cache)) == 2 and set(first) < set(compiled(cache))


@pocl
def test_an_edited_included_file_is_compiled_again(tmp_path, kernels):
    cache = tmp_path / "pocl"
    code, out = build_in_new_process(cache, kernels)
    assert code == 0, out
    with open(kernels / "triangle.cl", "a") as f:      # included by render.cl
        f.write("\n#error edited after it was cached\n")
    code, out = build_in_new_process(cache, kernels)
    assert code == 3 and "edited after it was cached" in out, out


def _pocl_asserts():
    """Whether the PoCL found is built with assertions (Debian's pocl-opencl-icd: its
    version names "+Asserts"): it aborts on a corrupt cache entry (`Assertion 'mod'
    failed` in pocl_llvm_build_program) instead of failing the build."""
    return _pocl_works() and "Asserts" in kdevice.choose_device("pocl").platform.version


@pocl
@pytest.mark.skipif(_pocl_asserts(), reason="PoCL built with assertions aborts on a corrupt entry")
def test_a_corrupt_cache_entry_is_reported_with_what_to_remove(tmp_path, kernels):
    cache = tmp_path / "pocl"
    code, out = build_in_new_process(cache, kernels)
    assert code == 0, out
    for path in compiled(cache):
        Path(path).write_bytes(b"not LLVM bitcode")
    code, out = build_in_new_process(cache, kernels)
    assert "KernelBuildError" in out and "corrupt" in out and str(cache) in out, out
    shutil.rmtree(cache)
    code, out = build_in_new_process(cache, kernels)
    assert code == 0 and "render_camera" in out, out


INTEL_BUILD = """
import kdray.device as dev
context, _ = dev.create_context("intel")
defines = {"STACK_SIZE": 8, "LOCAL_SIZE": 8, "BATCH_SIZE": 64, "OUT_T": None}
program = dev.build_program(context, "render.cl", defines)
print("served from the cache:", program._build_duration_info[1])
"""


def _intel_works():
    try:
        kdevice.choose_device("intel")
    except kdevice.DeviceError:
        return False
    return True


@pytest.mark.skipif(not _intel_works(), reason="no working Intel CPU runtime")
def test_intel_builds_are_served_by_pyopencl_cache(tmp_path):
    """Intel's CPU runtime keeps no compiled programs of its own (a build takes seconds
    there); pyopencl's binary cache (in XDG_CACHE_HOME/pyopencl) serves a second process."""
    env = dict(os.environ, XDG_CACHE_HOME=str(tmp_path))
    outputs = []
    for _ in range(2):
        proc = subprocess.run([sys.executable, "-c", INTEL_BUILD], capture_output=True,
                              text=True, env=env, timeout=300)
        assert proc.returncode == 0, proc.stderr
        outputs.append(proc.stdout)
    assert "served from the cache: False" in outputs[0]
    assert "served from the cache: True" in outputs[1]
    assert any((tmp_path / "pyopencl").rglob("*"))
