"""The OpenCL runtimes installed in this environment with pip, made visible to
pyopencl's loader.

pyopencl's wheel carries its own OpenCL loader, which
reads driver files (.icd) from /etc/OpenCL/vendors and from its own folder
(pyopencl/.libs) the first time a process lists the platforms, and never again in that
process. Intel's CPU runtime (`pip install intel-opencl-rt intel-cmplr-lib-rt`) puts
its library into the environment (`<prefix>/lib/libintelocl.so`) with no .icd file the
loader can use, so `register_runtimes` writes one into pyopencl/.libs; kdray calls it
at import and before every listing.

Intel's runtime needs the environment's TBB (libtbb.so.12, from the `tbb` wheel), newer
than the one Open3D bundles under the same name: once Open3D's is loaded, the dynamic
linker hands it to Intel's runtime too, which then cannot load (a TBB symbol is
missing). So on Linux kdray registers its own copy of the runtime (`private_runtime`):
a folder `<prefix>/lib/kdray-intel-cpu-<key>/` holding a copy of libintelocl.so that
needs its TBB under another name (PRIVATE_TBB), a copy of that TBB under that name, and
links to the runtime's other files. Each library then has its own TBB, whatever was
imported first. kdray makes the folder once per installed runtime, at set-up or at the
first import (about 100 MB, one copy; `private_runtime`). Where it cannot, kdray
registers the runtime itself as before and loads the environment's TBB at import when
no TBB is loaded yet (an Open3D imported afterwards shares it); in the other order the
Intel platform is missing, and `list_devices` and the no-working-device error say why.
"""
import ctypes
import importlib.util
import logging
import hashlib
import mmap
import os
import re
import shutil
import struct
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


# ---------------------------------------------------------------- kdray's copy of Intel's runtime

PRIVATE_TBB = "libtbbkd.so"
"""The name under which kdray's copy of Intel's runtime needs its TBB, and the name (file
and SONAME) of its copy of that TBB: no other library is or needs one of that name, so
the dynamic linker never hands it another's TBB (nor another library this one). No
longer than the name it replaces ("libtbb.so.12"): `rename_dynamic` renames in place."""

PRIVATE_PREFIX = "kdray-intel-cpu-"
"""The folders of kdray's copy of Intel's runtime: <prefix>/lib/kdray-intel-cpu-<key>,
beside the runtime, so that its links are relative and it goes with the environment."""

PRIVATE_VERSION = 1
"""In the folder's key: changes when the way the copy is made does."""

_STRING_TAGS = {1: "NEEDED", 14: "SONAME", 15: "RPATH", 29: "RUNPATH", 0x6ffffefa: "CONFIG",
                0x6ffffefb: "DEPAUDIT", 0x6ffffefc: "AUDIT", 0x7ffffffd: "AUXILIARY",
                0x7fffffff: "FILTER"}
"""The dynamic entries (d_tag) whose value names something in the dynamic string table."""


def _dynamic(elf):
    """The dynamic section of a 64-bit little-endian ELF file (bytes-like `elf`, the whole
    file): ([(d_tag, d_val)], file offset of the dynamic string table, its size).
    Raises ValueError for any other file."""
    if len(elf) < 64 or elf[:4] != b"\x7fELF" or elf[4] != 2 or elf[5] != 1:
        raise ValueError("not a 64-bit little-endian ELF file")
    phoff, = struct.unpack_from("<Q", elf, 0x20)
    phentsize, phnum = struct.unpack_from("<HH", elf, 0x36)
    loads, dynamic = [], None
    for i in range(phnum):
        p_type, _, offset, vaddr, _, filesz, _, _ = struct.unpack_from(
            "<IIQQQQQQ", elf, phoff + i * phentsize)
        if p_type == 1:                                 # PT_LOAD
            loads.append((vaddr, offset, filesz))
        elif p_type == 2:                               # PT_DYNAMIC
            dynamic = (offset, filesz)
    if dynamic is None:
        raise ValueError("no dynamic section")
    entries = []
    for at in range(dynamic[0], dynamic[0] + dynamic[1] - 15, 16):
        tag, value = struct.unpack_from("<qQ", elf, at)
        if tag == 0:                                    # DT_NULL
            break
        entries.append((tag, value))
    table = {tag: value for tag, value in entries if tag in (5, 10)}   # DT_STRTAB, DT_STRSZ
    if len(table) != 2:
        raise ValueError("no dynamic string table")
    strtab = next((offset + table[5] - vaddr for vaddr, offset, size in loads
                   if vaddr <= table[5] < vaddr + size), None)
    if strtab is None:
        raise ValueError("the dynamic string table is in no loaded segment")
    return entries, strtab, table[10]


