"""A ray query's rays as kernels/queries.cl reads them, and its launches: the mechanism
under kdray.rays (any hit, crossing counts, inside tests) and kdray.hit_lists (every
hit).

Rays are given as `Tracer.trace` takes them: origins (N, 3) or (3,) and directions
(N, 3) (or image-shaped, (..., 3), answered in that shape), world coordinates, float64
or float32; t_min, t_max scalars or (N,) arrays (per ray), 0 <= t_min <= t_max, t in
units of |direction| (`check_ranges`). A ray with a non-finite component or a zero
direction has no hit (occluded False, count 0, no intersections), as in `trace`.
`QueryRays` holds them as the kernels read them; `launch` runs one of queries.cl's
kernels over a part of them (the part that fits the device: `launches`), an image's
in blocks (`as_image`) and rays in no order taken in one (kdray.ray_order).
"""
import numpy as np

from . import device as _device
from . import ray_input
from .errors import DeviceError, KdrayError
from .host import page_aligned_empty
from .ray_order import ray_order


COUNT_RAW = 0x80000000
"""count_rays marks a count of every hit found, copies included (kernels/queries.cl)."""
WALK_FAULT = 0x40000000
"""The kernels' mark of a walk that met a corrupt tree (never for a valid one)."""
LIST_MORE = 0x20000000
"""list_rays marks the count of a ray that had more hits than slots (kernels/queries.cl)."""

LIST_SLOTS = 8
"""The slots a ray keeps in private memory in a first pass (kernels/queries.cl,
list_first, built with LIST_SLOTS), which writes only the hits it finds, one after
another: writing every ray's slots, mostly empty and fresh memory at each call, took
about a third of the pass's time."""

RUN_CPU = 64
"""Consecutive rays a work-item takes on a CPU device (one per work-item on a GPU). In
packet programs those that share their paths are walked as packets, the others
through the wide nodes two at a time (kernels/queries.cl, kd_walk_block), each holding
its query's state in private memory (about 200 bytes: 13 KB a work-item)."""


def check_t(t, name, shape=None):
    """t_min or t_max as a float64 array (0-d for a number): a real number or an array
    of numbers (strings and bools refused, not converted; ray_input.numbers). shape:
    the rays' shape less its last axis (ray_input.flat_rays'): an array of that shape,
    one value a ray as the rays lie (an (H, W) range for (H, W, 3) rays), is made flat."""
    if isinstance(t, (bool, str, bytes)) or t is None:
        raise KdrayError(f"{name} must be a number or an array of one a ray, got {t!r:.80}")
    t = ray_input.numbers(name, t).astype(np.float64, copy=False)
    if shape is not None and t.ndim > 1 and t.shape == tuple(shape):
        t = t.reshape(-1)
    return t


def check_ranges(t_min, t_max, n):
    """(lo, hi, t_step): t_min and t_max (numbers or (n,) arrays) as float64 arrays,
    0-d or of n elements, and t_step 1 where either is an array, else 0. KdrayError for
    NaN, t_min < 0, t_min > t_max or arrays of another length."""
    lo, hi = (check_t(t, name) for t, name in ((t_min, "t_min"), (t_max, "t_max")))
    for name, a in (("t_min", lo), ("t_max", hi)):
        if a.ndim > 1 or (a.ndim == 1 and len(a) != n):
            raise KdrayError(f"{name} must be a number or an array of one value a ray "
                             f"({n}, or shaped as the rays less their last axis), got "
                             f"shape {a.shape}")
    if lo.ndim == 0 and hi.ndim == 0:
        # two numbers (most calls): the same checks in Python floats, a few us sooner
        a, b = float(lo), float(hi)
        if a != a or b != b:
            raise KdrayError("t_min and t_max must not be NaN")
        if not a >= 0:
            raise KdrayError("t_min must be >= 0 (hits behind a ray's origin never count)")
        if a > b:
            raise KdrayError(f"need t_min <= t_max, got t_min={a} > t_max={b} (ray 0)")
        return lo, hi, 0
    if np.isnan(lo).any() or np.isnan(hi).any():
        raise KdrayError("t_min and t_max must not be NaN")
    if not (lo >= 0).all():
        raise KdrayError("t_min must be >= 0 (hits behind a ray's origin never count)")
    bad = np.flatnonzero(np.broadcast_to(lo > hi, (n,) if lo.ndim or hi.ndim else ()))
    if bad.size:
        i = int(bad[0])
        a = lo if lo.ndim == 0 else lo[i]
        b = hi if hi.ndim == 0 else hi[i]
        raise KdrayError(f"need t_min <= t_max, got t_min={float(a)} > t_max={float(b)} "
                         f"(ray {i})")
    return lo, hi, (1 if lo.ndim or hi.ndim else 0)


