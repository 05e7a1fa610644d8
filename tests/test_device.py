"""Device choice: every device probed, the default never a simulator, a broken device
skipped by the default and refused when named, and Intel's CPU runtime registered (and
its TBB conflict with Open3D reported). Failures are made on real devices with probe
sources that do not build or give a wrong answer there; only the default order is
checked on stand-ins for devices."""
import logging
import os
import subprocess
import sys
import textwrap
from pathlib import Path
from types import SimpleNamespace

import pytest

from kdray import device as kdevice
from kdray import runtimes as kruntimes
from kdray.errors import DeviceError
from helpers import run

cl = pytest.importorskip("pyopencl")
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def all_devices():
    """[("i:j", device)] of every device of every platform."""
    return kdevice._entries(kdevice._platforms())


@pytest.fixture(autouse=True)
def no_pyopencl_ctx(monkeypatch):
    monkeypatch.delenv("PYOPENCL_CTX", raising=False)


def one_line(text):
    return len([ln for ln in str(text).splitlines() if ln.strip()]) == 1


# ---------------------------------------------------------------- real devices

def test_probe_works_on_every_device():
    for spec, device in all_devices():
        result = kdevice.probe(device)
        assert result.works == (result.reason == "") and (result.works or one_line(result.reason))
        # PoCL 3.0 cannot build for AMD Zen 5 ("unknown target CPU 'generic'") and
        # crashes on vector code on Zen 4 (device.compiler_fault)
        assert result.works or "unknown target CPU" in result.reason or (
            result.reason == kdevice.compiler_fault(device)), (spec, result)
        assert result.seconds >= 0
        assert kdevice.probe(device) is result                 # cached per process


def test_default_is_a_working_device_and_never_a_simulator():
    default = kdevice.choose_device(None)
    assert not kdevice.is_simulator(default) and kdevice.probe(default).works
    order = kdevice.working_devices()
    assert order[0][1] == default
    kinds = [kdevice.device_kind(d) for _, d, _ in order]
    assert "simulator" not in kinds or kinds.index("simulator") == len(kinds) - kinds.count("simulator")
    assert all(not kdevice.is_simulator(d) for _, d, _ in kdevice.working_devices(False))
    for spec, device, impl in order:
        assert kdevice.choose_device(spec) == device and impl == kdevice.implementation(device)


def test_simulators_are_chosen_only_by_name():
    sims = [d for _, d in all_devices() if kdevice.is_simulator(d)]
    if not sims:
        pytest.skip("no simulator (Oclgrind) installed")
    assert kdevice.device_kind(sims[0]) == "simulator"
    assert kdevice.choose_device("oclgrind") == sims[0]


def test_implementation_names_choose_platforms():
    for spec, device in all_devices():
        impl = kdevice.implementation(device)
        if kdevice.probe(device).works and impl in ("pocl", "intel", "oclgrind"):
            assert kdevice.choose_device(impl).platform == device.platform


def test_devices_command_lists_every_device_probed(capsys):
    code, out, err = run(capsys, "devices")
    assert code == 0, err
    lines = out.splitlines()
    for spec, device in all_devices():
        line = next(ln for ln in lines if ln.strip().startswith(f"--device {spec} "))
        assert device.name.strip() in line
        assert kdevice.device_kind(device) in line
        assert ": works (probe " in line or ": fails: " in line
        assert "_is_bitfield" not in line
    default = kdevice.choose_device(None)
    spec = next(s for s, d in all_devices() if d == default)
    assert lines[-1].startswith(f"default: --device {spec} ")


# ---------------------------------------------------------------- broken devices (by probe source)

def _probe_with(source, device):
    """The probe of `device` with another probe source."""
    real = kdevice.PROBE_SOURCE
    kdevice.PROBE_SOURCE = source
    try:
        return kdevice.probe(device)
    finally:
        kdevice.PROBE_SOURCE = real


