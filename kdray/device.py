"""Choosing an OpenCL device and building kdray's programs.

    context, device = create_context("0:1")      # PYOPENCL_CTX syntax; None = the best working device
    program = build_program(context, "render.cl", {"STACK_SIZE": 24, "OUT_UV": None})
    for line in list_devices(): print(line)      # every device, probed, and the default

Programs are plain OpenCL C in the repository's `kernels/` folder, built with real
`#include`s (`-I kernels/`) and `-D` options. Nothing here keeps module-level OpenCL
objects: a `Tracer` owns its context and queue and caches the programs it builds.
pyopencl is imported inside the functions, so the rest of kdray imports without it.

Devices are probed, never trusted: a device can be listed and still be unable to build
programs (PoCL 3.0 on AMD Zen 5: "unknown target CPU 'generic'"), or crash the process
on some programs, which no probe can catch (PoCL 3.0 on Zen 4: `compiler_fault`, checked
first). `probe` builds and runs a small kernel that uses what kdray's kernels use and
checks its answer. The default device is the first that works of: GPUs, then CPU
runtimes in the order CPU_RUNTIME_ORDER gives for this machine's CPU vendor, then
anything else. Simulators (SIMULATORS: Oclgrind reports every device type, so it looks
like a GPU) are never the default; they can be chosen by name. The probes' results are
kept for the life of the process in `_PROBES`, keyed by the device's identity, and the
CPU's vendor once read (`cpu_vendor`): the process-wide state of this module.

Runtimes installed with pip (Intel's CPU runtime) are made visible to pyopencl's loader
by `kdray.runtimes`, before the first listing of platforms.

Build options never relax IEEE arithmetic (no fast or finite-only math): the
traversal relies on IEEE infinities, NaN and signed zeros. Where the device offers it,
-cl-fp32-correctly-rounded-divide-sqrt makes single-precision division exact, so a
device gives the same t, u, v as any other that rounds correctly.

Compiled programs are cached on disk by the OpenCL driver, not here: PoCL keeps them
in POCL_CACHE_DIR (default ~/.cache/pocl/kcache; POCL_KERNEL_CACHE=0 turns it off),
keyed by the preprocessed source (the `#include`d files too) and the options, with
the code it compiles at a kernel's first launch beside them; NVIDIA's driver keeps
its own; pyopencl's binary cache serves the drivers that have none. Some drivers'
caches hash the top-level source and options but not the `#include`d files, so every
build passes `-DKDRAY_KERNELS=<hash of every file in kernels/>`: a cache keyed by the
options can never serve a program built from other kernels.
"""
import contextlib
import functools
import hashlib
import logging
import os
import platform
import re
import tempfile
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

from .errors import DeviceError, KernelBuildError, one_line
from .runtimes import register_runtimes, unavailable_runtimes

log = logging.getLogger(__name__)

KERNEL_DIR = Path(__file__).resolve().parent / "kernels"
"""The OpenCL sources: the top-level `kernels/` folder, linked into the package as
`kdray/kernels` so that a wheel (package data) carries it too."""

SIMULATORS = ("Oclgrind",)
"""Substrings of the names of platforms that simulate a device for debugging: never the
default device, chosen only by name (`--device oclgrind`)."""

CPU_RUNTIME_ORDER = {"GenuineIntel": ("intel", "pocl"), "": ("pocl", "intel")}
"""CPU runtimes by preference, as `implementation` names, by the vendor of this machine's
CPU (`cpu_vendor`; "" for any other); CPUs of other runtimes come after these. The
order is what was measured where both work (BENCHMARKS.md): on Intel's CPUs Intel's
runtime renders, traces, sets up and compiles programs faster; on AMD's (Zen 4) PoCL
traced and compiled faster. Where PoCL 3.0 cannot start (CPUs newer than its LLVM 14)
or would crash (`compiler_fault`: Zen 4 with AVX-512) its probe fails and Intel's runtime
is the default whatever the order."""


