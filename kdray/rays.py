"""Ray queries beyond the nearest hit: any hit, every hit, crossing counts, inside tests.

    tracer.occluded(origins, directions, t_min=0, t_max=inf)    # (N,) bool
    tracer.count(origins, directions)                           # (N,) int32 crossings
    tracer.contains(points)                                     # (N,) bool, closed meshes
    hits = tracer.intersections(origins, directions, max_hits=None)
    hits.offsets (N + 1,) int64; per hit: hits.ray, .t, .prim, .u, .v, .object

The functions here take a Tracer (kdray.trace) and run kernels/queries.cl on its
device and tree; `Tracer.occluded` and the others are thin faces over them. Rays are
given as `Tracer.trace` takes them: origins (N, 3) or (3,) and directions (N, 3) (or
image-shaped, (..., 3), answered in that shape), world coordinates, float64 or float32;
t_min, t_max scalars or (N,) arrays (per ray), 0 <= t_min <= t_max, t in units of
|direction|. A ray with a non-finite component or a zero direction has no hit
(occluded False, count 0, no intersections), as in `trace`.

Which hits (docs/conventions.md, "Ray queries"):
- occluded and intersections take the nearest hit's test (kernels/triangle.cl): a ray
  through an edge or a vertex hits every triangle that has it, so `occluded` is exactly
  `trace(...).hit` and intersections' first hit is trace's hit (ties by input id).
- count takes the crossing rule: edge functions with exact signs, an exactly zero one
  decided as if the ray were moved by a fixed infinitesimal step in its sheared plane,
  so a ray through an edge or a vertex shared by consistently oriented triangles
  crosses there once. `count` <= the number of intersections; they differ only where
  a ray meets an edge or a vertex.
- A triangle in several leaves of the tree is counted and listed once.
"""
import dataclasses
import functools

import numpy as np

from . import device as _device
from . import point_order, ray_input
from .double import flat_rays64, wants_double
from .errors import DeviceError, KdrayError
from .host import available_memory, check_host_memory, page_aligned_empty, take_rows
from .points import SORT_FROM, check_points, spatial_order
from .ray_order import ray_order
from .tree import object_ids


CONTAINS_DIRECTION = np.array([0.5377513, 0.6153846, 0.5763888], dtype=np.float32)
"""The direction `contains` casts a point's ray along, its components' signs those of
the point's offset from the box's centre (`contains_directions`): fixed, so that an
answer is the same every run, and not in any axis plane or along a diagonal, where
meshes built on grids have their edges (a ray through an edge or vertex is still
counted exactly)."""


def contains_directions(tracer, points):
    """(N, 3) float32: the direction of each point's ray in `contains` (points (N, 3)
    float64, world coordinates): CONTAINS_DIRECTION with each component's sign that of
    the point's offset from the centre of the tree's box (+ at the centre), away from
    the centre towards the nearest corner, so that the ray leaves the box soon: half
    the walk, on average, of one direction for all (random points in a box)."""
    return np.take(_OCTANT_DIRECTIONS, _sides(tracer, points), axis=0)


def _sides(tracer, points):
    """(N,) uint8: bit k set where the point (points (N, 3) float64, world coordinates)
    is at or above the middle of the tree's box on axis k: its octant of the box."""
    c = _middle(tracer)
    # column by column, in uint8: 3x as fast as comparing the (N, 3) array with c
    sides = (points[:, 0] >= c[0]).view(np.uint8)
    for k in (1, 2):
        sides |= (points[:, k] >= c[k]).view(np.uint8) << k
    return sides


def _middle(tracer):
    """(3,) float64: the middle of the tree's box in world coordinates, whose sides
    `_sides` tells."""
    lo, hi = (np.asarray(b, dtype=np.float64) for b in tracer.tree.world_box())
    return 0.5 * (lo + hi)


_OCTANT_DIRECTIONS = np.where((np.arange(8)[:, None] >> np.arange(3)) & 1 == 1,
                              CONTAINS_DIRECTION, -CONTAINS_DIRECTION)
"""(8, 3) float32: the direction of `contains_directions` for each octant (`_sides`)."""

COUNT_RAW = 0x80000000
"""count_rays marks a count of every hit found, copies included (kernels/queries.cl)."""
WALK_FAULT = 0x40000000
"""The kernels' mark of a walk that met a corrupt tree (never for a valid one)."""
LIST_MORE = 0x20000000
"""list_rays marks the count of a ray that had more hits than slots (kernels/queries.cl)."""

GUESS_HITS = 8
"""Slots a ray gets in `intersections`' first pass (at most LIST_SLOTS), which lists
every hit of the rays that have no more (most rays: 0.4-0.7 hits a ray for a camera's
or random rays, 2.6 for rays aimed at a closed mesh from outside, of which 5 % have
more than 4); only the others are counted, then listed again with their own number
of slots."""

LIST_SLOTS = 8
"""The slots a ray keeps in private memory in a first pass (kernels/queries.cl,
list_first, built with LIST_SLOTS), which writes only the hits it finds, one after
another: writing every ray's slots, mostly empty and fresh memory at each call, took
about a third of the pass's time."""

GUESS_CHUNK = 1 << 20
"""Rays `intersections` takes through its first pass at once: their slots (GUESS_HITS
a ray, 128 bytes) are reserved, and only their hits' pages are written."""

RUN_CPU = 64
"""Consecutive rays a work-item takes on a CPU device (one per work-item on a GPU). In
packet programs those that share their paths are walked as packets, the others
through the wide nodes two at a time (kernels/queries.cl, kd_walk_block), each holding
its query's state in private memory (about 200 bytes: 13 KB a work-item)."""

HIT_BYTES = 16
"""Host bytes of one listed hit: t (4), u and v (8), prim (4); ray and object are
made on the host when asked (8 bytes each)."""

COUNT_FIRST = 1 << 12
"""The rays with many hits `intersections` counts first, then twice as many at a time,
so that lists that cannot fit in memory are refused once the hits counted so far do
not fit, not after every ray is counted (a million rays through 40,000 stacked
triangles take minutes to count)."""