def _string(elf, strtab, size, index):
    end = elf.find(b"\0", strtab + index, strtab + size) if index < size else -1
    if end < 0:
        raise ValueError(f"string {index} is outside the dynamic string table")
    return bytes(elf[strtab + index:end]).decode("utf-8", "replace")


def dynamic_strings(elf):
    """[(name of the entry, string)] of an ELF shared object's dynamic entries that name
    something ("NEEDED", "SONAME", "RUNPATH", ...), in order. elf : bytes-like, the whole
    file. Raises ValueError for a file that is not a 64-bit little-endian ELF."""
    entries, strtab, size = _dynamic(elf)
    return [(_STRING_TAGS[tag], _string(elf, strtab, size, value))
            for tag, value in entries if tag in _STRING_TAGS]


def _string_uses(elf, strtab, entries):
    """Every index into the dynamic string table that the file holds: the dynamic entries',
    and the symbols' and symbol versions' names (found through the section headers)."""
    uses = [value for tag, value in entries if tag in _STRING_TAGS]
    shoff, = struct.unpack_from("<Q", elf, 0x28)
    shentsize, shnum = struct.unpack_from("<HH", elf, 0x3A)
    if shoff == 0 or shnum == 0:
        raise ValueError("no section headers (which names share bytes is unknown)")
    sections = [struct.unpack_from("<IIQQQQIIQQ", elf, shoff + i * shentsize)
                for i in range(shnum)]
    dynstr = {i for i, s in enumerate(sections) if s[4] == strtab}      # sh_offset
    for _, sh_type, _, _, offset, size, link, info, _, entsize in sections:
        if link not in dynstr:
            continue
        if sh_type == 11:                               # SHT_DYNSYM: st_name first
            uses += [struct.unpack_from("<I", elf, at)[0]
                     for at in range(offset, offset + size, entsize or 24)]
        elif sh_type in (0x6ffffffd, 0x6ffffffe):       # SHT_GNU_verdef, SHT_GNU_verneed
            at = offset
            for _ in range(info):                       # sh_info: the number of entries
                if sh_type == 0x6ffffffd:               # Verdef, its Verdaux: vda_name
                    _, _, _, count, _, aux, step = struct.unpack_from("<HHHHIII", elf, at)
                    name_at = 0
                else:                                   # Verneed (vn_file), its Vernaux: vna_name
                    _, count, file, aux, step = struct.unpack_from("<HHIII", elf, at)
                    uses.append(file)
                    name_at = 8
                a = at + aux
                for _ in range(count):
                    name, = struct.unpack_from("<I", elf, a + name_at)
                    uses.append(name)
                    a += struct.unpack_from("<I", elf, a + name_at + 4)[0]
                at += step
    return uses


def rename_dynamic(path, tag, old, new):
    """Rename the dynamic entry `tag` ("NEEDED", "SONAME") `old` of the ELF shared object
    `path` to `new`, in the file: the string is overwritten, so `new` may be no longer than
    `old`, and no other name may share its bytes (a linker may keep "c.so.6" as the tail
    of "libc.so.6"). What patchelf --replace-needed and --set-soname do, for a name that
    fits. Raises ValueError when the file has no such entry or it cannot be renamed so,
    OSError when the file cannot be written."""
    code = next(t for t, name in _STRING_TAGS.items() if name == tag)
    raw_old, raw_new = old.encode(), new.encode()
    if not raw_new or b"\0" in raw_new or len(raw_new) > len(raw_old):
        raise ValueError(f"cannot rename {old} to {new} in place: the new name is longer")
    with open(path, "r+b") as f, mmap.mmap(f.fileno(), 0) as elf:
        entries, strtab, size = _dynamic(elf)
        starts = {value for t, value in entries
                  if t == code and _string(elf, strtab, size, value) == old}
        if not starts:
            raise ValueError(f"{path} has no {tag} entry {old}")
        uses = _string_uses(elf, strtab, entries)
        for start in starts:
            if any(start < u < start + len(raw_old) for u in uses):
                raise ValueError(f"another name in {path} shares the bytes of {tag} {old}")
            elf[strtab + start:strtab + start + len(raw_old)] = raw_new.ljust(len(raw_old), b"\0")
        elf.flush()


