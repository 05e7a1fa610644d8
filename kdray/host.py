"""Host memory: page-aligned arrays for CPU devices, and how much memory is free.

    a = page_aligned_empty((n, 3), np.float32)     # from a PAGE boundary (COPY_BELOW bytes on)
    t = huge_page_copy(tris)                       # a copy in huge pages where it can be
    check_host_memory(nbytes, "a 4096x4096 render of depth")   # KdrayError if too much
"""
import concurrent.futures
import math
import mmap
import os
import time

import numpy as np

from .errors import KdrayError

PAGE = 4096
"""Alignment of the host arrays kdray gives a CPU device: Intel's CPU runtime uses a
CL_MEM_USE_HOST_PTR array in place only when it starts on a page, and copies it at
every launch otherwise, which costs more than a copy to pages first."""


COPY_BELOW = PAGE
"""Bytes below which a host array is copied to and from a CPU device rather than used in
place (kdray.device_tree reads it at each launch), and `page_aligned_empty` puts it
anywhere. A buffer over the host's memory must be mapped to be read back and, on
Intel's runtime, start on a page (an array passed from its page's start, or copied to
pages); a copy of less than a page costs less than that, so small calls are cheaper
this way, but buffers of the runtime's own from a page or two on cost much more to
make and read than a map (BENCHMARKS.md, "Small calls")."""


def page_aligned_empty(shape, dtype):
    """An uninitialised C-contiguous array of `shape` and `dtype` for a launch to use:
    its data starting at a multiple of PAGE bytes from COPY_BELOW bytes on, a smaller
    one (copied to a device, never used in place) wherever numpy puts it."""
    dtype = np.dtype(dtype)
    nbytes = math.prod(int(n) for n in shape) * dtype.itemsize
    if nbytes < COPY_BELOW:
        return np.empty(shape, dtype)
    return _on_page(shape, dtype, nbytes)


def _on_page(shape, dtype, nbytes):
    """An uninitialised C-contiguous array of `shape` and `dtype` (a np.dtype; nbytes
    its size) whose data starts at a multiple of PAGE."""
    raw = np.empty(nbytes + PAGE, dtype=np.uint8)
    start = -raw.ctypes.data % PAGE
    return raw[start:start + nbytes].view(dtype).reshape(shape)


_POOL = (None, None)
"""(process id, ThreadPoolExecutor) of `threads`."""


def threads():
    """Threads for large numpy passes over host arrays (numpy releases the GIL in them),
    one a CPU: started once a process and kept (a pool started at each call took about
    1.7 ms more of a 2^20-ray conversion, median), a new one in a process forked after
    it was made (whose threads the fork did not copy)."""
    global _POOL
    pid, pool = _POOL
    if pool is None or pid != os.getpid():
        pool = concurrent.futures.ThreadPoolExecutor(os.cpu_count() or 1,
                                                     thread_name_prefix="kdray-host")
        _POOL = (os.getpid(), pool)
    return pool


TAKE_CHUNK = 1 << 16
"""The fewest rows `take_rows` gives a thread."""


def row_abs_max(a):
    """(N,) each row's largest |component| of an (N, 3) float array, NaN components
    left out (np.fmax): three column passes, about 3.5x as fast as np.abs(a).max(axis=1)."""
    a = np.abs(a)
    return np.fmax(np.fmax(a[:, 0], a[:, 1]), a[:, 2])


def take_rows(a, index, out=None, mode="wrap"):
    """a[index] for an (N, ...) array a and an (M,) int index (each in 0 .. N - 1, or
    as `mode` takes one that is not: np.take's "wrap" or "clip"), into `out` (an (M,
    ...) array of a's dtype, C-contiguous) or a new array: np.take along the first
    axis, which gathers the rows of an (N, 3) float64 array 3x as fast as a[index], in
    parts on `threads` (a gather at random waits on memory: 2^20 rows of three float32
    in 8.4 ms on 2 threads against 16.5 on one)."""
    index = np.asarray(index)
    if out is None:
        out = np.empty((len(index),) + a.shape[1:], dtype=a.dtype)
    parts = len(index) // TAKE_CHUNK
    if parts >= 2:                       # (os.cpu_count reads the system: asked only here)
        parts = min(os.cpu_count() or 1, parts)
    if parts < 2:
        return np.take(a, index, axis=0, out=out, mode=mode)
    bounds = np.linspace(0, len(index), parts + 1).astype(np.int64)
    list(threads().map(lambda k: np.take(a, index[bounds[k]:bounds[k + 1]], axis=0,
                                         out=out[bounds[k]:bounds[k + 1]], mode=mode),
                       range(parts)))
    return out


