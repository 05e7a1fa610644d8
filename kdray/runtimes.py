"""The OpenCL runtimes installed in this environment with pip, made visible to
pyopencl's loader.

pyopencl's wheel carries its own OpenCL loader, which
reads driver files (.icd) from /etc/OpenCL/vendors and from its own folder
(pyopencl/.libs) the first time a process lists the platforms, and never again in that
process. Intel's CPU runtime (`pip install intel-opencl-rt intel-cmplr-lib-rt`) puts
its library into the environment (`<prefix>/lib/libintelocl.so`) with no .icd file the
loader can use, so `register_runtimes` writes one into pyopencl/.libs; kdray calls it
at import and before every listing. Intel's runtime needs the environment's TBB
(libtbb.so.12, from the `tbb` wheel), newer than the one Open3D bundles: once Open3D's
is loaded, Intel's runtime cannot load in that process. So at import kdray loads the
environment's TBB when Intel's runtime is installed and no TBB is loaded yet (an
Open3D imported afterwards shares it and works); in the other order the Intel
platform is missing, and `list_devices` and the no-working-device error say why.
"""
import ctypes
import importlib.util
import logging
import os
import re
import sys
import time
from pathlib import Path

from .errors import one_line

log = logging.getLogger(__name__)

INTEL_CPU_PLATFORM = "Intel(R) OpenCL"
"""The platform name of Intel's CPU runtime (its GPU driver's is "Intel(R) OpenCL Graphics")."""

INTEL_AFFINITY = {"DPCPP_CPU_CU_AFFINITY": "close", "DPCPP_CPU_PLACES": "cores"}
"""Set for Intel's CPU runtime (`thread_binding`): it binds each of its worker threads
to a core of its own. Without them, on a 2-core VM, a kernel launched after the process
had been idle for a moment often ran on one core for its first 4-12 ms: the runtime's
worker and the thread waiting for the kernel (which the runtime makes work too) took
turns on one core in 4 ms slices until Linux moved one of them (`perf sched`;
BENCHMARKS.md, "Calls after an idle moment"). The runtime then binds the thread that
creates the process's first context as well; kdray undoes that at once
(`device.new_context`). It binds nothing when the process's CPU affinity is already
restricted (taskset, a cpuset)."""

INTEL_AFFINITY_NAMES = ("DPCPP_CPU_CU_AFFINITY", "DPCPP_CPU_PLACES", "SYCL_CPU_CU_AFFINITY",
                        "SYCL_CPU_PLACES")
"""Intel's runtime's variables for binding threads: if the environment sets any of them,
kdray sets none of INTEL_AFFINITY."""

POCL_AFFINITY = {"POCL_AFFINITY": "1"}
"""Set for PoCL (`thread_binding`, unless the environment sets POCL_AFFINITY): it binds
its worker threads one to a core (the thread waiting for a kernel only waits). The same
calls after an idle moment had a long tail unbound (BENCHMARKS.md)."""


ICD_NAME = "intel-cpu-kdray.icd"
"""kdray's driver file for Intel's CPU runtime in pyopencl/.libs: one line, the library's
absolute path (libintelocl.so finds its own libraries through its RUNPATH $ORIGIN)."""


def intel_library(prefix=None, windows=None):
    """Where Intel's CPU runtime from its wheel lies in the environment `prefix` (default
    sys.prefix): Path, which need not exist. windows : bool, default this system's."""
    prefix = Path(os.path.abspath(sys.prefix if prefix is None else prefix))
    windows = (os.name == "nt") if windows is None else windows
    if windows:
        return prefix / "Library" / "bin" / "intelocl64.dll"
    return prefix / "lib" / "libintelocl.so"


def _icd_folder():
    """pyopencl's folder of driver files (pyopencl/.libs, beside its bundled loader): Path,
    or None when pyopencl is missing or has no bundled loader (it then uses the system's)."""
    try:
        spec = importlib.util.find_spec("pyopencl")
    except (ImportError, ValueError):
        return None
    if spec is None or not spec.submodule_search_locations:
        return None
    folder = Path(list(spec.submodule_search_locations)[0]) / ".libs"
    return folder if folder.is_dir() else None