def _breaking_source(target, others):
    """A probe source that fails to build on `target` and works on `others`, or None."""
    words = target.version.split()
    version = words[1].replace(".", "") + "0" if len(words) > 1 else "0"
    conditions = ["defined(cl_intel_required_subgroup_size)", "defined(__x86_64__)",
                  "defined(__SPIR__)", "defined(__NV_CL_C_VERSION)", "defined(__AMD__)",
                  f"__OPENCL_VERSION__ == {version}"]
    for cond in conditions:
        source = f"#if {cond}\n#error kdray test: broken on purpose\n#endif\n" + kdevice.PROBE_SOURCE
        if not _probe_with(source, target).works and all(_probe_with(source, d).works for d in others):
            return source
    return None


@pytest.fixture
def broken_default(monkeypatch):
    """(spec, device, fallback device): a probe source breaks the default device only."""
    order = [(s, d) for s, d, _ in kdevice.working_devices(include_simulators=False)]
    if len(order) < 2:
        pytest.skip("needs two working non-simulator devices")
    (spec, target), (_, fallback) = order[0], order[1]
    source = _breaking_source(target, [d for _, d in order[1:]])
    if source is None:
        pytest.skip(f"no preprocessor condition tells {target.name} from the others")
    monkeypatch.setattr(kdevice, "PROBE_SOURCE", source)
    return spec, target, fallback


def test_default_skips_a_broken_device_and_says_why(broken_default, caplog, capsys):
    spec, target, fallback = broken_default
    caplog.set_level(logging.INFO, logger="kdray.device")
    assert kdevice.choose_device(None) == fallback
    skipped = [r.getMessage() for r in caplog.records if r.getMessage().startswith("skipping")]
    assert any(f"--device {spec} " in m and "broken on purpose" in m for m in skipped), skipped
    code, out, err = run(capsys, "devices")
    assert code == 0, err
    line = next(ln for ln in out.splitlines() if ln.strip().startswith(f"--device {spec} "))
    assert ": fails: the probe kernel does not build: " in line and "broken on purpose" in line


def test_a_broken_device_named_explicitly_is_refused(broken_default, capsys, monkeypatch, tmp_path):
    spec, target, _ = broken_default
    with pytest.raises(DeviceError) as e:
        kdevice.choose_device(spec)
    message = str(e.value)
    assert one_line(message) and target.name.strip() in message and "broken on purpose" in message
    assert kdevice.remedy(target) in message
    monkeypatch.setenv("PYOPENCL_CTX", spec)
    with pytest.raises(DeviceError):
        kdevice.create_context(None)
    from helpers import SCENES
    code, _, err = run(capsys, "render", SCENES / "sphere.obj", "-o", tmp_path / "o.exr",
                       "--device", spec)
    assert code == 1 and one_line(err) and "broken on purpose" in err


def test_a_wrong_answer_is_a_failure():
    spec, device, _ = kdevice.working_devices()[0]
    source = kdevice.PROBE_SOURCE
    result = _probe_with(source.replace("s += (float)k;", "s += (float)k + 1.0f;"), device)
    assert not result.works
    assert result.reason == ("wrong answer from the probe kernel: the loop's sum of work-item 1 "
                             "is 2.0, expected 1.0")
    result = _probe_with(source.replace("atomic_add(&counter[1], i);", ""), device)
    assert "atomic_add's counters are [16, 0], expected [16, 120]" in result.reason
    result = _probe_with(source.replace("kdray_probe", "other"), device)
    assert result.reason.startswith("the probe kernel fails to run: ")
    assert kdevice.probe(device).works


