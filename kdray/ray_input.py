"""Rays as the kernels read them: the caller's arrays checked, flattened and, where the
kernel does not shift them itself, made relative to the tree's origin and rounded.

    o, d, shape = flat_rays(origins, directions)        # (N, 3) or (3,), (N, 3), shape
    o, d, o_step = origin_rows(o, d)                    # (M, 3): M = N, or 1 (o_step 0)
    o32, d32 = rays32(o, d, o_step, origin, scale)      # float32 (page_aligned_empty's)
    o, d, o_step, rays_world = kernel_rays(origins, directions, origin, scale, in_kernel)

Precision: an origin is taken relative to the tree's float64 `origin`, in units of its
`scale` (a power of two), in float64 and only then rounded to float32, so that a scene
far from 0 or at any scale traces as accurately as one at 0 and 1 across
(docs/conventions.md). Directions are not scaled: t stays in units of |direction|.
"""
import numpy as np

from .errors import KdrayError
from .host import check_host_memory, page_aligned_empty, threads

CONVERT_CHUNK = 1 << 18
"""Rays per chunk when large ray arrays are converted to float32 on threads."""

RAY_BYTES = {"float": 12, "double": 24}
"""Bytes of a ray's origin or direction as trace_rays reads it."""

C_TYPES = {np.dtype(np.float32): "float", np.dtype(np.float64): "double"}
"""The ray arrays trace_rays reads as they are (RAYS_WORLD): numpy dtype -> C type."""


RAY_HOST_BYTES = 80
"""Host bytes a ray needs at most while it is traced: its float32 origin and direction
(24), the nearest hit's outputs (t, prim, u, v, normal: 28), for rays taken in an order
(kdray.ray_order) its key, its place in the sort and in the order (14), and its float32
t range where it has one of its own (8), rounded up. `flat_rays` checks the host has
them for every ray before anything is made."""


def numbers(name, values, error=KdrayError):
    """np.asarray(values), an array of numbers (integers or floats; bools, strings,
    complex numbers and objects are refused, never converted): `error` naming `name`
    otherwise, a ragged list too."""
    try:
        a = np.asarray(values)
    except (ValueError, TypeError) as e:          # a ragged list
        raise error(f"{name} must be an array of numbers ({str(e).splitlines()[0][:120]})") from None
    if a.dtype.kind not in "fiu":
        raise error(f"{name} must be an array of numbers, got dtype {a.dtype}")
    return a


def flat_rays(origins, directions):
    """(origins, directions, shape): directions (..., 3) as (N, 3) and origins, (3,) or
    of the directions' shape, as (N, 3) or (3,) (views where numpy can make them);
    shape: the rays' shape, directions.shape[:-1]. KdrayError for other shapes, arrays
    that are not numbers (`numbers`), and more rays than the host's memory holds
    (RAY_HOST_BYTES a ray, checked before anything is made)."""
    d = numbers("directions", directions)
    if d.ndim < 2 or d.shape[-1] != 3:
        raise KdrayError(f"directions must be an (N, 3) or (H, W, 3) array, got shape {d.shape}")
    o = numbers("origins", origins)
    if o.shape != (3,) and o.shape != d.shape:
        raise KdrayError(f"origins {o.shape} must be (3,) or the directions' shape {d.shape}")
    n = d.size // 3
    check_host_memory(n * RAY_HOST_BYTES, f"tracing {n:,} rays", "trace fewer rays at a time")
    if d.ndim == 2:
        return o, d, d.shape[:1]
    return (o if o.shape == (3,) else o.reshape(-1, 3)), d.reshape(-1, 3), d.shape[:-1]


def origin_rows(origins, directions):
    """(o (M, 3), d (N, 3), o_step): M = N (o_step 1), or 1 with o_step 0 when every
    ray has one origin, given as (3,) or broadcast (stride 0): read once.
    KdrayError unless directions are (N, 3) and origins (3,) or (N, 3)."""
    d = np.asarray(directions)
    if d.ndim != 2 or d.shape[1] != 3:
        raise KdrayError(f"directions must be an (N, 3) array, got shape {d.shape}")
    o = np.asarray(origins)
    if o.shape == (3,):
        o = o.reshape(1, 3)
    elif o.shape != d.shape:
        raise KdrayError(f"origins {o.shape} and directions {d.shape} must both be (N, 3)")
    if len(o) > 1 and o.strides[0] == 0:
        o = o[:1]
    return o, d, 0 if len(o) == 1 and len(d) != 1 else 1


def rays32(o, d, o_step, origin, scale):
    """(o32 (M, 3), d32 (N, 3)) float32 (host.page_aligned_empty's): origins o ((M,
    3), as `origin_rows` gives them) made relative to `origin` ((3,) float64) in units
    of `scale` in float64 and only then rounded, directions d rounded."""
    o = o.astype(np.float64, copy=False)
    # o - origin in float64, rounded to float32 on the way out (buffered: no float64
    # temporary of the whole array); large arrays in chunks on threads (numpy releases
    # the GIL), the same arithmetic element by element
    o32 = page_aligned_empty(o.shape, np.float32)
    d32 = page_aligned_empty(d.shape, np.float32)

    def convert(rows):
        with np.errstate(over="ignore", invalid="ignore"):
            if o_step:
                shifted = np.empty((len(o32[rows]), 3))
                for k in range(3):   # by column: numpy's loops over rows of 3 are slow
                    np.subtract(o[rows, k], origin[k], out=shifted[:, k])
                if scale != 1.0:
                    shifted /= scale
                np.copyto(o32[rows], shifted, casting="unsafe")
            np.copyto(d32[rows], d[rows], casting="unsafe")

    if not o_step:
        with np.errstate(over="ignore", invalid="ignore"):
            np.copyto(o32, (o - origin) / scale, casting="unsafe")
    chunks = [slice(i, i + CONVERT_CHUNK) for i in range(0, len(d), CONVERT_CHUNK)]
    if len(chunks) > 1:
        list(threads().map(convert, chunks))
    elif chunks:
        convert(chunks[0])
    return o32, d32


def kernel_rays(origins, directions, origin, scale, in_kernel):
    """The rays as trace_rays takes them: (o, d, o_step, rays_world).

    in_kernel (a device with double precision that is a CPU or refines its hits):
    float64 and float32 rays go to the kernel as they are (C-contiguous, on a CPU no
    copy when they are), which shifts and rounds them itself; rays_world is then their
    (origin, direction) C types ("double" or "float"). Other dtypes (float16, integers,
    long double) go as float64, the caller's rays as the queries take them (kdray.rays'
    exact rays), so that hits are refined from the same numbers. Else `rays32`'s float32
    arrays, and rays_world None."""
    o, d, o_step = origin_rows(origins, directions)
    if in_kernel:
        o = o if o.dtype in C_TYPES else o.astype(np.float64)
        d = d if d.dtype in C_TYPES else d.astype(np.float64)
        return (np.ascontiguousarray(o), np.ascontiguousarray(d), o_step,
                (C_TYPES[o.dtype], C_TYPES[d.dtype]))
    return (*rays32(o, d, o_step, origin, scale), o_step, None)
