"""numba options shared by the builder's modules.

`BORROW`: compile a function without numba's reference counts (NRT). A compiled
function increments and decrements, with atomic instructions, the count of every
array it is passed, on entry and on return; the per-node and per-straddler calls of
the build (`classify`, `split_merge`, `clip_split`, ...) pass up to ten arrays
each, and the counts took about a tenth of a bunny build (BENCHMARKS.md). Such a
function only reads and writes arrays its caller owns: it may not allocate, slice
into a new array it keeps, or call a function that does (numba then refuses to
compile it). `_nrt` is numba's own, underscored, option; where a numba lacks it the
functions keep their counts and are only slower.
"""
try:
    from numba.core.cpu import CPUTargetOptions
    _HAS_NRT_OPTION = hasattr(CPUTargetOptions, "_nrt")
except ImportError:                     # a numba whose internals moved
    _HAS_NRT_OPTION = False

BORROW = {"_nrt": False} if _HAS_NRT_OPTION else {}
"""Keyword arguments for numba.njit: no reference counts (see the module's docstring)."""