def test_no_working_device_is_one_line_naming_each(monkeypatch, capsys):
    monkeypatch.setattr(kdevice, "PROBE_SOURCE", "#error kdray test: broken everywhere\n")
    with pytest.raises(DeviceError) as e:
        kdevice.choose_device(None)
    message = str(e.value)
    assert one_line(message) and message.startswith("no OpenCL device works: ")
    for spec, device in all_devices():
        if not kdevice.is_simulator(device):
            assert f"(--device {spec}) fails: " in message and kdevice.remedy(device) in message
    code, out, err = run(capsys, "devices")
    assert code == 1 and one_line(err) and "no OpenCL device works" in err
    assert out.count(": fails: ") == len(all_devices()) and "default: none" in out


# ---------------------------------------------------------------- order, names, registration

def fake(platform, type_bits, name="dev"):
    return SimpleNamespace(name=name, type=type_bits, platform=SimpleNamespace(name=platform))


@pytest.mark.parametrize("vendor", ["GenuineIntel", "AuthenticAMD"])
def test_default_order_gpus_cpus_by_runtime_others_simulators_last(monkeypatch, vendor):
    T = cl.device_type
    monkeypatch.setattr(kdevice, "cpu_vendor", lambda: vendor)
    devices = [fake("Oclgrind", T.ALL), fake("Portable Computing Language", T.CPU),
               fake("Some FPGA", T.ACCELERATOR), fake("Intel(R) OpenCL", T.CPU),
               fake("Clover", T.CPU), fake("NVIDIA CUDA", T.GPU)]
    order = [d.platform.name for _, d in kdevice._ordered(list(enumerate(devices)))]
    cpus = (["Intel(R) OpenCL", "Portable Computing Language"] if vendor == "GenuineIntel"
            else ["Portable Computing Language", "Intel(R) OpenCL"])
    assert order == ["NVIDIA CUDA"] + cpus + ["Clover", "Some FPGA", "Oclgrind"]
    assert [kdevice.implementation(d) for d in devices] == [
        "oclgrind", "pocl", "some fpga", "intel", "clover", "nvidia"]
    assert [kdevice.device_kind(d) for d in devices] == [
        "simulator", "CPU", "accelerator", "CPU", "CPU", "GPU"]
    assert "intel-opencl-rt" in kdevice.remedy(devices[1])
    assert kdevice.remedy(fake("Clover", T.CPU)) == kdevice.OTHER_REMEDY


def test_cpu_runtime_order_by_vendor():
    assert kdevice.cpu_runtime_order("GenuineIntel") == ("intel", "pocl")
    for vendor in ("AuthenticAMD", "HygonGenuine", ""):
        assert kdevice.cpu_runtime_order(vendor) == ("pocl", "intel")
    assert kdevice.cpu_runtime_order() == kdevice.cpu_runtime_order(kdevice.cpu_vendor())
    if Path("/proc/cpuinfo").is_file() and "vendor_id" in Path("/proc/cpuinfo").read_text():
        assert kdevice.cpu_vendor() and kdevice.cpu_vendor() in Path("/proc/cpuinfo").read_text()


def test_pocl_compiling_for_a_cpu_without_avx512_on_one_with_it_fails_its_probe():
    """PoCL's LLVM target CPU is read from its version's HSTR; where it names a CPU
    without AVX-512 while the device reports 16-lane floats (PoCL 3.0 on Zen 4 says
    "znver3", and then crashes the process compiling vector code), the probe fails
    without building anything, so that the default device is another one."""
    T = cl.device_type

    def pocl(cpu, native):
        d = fake("Portable Computing Language", T.CPU, name="pthread-AMD EPYC")
        d.version = f"OpenCL 3.0 PoCL HSTR: pthread-x86_64-unknown-linux-gnu-{cpu}"
        d.native_vector_width_float = native
        return d

    assert kdevice.llvm_cpu(pocl("znver3", 16)) == "znver3"
    assert kdevice.llvm_cpu(pocl("skylake-avx512", 16)) == "skylake-avx512"
    assert kdevice.llvm_cpu(pocl("x86-64-v4", 16)) == "x86-64-v4"
    for cpu in ("znver3", "haswell"):
        fault = kdevice.compiler_fault(pocl(cpu, 16))
        assert f"compiles for {cpu}, a CPU without AVX-512" in fault
        assert kdevice._run_probe(pocl(cpu, 16), kdevice.PROBE_SOURCE) == fault
    for cpu in ("skylake-avx512", "znver4", "sapphirerapids", "x86-64-v4"):
        assert kdevice.compiler_fault(pocl(cpu, 16)) == "", cpu
    assert kdevice.compiler_fault(pocl("znver3", 8)) == ""     # an AVX2 CPU
    intel = fake("Intel(R) OpenCL", T.CPU)
    intel.version, intel.native_vector_width_float = "OpenCL 3.0 (Build 0)", 16
    assert kdevice.llvm_cpu(intel) is None and kdevice.compiler_fault(intel) == ""
    odd = pocl("znver3", 16)
    odd.version = "OpenCL 3.0 PoCL"
    assert kdevice.llvm_cpu(odd) is None and kdevice.compiler_fault(odd) == ""