HUGE_PAGE = 2 << 20
"""A transparent huge page on x86-64 Linux. A tree's kernels read its buffers at random
(a ray's nodes and leaves), and through a tree of tens of MiB a 4 KiB page is a TLB
miss at nearly every read, costly in a virtual machine (two page tables to walk); 2
MiB pages keep a 100 MiB tree within the TLB's reach (BENCHMARKS.md)."""


def huge_page_copy(array):
    """A C-contiguous copy of `array` in memory from `huge_page_empty`."""
    array = np.ascontiguousarray(array)
    out = huge_page_empty(array.shape, array.dtype)
    np.copyto(out, array)
    return out


def huge_page_empty(shape, dtype):
    """An uninitialised C-contiguous array whose data starts on a HUGE_PAGE boundary,
    its whole huge pages advised to the kernel as such (madvise MADV_HUGEPAGE: Linux
    backs them with huge pages where transparent huge pages are enabled, "always" or
    "madvise"); the tail, smaller arrays and other systems in pages of PAGE bytes
    (from a page's start). Its memory is freed with the array."""
    dtype = np.dtype(dtype)
    nbytes = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
    advice = getattr(mmap, "MADV_HUGEPAGE", None)
    if advice is None or nbytes < HUGE_PAGE:
        return _on_page(shape, dtype, nbytes)
    # private anonymous memory (a shared mapping follows shmem's huge page setting)
    region = mmap.mmap(-1, nbytes + HUGE_PAGE, flags=mmap.MAP_PRIVATE | mmap.MAP_ANONYMOUS)
    raw = np.frombuffer(region, dtype=np.uint8)
    start = -raw.ctypes.data % HUGE_PAGE
    try:
        region.madvise(advice, start, nbytes // HUGE_PAGE * HUGE_PAGE)
    except OSError:
        pass                                 # no huge pages here: small pages it is
    return raw[start:start + nbytes].view(dtype).reshape(shape)


def available_memory():
    """Bytes of host memory this process may still allocate, or None if unknown: the
    system's available memory (Linux MemAvailable), or less where the process's
    address space is limited (RLIMIT_AS: `ulimit -v`, test harnesses) and the room
    left under that limit is smaller."""
    found = [n for n in (_system_available(), _address_space_room()) if n is not None]
    return min(found) if found else None


MEMINFO_SECONDS = 1.0
"""How long a reading of the system's available memory is reused
(`_system_available`). Every call checks its memory, some several times, and reading
/proc/meminfo each time took half of a one-ray trace's time; a loop that calls a few
times a second (a robot's, a game's) finds the machine idle at each call, where the
read costs most. A reading a second old guides as well as a fresh one: the check only
turns an allocation the host cannot hold into an error, and another process may
allocate right after any check."""

_MEMINFO = (-float("inf"), None)          # (time.monotonic() read at, bytes or None)


def _system_available():
    """The system's available memory in bytes (Linux MemAvailable, else the free
    physical pages), or None: read at most every MEMINFO_SECONDS."""
    global _MEMINFO
    read_at, have = _MEMINFO
    now = time.monotonic()
    if now - read_at < MEMINFO_SECONDS:
        return have
    have = _read_available()
    _MEMINFO = (now, have)
    return have


def _read_available():
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def _address_space_room():
    """RLIMIT_AS less this process's virtual size (Linux VmSize), or None: no limit,
    or not known."""
    try:
        import resource
        limit = resource.getrlimit(resource.RLIMIT_AS)[0]
        if limit == resource.RLIM_INFINITY:
            return None
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmSize:"):
                    return max(limit - int(line.split()[1]) * 1024, 0)
    except (ImportError, OSError, ValueError, IndexError):
        pass
    return None


def check_host_memory(nbytes, what, hint="ask for a smaller image or fewer AOVs",
                      error=KdrayError):
    """`error` (KdrayError or a subclass), before anything is allocated, when `what`
    needs more host memory than is available (the message ends with `hint`)."""
    have = available_memory()
    if have is not None and nbytes > have:
        raise error(f"{what} needs about {nbytes / 2**30:.1f} GiB of memory, but "
                         f"{have / 2**30:.1f} GiB are available: {hint}")