COUNT_LIST_BYTES = 1 << 30
"""The most host memory the hits listed to count rays with many take at once (`_counts`,
whose answers need none of them after; and no more than a quarter of what is
available): the rays are listed in groups that fit, so that a count's memory does not
grow with its hits."""


@dataclasses.dataclass(eq=False)
class Intersections:
    """Every hit of N rays, in compressed rows: the hits of ray i are
    offsets[i] .. offsets[i + 1] - 1, sorted by t, ties by input triangle id.

    offsets : (N + 1,) int64
    t : (H,) float32 (float64 with precision="double"), in units of |direction|
    prim : (H,) uint32 input triangle id;  u, v : (H,) barycentrics as `Hits` has them
    object_table : the tree's KdTree.objects, which `object` looks up prim in
    shape : the rays' shape ((N,), or (H, W) for image-shaped rays: ray i is then the
        row-major ray i)."""

    offsets: np.ndarray
    t: np.ndarray
    prim: np.ndarray
    u: np.ndarray
    v: np.ndarray
    object_table: np.ndarray = dataclasses.field(default=None, repr=False)
    shape: tuple = None

    def __len__(self):
        return len(self.offsets) - 1

    @property
    def counts(self):
        """(N,) int64: hits of each ray (in the rays' shape)."""
        counts = np.diff(self.offsets)
        return counts if self.shape is None else counts.reshape(self.shape)

    @functools.cached_property
    def ray(self):
        """(H,) int64: the ray of each hit (its index in the flattened rays)."""
        return np.repeat(np.arange(len(self), dtype=np.int64), np.diff(self.offsets))

    @functools.cached_property
    def object(self):
        """(H,) uint32: each hit triangle's object (kdray.tree.object_ids)."""
        return object_ids(self.prim, self.object_table)

    def of(self, i):
        """(t, prim) of ray i's hits (views)."""
        a, b = self.offsets[i], self.offsets[i + 1]
        return self.t[a:b], self.prim[a:b]


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


def range_pairs(t_min, t_max, n, scale):
    """(t_ranges, t_step) as trace_rays takes them (render.cl): a page-aligned
    float32 array of (t_min, t_max) pairs in the tree's units, (n, 2) (t_step 1) or
    (1, 2) (t_step 0: one range for all), from numbers or (n,) arrays
    (`check_ranges`; beyond float32: inf, the same range)."""
    lo, hi, step = check_ranges(t_min, t_max, n)
    pairs = page_aligned_empty((n if step else 1, 2), np.float32)
    with np.errstate(over="ignore"):
        pairs[:, 0] = lo / scale
        pairs[:, 1] = hi / scale
    return pairs, step