def _ranges(t_min, t_max, n, scale):
    """(t_mins, t_maxs, t_step) as queries.cl takes them: float32 arrays in the tree's
    units, of n elements (t_step 1) or of one (t_step 0) (`check_ranges`)."""
    lo, hi, step = check_ranges(t_min, t_max, n)
    shape = (n,) if step else (1,)
    with np.errstate(over="ignore"):
        return (np.ascontiguousarray(np.broadcast_to(lo / scale, shape), dtype=np.float32),
                np.ascontiguousarray(np.broadcast_to(hi / scale, shape), dtype=np.float32),
                step)


_FLOAT32_MAX = float(np.finfo(np.float32).max)


def range_pairs(t_min, t_max, n, scale):
    """(t_ranges, t_step) as trace_rays takes them (render.cl): a float32 array
    (host.page_aligned_empty's) of (t_min, t_max) pairs in the tree's units, (n, 2)
    (t_step 1) or (1, 2) (t_step 0: one range for all), from numbers or (n,) arrays
    (`check_ranges`; beyond float32: inf, the same range)."""
    lo, hi, step = check_ranges(t_min, t_max, n)
    pairs = page_aligned_empty((n if step else 1, 2), np.float32)
    if not step:
        a, b = float(lo) / scale, float(hi) / scale
        if a <= _FLOAT32_MAX and (b <= _FLOAT32_MAX or b == np.inf):
            pairs[0] = (a, b)                    # no rounding past float32 (most calls)
            return pairs, step
    with np.errstate(over="ignore"):
        pairs[:, 0] = lo / scale
        pairs[:, 1] = hi / scale
    return pairs, step