def test_intel_library_paths():
    assert kruntimes.intel_library("/env", windows=False) == Path("/env/lib/libintelocl.so")
    assert kruntimes.intel_library("/env", windows=True) == Path("/env/Library/bin/intelocl64.dll")
    lib = r"C:\env\Library\bin\intelocl64.dll"
    assert kruntimes.windows_icd_filenames(None, lib) == lib
    assert kruntimes.windows_icd_filenames(r"C:\gpu.dll", lib) == rf"C:\gpu.dll;{lib}"
    assert kruntimes.windows_icd_filenames(rf"C:\gpu.dll;{lib};", lib) == rf"C:\gpu.dll;{lib}"


def test_sync_icd_writes_refreshes_and_removes(tmp_path, caplog):
    caplog.set_level(logging.INFO, logger="kdray.runtimes")
    lib = tmp_path / "lib" / "libintelocl.so"
    folder = tmp_path / "libs"
    folder.mkdir()
    icd = folder / kruntimes.ICD_NAME
    assert kruntimes.sync_icd(lib, folder) == "absent" and not icd.exists()
    lib.parent.mkdir()
    lib.write_bytes(b"")
    assert kruntimes.sync_icd(lib, folder) == "written" and icd.read_text() == f"{lib}\n"
    assert kruntimes.sync_icd(lib, folder) == "current"
    icd.write_text("/opt/anaconda1anaconda2anaconda3/lib/libintelocl.so\n")
    assert kruntimes.sync_icd(lib, folder) == "written" and icd.read_text() == f"{lib}\n"
    assert sorted(p.name for p in folder.iterdir()) == [kruntimes.ICD_NAME]   # no temporary left
    lib.unlink()
    assert kruntimes.sync_icd(lib, folder) == "removed" and not icd.exists()
    lib.write_bytes(b"")
    not_a_folder = tmp_path / "file"
    not_a_folder.write_text("")
    assert kruntimes.sync_icd(lib, not_a_folder).startswith("failed: cannot write")
    assert any("is not registered" in r.getMessage() for r in caplog.records)


MAPS = """\
55d0c0a00000-55d0c0a21000 r--p 00000000 08:01 1234  /usr/bin/python3.11
7f10a0000000-7f10a0100000 r-xp 00000000 08:01 2345  /env/lib/python3.11/site-packages/open3d/libtbb.so.12
7f10a0100000-7f10a0200000 r--p 00100000 08:01 2345  /env/lib/python3.11/site-packages/open3d/libtbb.so.12
7f10a0300000-7f10a0400000 r-xp 00000000 08:01 3456  /env/lib/libtbbmalloc.so.2
7f10a0500000-7f10a0600000 r-xp 00000000 08:01 4567  /env/lib/libtbb.so.12
7f10a0700000-7f10a0701000 rw-p 00000000 00:00 0
7ffd5e1f0000-7ffd5e211000 rw-p 00000000 00:00 0     [stack]
7f10a0800000-7f10a0900000 r-xp 00000000 08:01 5678  /tmp/a dir/libtbb_debug.so.12.20 (deleted)
"""