def _tbb_needed(library):
    """The TBB (a NEEDED "libtbb.so.N") that the shared object `library` needs, or None."""
    with open(library, "rb") as f, mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as elf:
        needed = [s for tag, s in dynamic_strings(elf) if tag == "NEEDED"]
    return next((s for s in needed if re.fullmatch(r"libtbb\.so(\.\d+)*", s)), None)


def private_folder(library):
    """Where kdray's copy of Intel's runtime `library` (Path) lies, and the TBB the runtime
    needs: (folder Path, which need not exist, TBB name), or None when the runtime needs
    no TBB of that name. The folder's key changes with the library's and its TBB's size
    and time, so that an upgraded runtime or TBB gets a new copy. Raises OSError when a
    file cannot be read, ValueError when the library is not an ELF shared object."""
    tbb = _tbb_needed(library)
    if tbb is None:
        return None
    digest = hashlib.blake2b(str(PRIVATE_VERSION).encode(), digest_size=8)
    for path in (library, library.parent / tbb):
        st = os.stat(path)
        digest.update(f"\0{os.path.realpath(path)}\0{st.st_size}\0{st.st_mtime_ns}".encode())
    return library.parent / f"{PRIVATE_PREFIX}{digest.hexdigest()}", tbb


def make_private_runtime(library, folder, tbb):
    """Make `folder` (see `private_folder`): links to every file beside `library` (its
    libraries, the builtins it loads at run time, its configuration), except the runtime
    itself and its TBB, which are copied: libintelocl.so needing PRIVATE_TBB instead of
    `tbb`, and `tbb` as PRIVATE_TBB. Made in a temporary folder renamed into place, so
    that a process sees all of it or none, and several may make it at once. Returns
    the copy of the library. Raises OSError (e.g. the environment is read-only or the
    disk full) or ValueError (`rename_dynamic`)."""
    library, folder = Path(library), Path(folder)
    source = library.parent
    copy = folder / library.name
    temporary = source / f".{folder.name}.{os.getpid()}.tmp"
    shutil.rmtree(temporary, ignore_errors=True)
    temporary.mkdir()
    try:
        for entry in os.scandir(source):
            name = entry.name
            if (name.startswith((".", "libintelocl.so", PRIVATE_PREFIX)) or name == PRIVATE_TBB
                    or re.fullmatch(r"libtbb\.so(\.\d+)*", name) or entry.is_dir()):
                continue
            os.symlink(os.path.join("..", name), temporary / name)
        shutil.copy(os.path.realpath(library), temporary / library.name)
        shutil.copy(os.path.realpath(source / tbb), temporary / PRIVATE_TBB)
        rename_dynamic(temporary / library.name, "NEEDED", tbb, PRIVATE_TBB)
        with open(temporary / PRIVATE_TBB, "rb") as f, \
                mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as elf:
            soname = next((s for tag, s in dynamic_strings(elf) if tag == "SONAME"), None)
        if soname is not None:
            rename_dynamic(temporary / PRIVATE_TBB, "SONAME", soname, PRIVATE_TBB)
        try:
            os.rename(temporary, folder)
        except OSError:
            if not copy.is_file():          # not made by another process meanwhile
                raise
    finally:
        shutil.rmtree(temporary, ignore_errors=True)
    _remove_private(source, keep=folder.name)
    return copy