@functools.lru_cache(maxsize=None)
def cpu_vendor():
    """This machine's CPU vendor as the CPU names itself ("GenuineIntel", "AuthenticAMD",
    ...: `vendor_id` of /proc/cpuinfo on Linux, the processor string elsewhere, as on
    Windows), "" when neither says. Read once per process."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as f:
            for line in f:
                if line.startswith("vendor_id"):
                    return line.partition(":")[2].strip()
        return ""
    except OSError:
        words = platform.processor().replace(",", " ").split()
        return next((w for w in words if w in ("GenuineIntel", "AuthenticAMD")), "")


def cpu_runtime_order(vendor=None):
    """The CPU runtimes' default order (a tuple of `implementation` names) on a CPU of
    `vendor` (None: this machine's, `cpu_vendor`): CPU_RUNTIME_ORDER's entry."""
    vendor = cpu_vendor() if vendor is None else vendor
    return CPU_RUNTIME_ORDER.get(vendor, CPU_RUNTIME_ORDER[""])

REMEDIES = {
    "pocl": "pip install intel-opencl-rt intel-cmplr-lib-rt (Intel's CPU runtime runs on any "
            "x86-64 CPU) or a newer PoCL (e.g. Debian's pocl-opencl-icd)",
    "intel": "pip install --force-reinstall intel-opencl-rt intel-cmplr-lib-rt, or use PoCL "
             "(pip install pocl-binary-distribution)",
    "oclgrind": "Oclgrind is a simulator for debugging; choose another device",
    "nvidia": "update the NVIDIA driver",
    "amd": "update the AMD GPU driver (ROCm)",
    "apple": "update macOS",
}
"""What to do when an implementation's device fails its probe, by `implementation` name."""

OTHER_REMEDY = "update or reinstall the device's OpenCL driver"

_NO_PLATFORM = ("no OpenCL platform found: `pip install pocl-binary-distribution` for a "
                "CPU device, or install your GPU's OpenCL driver")

# (implementation name, words of a platform's name, lower case); the first match wins
_IMPLEMENTATIONS = (
    ("pocl", ("portable computing language", "pocl")),
    ("oclgrind", ("oclgrind",)),
    ("intel", ("intel",)),
    ("nvidia", ("nvidia",)),
    ("amd", ("amd", "advanced micro devices")),
    ("apple", ("apple",)),
)


def _cl():
    try:
        import pyopencl
    except ImportError as e:  # pragma: no cover - pyopencl is a dependency
        raise DeviceError(f"pyopencl is not installed ({e}): `pip install pyopencl "
                          f"pocl-binary-distribution`") from None
    return pyopencl


# ---------------------------------------------------------------- platforms and devices

def _platforms():
    register_runtimes()
    cl = _cl()
    try:
        platforms = cl.get_platforms()
    except cl.Error:
        platforms = []
    if not platforms:
        raise DeviceError("; ".join([_NO_PLATFORM] + [f"{name}: {reason}"
                                                      for name, reason in unavailable_runtimes([])]))
    return platforms


def _devices(platform):
    cl = _cl()
    try:
        return platform.get_devices()
    except cl.Error:
        return []


def _entries(platforms):
    """[("i:j", device)] of every device of every platform, in the loader's order."""
    return [(f"{i}:{j}", d) for i, p in enumerate(platforms) for j, d in enumerate(_devices(p))]


def implementation(device):
    """Short name of a device's OpenCL implementation, from its platform's name: "pocl",
    "intel", "oclgrind", "nvidia", "amd", "apple", else the platform's name in lower case.
    device : pyopencl Device (or Platform)."""
    platform = getattr(device, "platform", device)
    name = platform.name.strip().lower()
    for short, words in _IMPLEMENTATIONS:
        if any(w in name for w in words):
            return short
    return name


def is_simulator(device):
    """Whether the device's platform simulates devices for debugging (SIMULATORS)."""
    name = getattr(device, "platform", device).name.lower()
    return any(s.lower() in name for s in SIMULATORS)


def device_kind(device):
    """"simulator", "GPU", "CPU", "accelerator" or "other"."""
    cl = _cl()
    if is_simulator(device):
        return "simulator"
    for bit, kind in ((cl.device_type.GPU, "GPU"), (cl.device_type.CPU, "CPU"),
                      (cl.device_type.ACCELERATOR, "accelerator")):
        if device.type & bit:
            return kind
    return "other"


AVX512_CPUS = ("knl", "knm", "skylake-avx512", "skx", "cascadelake", "cooperlake", "cannonlake",
               "icelake-client", "icelake-server", "tigerlake", "rocketlake", "sapphirerapids",
               "emeraldrapids", "graniterapids", "graniterapids-d", "diamondrapids", "znver4",
               "znver5", "x86-64-v4")
"""LLVM's names of the x86 CPUs with AVX-512 (its X86 target), for `compiler_fault`."""


def llvm_cpu(device):
    """The CPU a PoCL device compiles for, as LLVM names it ("znver3", "skylake-avx512"),
    read from the HSTR of its version string ("... HSTR: pthread-x86_64-unknown-linux-gnu-
    znver3"); None for other implementations, or when the version does not say."""
    if implementation(device) != "pocl":
        return None
    m = re.search(r"HSTR:\s*\S*?(?:x86_64|i[3-6]86)-[^-\s]+-[^-\s]+-[^-\s]+-(\S+)",
                  device.version)
    return m.group(1) if m else None


def compiler_fault(device):
    """Why `device`'s compiler is known to crash on kdray's kernels, one line, or "".

    PoCL whose LLVM compiles for a CPU it does not know to have AVX-512 (`llvm_cpu` not
    in AVX512_CPUS) on a CPU that has it (native_vector_width_float 16): PoCL 3.0
    (LLVM 14) names Zen 4 "znver3" and then crashes the process compiling vector code,
    any float16 and packets of 8 with STATS among it (SIGSEGV, or LLVM's "Cannot
    select"; tests/repros/pocl_zen4_float16.py). A crash cannot be caught, so the probe
    cannot find this by running code.
    """
    cpu = llvm_cpu(device)
    native = int(getattr(device, "native_vector_width_float", 0) or 0)
    if cpu is not None and native >= 16 and cpu not in AVX512_CPUS:
        return (f"its LLVM compiles for {cpu}, a CPU without AVX-512, on this CPU with it, "
                f"and then crashes on vector code")
    return ""


def remedy(device):
    """What to do when `device` fails its probe: one phrase from REMEDIES."""
    return REMEDIES.get(implementation(device), OTHER_REMEDY)


def _rank(device):
    """Sort key of the default order: GPUs, CPU runtimes by `cpu_runtime_order`, the rest,
    simulators last."""
    kind = device_kind(device)
    if kind == "GPU":
        return (0, 0)
    if kind == "CPU":
        impl = implementation(device)
        order = cpu_runtime_order() + (impl,)
        return (1, order.index(impl))
    return (3, 0) if kind == "simulator" else (2, 0)


def _ordered(entries):
    return sorted(entries, key=lambda entry: _rank(entry[1]))   # stable: the loader's order next


# ---------------------------------------------------------------- the probe

@dataclass(frozen=True)
class Probe:
    """What `probe` found: works (bool), reason (str, one line; "" when it works), seconds
    (float: the probe's time, the program's build included)."""
    works: bool
    reason: str
    seconds: float


PROBE_SOURCE = r"""/* kdray's device probe: what kdray's kernels need, with an answer checked exactly */
#ifdef KDRAY_PROBE_FP64
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
#endif
__kernel void kdray_probe(__global const float *xyz, __global float *out,
                          volatile __global uint *counter, __local float *tile)
{
    uint i = (uint)get_global_id(0), l = (uint)get_local_id(0), n = (uint)get_local_size(0);
    float3 p = vload3(i, xyz);                     /* (3i, 3i + 1, 3i + 2) */
    float s = 0.0f;
    for (uint k = 1u; k <= i; k++)                 /* i (i + 1) / 2 */
        s += (float)k;
    tile[l] = p.x + p.y + p.z;                     /* 9i + 3 */
    barrier(CLK_LOCAL_MEM_FENCE);
    float next = tile[(l + 1u) % n];               /* the next work-item's, in the group */
    atomic_add(&counter[0], 1u);
    atomic_add(&counter[1], i);
#ifdef KDRAY_PROBE_FP64
    float half_s = (float)((double)s * 0.5 + (double)p.z);
#else
    float half_s = s * 0.5f + p.z;
#endif
    vstore4((float4)(s, next, tile[l] / (p.y - p.x + 2.0f), half_s), i, out);   /* (9i+3)/3 */
}
"""
"""The probe's OpenCL C: kernel `kdray_probe` (see `probe`). A test may replace it; the
probes are cached per source."""

_PROBE_ITEMS = 16
_PROBE_COLUMNS = ("the loop's sum", "__local memory after a barrier", "a division",
                  "a double conversion")

_PROBES = {}
"""Process-wide cache of `probe` results: (platform name, device name, driver version,
int_ptr, hash of PROBE_SOURCE) -> Probe. Devices do not change while a process runs."""


def probe(device):
    """Build and run a small kernel on `device` (a float3 vload, a loop, a barrier over
    __local memory, atomic_add on a global counter, a float division, a double
    conversion where the device has cl_khr_fp64) and check its answer exactly.

    Returns a Probe; never raises for a broken device (build failures give the build
    log's first error line). Cached per process (`_PROBES`); the first probe of a device
    includes the program's build.
    """
    source = PROBE_SOURCE
    try:
        key = (device.platform.name.strip(), device.name.strip(), device.driver_version.strip(),
               int(device.int_ptr), hashlib.sha256(source.encode()).hexdigest())
    except Exception as e:     # a device that cannot even be queried
        return Probe(False, one_line(f"cannot query the device: {e}"), 0.0)
    result = _PROBES.get(key)
    if result is None:
        t0 = time.perf_counter()
        try:
            reason = _run_probe(device, source)
        except Exception as e:  # any failure of a driver is the device's, not the caller's
            reason = one_line(f"{type(e).__name__}: {e}")
        result = _PROBES[key] = Probe(not reason, reason, time.perf_counter() - t0)
        log.debug("probe of %s: %s (%.3f s)", device.name.strip(), reason or "works", result.seconds)
    return result


def _run_probe(device, source):
    """"" when the probe kernel gives the right answer on `device`, else why not (one line)."""
    import numpy as np
    fault = compiler_fault(device)
    if fault:
        return fault
    cl = _cl()
    n = _PROBE_ITEMS
    group = 1
    while group < 8 and group * 2 <= int(device.max_work_group_size):
        group *= 2
    try:
        context = new_context(device)
        queue = cl.CommandQueue(context)
    except cl.Error as e:
        return one_line(f"cannot create a context and queue: {e}")
    options = _precision_options(device) + (["-DKDRAY_PROBE_FP64"] if has_fp64(device) else [])
    try:
        program = _build(cl.Program(context, source), options)
    except cl.Error as e:           # pyopencl's message holds the build log
        return "the probe kernel does not build: " + _first_error(str(e), e)
    xyz = np.arange(3 * n, dtype=np.float32)
    out = np.zeros(4 * n, dtype=np.float32)
    counter = np.zeros(2, dtype=np.uint32)
    mf = cl.mem_flags
    try:
        xyz_buf = cl.Buffer(context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=xyz)
        out_buf = cl.Buffer(context, mf.WRITE_ONLY, out.nbytes)
        counter_buf = cl.Buffer(context, mf.READ_WRITE | mf.COPY_HOST_PTR, hostbuf=counter)
        kernel = cl.Kernel(program, "kdray_probe")
        kernel(queue, (n,), (group,), xyz_buf, out_buf, counter_buf, cl.LocalMemory(4 * group))
        cl.enqueue_copy(queue, out, out_buf)
        cl.enqueue_copy(queue, counter, counter_buf)
        queue.finish()
    except cl.Error as e:
        return one_line(f"the probe kernel fails to run: {e}")
    want_out, want_counter = _probe_answer(n, group)
    got = out.reshape(n, 4)
    columns = _PROBE_COLUMNS if has_fp64(device) else _PROBE_COLUMNS[:3] + ("float arithmetic",)
    for c, what in enumerate(columns):
        bad = got[:, c] != want_out[:, c]
        if c == 2 and not _exact_division(device):
            # without correctly rounded division OpenCL allows 2.5 ulp
            ulp = np.spacing(want_out[:, c])
            bad = ~(np.abs(got[:, c] - want_out[:, c]) <= 2.5 * ulp)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            return (f"wrong answer from the probe kernel: {what} of work-item {i} is "
                    f"{float(got[i, c])!r}, expected {float(want_out[i, c])!r}")
    if not np.array_equal(counter, want_counter):
        return (f"wrong answer from the probe kernel: atomic_add's counters are "
                f"{counter.tolist()}, expected {want_counter.tolist()}")
    return ""


def _probe_answer(n, group):
    """The probe kernel's right answer for n work-items in groups of `group`: out (n, 4)
    float32 and the counters (2,) uint32."""
    import numpy as np
    i = np.arange(n, dtype=np.int64)
    s = i * (i + 1) // 2
    nxt = i // group * group + (i % group + 1) % group
    out = np.stack([s, 9 * nxt + 3, 3 * i + 1, s / 2 + 3 * i + 2], axis=1).astype(np.float32)
    return out, np.array([n, n * (n - 1) // 2], dtype=np.uint32)


def _build_log(program, device):
    cl = _cl()
    try:
        return program.get_build_info(device, cl.program_build_info.LOG) or ""
    except Exception:
        return ""


def _first_error(build_log, error):
    """The first line of a build log that names an error, else its first line, else the
    exception's text."""
    lines = [ln.strip() for ln in (build_log or "").splitlines() if ln.strip()]
    return next((ln for ln in lines if "error" in ln.lower()), lines[0] if lines else one_line(error))


# ---------------------------------------------------------------- choosing

def _pick(items, key, what, names, aliases=None):
    """One of `items` by index ("1"), by a case-insensitive substring of its name, or by
    one of its `aliases` (equal, case-insensitive)."""
    key = key.strip()
    if key.isascii() and key.isdigit():        # not "²", whose isdigit() int() refuses
        i = int(key)
        if i >= len(items):
            raise DeviceError(f"no OpenCL {what} {i} (there are {len(items)}: "
                              f"{'; '.join(names) or 'none'})")
        return items[i]
    for item, name in zip(items, names):
        if key.lower() in name.lower():
            return item
    for item, alias in zip(items, aliases or ()):
        if key.lower() == alias.lower():
            return item
    raise DeviceError(f"no OpenCL {what} matches {key!r} (there are: {'; '.join(names) or 'none'})")


def _pick_spec(platforms, spec):
    """("i:j", device) for a PYOPENCL_CTX-style spec."""
    plat_key, _, dev_key = str(spec).partition(":")
    names = [p.name.strip() for p in platforms]
    try:
        platform = _pick(platforms, plat_key, "platform", names,
                         [implementation(p) for p in platforms])
    except DeviceError as e:
        missing = [f"{name}: {reason}" for name, reason in unavailable_runtimes(platforms)]
        raise DeviceError("; ".join([str(e)] + missing)) from None
    i = platforms.index(platform)
    devices = _devices(platform)
    if not devices:
        raise DeviceError(f"OpenCL platform {platform.name!r} has no devices")
    device = devices[0] if dev_key.strip() == "" else \
        _pick(devices, dev_key, "device", [d.name.strip() for d in devices])
    return f"{i}:{devices.index(device)}", device


def choose_device(spec=None):
    """The OpenCL device for `spec`, probed (see `probe`).

    spec : None, or a PYOPENCL_CTX-style string "PLATFORM[:DEVICE]", each part an index,
        a case-insensitive substring of the name, or for a platform its `implementation`
        name ("0", "0:1", "nvidia", "pocl", "oclgrind", "portable:0").
        None reads the PYOPENCL_CTX environment variable; unset or "" takes the first
        device that works in the default order (GPUs, CPU runtimes by cpu_runtime_order,
        the rest; never a simulator), logging at INFO why each one before it was skipped.
        Never prompts.
    Raises DeviceError when no platform or no matching device exists, when the device
    named by spec fails its probe (never a silent switch to another device), or when no
    device works: one line naming each device's failure and its remedy.
    """
    if spec is not None and not isinstance(spec, str):
        raise DeviceError(f"the device must be None or a --device string such as \"0:1\", "
                          f"got {spec!r:.60}")
    platforms = _platforms()
    if spec is None:
        spec = os.environ.get("PYOPENCL_CTX")
    if spec is None or str(spec).strip() == "":
        return _default_device(platforms)
    index, device = _pick_spec(platforms, spec)
    result = probe(device)
    if not result.works:
        raise DeviceError(f"OpenCL device {describe(device)} (--device {index}) does not work: "
                          f"{result.reason} (to fix: {remedy(device)})")
    return device


def _default_device(platforms):
    entries = _entries(platforms)
    missing = [f"{name}: {reason}" for name, reason in unavailable_runtimes(platforms)]
    for text in missing:
        log.info("not available: %s", text)
    failures, simulators = [], []
    for index, device in _ordered(entries):
        if is_simulator(device):
            simulators.append(f"{device.name.strip()} (--device {index})")
            log.info("not a default device: --device %s %s (a simulator for debugging)", index,
                     describe(device))
            continue
        result = probe(device)
        if result.works:
            return device
        log.info("skipping --device %s %s: %s", index, describe(device), result.reason)
        failures.append(f"{describe(device)} (--device {index}) fails: {result.reason} "
                        f"(to fix: {remedy(device)})")
    get_one = _NO_PLATFORM.partition(": ")[2]
    if not entries:
        raise DeviceError("; ".join([f"no OpenCL device found: {get_one}"] + missing))
    notes = [f"{', '.join(simulators)}: a simulator for debugging, used only when chosen with "
             f"--device"] if simulators else []
    if not failures:
        notes.append(get_one)
    raise DeviceError("no OpenCL device works: " + "; ".join(failures + missing + notes))


def working_devices(include_simulators=True):
    """[(spec "i:j", device, implementation name)] of every device whose probe works, in
    the default order (simulators last, or left out)."""
    found = []
    for index, device in _ordered(_entries(_platforms())):
        if (include_simulators or not is_simulator(device)) and probe(device).works:
            found.append((index, device, implementation(device)))
    return found


def new_context(device):
    """cl.Context([device]), the calling thread's CPU affinity kept: Intel's CPU runtime,
    which kdray asks to bind its worker threads (runtimes.thread_binding), binds the
    thread that creates the process's first context to one core too. Raises cl.Error."""
    cl = _cl()
    before = _thread_affinity()
    try:
        return cl.Context([device])
    finally:
        if before is not None and _thread_affinity() != before:
            os.sched_setaffinity(0, before)
            log.debug("restored this thread's CPU affinity after creating a context on %s",
                      device.name.strip())


def _thread_affinity():
    """The calling thread's CPUs (os.sched_getaffinity(0)), or None where unknown."""
    try:
        return os.sched_getaffinity(0)
    except (AttributeError, OSError):
        return None


def create_context(spec=None):
    """(context, device) for `spec` (see `choose_device`)."""
    cl = _cl()
    device = choose_device(spec)
    try:
        context = new_context(device)
    except cl.Error as e:
        raise DeviceError(f"cannot create an OpenCL context on {device.name!r}: {e}") from None
    log.info("OpenCL device: %s (%s)", device.name.strip(), device.platform.name.strip())
    return context, device


def describe(device):
    """One line naming a device: 'NAME (PLATFORM, OpenCL x.y, N compute units)'."""
    return (f"{device.name.strip()} ({device.platform.name.strip()}, "
            f"{device.version.strip()}, {device.max_compute_units} compute units)")


# ---------------------------------------------------------------- the table of `kdray devices`

@dataclass(frozen=True)
class DeviceEntry:
    """One device of `device_table`: spec ("i:j", for --device), device (pyopencl Device),
    implementation, kind (`device_kind`), description (`describe`), probe (Probe)."""
    spec: str
    device: object
    implementation: str
    kind: str
    description: str
    probe: Probe


@dataclass(frozen=True)
class DeviceTable:
    """What `device_table` found: platforms (tuple of (index, name, version, tuple of
    DeviceEntry)), unavailable (tuple of (name, reason): installed runtimes whose platform
    is missing), default (the DeviceEntry `choose_device(None)` picks, or None), error
    (why there is no default, "" when there is one)."""
    platforms: tuple
    unavailable: tuple
    default: object
    error: str

    def lines(self):
        """The table as plain text lines, one per platform, device and missing runtime."""
        out = []
        for i, name, version, entries in self.platforms:
            out.append(f"platform {i}: {name} ({version})")
            for e in entries:
                state = (f"works (probe {e.probe.seconds:.2f} s)" if e.probe.works
                         else f"fails: {e.probe.reason}")
                out.append(f"  --device {e.spec}  {e.kind:<11}  {e.description}: {state}")
        for name, reason in self.unavailable:
            out.append(f"not loaded: {name}: {reason}")
        if self.default is not None:
            source = " (PYOPENCL_CTX)" if os.environ.get("PYOPENCL_CTX", "").strip() else ""
            out.append(f"default{source}: --device {self.default.spec}  {self.default.description}")
        else:
            out.append(f"default: none ({self.error})")
        return out


def device_table():
    """Every platform and device, each probed, the installed runtimes that did not load, and
    the default device: a DeviceTable. Raises DeviceError only when there is no platform."""
    platforms = _platforms()
    rows, everything = [], []
    for i, cl_platform in enumerate(platforms):
        entries = []
        for j, device in enumerate(_devices(cl_platform)):
            entries.append(DeviceEntry(f"{i}:{j}", device, implementation(device),
                                       device_kind(device), describe(device), probe(device)))
        everything += entries
        rows.append((i, cl_platform.name.strip(), cl_platform.version.strip(), tuple(entries)))
    default, error = None, ""
    try:
        chosen = choose_device(None)
    except DeviceError as e:
        error = str(e)
    else:
        default = next((e for e in everything if e.device == chosen), None)
    return DeviceTable(tuple(rows), tuple(unavailable_runtimes(platforms)), default, error)


def list_devices():
    """Lines describing every platform and device (with its --device string, kind and
    whether it works), the installed runtimes that did not load, and the default."""
    return device_table().lines()


# ---------------------------------------------------------------- programs

def is_cpu(device):
    """Whether kdray treats the device as a CPU (packets, zero-copy buffers, CPU work
    sizes): its `device_kind` is "CPU". A simulator is not one, although Oclgrind
    reports every device type: it runs the GPU path, which its checks are for."""
    return device_kind(device) == "CPU"


def has_fp64(device):
    return "cl_khr_fp64" in device.extensions.split()


def kernels_hash(folder=None):
    """The first 16 hex digits of the SHA-256 of every file in `folder` (default
    KERNEL_DIR): names and contents, in name order. Raises DeviceError when the folder
    cannot be read."""
    folder = Path(KERNEL_DIR if folder is None else folder)
    digest = hashlib.sha256()
    try:
        for path in sorted(folder.iterdir()):
            if path.is_file():
                data = path.read_bytes()
                digest.update(f"{path.name}\0{len(data)}\0".encode())
                digest.update(data)
    except OSError as e:
        raise DeviceError(f"kernel folder {folder} cannot be read ({e.strerror or e}); "
                          f"kdray's kernels/ folder must sit beside the kdray package") from None
    return digest.hexdigest()[:16]


def build_options(device, defines):
    """-I, -D and precision options for `device`, with -DKDRAY_KERNELS=kernels_hash().

    defines : dict name -> value, or None for a bare `-D NAME`.
    """
    options = ["-I", str(KERNEL_DIR), f"-DKDRAY_KERNELS={kernels_hash()}"]
    for name, value in sorted(defines.items()):
        options.append(f"-D{name}" if value is None else f"-D{name}={value}")
    return options + _precision_options(device)


def _exact_division(device):
    """Whether the device can divide and take square roots correctly rounded (float)."""
    cl = _cl()
    try:
        return bool(device.single_fp_config & cl.device_fp_config.CORRECTLY_ROUNDED_DIVIDE_SQRT)
    except cl.Error:
        return False


def _precision_options(device):
    return ["-cl-fp32-correctly-rounded-divide-sqrt"] if _exact_division(device) else []


def build_program(context, source_name, defines=None):
    """Build `kernels/<source_name>` for the context's devices.

    Raises KernelBuildError (with the compiler's log in `.log`) when it does not build.
    """
    cl = _cl()
    path = KERNEL_DIR / source_name
    try:
        source = path.read_text(encoding="utf-8")
    except OSError as e:
        raise DeviceError(f"kernel source {path} cannot be read ({e.strerror or e}); "
                          f"kdray's kernels/ folder must sit beside the kdray package") from None
    device = context.devices[0]
    options = build_options(device, defines or {})
    program = cl.Program(context, source)
    try:
        program = _build(program, options)
    except cl.Error as e:
        build_log = _build_log(program, device) or str(e)
        first = _first_error(build_log, e)
        raise KernelBuildError(
            f"OpenCL program {source_name} failed to build on {device.name.strip()} "
            f"(options: {' '.join(options)}): {first}", log=build_log) from None
    # A corrupt entry in the driver's cache builds "successfully" into a program without
    # kernels (seen with PoCL 3.0: creating a kernel then fails, and the process aborts
    # when it exits); say what to remove instead.
    if "__kernel" in source and program.get_info(cl.program_info.NUM_KERNELS) == 0:
        raise KernelBuildError(
            f"OpenCL program {source_name} built on {device.name.strip()} without its kernels: "
            f"the driver's compiler cache is probably corrupt; remove it ({_driver_cache(device)}) "
            f"and run again")
    return program


def _build(program, options):
    """program.build(options) (a pyopencl Program), without the harmless notes PoCL and
    some drivers print; on failure removes the copy of the source pyopencl saves in the
    temporary folder for drivers without a compiler cache (of no use here; the error
    holds the build log) and raises the cl.Error."""
    cl = _cl()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", cl.CompilerWarning)
            return program.build(options=options)
    except cl.Error as e:
        saved = re.search(r"\(source saved as (.+?\.cl)\)", str(e))
        if saved and os.path.dirname(saved.group(1)) == tempfile.gettempdir():
            with contextlib.suppress(OSError):
                os.remove(saved.group(1))
        raise


def _driver_cache(device):
    """Where the device's driver keeps compiled programs, in words."""
    if "portable computing language" in device.platform.name.lower():
        xdg = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
        return os.environ.get("POCL_CACHE_DIR") or os.path.join(xdg, "pocl", "kcache")
    return "see the OpenCL driver's documentation"