def sync_icd(library, folder):
    """Make `folder`/ICD_NAME name `library` while it exists, and remove it once it does not.

    library, folder : Path. Returns what was done: "written", "current", "removed",
    "absent", or "failed: <why>" (logged at INFO; never raises).
    """
    icd = Path(folder) / ICD_NAME
    want = f"{library}\n"
    try:
        have = icd.read_text(encoding="utf-8")
    except (OSError, ValueError):         # ValueError: not UTF-8, rewritten
        have = "" if icd.exists() else None
    try:
        if not Path(library).is_file():
            if have is None:
                return "absent"
            icd.unlink()
            log.info("removed %s: Intel's CPU runtime %s is no longer installed", icd, library)
            return "removed"
        if have == want:
            return "current"
        tmp = icd.with_name(f".{ICD_NAME}.{os.getpid()}.tmp")   # the loader reads *.icd only
        try:
            tmp.write_text(want, encoding="utf-8")
            os.replace(tmp, icd)
        finally:
            if tmp.exists():
                tmp.unlink()
    except OSError as e:
        why = f"cannot write {icd} ({e.strerror or e})"
        log.info("Intel's CPU runtime %s is not registered with pyopencl's OpenCL loader: %s",
                 library, why)
        return f"failed: {why}"
    log.info("registered Intel's CPU runtime %s with pyopencl's OpenCL loader (%s)", library, icd)
    return "written"


def windows_icd_filenames(current, library):
    """The value of OCL_ICD_FILENAMES (';'-separated driver DLLs the Khronos loader adds to
    the registry's) with `library` appended once. current : str or None."""
    parts = [p for p in (current or "").split(";") if p]
    if any(os.path.normcase(p) == os.path.normcase(str(library)) for p in parts):
        return ";".join(parts)
    return ";".join(parts + [str(library)])


_TBB_FILE = re.compile(r"libtbb(_debug)?\.so(\.\d+)*")     # not libtbbmalloc, libtbbbind


def loaded_tbbs(maps_text):
    """The TBB libraries (libtbb.so*) mapped into a process, from the text of its
    /proc/<pid>/maps: list of paths, in order of first appearance."""
    found = []
    for line in maps_text.splitlines():
        fields = line.split(None, 5)
        if len(fields) < 6:
            continue
        path = fields[5].strip()
        if path.endswith(" (deleted)"):
            path = path[:-len(" (deleted)")]
        if _TBB_FILE.fullmatch(os.path.basename(path)) and path not in found:
            found.append(path)
    return found


def foreign_tbb(maps_text, folder):
    """The first TBB mapped (see `loaded_tbbs`) that is not in `folder` (the one Intel's
    runtime loads), or None."""
    own = os.path.realpath(folder)
    for path in loaded_tbbs(maps_text):
        if os.path.dirname(os.path.realpath(path)) != own:
            return path
    return None


def _own_maps():
    """/proc/self/maps as text, or None (not Linux)."""
    try:
        with open("/proc/self/maps", encoding="utf-8", errors="replace") as f:
            return f.read()
    except OSError:
        return None


def _preload_tbb(folder):
    """Load folder/libtbb.so.12 (RTLD_GLOBAL) when no TBB is loaded yet, so that a library
    loaded later that needs libtbb.so.12 (Open3D) shares the one Intel's runtime needs."""
    tbb = Path(folder) / "libtbb.so.12"
    maps = _own_maps()
    if maps is None or loaded_tbbs(maps) or not tbb.is_file():
        return
    try:
        ctypes.CDLL(str(tbb), mode=ctypes.RTLD_GLOBAL)
    except OSError as e:
        log.info("cannot load %s for Intel's CPU runtime: %s", tbb, e)
        return
    log.debug("loaded %s for Intel's CPU runtime, before any other TBB", tbb)


def binds_threads(environ):
    """False when `environ` (a mapping like os.environ) sets KDRAY_BIND_THREADS=0: kdray
    then binds no threads, neither the CPU runtimes' (`thread_binding`) nor the
    builder's (`kdray.builder.threads`)."""
    return environ.get("KDRAY_BIND_THREADS", "").strip() != "0"


def thread_binding(environ):
    """The variables kdray adds to `environ` (a mapping like os.environ) so that the CPU
    runtimes bind their worker threads to cores: INTEL_AFFINITY unless environ sets any
    of INTEL_AFFINITY_NAMES, POCL_AFFINITY unless it sets POCL_AFFINITY; none with
    KDRAY_BIND_THREADS=0 (`binds_threads`)."""
    if not binds_threads(environ):
        return {}
    add = {}
    if not any(name in environ for name in INTEL_AFFINITY_NAMES):
        add.update(INTEL_AFFINITY)
    if not any(name in environ for name in POCL_AFFINITY):
        add.update(POCL_AFFINITY)
    return add