class QueryRays:
    """The rays of one query as queries.cl reads them: float32, relative to the tree's
    origin in its units (kdray.ray_input.rays32, made when first needed), or where
    `world` is set (an image's rays on a CPU: `as_image`) the caller's arrays as they are,
    which the kernels convert to the same numbers as they read them (RAYS_WORLD); with
    their t ranges (`_ranges`), and image_w: the width of the row-major image they are
    (0: none known; `as_image`)."""

    def __init__(self, tracer, origins, directions, t_min, t_max):
        o, d, self.shape = ray_input.flat_rays(origins, directions)
        o, d, self.o_step = ray_input.origin_rows(o, d)
        self.n = len(d)
        self.image_w = 0
        self.world = None                        # or the (origin, direction) C types
        self._frame = (tracer._origin, tracer._scale)
        self._given = (o, d)                     # as the caller gave them (`exact`)
        self._relative = None
        t_min, t_max = check_t(t_min, "t_min", self.shape), check_t(t_max, "t_max", self.shape)
        self.t_mins, self.t_maxs, self.t_step = _ranges(t_min, t_max, self.n, tracer._scale)

    @classmethod
    def relative(cls, tracer, o32, d32, given):
        """QueryRays of rays already as queries.cl reads them (o32, d32: (N, 3) float32,
        host.page_aligned_empty's, relative to the tree's origin in its units), each over
        (0, inf); given: a function returning (o, d) as the caller gave them, called
        only where they are needed (`exact`, `subset`)."""
        rays = object.__new__(cls)
        rays.n = len(d32)
        rays.shape, rays.image_w, rays.o_step, rays.world = (rays.n,), 0, 1, None
        rays._frame = (tracer._origin, tracer._scale)
        rays._relative, rays._given = (o32, d32), given
        rays.t_mins, rays.t_maxs, rays.t_step = _ranges(0.0, np.inf, rays.n, tracer._scale)
        return rays

    @property
    def o(self):
        """Origins as float32 relative to the tree (made on first use)."""
        return self._rays32()[0]

    @property
    def d(self):
        """Directions as float32 (made on first use)."""
        return self._rays32()[1]

    def _rays32(self):
        """(o32, d32): the float32 rays relative to the tree (ray_input.rays32)."""
        if self._relative is None:
            o, d = self.given()
            self._relative = ray_input.rays32(o, d, self.o_step, *self._frame)
        return self._relative

    def given(self):
        """(o, d): the rays as the caller gave them (made on first use where `relative`
        did not keep them)."""
        if callable(self._given):
            self._given = self._given()
        return self._given

    def exact(self, start, stop):
        """(o64, d64): the float64 rays start .. stop - 1 as given, in world
        coordinates, which list_rays refines hits from with REFINE
        (`launch`'s exact arguments): the caller's arrays themselves where they are
        float64 and contiguous, which the device reads in place."""
        if not hasattr(self, "_exact"):
            o, d = self.given()
            self._exact = (np.ascontiguousarray(o, dtype=np.float64),
                           np.ascontiguousarray(d, dtype=np.float64))
        o, d = self._exact
        return (o[start:stop] if self.o_step else o), d[start:stop]

    def ray_bytes(self):
        """(origin, direction) bytes of a ray as the kernels read them."""
        if self.world:
            return tuple(ray_input.RAY_BYTES[t] for t in self.world)
        return 12, 12

    def part(self, start, stop):
        """(o, d, t_mins, t_maxs) of rays start .. stop - 1, as the kernels read them
        (the caller's arrays where `world`)."""
        o, d = (np.ascontiguousarray(a) for a in self.given()) if self.world else self._rays32()
        o = o[start:stop] if self.o_step else o
        t = slice(start, stop) if self.t_step else slice(None)
        return o, d[start:stop], self.t_mins[t], self.t_maxs[t]

    def subset(self, index):
        """A QueryRays of the rays `index` ((k,) int array, or a slice) only, read as float32
        (views of those made already, else made for them alone)."""
        other = object.__new__(QueryRays)
        o, d = self.given()
        other.n = len(d[index])
        other.shape, other.image_w, other.world = (other.n,), 0, None
        other.o_step, other.t_step = self.o_step, self.t_step
        other._frame = self._frame
        other._given = (o[index] if self.o_step else o, d[index])
        other._relative = None
        if self._relative is not None:
            o32, d32 = self._relative
            other._relative = (o32[index] if self.o_step else o32, d32[index])
        other.t_mins = self.t_mins[index] if self.t_step else self.t_mins
        other.t_maxs = self.t_maxs[index] if self.t_step else self.t_maxs
        return other


def as_image(tracer, rays, origins, directions):
    """`rays` with image_w set where they are an image (image-shaped, or (N, 3) rays
    found to be one as `Tracer.trace` finds them: kdray.ray_grid) and packet programs
    walk them in blocks of 4 x packet / 4 pixels (kernels/queries.cl, kd_block_rays),
    which share more of the tree than a row's; the answers are the same."""
    from .trace import IMAGE_SEARCH_MIN_RAYS
    if tracer.packet == 1 or _run(tracer) % tracer.packet:
        return rays
    if len(rays.shape) >= 2:
        rays.image_w = rays.shape[-1]
    elif rays.n >= IMAGE_SEARCH_MIN_RAYS:
        o, d, _ = ray_input.flat_rays(origins, directions)
        rays.image_w, search = tracer._image_width(o, d)
        if search is not None:
            search()                             # keeps the width for the next call
            rays.image_w = tracer._image_width(o, d)[0]
    o, d = rays.given()
    if rays.image_w and tracer._rays_in_kernel and {o.dtype, d.dtype} <= set(ray_input.C_TYPES):
        # an image's rays are read as given, in order: no float32 copy made on the host
        # (a sixth of a camera's count), the same numbers
        rays.world = (ray_input.C_TYPES[o.dtype], ray_input.C_TYPES[d.dtype])
    return rays