def _remove_private(source, keep=None):
    """Remove the folders of kdray's copies of Intel's runtime in `source` other than
    `keep`, and the temporary folders of processes that no longer run. Never raises."""
    try:
        entries = list(os.scandir(source))
    except OSError:
        return
    for entry in entries:
        name = entry.name
        if name.startswith(PRIVATE_PREFIX) and name != keep:
            shutil.rmtree(entry.path, ignore_errors=True)
            log.info("removed %s: a copy of an Intel CPU runtime no longer installed", entry.path)
        elif name.startswith("." + PRIVATE_PREFIX) and name.endswith(".tmp"):
            pid = name[:-len(".tmp")].rpartition(".")[2]
            if pid.isdigit() and not _running(int(pid)):
                shutil.rmtree(entry.path, ignore_errors=True)


def _running(pid):
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:                     # another user's: it runs
        return True
    return True


def private_runtime(library, create=True):
    """kdray's copy of Intel's runtime `library` (see the module's docstring): its Path,
    made first when it is missing and `create` is true; None when the runtime needs no
    TBB or the copy cannot be made (logged at INFO; then the runtime is registered
    itself, as before). Cheap when the copy exists: one read of the library's header,
    three stats."""
    library = Path(library)
    try:
        where = private_folder(library)
    except (OSError, ValueError) as e:
        log.info("cannot read Intel's CPU runtime %s: %s", library, e)
        return None
    if where is None:
        return None
    folder, tbb = where
    copy = folder / library.name
    if copy.is_file() or not create:
        return copy if copy.is_file() else None
    t0 = time.perf_counter()
    try:
        made = make_private_runtime(library, folder, tbb)
    except (OSError, ValueError) as e:
        log.info("cannot make kdray's copy of Intel's CPU runtime in %s (%s): it is registered "
                 "itself, and cannot load in a process that loaded another TBB first (Open3D's)",
                 folder, getattr(e, "strerror", None) or e)
        return None
    log.info("made kdray's copy of Intel's CPU runtime in %s, with its own TBB (%.2f s)",
             folder, time.perf_counter() - t0)
    return made


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
    Intel's CPU runtime (see the module docstring), on Linux kdray's copy of it with its
    own TBB (`private_runtime`, made here the first time), or where that cannot be made
    the runtime itself, with its TBB loaded first.

    Idempotent and cheap (a few file reads and stats) once the copy exists; to take
    effect it must run before the process first lists OpenCL platforms, so kdray calls
    it at import and in every listing. Writes only into the environment (pyopencl's
    folder, the copy's beside the runtime), never raises; what cannot be done is logged
    at INFO, and `list_devices` says why the platform is missing.
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
    linux = sys.platform.startswith("linux")
    private = private_runtime(library) if linux and library.is_file() else None
    folder = _icd_folder()
    if folder is not None and sync_icd(private or library, folder) == "removed":
        _remove_private(library.parent)             # the runtime was uninstalled
    if linux:
        # read by the runtimes when they start (PoCL) or create their first context
        # (Intel's): before the first listing is early enough
        os.environ.update(thread_binding(os.environ))
        if library.is_file() and private is None:
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


def registered_library(library=None):
    """The library kdray registers for Intel's CPU runtime `library` (default
    `intel_library()`): kdray's copy (`private_runtime`) where it exists, else `library`."""
    library = intel_library() if library is None else Path(library)
    if os.name == "nt" or not library.is_file():
        return library
    return private_runtime(library, create=False) or library


def _intel_missing_reason(library):
    """Why Intel's CPU runtime, registered as `library` (the runtime's own library or
    kdray's copy of it), is not among the listed platforms: one line."""
    cannot = "Intel's CPU runtime is installed but cannot load"
    not_listed = "Intel's CPU runtime is installed but not listed"
    library = Path(library)
    try:
        ctypes.CDLL(str(library))      # what the OpenCL loader does, with the error kept
    except OSError as e:
        maps = _own_maps()
        own_tbb = library.parent.name.startswith(PRIVATE_PREFIX)     # no TBB can be in its way
        other = foreign_tbb(maps, library.parent) if maps is not None and not own_tbb else None
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
    registered = registered_library(library)
    return [(f"{INTEL_CPU_PLATFORM} ({registered})", _intel_missing_reason(registered))]