def test_tbb_maps_parsing():
    assert kruntimes.loaded_tbbs(MAPS) == ["/env/lib/python3.11/site-packages/open3d/libtbb.so.12",
                                         "/env/lib/libtbb.so.12", "/tmp/a dir/libtbb_debug.so.12.20"]
    assert kruntimes.foreign_tbb(MAPS, "/env/lib") == "/env/lib/python3.11/site-packages/open3d/libtbb.so.12"
    own = "".join(ln + "\n" for ln in MAPS.splitlines() if "open3d" not in ln and "tmp" not in ln)
    assert kruntimes.foreign_tbb(own, "/env/lib") is None
    assert kruntimes.loaded_tbbs("") == [] and kruntimes.foreign_tbb("", "/env/lib") is None


def test_reasons_for_a_missing_intel_platform(tmp_path, monkeypatch):
    import _ctypes
    broken = tmp_path / "lib" / "libintelocl.so"
    broken.parent.mkdir()
    broken.write_bytes(b"not a shared object")
    lib = Path(_ctypes.__file__)                  # a shared object that loads
    folder = tmp_path / "libs"
    folder.mkdir()
    monkeypatch.delenv("OCL_ICD_VENDORS", raising=False)
    monkeypatch.setattr(kruntimes, "_own_maps", lambda: MAPS)
    assert kruntimes._intel_missing_reason(broken) == (
        "Intel's CPU runtime is installed but cannot load: /env/lib/python3.11/site-packages/"
        "open3d/libtbb.so.12 was loaded first (Open3D bundles an older TBB); import kdray "
        "before open3d")
    monkeypatch.setattr(kruntimes, "_own_maps", lambda: "")
    reason = kruntimes._intel_missing_reason(broken)                  # dlopen's own words
    assert reason.startswith("Intel's CPU runtime is installed but cannot load: ") and \
        str(broken) in reason
    monkeypatch.setenv("OCL_ICD_VENDORS", "/somewhere")
    assert "OCL_ICD_VENDORS is set" in kruntimes._intel_missing_reason(lib)
    monkeypatch.delenv("OCL_ICD_VENDORS")
    monkeypatch.setattr(kruntimes, "_icd_folder", lambda: None)
    assert "system's OpenCL loader" in kruntimes._intel_missing_reason(lib)
    monkeypatch.setattr(kruntimes, "_icd_folder", lambda: folder)
    assert "kdray could not write" in kruntimes._intel_missing_reason(lib)
    (folder / kruntimes.ICD_NAME).write_text(f"{lib}\n")
    monkeypatch.setattr(kruntimes, "_process_start", lambda: 0.0)
    assert "listed before kdray registered it" in kruntimes._intel_missing_reason(lib)
    monkeypatch.setattr(kruntimes, "_process_start", lambda: 4e9)
    assert "OCL_ICD_DEBUG=15" in kruntimes._intel_missing_reason(lib)


# ---------------------------------------------------------------- fresh processes
# (Open3D and kdray in one process, in either order: tests/test_import_order.py)

def _python(code, *args, **env):
    """(exit code, stdout, stderr) of a fresh `python -c code args...` in the repository,
    in this environment without the runtimes' thread-binding variables (this process's
    kdray set them; the child's sets its own) and with `env` added."""
    names = set(kruntimes.INTEL_AFFINITY_NAMES) | set(kruntimes.POCL_AFFINITY)
    clean = {k: v for k, v in os.environ.items() if k not in names}
    proc = subprocess.run([sys.executable, "-c", textwrap.dedent(code), *args],
                          capture_output=True, text=True, cwd=ROOT, timeout=120,
                          env=dict(clean, **env))
    return proc.returncode, proc.stdout, proc.stderr