def _run(tracer):
    """Rays a work-item of queries.cl takes on the tracer's device (its RUN)."""
    return RUN_CPU if tracer._cpu else 1


def _program(tracer, kernel, world=None):
    """queries.cl's `kernel` (count_rays, list_rays, or the first pass's list_first:
    LIST_SLOTS slots a ray in private memory), the only kernel compiled in its program
    (KD_ONLY_*: each compiles in about half the time of two), built for the tracer's
    device and tree (kept with its other programs): {"program": Program, kernel:
    Kernel, "run": rays a work-item}; world: None, or the (origin, direction) C types
    of rays read as given (RAYS_WORLD, `QueryRays.world`)."""
    first = kernel == "list_first"
    run = _run(tracer)
    local = tracer.local_size if tracer._cpu else min(
        64, int(tracer.device.max_work_group_size))
    defines = {"STACK_SIZE": tracer.packet_stack_size, "LOCAL_SIZE": local, "RUN": run}
    if tracer.refine:
        defines["REFINE"] = None
    if tracer.packet > 1:
        # a lone ray's leaf tested a packet's width of triangles at a time (the tree's
        # leaves are laid out in such runs for packet Tracers)
        defines["PACKET"] = tracer.packet
        defines["PACKET_STACK_SIZE"] = tracer.packet_stack_size
        if tracer._plain_vector_ops:
            defines["KD_PLAIN_VECTOR_OPS"] = None
        defines.update(tracer._packet_rules())
        # rays that share no path walk the tree's wide nodes (kernels/wide.cl)
        defines["KD_WIDE"] = None
        defines["WIDE_STACK"] = tracer._wide()[1]
    if first:
        defines["LIST_SLOTS"] = LIST_SLOTS
    if world:
        defines["RAYS_WORLD"] = None
        defines["ORIGIN_T"], defines["DIRECTION_T"] = world
        if tracer._scale != 1.0:
            # exact: a power of two as a hexadecimal literal (as Tracer._program's)
            defines["SCALE"] = f"{tracer._scale.hex()}f"
            defines["SCALE_INV"] = (1.0 / tracer._scale).hex()
    if kernel == "count_rays":
        defines["KD_ONLY_COUNT_RAYS"] = None
    elif kernel == "list_rays":
        defines["KD_ONLY_LIST_RAYS"] = None
    entry = tracer._built("queries.cl", defines, (kernel,))
    entry["run"], entry["local"] = run, local
    return entry