def register_runtimes():
    """Make the OpenCL runtimes installed in this environment visible to pyopencl's loader:
    Intel's CPU runtime (see the module docstring), and on Linux load its TBB first.

    Idempotent and cheap (a file read); to take effect it must run before the process
    first lists OpenCL platforms, so kdray calls it at import and in every listing.
    Writes only into the environment (pyopencl's folder), never raises; what cannot be
    done is logged at INFO, and `list_devices` says why the platform is missing.
    """
    library = intel_library()
    if os.name == "nt":
        # Untested on Windows. pyopencl's Windows wheel uses the Khronos loader, which
        # adds the DLLs listed in OCL_ICD_FILENAMES to the registry's drivers; Intel's
        # wheel installs intelocl64.dll (and the TBB DLLs it needs) in <prefix>\Library\bin.
        if library.is_file():
            current = os.environ.get("OCL_ICD_FILENAMES")
            value = windows_icd_filenames(current, library)
            if value != current:
                os.environ["OCL_ICD_FILENAMES"] = value
        return
    folder = _icd_folder()
    if folder is not None:
        sync_icd(library, folder)
    if sys.platform.startswith("linux"):
        # read by the runtimes when they start (PoCL) or create their first context
        # (Intel's): before the first listing is early enough
        os.environ.update(thread_binding(os.environ))
        if library.is_file():
            _preload_tbb(library.parent)


def _process_start():
    """When this process started, in time.time() seconds (Linux, 10 ms resolution), or None."""
    try:
        with open("/proc/self/stat") as f:
            fields = f.read().rpartition(")")[2].split()
        started = int(fields[19]) / os.sysconf("SC_CLK_TCK")   # field 22: ticks after boot
        return time.time() - (time.clock_gettime(time.CLOCK_BOOTTIME) - started)
    except (OSError, ValueError, IndexError, AttributeError):
        return None


def _intel_missing_reason(library):
    """Why Intel's CPU runtime, installed at `library`, is not among the listed platforms:
    one line."""
    cannot = "Intel's CPU runtime is installed but cannot load"
    not_listed = "Intel's CPU runtime is installed but not listed"
    try:
        ctypes.CDLL(str(library))      # what the OpenCL loader does, with the error kept
    except OSError as e:
        maps = _own_maps()
        other = foreign_tbb(maps, library.parent) if maps is not None else None
        if other and "open3d" in other.lower():
            return (f"{cannot}: {other} was loaded first (Open3D bundles an older TBB); "
                    f"import kdray before open3d")
        if other:
            return (f"{cannot}: {other} was loaded first (an older TBB than the runtime needs); "
                    f"import kdray before the module that loads it")
        return f"{cannot}: {one_line(str(e))}"
    if os.environ.get("OCL_ICD_VENDORS"):
        return (f"{not_listed}: OCL_ICD_VENDORS is set, so the OpenCL loader reads driver files "
                f"from {os.environ['OCL_ICD_VENDORS']} only; unset it")
    if os.name == "nt":
        return (f"{not_listed}: kdray adds it to OCL_ICD_FILENAMES, which the OpenCL loader reads "
                f"once per process; import kdray before listing OpenCL platforms")
    folder = _icd_folder()
    if folder is None:
        return (f"{not_listed}: pyopencl uses the system's OpenCL loader; register it with a file "
                f"/etc/OpenCL/vendors/intel-cpu.icd holding the line {library}")
    icd = folder / ICD_NAME
    try:
        registered = icd.read_text(encoding="utf-8") == f"{library}\n"
        written = icd.stat().st_mtime
    except (OSError, ValueError):
        registered, written = False, None
    if not registered:
        return (f"{not_listed}: kdray could not write {icd} (see kdray -v); write that file "
                f"with the line {library}")
    started = _process_start()
    if started is not None and written >= started:
        return (f"{not_listed} in this process: the platforms were listed before kdray registered "
                f"it (the OpenCL loader reads its list once per process); it is listed from the "
                f"next process on, or import kdray before listing OpenCL platforms")
    return (f"{not_listed}: it is registered ({icd}) but the OpenCL loader skips it "
            f"(OCL_ICD_DEBUG=15 shows why)")


def unavailable_runtimes(platforms):
    """[(name, reason)] of the runtimes installed in this environment that are not among
    `platforms` (pyopencl Platforms)."""
    library = intel_library()
    if not library.is_file() or any(p.name.strip() == INTEL_CPU_PLATFORM for p in platforms):
        return []
    return [(f"{INTEL_CPU_PLATFORM} ({library})", _intel_missing_reason(library))]
