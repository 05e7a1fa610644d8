"""The build's largest scratch array, kept for the next build.

The root's sorted events and the builder's two event stacks share one uint64 array
(`events.sorted_root_events`, `subdivide.split_keys`), about 144 bytes a triangle, most
of whose pages a build writes. A new array's pages come fresh from the kernel (page
faults, zeroing), and builds of 10k-40k triangles took 0.95-0.96 of the time when the
last build's array was used again (in turns; the bunny's 0.99, none at 278k:
BENCHMARKS.md, "The builder's threads and parameters"). So one such array, of at most
KEEP_BYTES, is kept after a build for the next one: meshes built one after another (a
dataset's scenes, repeated builds) reuse it. Larger arrays are never kept (holding one
to the end of a build would raise its peak memory); `release` frees the kept one.

The array is taken by one build at a time (a lock; a build that finds it taken, or too
small, makes its own), so builds on several threads stay independent. What it holds
never reaches a tree: the builder overwrites every key it reads.
"""
import threading

import numpy as np

KEEP_BYTES = 16 << 20
"""The largest array kept between builds (16 MiB: meshes of up to about 116k triangles)."""

_lock = threading.Lock()
_kept = None


def take(n):
    """(n,) uint64, uninitialized: the kept array's first n keys when it is free and
    long enough (removed from the keeping until `give`), else a new array."""
    global _kept
    with _lock:
        kept = _kept
        if kept is not None and len(kept) >= n:
            _kept = None
            return kept[:n]
    return np.empty(n, dtype=np.uint64)


def keeps(keys):
    """Whether `give` would keep this array (a view of one: the whole array)."""
    return _whole(keys).nbytes <= KEEP_BYTES


def give(keys):
    """Keep the array of `keys` (from `take`) for the next build, if `keeps` it and it is
    longer than the one kept now."""
    global _kept
    whole = _whole(keys)
    if whole.nbytes > KEEP_BYTES:
        return
    with _lock:
        if _kept is None or len(whole) > len(_kept):
            _kept = whole


def release():
    """Drop the kept array (its memory goes back once nothing else holds it)."""
    global _kept
    with _lock:
        _kept = None


def _whole(keys):
    return keys if keys.base is None else keys.base