# ---------------------------------------------------------------- the runtimes' worker threads

def test_thread_binding_defaults_give_way_to_the_callers():
    both = {**kruntimes.INTEL_AFFINITY, **kruntimes.POCL_AFFINITY}
    assert kruntimes.thread_binding({}) == both
    assert kruntimes.thread_binding({"PATH": "/bin"}) == {
        "DPCPP_CPU_CU_AFFINITY": "close", "DPCPP_CPU_PLACES": "cores", "POCL_AFFINITY": "1"}
    for name in kruntimes.INTEL_AFFINITY_NAMES:
        assert kruntimes.thread_binding({name: "spread"}) == kruntimes.POCL_AFFINITY
    assert kruntimes.thread_binding({"POCL_AFFINITY": "0"}) == kruntimes.INTEL_AFFINITY
    assert kruntimes.thread_binding({"KDRAY_BIND_THREADS": "0"}) == {}
    assert kruntimes.thread_binding({"KDRAY_BIND_THREADS": "1"}) == both


AFFINITY_AFTER_A_TRACER = """
    import os, sys
    import kdray
    mesh = kdray.load("scenes/sphere.obj")
    tree = kdray.build(mesh.vertices, mesh.faces)
    before = os.sched_getaffinity(0)
    tracer = kdray.Tracer(tree, device=sys.argv[1])
    camera = kdray.Camera.look_at((0, 0, 3), (0, 0, 0), width=64, height=64)
    hit = int((tracer.render(camera, aovs=("id",))["id"] != 0xFFFFFFFF).sum())
    bound = [t for t in os.listdir("/proc/self/task")
             if len(os.sched_getaffinity(int(t))) == 1]
    print(os.environ.get("DPCPP_CPU_CU_AFFINITY"), os.environ.get("POCL_AFFINITY"),
          sorted(before) == sorted(os.sched_getaffinity(0)), hit > 0, len(bound) > 0)
"""
# (without the variables Intel's runtime 2026.2 binds its worker thread in some processes
# and not in others; PoCL binds none)

several_cpus = hasattr(os, "sched_getaffinity") and len(os.sched_getaffinity(0)) >= 2


def _working(impl):
    """Whether a device of implementation `impl` ("intel", "pocl") works here."""
    return any(kdevice.implementation(d) == impl and kdevice.probe(d).works
               for _, d in all_devices())


@pytest.mark.parametrize("impl", ["intel", "pocl"])
def test_a_tracer_binds_the_workers_and_leaves_the_callers_thread_free(impl):
    if not several_cpus or not _working(impl):
        pytest.skip(f"needs a working {impl} device and 2 or more CPUs")
    # a fresh process: Intel's runtime binds the thread that creates its first context
    code, out, err = _python(AFFINITY_AFTER_A_TRACER, impl)
    assert code == 0, err
    assert out.split() == ["close", "1", "True", "True", "True"], out


@pytest.mark.parametrize("impl", ["intel", "pocl"])
def test_kdray_bind_threads_0_sets_no_variable(impl):
    if not several_cpus or not _working(impl):
        pytest.skip(f"needs a working {impl} device and 2 or more CPUs")
    code, out, err = _python(AFFINITY_AFTER_A_TRACER, impl, KDRAY_BIND_THREADS="0")
    assert code == 0, err
    words = out.split()
    assert words[:4] == ["None", "None", "True", "True"], out
    if impl == "pocl":
        assert words[4] == "False", out


def test_device_specs_of_other_digits_are_one_line(capsys):
    """A --device or PYOPENCL_CTX part that Python's isdigit() takes but int() refuses
    ("²") is a name that matches nothing: one line, no traceback."""
    for spec in ("²", "2:²", "١"):
        with pytest.raises(DeviceError, match="no OpenCL platform matches|no OpenCL device"):
            kdevice.choose_device(spec)