def launch(tracer, kernel_name, rays, start, stop, extra, outputs, exact=False, read=True):
    """Run `kernel_name` on rays start .. stop - 1: extra (the kernel's arguments after
    the rays: numpy scalars, or host arrays it reads, or None for NULL, or a device
    buffer as it is), then with `exact` the float64 rays as given (KD_EXACT_RAY_ARGS:
    `QueryRays.exact`, the tree's origin and scale), and outputs (dict name -> host array it
    writes, in argument order). read False: the outputs are left on the device, their
    buffers returned (name -> buffer) once the kernel has run, for the caller to read
    (Tracer._read_outputs) as much of them as it needs."""
    cl = _device._cl()
    n = stop - start
    if n == 0:
        return {}
    entry = _program(tracer, kernel_name, world=rays.world)
    o, d, t_mins, t_maxs = rays.part(start, stop)
    keep = []                                    # the host arrays the buffers use

    def inp(array):
        if array is None or isinstance(array, (np.generic, cl.MemoryObject)):
            return array                         # None: NULL
        array = np.ascontiguousarray(array)
        keep.append(array)
        return tracer._whole_input(array)        # queries.cl takes no offsets for them

    # Read-write: list_rays keeps its slots sorted in place (it reads what it wrote),
    # and compilers may turn a kernel's store in a loop into a load before it and a
    # store after it (Oclgrind's LLVM does, for out[ids[l]] in packet programs), which
    # reads a write-only buffer. On a CPU the buffers are the host's arrays either way,
    # elsewhere nothing is copied in. An output given as None is not written (NULL).
    device_out = {name: None if a is None else tracer._output_buffer(a, read=True)
                  for name, a in outputs.items()}
    exact_args = ()
    if exact:
        # read in place from their page's start, at an offset (list_rays)
        given = rays.exact(start, stop)
        keep.extend(given)
        (o64, o_at), (d64, d_at) = map(tracer._input_buffer, given)
        exact_args = (o64, d64, np.uint32(o_at), np.uint32(d_at),
                      *np.asarray(tracer._origin, dtype=np.float64),
                      np.float64(1.0 / tracer._scale))
    # an image's blocks only where the launch takes all its rays; other rays in no
    # order of their own taken in one (kdray.ray_order)
    image_w = rays.image_w if (start, stop) == (0, rays.n) else 0
    keep.extend((o, d))
    (o_buf, o_at), (d_buf, d_at) = tracer._input_buffer(o), tracer._input_buffer(d)
    box = tracer._world_box if rays.world else tracer.tree.bounds
    order = None if image_w else ray_order(tracer, o, d, *box, rays.o_step,
                                           ((o_buf, o_at), (d_buf, d_at)))
    wide = (tracer._wide()[0],) if tracer.packet > 1 else ()
    origin = tuple(np.float64(x) for x in tracer._origin) if rays.world else ()
    args = (tracer._nodes, tracer._tris, tracer._tri_ids, tracer._bounds,
            np.uint32(tracer._n_nodes), *wide, o_buf, d_buf, np.uint32(rays.o_step),
            np.uint32(o_at), np.uint32(d_at), *origin, inp(t_mins), inp(t_maxs),
            np.uint32(rays.t_step), np.uint32(n), np.uint32(image_w), inp(order),
            *map(inp, extra), *exact_args, *device_out.values())
    items = -(-n // entry["run"])
    if image_w:
        # kd_block_rays: a work-item's band of 4 * run / packet columns, packet / 4 rows
        band_w, rows = 4 * (entry["run"] // tracer.packet), tracer.packet // 4
        items = -(-image_w // band_w) * -(-(n // image_w) // rows)
    local = entry["local"]
    tracer._enqueue(entry, kernel_name, -(-items // local) * local, local, args)
    if not read:
        tracer.queue.finish()                    # the inputs in `keep` are read by now
        return device_out
    tracer._read_outputs({k: v for k, v in device_out.items() if v is not None}, outputs)


def launches(tracer, rays, widths):
    """(start, stop) of each launch over `rays`, as many rays a launch as fit beside the
    tree (Tracer._launch_size); widths: the launch's bytes a ray besides the rays'."""
    o_bytes, d_bytes = rays.ray_bytes()
    step = tracer._launch_size([o_bytes * rays.o_step, d_bytes, 8 * rays.t_step] + widths)
    return [(start, min(rays.n, start + step)) for start in range(0, rays.n, step)]


def check_fault(faulty, what):
    """DeviceError when any ray's walk met a corrupt tree (faulty: (N,) bool)."""
    if faulty.any():
        raise DeviceError(f"{what}: the walk met a tree deeper than its depth or with more "
                          f"leaves than nodes; the tree is corrupt (kdray info --check)")


def count_pass(tracer, rays, crossing):
    """(counts, raw) of count_rays over `rays` (crossing: the count's rule): counts
    (N,) int32, the kernel's output itself, each ray's distinct triangles hit, but for
    the rays `raw` ((k,) int64) whose count was lost (kernels/queries.cl,
    kd_count_hit: more hits than it keeps, KD_SEEN, far out of their order): theirs is
    every hit found, copies included, a bound on their distinct hits."""
    out = page_aligned_empty((rays.n,), np.uint32)
    for start, stop in launches(tracer, rays, [4]):
        launch(tracer, "count_rays", rays, start, stop, (np.uint32(crossing),),
                {"out": out[start:stop]})
    # one pass finds the marked rays (COUNT_RAW, WALK_FAULT), then only they are read
    marked = np.flatnonzero(out >= np.uint32(WALK_FAULT))
    check_fault(out[marked] == WALK_FAULT, "count")
    raw = marked[(out[marked] & np.uint32(COUNT_RAW)) != 0]
    out[raw] &= ~np.uint32(COUNT_RAW)
    return out.view(np.int32), raw