class _Rays:
    """The rays of one query as queries.cl reads them: float32, relative to the tree's
    origin in its units (kdray.ray_input.rays32, made when first needed), or where
    `world` is set (an image's rays on a CPU: `_image`) the caller's arrays as they are,
    which the kernels convert to the same numbers as they read them (RAYS_WORLD); with
    their t ranges (`_ranges`), and image_w: the width of the row-major image they are
    (0: none known; `_image`)."""

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
        """_Rays of rays already as queries.cl reads them (o32, d32: (N, 3) float32,
        page-aligned, relative to the tree's origin in its units), each over (0, inf);
        given: a function returning (o, d) as the caller gave them, called only where
        they are needed (`exact`, `subset`)."""
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
        (`_launch`'s exact arguments): the caller's arrays themselves where they are
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
        """A _Rays of the rays `index` ((k,) int array, or a slice) only, read as float32
        (views of those made already, else made for them alone)."""
        other = object.__new__(_Rays)
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


def _image(tracer, rays, origins, directions):
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
    return RUN_CPU if _device.is_cpu(tracer.device) else 1


def _program(tracer, kernel, world=None):
    """queries.cl's `kernel` (count_rays, list_rays, or the first pass's list_first:
    LIST_SLOTS slots a ray in private memory), the only kernel compiled in its program
    (KD_ONLY_*: each compiles in about half the time of two), built for the tracer's
    device and tree (kept with its other programs): {"program": Program, kernel:
    Kernel, "run": rays a work-item}; world: None, or the (origin, direction) C types
    of rays read as given (RAYS_WORLD, `_Rays.world`)."""
    first = kernel == "list_first"
    run = _run(tracer)
    local = tracer.local_size if _device.is_cpu(tracer.device) else min(
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


def _launch(tracer, kernel_name, rays, start, stop, extra, outputs, exact=False, read=True):
    """Run `kernel_name` on rays start .. stop - 1: extra (the kernel's arguments after
    the rays: numpy scalars, or host arrays it reads, or None for NULL, or a device
    buffer as it is), then with `exact` the float64 rays as given (KD_EXACT_RAY_ARGS:
    `_Rays.exact`, the tree's origin and scale), and outputs (dict name -> host array it
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
    box = tracer.tree.world_box() if rays.world else tracer.tree.bounds
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


def _launches(tracer, rays, widths):
    """(start, stop) of each launch over `rays`, as many rays a launch as fit beside the
    tree (Tracer._launch_size); widths: the launch's bytes a ray besides the rays'."""
    o_bytes, d_bytes = rays.ray_bytes()
    step = tracer._launch_size([o_bytes * rays.o_step, d_bytes, 8 * rays.t_step] + widths)
    return [(start, min(rays.n, start + step)) for start in range(0, rays.n, step)]


def _check_fault(faulty, what):
    """DeviceError when any ray's walk met a corrupt tree (faulty: (N,) bool)."""
    if faulty.any():
        raise DeviceError(f"{what}: the walk met a tree deeper than its depth or with more "
                          f"leaves than nodes; the tree is corrupt (kdray info --check)")


def occluded(tracer, origins, directions, t_min=0.0, t_max=np.inf, precision="single"):
    """(N,) bool (the rays' shape): whether each ray hits anything with t_min < t <
    t_max, the same answers as `trace(...).hit`: `trace`'s traversal (render.cl,
    trace_rays with ANY_HIT), each ray over its own range, stopped at the first hit it
    finds; rays that share no path walk the wide nodes (kernels/wide.cl).
    precision="double": `trace(..., precision="double").hit`, the hits that count in
    float64 (`_any_counted64`)."""
    double = wants_double(precision, tracer.tree)
    o, d, shape = ray_input.flat_rays(origins, directions)
    t_min, t_max = check_t(t_min, "t_min", shape), check_t(t_max, "t_max", shape)
    hits = tracer._trace_rays(o, d, shape, t_min, t_max, (), any_hit=True)
    if double:
        return _any_counted64(tracer, hits.prim, origins, directions, t_min,
                              t_max).reshape(shape)
    return hits.hit.reshape(shape)


def _any_counted64(tracer, prim, origins, directions, t_min, t_max):
    """(N,) bool: `occluded` in double precision, from the any-hit walk's triangles
    (prim (N,) uint32 input ids, MISS where none): a ray whose triangle counts in
    float64 (_counted64) is occluded; one whose triangle does not (its float64 t out of
    range, or its origin on its float64 plane: a ray from a surface point) is occluded
    where any other of its float32 hits counts, which its nearest that counts
    (`_counted_lists`) says. Float64 only drops hits, so a ray with no float32 hit
    stays unoccluded, as `trace`'s double hits do."""
    from .layout import MISS
    n = len(prim)
    o, d = flat_rays64(origins, directions)
    lo, hi = _flat_t(t_min, n), _flat_t(t_max, n)
    hit = prim != MISS
    counted = hit & _hits_counted64(tracer, prim, o, d, lo, hi)
    doubt = np.flatnonzero(hit & ~counted)
    if doubt.size:
        # each listed with room for two: most such rays start on the triangle found
        ray = _counted_lists(tracer, o, d, lo, hi, doubt, 2, 1)[0]
        counted[ray] = True
    return counted


def _count_pass(tracer, rays, crossing):
    """(counts, raw) of count_rays over `rays` (crossing: the count's rule): counts
    (N,) int32, the kernel's output itself, each ray's distinct triangles hit, but for
    the rays `raw` ((k,) int64) whose count was lost (kernels/queries.cl,
    kd_count_hit: more hits than it keeps, KD_SEEN, far out of their order): theirs is
    every hit found, copies included, a bound on their distinct hits."""
    out = page_aligned_empty((rays.n,), np.uint32)
    for start, stop in _launches(tracer, rays, [4]):
        _launch(tracer, "count_rays", rays, start, stop, (np.uint32(crossing),),
                {"out": out[start:stop]})
    # one pass finds the marked rays (COUNT_RAW, WALK_FAULT), then only they are read
    marked = np.flatnonzero(out >= np.uint32(WALK_FAULT))
    _check_fault(out[marked] == WALK_FAULT, "count")
    raw = marked[(out[marked] & np.uint32(COUNT_RAW)) != 0]
    out[raw] &= ~np.uint32(COUNT_RAW)
    return out.view(np.int32), raw


def _counts(tracer, rays, crossing):
    """(N,) int32 exact counts of distinct triangles hit (crossing: the count's rule):
    `_count_pass`'s, its rays whose count was lost mended in place."""
    counts, raw = _count_pass(tracer, rays, crossing)
    # listed, which deduplicates, a group of rays at a time (COUNT_LIST_BYTES; every
    # hit found, copies too, a slot)
    caps = counts[raw].astype(np.int64)
    have = available_memory()
    most = COUNT_LIST_BYTES if have is None else min(COUNT_LIST_BYTES, have // 4)
    for group in _groups(caps, most // (HIT_BYTES + 4)):
        listed, _ = _list(tracer, rays.subset(raw[group]), caps[group], crossing)
        counts[raw[group]] = np.diff(listed.offsets)
    return counts


def _groups(sizes, most):
    """Slices of consecutive entries of sizes ((k,) int64) whose sums are at most `most`
    (one entry a group where it alone is more), in order."""
    ends = np.cumsum(sizes)
    start = 0
    while start < len(sizes):
        before = int(ends[start - 1]) if start else 0
        stop = max(start + 1, int(np.searchsorted(ends, before + most, side="right")))
        yield slice(start, stop)
        start = stop


def count(tracer, origins, directions, t_min=0.0, t_max=np.inf, precision="single"):
    """(N,) int32 (the rays' shape): how many times each ray crosses the surface with
    t_min < t < t_max, under the crossing rule (module docstring): a ray through an edge
    or a vertex shared by consistently oriented triangles crosses there once.
    precision="double": the crossings that count in float64 (`_crossings64`)."""
    double = wants_double(precision, tracer.tree)
    rays = _image(tracer, _Rays(tracer, origins, directions, t_min, t_max), origins,
                  directions)
    counts = _counts(tracer, rays, True)
    if double:
        counts = _crossings64(tracer, rays, counts, origins, directions, t_min, t_max)
    return counts.reshape(rays.shape)


def _crossings64(tracer, rays, counts, origins, directions, t_min, t_max):
    """(N,) int32: `count` in double precision, from its float32 counts ((N,) int32,
    exact): each ray that crosses anything has its crossings listed (the same rule,
    `_list`), and those that do not count in float64 (_counted64: float64 t out of
    range, or the origin on the float64 plane) are dropped, a group of rays of at most
    COUNT_LIST_BYTES of lists at a time."""
    n = len(counts)
    o, d = flat_rays64(origins, directions)
    lo, hi = _flat_t(t_min, n), _flat_t(t_max, n)
    rows = np.flatnonzero(counts > 0)
    caps = counts[rows].astype(np.int64)
    have = available_memory()
    most = COUNT_LIST_BYTES if have is None else min(COUNT_LIST_BYTES, have // 4)
    out = counts.copy()
    # a listed crossing: its slot and count (HIT_BYTES + 4), then its ray, float64 t,
    # uv and tests on the host (about 64)
    for group in _groups(caps, most // (HIT_BYTES + 4 + 64)):
        at = rows[group]
        listed, _ = _list(tracer, rays.subset(at), caps[group], True)
        keep = _hits_counted64(tracer, listed.prim, o, d, lo, hi, rays=at[listed.ray])
        out[at] = np.bincount(listed.ray[keep], minlength=len(at))
    return out


WINDING = 2
"""count_rays' `crossing` argument for crossings summed with their facings (KD_WINDING;
0: every triangle hit, 1: crossings)."""
WINDING_RAW = 0x7FFFFFFF
"""count_rays' mark of a ray whose count was lost (kernels/queries.cl, kd_count_hit:
more crossings than it keeps, KD_SEEN, coming far out of their order) in its winding
mode (KD_WINDING)."""


def _contains_rays(tracer, p):
    """(rays, order): the rays of `contains` from points p ((N, 3) float64, world
    coordinates, finite), in spatial order (kdray.points.spatial_order: near points
    one after another, the points of each octant of the box one run, so that the
    directions are 8 repeated rows) from SORT_FROM points on (order None below and the
    directions `contains_directions`), which changes no answer."""
    if len(p) < SORT_FROM:
        return _Rays(tracer, p, contains_directions(tracer, p), 0.0, np.inf), None
    if point_order.available(tracer):
        # the keys, the gather and the rounding on the device (kdray.point_order)
        order, o32, d32 = point_order.contains_rays(tracer, p, _middle(tracer),
                                                    _OCTANT_DIRECTIONS)
        return _Rays.relative(tracer, o32, d32, lambda: (take_rows(p, order), d32)), order
    sides = _sides(tracer, p)
    order = spatial_order(p, *tracer.tree.world_box(), sides)
    d = np.repeat(_OCTANT_DIRECTIONS, np.bincount(sides, minlength=8), axis=0)
    # the points made float32 and relative to the tree first, then put in order: half
    # the bytes of float64 rows to gather (the same numbers either way)
    o32, d32 = ray_input.rays32(p, d, 1, tracer._origin, tracer._scale)
    ordered = page_aligned_empty(p.shape, np.float32)
    take_rows(o32, order, out=ordered)
    return _Rays.relative(tracer, ordered, d32, lambda: (take_rows(p, order), d)), order


def _unsorted(a, order):
    """a ((N,), in the order of `_contains_rays`' rays) in the points' order: a new
    array, scattered once."""
    if order is None:
        return a
    out = np.empty_like(a)
    out[order] = a
    return out


def crossing_windings(tracer, points):
    """(N,) int64 (points (N, 3) float64, world coordinates, finite): each point's ray
    of `contains` (contains_directions) with its crossings' facings summed, +1 where
    the ray leaves through a triangle's front and -1 where it enters (kernels/queries.cl,
    kd_facing): on a closed, consistently oriented mesh the exact winding number of the
    point (points.closed_cycle). WINDING_RAW for a ray whose count was lost (more than
    32 crossings far out of their order in a k-d walk, kernels/queries.cl)."""
    def windings(p):
        rays, order = _contains_rays(tracer, p)
        out = page_aligned_empty((rays.n,), np.uint32)
        for start, stop in _launches(tracer, rays, [4]):
            _launch(tracer, "count_rays", rays, start, stop, (np.uint32(WINDING),),
                    {"out": out[start:stop]})
        _check_fault(out == WALK_FAULT, "winding")
        w = np.where(out == WINDING_RAW, WINDING_RAW, out.view(np.int32)).astype(np.int64)
        return _unsorted(w, order)
    return _in_point_chunks(tracer, points, windings)


POINT_CHUNK = 1 << 30
"""Points `contains` and `crossing_windings` order and answer at a time at most: their
order and counts are uint32 (kdray.point_order), so more points than 2^32 are taken in
parts (the answers do not depend on it)."""

POINT_DEVICE_BYTES = (24, 80)
"""(largest buffer, all buffers) device bytes a point of `contains` takes in
kdray.point_order: the float64 point itself, then with its keys, order, sides and
float32 rays (67 bytes, and room)."""


def point_chunk(tracer):
    """Points `contains` answers at a time on the tracer's device: POINT_CHUNK, or fewer
    where the whole set's float64 points would pass the device's largest buffer, or
    (a device with memory of its own: a GPU) their buffers together a quarter of its
    memory; a CPU device's buffers are the host's arrays, whose memory is checked
    before (check_points)."""
    device = tracer.device
    most = int(device.max_mem_alloc_size) // POINT_DEVICE_BYTES[0]
    if not tracer._zero_copy:
        most = min(most, int(device.global_mem_size) // (4 * POINT_DEVICE_BYTES[1]))
    return max(1, min(POINT_CHUNK, most))


def _in_point_chunks(tracer, p, answer):
    """answer(p) ((N,) array for points p (N, 3)) for `point_chunk` points at a time,
    the parts' answers concatenated (one part: answer(p) itself)."""
    chunk = point_chunk(tracer)
    if len(p) <= chunk:
        return answer(p)
    return np.concatenate([answer(p[a:a + chunk]) for a in range(0, len(p), chunk)])


def contains(tracer, points):
    """(N,) bool (the points' shape (..., 3) less its last axis): whether each point is
    inside the mesh, by the parity of `count` along a fixed direction from the point
    (`contains_directions`: CONTAINS_DIRECTION, away from the box's centre): exact for
    a closed, consistently oriented mesh, with no jitter, vote or second ray, and the
    same every run.

    A point on the surface (within the rounding of a hit's t, kernels/triangle.cl) is
    answered as if moved an infinitesimal step along its direction: inside where that
    direction points into the mesh. For a mesh that is not closed, parity has no
    meaning (a ray may leave through a hole): the answer is that of the one ray.
    KdrayError for points that are not finite or not (..., 3)."""
    p, shape = check_points(points)
    if len(p) == 0:
        return np.zeros(shape, dtype=bool)
    def inside(p):
        rays, order = _contains_rays(tracer, p)
        # the parity from each count's low byte (a cast, one byte a point from there
        # on): half the time of `% 2 == 1` and a copy before the scatter
        parity = _counts(tracer, rays, True).astype(np.uint8)
        parity &= 1
        return _unsorted(parity.view(bool), order)
    return _in_point_chunks(tracer, p, inside).reshape(shape)


def _list(tracer, rays, caps, crossing=False, nearest_k=False):
    """(Intersections, more) of `rays` (their float32 t, u, v) with at most caps[i]
    hits of ray i ((N,) int64; at least its distinct hits for every hit; or an int,
    the same for all; crossing: its crossings, the count's rule, not every hit), its
    nearest in (t, input id) order: the kernel fills each ray's slots (list_rays; a cap
    of at most LIST_SLOTS for all, `_first_pass`), then the slots left empty are
    dropped. more: (N,) bool, the rays that had
    more hits than caps[i]. nearest_k: the caps are the nearest hits wanted (max_hits,
    or a ray's exact count), not whether there are more: a ray's walk ends once its
    slots are taken and the last hit is final (queries.cl, kd_list_done), and `more`
    is then not known."""
    cap = int(caps) if np.ndim(caps) == 0 else None      # the same for every ray
    if cap is not None and cap <= LIST_SLOTS:
        n_found, more, first, slots = _first_pass(tracer, rays, cap, crossing, nearest_k)
        return _gathered(tracer, n_found, first, slots), more
    caps = np.broadcast_to(np.asarray(caps, dtype=np.int64), (rays.n,))
    offsets = _offsets(caps)
    total = int(offsets[-1])
    _check_hits_memory(total * (HIT_BYTES + 4) + rays.n * 12, total, rays.n)
    t = page_aligned_empty((total,), np.float32)
    uv = page_aligned_empty((total, 2), np.float32)
    prim = page_aligned_empty((total,), np.uint32)
    found = page_aligned_empty((rays.n,), np.uint32)
    # a launch's rays and slots fit the device (a ray's slots counted at their mean)
    mean = HIT_BYTES * total / max(rays.n, 1)
    # (the float32 rays, their float64 copies, t ranges, offsets, caps, count, slots)
    o_bytes, d_bytes = rays.ray_bytes()
    step = tracer._launch_size([(o_bytes + 24) * rays.o_step, d_bytes + 24, 8 * rays.t_step, 16,
                                int(mean) + 1])
    start = 0
    while start < rays.n:
        stop = min(rays.n, start + step)
        # and no more slots than the device's largest buffer holds
        limit = int(tracer.device.max_mem_alloc_size) // 8
        while stop - start > 1 and offsets[stop] - offsets[start] > limit:
            stop = start + (stop - start) // 2
        a, b = int(offsets[start]), int(offsets[stop])
        if b - a > limit:
            raise DeviceError(f"ray {start}'s {b - a} hits do not fit in one buffer on "
                              f"{tracer.device.name.strip()}: ask for fewer (max_hits)")
        extra = (np.uint32(crossing), np.uint32(nearest_k),
                 (offsets[start:stop] - a).astype(np.uint64), caps[start:stop].astype(np.uint32))
        _launch(tracer, "list_rays", rays, start, stop, extra,
                {"t": t[a:b] if b > a else np.empty(1, np.float32),
                 "uv": uv[a:b] if b > a else np.empty((1, 2), np.float32),
                 "prim": prim[a:b] if b > a else np.empty(1, np.uint32),
                 "found": found[start:stop]}, exact=tracer.refine)
        start = stop
    n_found, more = _found(found)
    if (n_found == caps).all():
        return Intersections(offsets, t, prim, uv[:, 0], uv[:, 1],
                             object_table=tracer.tree.objects), more
    return _gathered(tracer, n_found, offsets[:-1], (t, uv, prim)), more


def _check_hits_memory(nbytes, hits, rays, what=""):
    """KdrayError, before they are allocated, where nbytes for a list of `hits` hits of
    `rays` rays (`what` it is, if more than that) are more host memory than is
    available."""
    check_host_memory(nbytes, f"the {hits:,} hits of {rays:,} rays{' ' + what if what else ''}",
                      "list fewer rays at a time, or fewer hits a ray (max_hits)")


def _offsets(counts):
    """(N + 1,) int64: the compressed rows' offsets of (N,) counts."""
    offsets = np.zeros(len(counts) + 1, dtype=np.int64)
    np.cumsum(counts, out=offsets[1:])
    return offsets


def _found(found):
    """(n, more) of list_rays' or list_first's counts (found: (N,) uint32): each ray's
    hits listed ((N,) int64) and whether it had more (LIST_MORE); DeviceError where a
    walk met a corrupt tree."""
    # one pass finds the marked rays (LIST_MORE, WALK_FAULT), then only they are read
    marked = np.flatnonzero(found >= np.uint32(LIST_MORE))
    _check_fault(found[marked] == WALK_FAULT, "intersections")
    more = np.zeros(len(found), dtype=bool)
    more[marked] = True
    n_found = found.astype(np.int64)
    n_found[marked] &= ~LIST_MORE
    return n_found, more


def _gathered(tracer, counts, first, slots):
    """An Intersections of the hits listed in slots (t, uv, prim: (S,), (S, 2), (S,)):
    ray i's counts[i] hits ((N,) int64) from slot first[i] on ((N,) uint32 or int64).
    A run that reaches past the slots written takes what is there (past the end, the
    last slot): its caller puts those rays' hits in place. Gathered on the device where
    the slots are host memory it reads in place (`_rows_on_device`), else by numpy."""
    offsets = _offsets(counts)
    rows = _rows_on_device if tracer._zero_copy else _rows_on_host
    t, uv, prim = rows(tracer, counts, offsets, first, slots)
    return Intersections(offsets, t, prim, uv[:, 0], uv[:, 1], object_table=tracer.tree.objects)


def _rows_on_host(tracer, counts, offsets, first, slots):
    """(t, uv, prim) of `_gathered`'s rows (counts (N,), offsets (N + 1,) int64) by
    numpy: one index for the three gathers, made over the hits, not over every slot
    (most are empty)."""
    keep = np.arange(offsets[-1]) + np.repeat(first - offsets[:-1], counts)
    return tuple(take_rows(a, keep, mode="clip") for a in slots)


def _rows_on_device(tracer, counts, offsets, first, slots):
    """(t, uv, prim) of `_gathered`'s rows (counts (N,), offsets (N + 1,) int64), copied by
    kernels/hit_rows.cl, a ray a work-item: on a CPU about a quarter of numpy's time,
    which made an index over the hits and took three times with it on one thread."""
    n, total = len(offsets) - 1, int(offsets[-1])
    t = page_aligned_empty((total,), np.float32)
    uv = page_aligned_empty((total, 2), np.float32)
    prim = page_aligned_empty((total,), np.uint32)
    if not total:
        return t, uv, prim
    first = first if first.dtype in (np.uint32, np.int64) else first.astype(np.int64)
    first_t = "uint" if first.dtype == np.uint32 else "long"
    entry = tracer._built("hit_rows.cl", {"FIRST_T": first_t}, ("hit_rows",))
    (f_buf, f_at), (o_buf, o_at) = (tracer._input_buffer(a) for a in (first, offsets))
    tracer._run_items(entry, "hit_rows", n,
                      (f_buf, np.uint32(f_at), o_buf, np.uint32(o_at), np.uint32(n),
                       np.uint64(len(slots[0])), *map(tracer._whole_input, slots)),
                      {"t": t, "uv": uv, "prim": prim})
    return t, uv, prim


def _first_pass(tracer, rays, cap, crossing, nearest_k):
    """(n, more, first, slots): `_list`'s pass over `rays` with the same cap <=
    LIST_SLOTS for all, by list_first, which writes each work-item's hits one after
    another, so that only the slots of hits are written (the arrays' other pages are
    never touched): ray i's n[i] hits ((N,) int64) from slot first[i] on ((N,)
    uint32) of slots (t (S,) float32, uv (S, 2) float32, prim (S,) uint32), in (t,
    input id) order; more as `_list`'s."""
    cl = _device._cl()
    total = rays.n * cap
    _check_hits_memory(total * HIT_BYTES + rays.n * 24, total, rays.n)
    t = page_aligned_empty((total,), np.float32)
    uv = page_aligned_empty((total, 2), np.float32)
    prim = page_aligned_empty((total,), np.uint32)
    found = page_aligned_empty((rays.n,), np.uint32)
    first = page_aligned_empty((rays.n,), np.uint32)
    # (the float32 rays, their float64 copies, t ranges, count, first slot, slots)
    o_bytes, d_bytes = rays.ray_bytes()
    widths = [(o_bytes + 24) * rays.o_step, d_bytes + 24, 8 * rays.t_step, 8, HIT_BYTES * cap]
    step = min(tracer._launch_size(widths), int(tracer.device.max_mem_alloc_size) // (8 * cap))
    for start in range(0, rays.n, step):
        stop = min(rays.n, start + step)
        a, b = start * cap, stop * cap
        # where the launch's next hits go: a counter the work-items add to
        next_hit = cl.Buffer(tracer.context, cl.mem_flags.READ_WRITE | cl.mem_flags.COPY_HOST_PTR,
                             hostbuf=np.zeros(1, dtype=np.uint32))
        out = {"t": t[a:b], "uv": uv[a:b], "prim": prim[a:b], "found": found[start:stop],
               "first": first[start:stop]}
        device_out = _launch(tracer, "list_first", rays, start, stop,
                             (np.uint32(crossing), np.uint32(cap), np.uint32(nearest_k), next_hit),
                             out, exact=tracer.refine, read=False)
        # the slots as far as the hits go (a device other than a CPU copies no more)
        hits = np.zeros(1, dtype=np.uint32)
        cl.enqueue_copy(tracer.queue, hits, next_hit)
        used = {name: array[:int(hits[0])] if name in ("t", "uv", "prim") else array
                for name, array in out.items()}
        used = {name: array for name, array in used.items() if array.size}   # no 0 bytes
        tracer._read_outputs({name: device_out[name] for name in used}, used)
        if start:
            first[start:stop] += np.uint32(a)    # the slots' total fits (memory)
    n_found, more = _found(found)
    return n_found, more, first, (t, uv, prim)


def intersections(tracer, origins, directions, t_min=0.0, t_max=np.inf, max_hits=None,
                  precision="single"):
    """Every hit of each ray with t_min < t < t_max, sorted by t (ties by input id),
    each triangle once: an `Intersections`. max_hits=k keeps each ray's k nearest (the
    first k of the whole list). A first pass lists each ray's GUESS_HITS nearest and
    marks the rays that had more; those are counted, then listed again with as many
    slots: no hit is dropped for want of room (KdrayError when they do not fit in
    memory). precision="double": t, u, v in float64 from the tree's float64 triangles
    and the rays as given (kdray.double), sorted by that t."""
    double = wants_double(precision, tracer.tree)
    if max_hits is not None:
        if isinstance(max_hits, bool) or not isinstance(max_hits, (int, np.integer)):
            raise KdrayError(f"max_hits must be None or an integer >= 1, got "
                             f"{type(max_hits).__name__} {max_hits!r:.60}".replace("\n", " "))
        if max_hits < 1:
            raise KdrayError(f"max_hits must be at least 1, got {max_hits}")
        # a Python int (numpy's small integers overflow in the slots' sizes), and no
        # more than a ray can have: each triangle is listed once
        max_hits = min(int(max_hits), max(1, len(tracer.tree.triangles)))
    rays = _image(tracer, _Rays(tracer, origins, directions, t_min, t_max), origins,
                  directions)
    if rays.n <= GUESS_CHUNK:
        hits = _listed(tracer, rays, max_hits)
    else:
        hits = _concatenated([_listed(tracer, rays.subset(slice(a, a + GUESS_CHUNK)), max_hits)
                              for a in range(0, rays.n, GUESS_CHUNK)])
    hits.t *= np.float32(tracer._scale)      # a power of two: exact
    if double:
        hits, at_origin = _double(tracer, hits, origins, directions)
        hits = _in_range(tracer, hits, at_origin, origins, directions, t_min, t_max, max_hits)
    hits.shape = None if len(rays.shape) == 1 else rays.shape
    return hits


def _flat_t(t, n):
    """(n,) float64 view of a t range's end: a number, or an array of the rays' shape."""
    t = np.asarray(t, dtype=np.float64)
    return np.broadcast_to(t.reshape(-1) if t.ndim else t, (n,))


def _hits_counted64(tracer, prim, o, d, lo, hi, rays=None):
    """(h,) bool: whether each hit the kernels found (prim (h,) input ids, MISS: none)
    counts in float64 (_counted64) for its ray, row `rays[i]` (or i) of o, d (N, 3)
    float64 and lo, hi (N,)."""
    from .double import hits_double
    t, _, at_origin = hits_double(tracer.tree.triangles64, prim, o, d, rays=rays,
                                  tree=tracer.tree, on_plane=True)
    at = slice(None) if rays is None else rays
    return _counted64(t, at_origin, lo[at], hi[at])


def _counted64(t, at_origin, lo, hi):
    """(h,) bool: whether each double-precision hit counts: lo < t < hi (float64 t)
    and its ray's origin not on its float64 plane (kdray.double.ON_PLANE: a ray from a
    point on its triangle meets that plane at about t = 0, on either side)."""
    return (t > lo) & (t < hi) & ~at_origin


def _in_range(tracer, hits, at_origin, origins, directions, t_min, t_max, max_hits):
    """Double-precision `hits` (Intersections sorted by float64 t; at_origin, _double's)
    less those that do not count (_counted64): the float32 test found them in (t_min,
    t_max), but the float64 triangle, within float32 rounding of the tree's, puts them
    outside or at the origin (a ray from a point on its triangle). A ray whose list
    was cut at max_hits and has fewer that count is listed again with room for more
    (`_counted_lists`), so that it keeps its max_hits nearest that count."""
    o, d = flat_rays64(origins, directions)
    n = len(d)
    lo, hi = _flat_t(t_min, n), _flat_t(t_max, n)
    ray = hits.ray
    keep = _counted64(hits.t, at_origin, lo[ray], hi[ray])
    if keep.all():
        return hits
    parts = [(ray[keep], hits.t[keep], hits.prim[keep], hits.u[keep], hits.v[keep])]
    # rays cut at max_hits with fewer that count (none can have more hits than the tree
    # has triangles: intersections' bound)
    again = np.zeros(0, np.int64)
    if max_hits is not None and max_hits < len(tracer.tree.triangles):
        counted = np.bincount(ray[keep], minlength=n)
        again = np.flatnonzero((np.diff(hits.offsets) == max_hits) & (counted < max_hits))
    if again.size:
        cap = max_hits + int((max_hits - counted[again]).max())
        old = ~np.isin(parts[0][0], again)
        parts = [tuple(a[old] for a in parts[0]),
                 _counted_lists(tracer, o, d, lo, hi, again, cap, max_hits)]
    ray, t, prim, u, v = (np.concatenate(c) for c in zip(*parts))
    order = np.argsort(ray, kind="stable")             # each ray's hits stay in t order
    offsets = np.concatenate([[0], np.cumsum(np.bincount(ray, minlength=n))])
    return Intersections(offsets, t[order], prim[order], u[order], v[order],
                         object_table=hits.object_table)


def _counted_lists(tracer, o, d, lo, hi, rays, cap, max_hits):
    """(ray, t, prim, u, v) of the max_hits nearest hits that count (_counted64) of each
    ray of `rays` ((k,) int64 rows of o, d (N, 3) float64 and lo, hi (N,)), in (ray, t)
    order: each ray's cap nearest float32 hits listed, made float64 (_double), those
    that do not count dropped; a ray cut at cap with fewer than max_hits that count is
    listed again with twice the room (never more than the tree's triangles), so that
    the hits that do not count cost their rays a few lists, not one a hit."""
    parts = []
    most = len(tracer.tree.triangles)
    while rays.size:
        listed = intersections(tracer, o[rays], d[rays], lo[rays], hi[rays], cap)
        hits, at_origin = _double(tracer, listed, o[rays], d[rays])
        ray = hits.ray
        keep = _counted64(hits.t, at_origin, lo[rays][ray], hi[rays][ray])
        counted = np.bincount(ray[keep], minlength=len(rays))
        done = (counted >= max_hits) | (np.diff(hits.offsets) < cap) | (cap >= most)
        # a done ray's first max_hits that count (a ray's hits are in t order)
        rank = np.cumsum(keep) - 1
        rank -= np.concatenate([[0], np.cumsum(counted)])[ray]
        take = keep & done[ray] & (rank < max_hits)
        parts.append((rays[ray[take]], hits.t[take], hits.prim[take], hits.u[take],
                      hits.v[take]))
        rays, cap = rays[~done], min(most, 2 * cap)
    return tuple(np.concatenate(c) for c in zip(*parts))


def _kernel_normal(tri):
    """(k, 3) float32 unit normals of float32 triangles (k, 3, 3) as the kernels make
    them (ops.h: kd_normalize(kd_cross(p1 - p0, p2 - p0)), each operation in float32
    in the same order)."""
    a, b = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    c = np.stack([a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1], a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
                  a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]], axis=1)
    c = c / np.abs(c).max(axis=1, keepdims=True)
    return c / np.sqrt((c[:, :1] * c[:, :1] + c[:, 1:2] * c[:, 1:2]) + c[:, 2:] * c[:, 2:])


def nearest_in_range(tracer, hits, at_origin, origins, directions, t_min, t_max):
    """Tracer.trace's double-precision `hits` (Hits, float64 t, u, v; at_origin (N,)
    bool, hits_double's) with each hit that does not count (_counted64) replaced by the
    ray's nearest that does (`_counted_lists`), or a miss; that hit's
    normal is its triangle's, computed on the host as the kernel computes it."""
    from .layout import MISS
    n = len(hits.t)
    lo, hi = _flat_t(t_min, n), _flat_t(t_max, n)
    o, d = flat_rays64(origins, directions)
    out = np.flatnonzero((hits.prim != MISS) & ~_counted64(hits.t, at_origin, lo, hi))
    if out.size == 0:
        return hits
    # each listed with room for two: its nearest (this hit) does not count
    rows, *found = _counted_lists(tracer, o, d, lo, hi, out, 2, 1)
    t, prim = hits.t.copy(), hits.prim.copy()
    t[out], prim[out] = np.inf, MISS
    t[rows], prim[rows] = found[0], found[1]
    answers = {"t": t, "prim": prim}
    for name, value in (("u", found[2]), ("v", found[3])):
        if getattr(hits, name) is not None:
            a = getattr(hits, name).copy()
            a[out] = 0.0
            a[rows] = value
            answers[name] = a
    if hits.normal is not None:
        normal = hits.normal.copy()
        normal[out] = 0.0
        tri = tracer.tree.triangles[tracer.tree.stored_index()[found[1]]]
        normal[rows] = _kernel_normal(tri)
        answers["normal"] = normal
    return dataclasses.replace(hits, **answers)


def _listed(tracer, rays, max_hits):
    """`intersections`' hits of `rays` (float32, in the tree's units): every ray's
    GUESS_HITS nearest (its max_hits when fewer), then the rays that had more counted
    and listed again in full, each ray's hits put in place once."""
    guess = min(GUESS_HITS, LIST_SLOTS, max_hits or LIST_SLOTS)
    # max_hits within the guess: the first pass is a k-nearest query, its walks ending
    # at the k-th hit's leaf; else it must see whether a ray has more
    final = max_hits is not None and max_hits <= guess
    n, more, first, slots = _first_pass(tracer, rays, guess, False, final)
    redo = () if final else np.flatnonzero(more)
    if not len(redo):
        return _gathered(tracer, n, first, slots)
    # the rays with more: their whole lists in their places (all of them: the answer)
    again = _relisted(tracer, rays, redo, max_hits)
    if len(redo) == rays.n:
        return again
    n[redo] = again.counts
    # the whole list, and the index of the relisted hits in it (and its making's)
    total = int(n.sum())
    _check_hits_memory(total * HIT_BYTES + rays.n * 8 + len(again.t) * 24, total, rays.n)
    hits = _gathered(tracer, n, first, slots)
    at = np.arange(len(again.t)) + np.repeat(hits.offsets[redo] - again.offsets[:-1], n[redo])
    for name in ("t", "prim", "u", "v"):
        getattr(hits, name)[at] = getattr(again, name)
    return hits


def _relisted(tracer, rays, redo, max_hits):
    """The Intersections of rays `redo` ((k,) int64) in full (their max_hits nearest):
    counted, then listed with as many slots; a ray whose count was lost gets one a hit
    found, copies too (`_count_pass`), the slots its copies leave empty then dropped,
    not counted exactly by a list of its own first. Counted COUNT_FIRST rays first,
    then twice as many at a time: KdrayError once the hits counted so far do not fit
    in memory."""
    sub = rays.subset(redo)
    caps = np.empty(sub.n, dtype=np.int64)
    start, step = 0, COUNT_FIRST
    while start < sub.n:
        stop = min(sub.n, start + step)
        part = caps[start:stop]
        part[:] = _count_pass(tracer, sub.subset(slice(start, stop)), False)[0]
        if max_hits is not None:
            np.minimum(part, int(max_hits), out=part)
        # _list's check of the lists, on the hits counted so far
        counted = int(caps[:stop].sum())
        _check_hits_memory(counted * (HIT_BYTES + 4) + sub.n * 12, counted, stop,
                           "counted so far")
        start, step = stop, 2 * step
    return _list(tracer, sub, caps, nearest_k=True)[0]


def _concatenated(parts):
    """One Intersections of the rays of `parts` (Intersections of consecutive rays)."""
    hits, rays = sum(len(q.t) for q in parts), sum(len(q.offsets) - 1 for q in parts)
    _check_hits_memory(hits * HIT_BYTES + rays * 8, hits, rays)
    offsets = [parts[0].offsets]
    for part in parts[1:]:
        offsets.append(part.offsets[1:] + offsets[-1][-1])
    return Intersections(np.concatenate(offsets),
                         *(np.concatenate([getattr(q, name) for q in parts])
                           for name in ("t", "prim", "u", "v")),
                         object_table=parts[0].object_table)


def _double(tracer, hits, origins, directions):
    """(hits with t, u, v in float64 (kdray.double.hits_double) and sorted again by (t,
    input id) within each ray, (H,) bool in that order: the hits whose ray's origin
    lies on their float64 plane)."""
    from .double import hits_double
    o, d = flat_rays64(origins, directions)
    n = len(hits.prim)
    # the rays' index, t and uv, the order and its sort's keys, the four answers
    _check_hits_memory(n * (8 + 24 + 8 + 16 + 28), n, len(hits.offsets) - 1,
                       "in double precision")
    ray = hits.ray
    t, uv, at_origin = hits_double(tracer.tree.triangles64, hits.prim, o, d, rays=ray,
                                   tree=tracer.tree, on_plane=True)
    order = np.lexsort((hits.prim, t, ray))
    return Intersections(hits.offsets, t[order], hits.prim[order], uv[order, 0],
                         uv[order, 1], object_table=hits.object_table), at_origin[order]
