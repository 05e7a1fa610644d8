"""Tracer: a KdTree on an OpenCL device; nearest hits of rays and images of cameras.

    tracer = Tracer(tree, device=None)              # context, queue, tree upload
    hits = tracer.trace(origins, directions)        # (N, 3) world coordinates
    hits.t, hits.prim, hits.u, hits.v, hits.normal, hits.object
    images = tracer.render(camera, aovs=("depth", "normal", "bary", "id"))

The arrays of `hits` and their dtypes: kdray.hits.

Precision: the tree's float32 data is relative to its float64 `origin`, in units of
its `scale` (a power of two); ray origins are taken there in float64 (on the host or
in the kernel) and only then rounded to float32, so a scene at 1e6, or 1e30 across,
traces as accurately as one at 0 and 1 across. With `refine` (devices with double
precision) each hit's t, u, v are recomputed in double, so that they are accurate
whatever the triangle's size against t (docs/conventions.md).

The kernels are compiled once per option set (outputs, stack size, work sizes) and
kept on the Tracer; the kernels compute and store only the outputs asked for.
"""
import ctypes
import copy
import dataclasses
import functools
import logging
import threading
import time

import numpy as np

from . import device as _device
from . import ray_input
from . import hit_lists, query_rays
from . import rays as _rays
from . import points as _points
from . import render as _render
from .camera import Camera
from .double import double_hits, wants_double
from .errors import DeviceError, KdrayError
from .hits import TRACE_OUTPUTS, Hits, kernel_outputs  # noqa: F401 (kdray.trace.*, as before)
from .host import PAGE, check_host_memory, huge_page_copy, huge_page_empty, page_aligned_empty
from .layout import (KERNEL_OUTPUTS, MAX_DEPTH_LIMIT, MISS, OUTPUT_WIDTH, TRI_BLOCK,
                     device_sizes, device_triangles, n_triangle_blocks, triangle_blocks,
                     triangle_copies)
from . import lidar as _lidar
from .ray_grid import ImageWidths
from .ray_order import ray_order
from .render import DEFAULT_AOVS
from .tree import KdTree
from .validate import check_bool, check_class, whole_or_none
from .wide import stack_groups, wide_nodes
from .work_sizes import (PACKETS, POCL_ITEM_BYTES, STACK_SIZES, default_packet,  # noqa: F401 (kdray.trace.* names)
                         default_stack_size, default_work_sizes, max_local_size,
                         pocl_item_bytes, thread_stack_bytes)

log = logging.getLogger(__name__)

MAX_RAYS_PER_LAUNCH = 1 << 22
"""Rays per kernel launch at most: keeps the 32-bit batch counter far from overflow and
a launch's buffers (at most 92 bytes a ray) near 400 MB. Smaller devices take fewer
rays a launch (`rays_per_launch`)."""

IMAGE_SEARCH_MIN_RAYS = 1 << 17
"""`Tracer.trace` looks for an image in (N, 3) rays (`ray_grid.grid_width`) only from
this many rays on: the search costs about 1 ms whatever N, and tracing in blocks saves
a few % of the kernel's time, which repays it from about 2^17 rays of a simple mesh
(BENCHMARKS.md, "(N, 3) rays traced as the image they are"). Image-shaped rays are traced in blocks at
any size."""

_POISON = np.uint32(0x7FBADBAD)
"""Fill pattern for output buffers when `_poison_outputs` is set (a float NaN, a uint32
larger than any triangle id): a test can then see any element the kernel missed."""

_OUTPUTS = KERNEL_OUTPUTS + ("STATS",)   # the kernels' output arguments, in order

MAPS_KEPT = 2
"""Ray maps (camera models', lidars') a Tracer keeps (12 bytes a ray on the host and
12 on the device each): a dataset's views share their camera's intrinsics."""


def _one_at_a_time(method):
    """The method under its Tracer's lock (Tracer._lock): what a launch sets and reads
    of the shared kernels, counter, programs and lazily made buffers is one thread's
    at a time."""
    @functools.wraps(method)
    def locked(self, *args, **kwargs):
        with self._lock:
            return method(self, *args, **kwargs)
    return locked


class Tracer:
    """A KdTree uploaded to one OpenCL device.

    tree : KdTree
    device : None (the first working device: a GPU, else the best CPU runtime; see
        kdray.device.choose_device) or a PYOPENCL_CTX-style string ("0:1", "intel", "pocl")
    stack_size : short-stack entries (1..64); default `default_stack_size(tree)`.
        Results do not depend on it; smaller stacks restart more often.
    packet : rays per work-item, 1, 8 or 16 (packets in vector lanes: PACKETS); default
        `default_packet(device)`: 16 on AVX-512 CPUs, 8 on other CPUs, 1 on GPUs.
        Results do not depend on it.
    local_size, batch_size, groups : work-group size, rays a group takes at a time
        (a multiple of local_size * packet) and work-groups launched; defaults per
        device kind (`default_work_sizes`).
    refine : recompute t, u, v of each hit in double from the ray and the hit
        triangle's plane (kernels/triangle.cl, kd_refine_hit), so that they are accurate
        whatever the triangle's size against t; which triangle is hit does not change.
        Only on devices with cl_khr_fp64; `self.refine` says whether it is on.

    device_bytes : bytes of the tree on the device (`device_sizes`), and of its wide
        nodes (kdray.wide, about a tenth more) once a trace, query or render with
        packets has made them.
    """

    def __init__(self, tree, device=None, stack_size=None, local_size=None, batch_size=None,
                 groups=None, packet=None, refine=True):
        check_class(tree, KdTree, "Tracer's tree")
        cl = _device._cl()
        if stack_size is None:
            stack_size = default_stack_size(tree)
        if not (isinstance(stack_size, (int, np.integer)) and not isinstance(stack_size, bool)
                and 1 <= stack_size <= MAX_DEPTH_LIMIT):
            raise KdrayError(f"stack_size must be an integer from 1 to {MAX_DEPTH_LIMIT}, "
                             f"got {stack_size!r}")
        self.tree = tree
        self.stack_size = int(stack_size)
        # packets keep a full stack (no restarts): the tree's depth + 1 entries
        self.packet_stack_size = default_stack_size(tree)
        # work sizes: None (the device's default) or whole numbers, checked before a
        # context is made (nan, "8", 1.5 and True refused, not converted)
        packet, local_size, batch_size, groups = (
            whole_or_none(v, name, KdrayError)
            for v, name in ((packet, "packet"), (local_size, "local_size"),
                            (batch_size, "batch_size"), (groups, "groups")))
        if device is not None and not isinstance(device, str):
            raise KdrayError(f"device must be None or a --device string, got {device!r:.60}")
        refine = check_bool(refine, "refine", KdrayError)
        self.context, self.device = _device.create_context(device)
        self.queue = cl.CommandQueue(self.context)
        self.packet = int(default_packet(self.device) if packet is None else packet)
        if self.packet not in (1, *PACKETS):
            raise KdrayError(f"packet must be 1, {' or '.join(map(str, PACKETS))}, got {packet!r}")
        d_local, d_batch, d_groups = default_work_sizes(self.device, self.packet)
        self.local_size = int(local_size or d_local)
        # default batch: the device's, rounded up to a multiple of a round's rays
        per_round = self.local_size * self.packet
        self.batch_size = int(batch_size or -(-d_batch // per_round) * per_round)
        self.groups = int(groups or d_groups)
        self._check_local_size()
        if self.batch_size % per_round or self.groups < 1:
            raise KdrayError(f"batch_size ({self.batch_size}) must be a multiple of local_size "
                             f"x packet ({per_round}) and groups ({self.groups}) at least 1")
        # the kernels take batches from a 32-bit counter, which passes a launch's rays
        # by up to a batch a group: beyond 2^30 it would wrap (2^32 added nothing: a
        # kernel that never ended)
        if self.batch_size * self.groups > 1 << 30:
            raise KdrayError(f"batch_size x groups ({self.batch_size} x {self.groups}) must "
                             f"be at most 2^30")
        self._programs = {}
        # Threads may share a Tracer (and the Tracers of with_tree, which share its
        # queue and kernels): a kernel's arguments are set on the one pyopencl Kernel
        # and then enqueued, and trace's and render's batches are counted from one
        # counter set to 0 first, so each launch holds the lock (`_one_at_a_time`).
        self._lock = threading.RLock()
        self._maps = {}                       # camera models' ray maps (`_ray_map`)
        self._widths = ImageWidths()          # the image widths found (`_image_width`)
        self._poison_outputs = False
        # packets: how a leaf is tested (kernels/packet.cl, kd_packet_leaf): None = by
        # the kernel's rule; tests set 0 (triangle by triangle) or inf (ray by ray)
        self._lane_ratio = None
        self._cull_lane_ratio = None
        # packets whose origins lie far apart or whose directions diverge are traced
        # each ray on its own path (packet.cl, kd_alone): None = by the kernel's rule;
        # tests set the spread -1 (always), or the spread and the turn inf (never)
        self._alone_spread = None
        self._alone_turn = None
        # trace_rays: each work-item takes a run of its group's batch (render.cl,
        # item_runs) on CPUs, where a group's work-items run one after another; on
        # GPUs every local_size-th packet, for coalesced reads. Tests set both.
        self._item_runs = _device.is_cpu(self.device)
        # A CPU device works on host memory: buffers over numpy arrays need no copies
        self._zero_copy = _device.is_cpu(self.device)
        # ... in place only when the array starts on a page, on Intel's CPU runtime (PAGE)
        self._page_inputs = self._zero_copy and _device.implementation(self.device) == "intel"
        # PoCL calls vload and shuffle2 out of line: its packets avoid them (render.cl,
        # kd_deal)
        self._plain_vector_ops = _device.implementation(self.device) == "pocl"
        self.refine = bool(refine) and _device.has_fp64(self.device)
        # float64 rays shifted and rounded in the kernel (`_rays`): on a CPU device no
        # host pass and no copy; with refine, the hits refined from the rays as given
        self._rays_in_kernel = _device.has_fp64(self.device) and (self._zero_copy or self.refine)
        self._upload(tree)

    # -- set-up ----------------------------------------------------------------------

    def _buffer(self, array, resident=False):
        """A read-only device copy of `array` (one dummy element when it is empty:
        OpenCL has no empty buffers). resident: one of the tree's, kept as long as the
        Tracer is (`_tree_buffer`); "placed": such an array from `_grown`, taken as it
        is on a CPU device."""
        cl = _device._cl()
        array = np.ascontiguousarray(array)
        if array.size == 0:
            array = np.zeros(1, dtype=array.dtype)
        if resident and self._zero_copy:
            # the buffer keeps its host array (pyopencl's hostbuf), so the copy lives as
            # long; one from `_grown` is such memory already
            return cl.Buffer(self.context, cl.mem_flags.READ_ONLY | cl.mem_flags.USE_HOST_PTR,
                             hostbuf=array if resident == "placed" else huge_page_copy(array))
        return cl.Buffer(self.context, cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR,
                         hostbuf=array)

    def _tree_buffer(self, array):
        """A read-only device buffer of the tree's, kept as long as the Tracer is: on a
        CPU device the host's memory itself, a copy in huge pages (host.huge_page_copy:
        the kernels' reads at random through a large tree miss the TLB less), else a
        device copy."""
        return self._buffer(array, resident=True)

    def _check_fits(self, sizes):
        """sizes ({what: bytes} of the tree's device buffers: `device_sizes`, leaves in
        runs of a packet, and the wide nodes' once made), returned once checked:
        DeviceError when the tree cannot live on the device, one buffer being larger
        than the device's largest allocation, or all of them with one ray's launch
        buffers more than its global memory. Launches are sized to what is left
        (`_launch_size`)."""
        name = self.device.name.strip()
        largest = int(self.device.max_mem_alloc_size)
        for what, nbytes in sizes.items():
            if nbytes > largest:
                raise DeviceError(f"the tree's {what} ({nbytes / 2**20:.0f} MiB) do not fit in "
                                  f"one buffer on {name} (at most {largest / 2**20:.0f} MiB)")
        need = sum(sizes.values()) + max(ray_input.RAY_BYTES.values())
        have = int(self.device.global_mem_size)
        if need > have:
            raise DeviceError(f"the tree needs {need / 2**20:.0f} MiB on {name}, "
                              f"which has {have / 2**20:.0f} MiB")
        return sizes

    def _launch_size(self, widths, what="ray", cap=None):
        """Rays (or rows of pixels) a launch takes: `rays_per_launch` for this device and
        tree. widths: bytes per ray (row) of each of the launch's buffers. DeviceError
        when not even one `what` fits."""
        n = rays_per_launch(int(self.device.global_mem_size), int(self.device.max_mem_alloc_size),
                            self.device_bytes, widths, cap)
        if n < 1:
            raise DeviceError(f"one {what}'s buffers ({sum(widths)} bytes) do not fit beside the "
                              f"tree ({self.device_bytes / 2**20:.0f} MiB) on "
                              f"{self.device.name.strip()}")
        return n

    def _check_local_size(self):
        """KdrayError unless 1 <= local_size <= `max_local_size` for this Tracer's
        device, packet and packet stack (the tree's depth sets the last)."""
        most = max_local_size(self.device, self.packet, self.packet_stack_size)
        if self.local_size < 1 or self.local_size > most:
            why = ("" if most == self.device.max_work_group_size else
                   f" with packets of {self.packet} and a tree {self.tree.depth} deep (PoCL "
                   f"keeps every work-item's private data on one thread's "
                   f"{thread_stack_bytes() >> 20} MiB stack)")
            raise KdrayError(f"local_size {self.local_size} is not in 1..{most} on "
                             f"{self.device.name.strip()}{why}")

    def _upload(self, tree):
        cl = _device._cl()
        self.device_bytes = sum(self._check_fits(device_sizes(tree, self.packet)).values())
        self._n_nodes = len(tree.nodes)
        # packets read a leaf's triangles a packet's width at a time (kd_gather_tris)
        nodes, tris, tri_ids = device_triangles(tree, self.packet)
        self._n_copies = len(tri_ids)
        self._nodes = self._tree_buffer(nodes)
        self._tris = self._tree_buffer(triangle_blocks(tris))
        self._tri_ids = self._tree_buffer(tri_ids)
        self._bounds = self._buffer(np.asarray(tree.bounds, dtype=np.float32).reshape(6))
        self._counter = cl.Buffer(self.context, cl.mem_flags.READ_WRITE, 4)
        self._wide_nodes = None               # (buffer, stack), made when needed (`_wide`)
        self._wide_unfit = False              # they did not fit (`_wide_fits`)
        self._origin = np.asarray(tree.origin, dtype=np.float64)
        self._scale = float(tree.scale)       # a power of two: dividing by it is exact
        self._point_queries = {}              # the point queries' data of this tree (points.py)

    def _program(self, kernel, outputs, stats=False, rays_world=None, rays="pinhole",
                 any_hit=False, wide=False):
        """The built program of render.cl's `kernel` ("trace_rays" or "render_camera",
        the only kernel compiled in it: KD_ONLY_*) for a set of outputs ("T", "UV",
        "NORMAL", "ID"), cached with it: {"program": Program, kernel: Kernel} (and the
        argument types `_launch` gave it, under ("arg_types", kernel)). rays_world:
        None, or trace_rays takes rays in world coordinates, (origin type, direction
        type), each "float" or "double" (render.cl, RAYS_WORLD).
        rays: how render_camera makes its rays: "pinhole", "map" (a camera model's ray
        map, RAY_MAP) or "orthographic" (ORTHOGRAPHIC); render.cl says how.
        any_hit: trace_rays stops at any hit (ANY_HIT, for `occluded`), with the
        refinement's triangle test where the Tracer refines (REFINE: a far-reaching
        triangle's t from double decides its hit, so the same hits as trace's).
        wide: packets' rays that share no path walk the wide nodes (KD_WIDE, `_wide`):
        trace_rays' programs, packet programs only, not with stats (their kernels take
        the records after n_nodes: `_launch` passes them)."""
        defines = {"STACK_SIZE": self.stack_size, "LOCAL_SIZE": self.local_size,
                   "BATCH_SIZE": self.batch_size, "TILE_W": _render.RENDER_TILE[0],
                   "TILE_H": _render.RENDER_TILE[1]}
        if rays_world:
            defines["RAYS_WORLD"] = None
            defines["ORIGIN_T"], defines["DIRECTION_T"] = rays_world
        if rays == "map":
            defines["RAY_MAP"] = None
        elif rays == "orthographic":
            defines["ORTHOGRAPHIC"] = None
        if any_hit:
            defines["ANY_HIT"] = None
        if self.refine:
            defines["REFINE"] = None
        if self._scale != 1.0:
            # exact: a power of two as a hexadecimal literal
            defines["SCALE"] = f"{self._scale.hex()}f"
            defines["SCALE_INV"] = (1.0 / self._scale).hex()
        if self.packet > 1:
            defines["PACKET"] = self.packet
            if self._plain_vector_ops:
                defines["KD_PLAIN_VECTOR_OPS"] = None
            defines["PACKET_STACK_SIZE"] = self.packet_stack_size
            defines.update(self._packet_rules())
            if wide and not stats:
                defines["KD_WIDE"] = None
                defines["WIDE_STACK"] = self._wide()[1]
        for name in outputs:
            defines[f"OUT_{name}"] = None
        if stats:
            defines["STATS"] = None
        # one kernel a program: each compiles in about half the time of both
        defines["KD_ONLY_TRACE_RAYS" if kernel == "trace_rays" else "KD_ONLY_RENDER_CAMERA"] = None
        entry = self._built("render.cl", defines, (kernel,))
        entry["wide"] = "KD_WIDE" in defines
        return entry

    @_one_at_a_time
    def _wide(self):
        """(buffer, stack groups): the tree's wide nodes on the device (kdray.wide) and
        the stack groups the programs that walk them are compiled for (at least a group
        a level: `wide.stack_groups`), made at the first trace, query or render that
        needs them. Their leaves' triangle copies follow the k-d leaves' (from the next
        TRI_BLOCK on) in the triangle buffers, which are made again with them (the k-d
        part unchanged, so that every kernel reads either); their bytes join
        device_bytes. DeviceError when they do not fit (`_check_fits`)."""
        if self._wide_nodes is None:
            first_copy = TRI_BLOCK * n_triangle_blocks(self._n_copies)
            records, levels, copies = wide_nodes(self.tree, self.packet, first_copy)
            tris, ids = triangle_copies(self.tree, copies)
            ids = np.concatenate([np.full(first_copy - self._n_copies, MISS, np.uint32), ids])
            n_floats = 9 * TRI_BLOCK * n_triangle_blocks(len(tris))
            sizes = self._check_fits({
                "nodes": int(self.tree.nodes.nbytes), "wide nodes": records.nbytes,
                "triangles with the wide nodes' copies": 4 * (9 * first_copy + n_floats),
                "triangle ids with the wide nodes' copies": 4 * (self._n_copies + len(ids))})
            # the k-d part read back and the copies' blocks written after it, in place
            whole = self._grown(self._tris, 9 * first_copy, n_floats, np.float32)
            triangle_blocks(tris, out=whole[9 * first_copy:])
            self._tris = self._buffer(whole, resident="placed")
            whole = self._grown(self._tri_ids, self._n_copies, len(ids), np.uint32)
            whole[self._n_copies:] = ids
            self._tri_ids = self._buffer(whole, resident="placed")
            # a node's stack group stays until its last child is taken: the groups
            # belong to nodes on one path from the root, one a level at most
            self._wide_nodes = (self._tree_buffer(records), stack_groups(levels))
            self.device_bytes = sum(sizes.values())
        return self._wide_nodes

    def _wide_fits(self):
        """Whether the tree's wide nodes are on the device: made now if need be
        (`_wide`). False where they do not fit beside the tree (its DeviceError, made
        before any buffer changes), remembered: renders then keep to the k-d tree's
        packets, which give the same images; traces and queries with packets need them
        and raise the DeviceError."""
        if self._wide_nodes is None and not self._wide_unfit:
            try:
                self._wide()
            except DeviceError:
                self._wide_unfit = True
        return self._wide_nodes is not None

    def _grown(self, buffer, n, more, dtype):
        """A host array (n + more,) of `dtype` for a tree buffer (`_buffer(...,
        resident="placed")`), its first n elements read from `buffer` (of that dtype),
        the rest for the caller to write."""
        cl = _device._cl()
        whole = (huge_page_empty((n + more,), dtype) if self._zero_copy
                 else np.empty(n + more, dtype))
        if n:
            cl.enqueue_copy(self.queue, whole[:n], buffer)
        return whole

    def _packet_rules(self):
        """The tests' overrides of packet.cl's rules, -D float literals for every packet
        program (the queries' too): {} unless a test set them."""
        rules = (("KD_LANE_RATIO", self._lane_ratio), ("KD_ALONE_TURN", self._alone_turn),
                 ("KD_CULL_LANE_RATIO", self._cull_lane_ratio),
                 ("KD_ALONE_SPREAD", self._alone_spread))
        return {name: f"{min(float(v), 1e30):.9e}f" for name, v in rules if v is not None}

    @_one_at_a_time
    def _built(self, source, defines, kernels):
        """kernels/<source> built with `defines` (dict name -> value or None), once per
        Tracer and option set (a program build takes seconds on some runtimes), with
        its kernels: {"program": Program, name: Kernel for each of `kernels`}."""
        # the key: (name, value) pairs of the defines and the source, in name order
        key = tuple(sorted({**defines, "source": source}.items(), key=lambda kv: kv[0]))
        entry = self._programs.get(key)
        if entry is None:
            cl = _device._cl()
            started = time.perf_counter()
            program = _device.build_program(self.context, source, defines)
            log.debug("built %s with %s in %.2f s", source, " ".join(
                k if v is None else f"{k}={v}" for k, v in defines.items()),
                time.perf_counter() - started)
            entry = {"program": program}
            for name in kernels:
                entry[name] = cl.Kernel(program, name)
            self._programs[key] = entry
        return entry

    @_one_at_a_time
    def _enqueue(self, entry, kernel_name, global_size, local_size, args):
        """Launch kernel `kernel_name` of a program entry (`_built`) on args. Told the
        scalars' types, pyopencl packs them itself: its untyped set_arg takes about
        20 us a scalar, half the time of a launch of a few rays."""
        kernel = entry[kernel_name]
        types = tuple(a.dtype if isinstance(a, np.generic) else None for a in args)
        if entry.get(("arg_types", kernel_name)) != types:
            kernel.set_arg_types(types)
            entry[("arg_types", kernel_name)] = types
        kernel(self.queue, (global_size,), (local_size,), *args)

    def _run_items(self, entry, kernel_name, n, args, outputs, local=64):
        """Run `kernel_name` of a program entry (`_built`) over n work-items (groups of
        `local`, or the device's most, the last padded) on args, then outputs (dict name
        -> host array it writes, or None for NULL, in argument order), and bring the
        outputs back: the launch of the small kernels that take one item a work-item."""
        device_out = {k: None if a is None else self._output_buffer(a)
                      for k, a in outputs.items()}
        local = min(local, int(self.device.max_work_group_size))
        self._enqueue(entry, kernel_name, -(-n // local) * local, local,
                      (*args, *device_out.values()))
        self._read_outputs({k: b for k, b in device_out.items() if b is not None}, outputs)

    def _whole_input(self, array):
        """A read-only device buffer of a contiguous host array for a kernel that takes
        no element offset: `_input_buffer`'s, in place where it starts on a page (or the
        device copies anyway), else a copy of it."""
        if self._page_inputs and array.ctypes.data % PAGE:
            return self._buffer(array)
        return self._input_buffer(array)[0]

    def compile(self, aovs=DEFAULT_AOVS, trace=False, precision="single", stack_sizes=()):
        """Build the program `render` uses for `aovs` at `precision` (and with
        trace=True the ones `trace` uses for float64 and float32 rays) and launch each
        once on one pixel (ray), so that the time of compiling is spent here and not in
        the first render: some runtimes compile a kernel again at its first launch
        (PoCL, per work-group size). stack_sizes: also the programs of trees that get
        these stack sizes (kdray.work_sizes.STACK_SIZES; each launched on this tree,
        whose walks any larger stack holds, and left out where this Tracer's local size
        would not fit it), which the on-disk program cache (pyopencl's or the
        driver's) then holds for other trees (`kdray setup`). Returns the Tracer."""
        stack_sizes = tuple(stack_sizes)
        for size in stack_sizes:
            if (isinstance(size, bool) or not isinstance(size, (int, np.integer))
                    or size not in STACK_SIZES):
                raise KdrayError(f"stack_sizes must be some of {STACK_SIZES}, got {size!r:.40}")
        self._compile_one(aovs, trace, precision)
        for size in stack_sizes:
            if ((size, size) == (self.stack_size, self.packet_stack_size)     # built above
                    or self.local_size > max_local_size(self.device, self.packet, size)):
                continue
            # a copy of this Tracer (its tree, buffers, programs and lock) at that size
            other = copy.copy(self)
            other.stack_size = other.packet_stack_size = int(size)
            other._compile_one(aovs, trace, precision)
        return self

    def _compile_one(self, aovs, trace, precision):
        """`compile`'s programs at this Tracer's stack sizes, each launched once."""
        aovs = _render.parse_aovs(aovs)
        if precision == "double":          # the kernel's part of a double render
            aovs = tuple(dict.fromkeys([a for a in aovs if a in ("normal", "id")] + ["id"]))
        outputs = _render.kernel_outputs(aovs)
        # a camera with M = 0 at the tree's origin: its one ray has a zero direction
        # and misses at once
        camera_buf = self._buffer(np.zeros(12, dtype=np.float32))
        out = {k: page_aligned_empty(shape, dtype)
               for k, (shape, dtype) in _render.output_shapes(1, outputs).items()}
        self._launch("render_camera", outputs, _render.tile_slots(1, 1),
                     (camera_buf, None, np.uint32(1), np.uint32(0), np.uint32(1)), out,
                     wide=self.packet > 1 and self._wide_fits())
        if trace:
            for dtype in (np.float64, np.float32):
                self._trace(np.zeros((1, 3), dtype), np.zeros((1, 3), dtype))

    # -- launching ---------------------------------------------------------------------

    @_one_at_a_time
    def _launch(self, kernel_name, outputs, n, args, host_out, stats=False, rays_world=None,
                rays="pinhole", while_running=None, any_hit=False, wide=False):
        """Run `kernel_name` over n work slots (rays; for a render, its tiling's pixel
        slots) writing `host_out` (dict output -> host array, one row per ray or pixel).
        args: the kernel's arguments between the tree and the counter; while_running:
        None or a function to call once the kernel has been submitted, before waiting
        for it; any_hit, wide: see `_program`."""
        cl = _device._cl()
        if n == 0:
            return
        entry = self._program(kernel_name, outputs, stats, rays_world, rays, any_hit, wide)
        names = list(outputs) + (["STATS"] if stats else [])
        device_out = {}
        for name in names:
            device_out[name] = self._output_buffer(host_out[name])
        cl.enqueue_fill_buffer(self.queue, self._counter, np.uint32(0), 0, 4)
        groups = min(self.groups, -(-n // self.batch_size))
        wide = (self._wide()[0],) if entry["wide"] else ()
        call_args = (self._nodes, self._tris, self._tri_ids, self._bounds,
                     np.uint32(self._n_nodes), *wide, *args, self._counter,
                     *(device_out.get(name) for name in _OUTPUTS))
        self._enqueue(entry, kernel_name, groups * self.local_size, self.local_size, call_args)
        if while_running is not None:
            self.queue.flush()
            try:
                while_running()
            finally:
                self.queue.finish()         # the kernel writes host memory: wait for it
        self._read_outputs(device_out, host_out)

    def _read_outputs(self, device_out, host_out):
        """Bring the kernel's outputs (dict name -> buffer from `_output_buffer`) into
        their host arrays (host_out, by the same names) and wait for it."""
        cl = _device._cl()
        for name, buf in device_out.items():
            if self._zero_copy:
                # the buffer is the host array: a map makes the kernel's writes visible
                mapped, _ = cl.enqueue_map_buffer(self.queue, buf, cl.map_flags.READ, 0,
                                                  host_out[name].shape, host_out[name].dtype)
                mapped.base.release(self.queue)
            else:
                cl.enqueue_copy(self.queue, host_out[name], buf)
        self.queue.finish()

    def _input_buffer(self, array):
        """(buffer, offset): a read-only device buffer holding a contiguous host array
        from element `offset` on. On a CPU device the buffer is the host's memory
        (USE_HOST_PTR, no copy), else a copy with offset 0.

        Intel's CPU runtime works in place only on memory that starts on a page, and
        copies anything else itself, slowly. So an array that does not start on a page
        is passed from the start of its page, with its offset in elements: the runtime
        and the kernel only read from it, and the page is mapped (the array is in it).
        The caller keeps `array` alive until the launch has finished."""
        cl = _device._cl()
        offset = 0
        lead = array.ctypes.data % PAGE
        if self._page_inputs and lead:
            if lead % array.itemsize == 0:
                region = (ctypes.c_uint8 * (lead + array.nbytes)).from_address(array.ctypes.data - lead)
                offset = lead // array.itemsize
                array = np.frombuffer(region, dtype=np.uint8)
            else:
                aligned = page_aligned_empty(array.shape, array.dtype)
                np.copyto(aligned, array)
                array = aligned
        flag = cl.mem_flags.USE_HOST_PTR if self._zero_copy else cl.mem_flags.COPY_HOST_PTR
        return cl.Buffer(self.context, cl.mem_flags.READ_ONLY | flag, hostbuf=array), offset

    def _output_buffer(self, array, read=False):
        """A write-only device buffer for a contiguous host array (read: the kernel
        reads it too): on a CPU device the array itself, so nothing is copied back.
        Poisoned first when asked."""
        cl = _device._cl()
        access = cl.mem_flags.READ_WRITE if read else cl.mem_flags.WRITE_ONLY
        # 4-byte elements get _POISON, bytes (occluded's) 0xAD
        poison = _POISON if array.itemsize % 4 == 0 else np.uint8(0xAD)
        if self._poison_outputs:
            array.reshape(-1).view(poison.dtype)[:] = poison
        if self._zero_copy:
            return cl.Buffer(self.context, access | cl.mem_flags.USE_HOST_PTR, hostbuf=array)
        buf = cl.Buffer(self.context, access, array.nbytes)
        if self._poison_outputs:
            cl.enqueue_fill_buffer(self.queue, buf, poison, 0, array.nbytes)
        return buf

    # -- rays ----------------------------------------------------------------------------

    def _rays(self, origins, directions):
        """The rays as trace_rays takes them: (o, d, o_step, rays_world)
        (kdray.ray_input.kernel_rays, in the kernel where `_rays_in_kernel`)."""
        return ray_input.kernel_rays(origins, directions, self._origin, self._scale,
                                     self._rays_in_kernel)

    def trace(self, origins, directions, t_min=0.0, t_max=np.inf, precision="single",
              outputs=TRACE_OUTPUTS):
        """Nearest hit of every ray o + t d with t_min < t < t_max.

        origins : (N, 3) or (3,) float64 or float32, world coordinates
        directions : (N, 3), any length (t is in units of |direction|)
            Image-shaped rays, (H, W, 3) (or (..., H, W, 3)) for directions and
            origins (or (3,) origins), give Hits of shape (H, W) (normal (H, W, 3)):
            on a CPU they are traced in packets of 4 x 2 or 4 x 4 neighbouring pixels,
            as `render` traces its own, which share more of the tree than a row's,
            with the same hits bit for bit. (N, 3) rays that are an image in
            row-major or column-major order (a camera's rays flattened, as
            Camera.rays gives them) are found to be one (kdray.ray_grid) and traced
            in blocks too, from IMAGE_SEARCH_MIN_RAYS rays on (below, the search
            costs more than it saves).
        t_min : >= 0 (default 0: hits behind the origin or at it never count)
        t_min, t_max : numbers, or (N,) arrays, a range a ray (each lane of a packet
            over its own): the same hits, t, u, v and normals as each ray would get
            from a number
        precision : "single" (float32 t, u, v) or "double": the same hits, their t, u,
            v in float64 from the tree's float64 triangles (KdTree.triangles64) and
            the rays as given (kdray.double)
        outputs : which of TRACE_OUTPUTS ("uv", "normal") to compute besides t and
            prim (always); the others are None in Hits, and the kernel neither
            computes nor stores them.
        Returns Hits. Rays with non-finite components or a zero direction miss.
        """
        double = wants_double(precision, self.tree)
        kernel = kernel_outputs(outputs, double)
        origins, directions, shape = ray_input.flat_rays(origins, directions)
        t_min = query_rays.check_t(t_min, "t_min", shape)
        t_max = query_rays.check_t(t_max, "t_max", shape)
        hits = self._trace_rays(origins, directions, shape, t_min, t_max, kernel)
        if double:
            hits, at_origin = double_hits(self.tree, hits, origins, directions, on_plane=True)
            hits = hit_lists.nearest_in_range(self, hits, at_origin, origins, directions,
                                              t_min, t_max)
            if "uv" not in outputs:
                hits = dataclasses.replace(hits, u=None, v=None)
        return hits if len(shape) == 1 else hits._reshaped(shape)

    def _trace_rays(self, origins, directions, shape, t_min, t_max, outputs, any_hit=False):
        """Hits of flat rays (ray_input.flat_rays: their shape `shape`) with t ranges
        (numbers, or (N,) arrays) by trace_rays: image-shaped rays, given so or found
        so, in blocks of pixels on a CPU; any_hit: the first hit each ray's traversal
        finds (`_program`)."""
        if len(shape) >= 2:
            image_w, search = shape[-1], None
        elif self.packet > 1 and len(directions) >= IMAGE_SEARCH_MIN_RAYS:
            # (N, 3) rays that are an image in rows, as cameras give them, are traced in
            # blocks too; the packets do not change a hit, only the time
            image_w, search = self._image_width(origins, directions)
        else:
            image_w, search = 0, None
        hits, _ = self._trace(origins, directions, t_min, t_max, outputs=outputs,
                              image_w=image_w, while_running=search, any_hit=any_hit)
        return hits

    # -- ray queries beyond the nearest hit (kdray.rays) ---------------------------------

    def occluded(self, origins, directions, t_min=0.0, t_max=np.inf, precision="single"):
        """(N,) bool: any hit with t_min < t < t_max (kdray.rays.occluded)."""
        return _rays.occluded(self, origins, directions, t_min, t_max, precision)

    def count(self, origins, directions, t_min=0.0, t_max=np.inf, precision="single"):
        """(N,) int32: surface crossings with t_min < t < t_max (kdray.rays.count)."""
        return _rays.count(self, origins, directions, t_min, t_max, precision)

    def contains(self, points):
        """(N,) bool: points inside a closed mesh (kdray.rays.contains)."""
        return _rays.contains(self, points)

    def intersections(self, origins, directions, t_min=0.0, t_max=np.inf, max_hits=None,
                      precision="single"):
        """Every hit of each ray, sorted by t: kdray.hit_lists.Intersections
        (kdray.hit_lists.intersections)."""
        return hit_lists.intersections(self, origins, directions, t_min, t_max, max_hits,
                                       precision)

    # -- point queries (kdray.points) ---------------------------------------------------

    def closest_points(self, points, max_distance=np.inf, precision="single"):
        """The nearest surface point of each point: kdray.points.ClosestPoints
        (kdray.points.closest_points)."""
        return _points.closest_points(self, points, max_distance, precision)

    def distance(self, points, max_distance=np.inf, precision="single"):
        """(N,) float32 unsigned distance to the surface (kdray.points.distance)."""
        return _points.distance(self, points, max_distance, precision)

    def signed_distance(self, points, sign="winding", max_distance=np.inf, precision="single"):
        """(N,) float32 distance, negative inside (kdray.points.signed_distance)."""
        return _points.signed_distance(self, points, sign, max_distance, precision)

    def winding_number(self, points, beta=_points.WINDING_BETA, precision="single"):
        """(N,) float64 generalized winding number (kdray.points.winding_number)."""
        return _points.winding_number(self, points, beta, precision)

    def occupancy(self, points, sign="winding", precision="single"):
        """(N,) bool: points inside the surface (kdray.points.occupancy)."""
        return _points.occupancy(self, points, sign, precision)

    def _image_width(self, origins, directions):
        """(width, search) for (N, 3) rays: ray_grid.ImageWidths.width, a packet's
        block of 4 x packet / 4 pixels the fewest rows."""
        return self._widths.width(origins, directions, min_rows=self.packet // 4)

    def _trace(self, origins, directions, t_min=0.0, t_max=np.inf, stats=False,
               outputs=KERNEL_OUTPUTS, image_w=0, while_running=None, any_hit=False):
        """(Hits, STATS or None) of the rays; t_min, t_max: numbers, or (N,) arrays (a
        range a ray); outputs: the kernel outputs computed and
        stored (KERNEL_OUTPUTS order; T and ID always), the others None in Hits.
        image_w: 0, or the rays are rows of an image that wide (N a multiple of it),
        traced in packets of blocks of pixels (render.cl, trace_rays).
        while_running: None or a function called once while the first launch runs.
        any_hit: each ray's first hit found, not its nearest (`_program`)."""
        # any_hit (occluded) stores no t: its hit is the triangle's id alone
        always = {"ID"} if any_hit else {"T", "ID"}
        outputs = tuple(k for k in KERNEL_OUTPUTS if k in set(outputs) | always)
        o, d, o_step, rays_world = self._rays(origins, directions)
        n = len(d)
        t_ranges, t_step = query_rays.range_pairs(t_min, t_max, n, self._scale)
        out = {name: page_aligned_empty((n, width) if width > 1 else (n,), dtype)
               for name, (width, dtype) in OUTPUT_WIDTH.items()
               if name in outputs or (stats and name == "STATS")}
        o_bytes, d_bytes = (ray_input.RAY_BYTES[t] for t in rays_world or ("float", "float"))
        widths = [o_bytes] * o_step + [d_bytes] + [8] * t_step \
            + [OUTPUT_WIDTH[k][0] * 4 for k in out]
        # packets' rays that share no path walk the wide nodes, made now so that their
        # bytes count in what a launch may take
        wide = self.packet > 1 and not stats
        if wide:
            self._wide()
        per_launch = self._launch_size(widths)
        # with image blocks a launch takes whole rows of blocks (4 rows with packets
        # of 16); a band that does not fit in one launch is traced in rows
        band_rows = self.packet // 4 if image_w and self.packet > 1 else 0
        if band_rows and image_w * band_rows <= per_launch:
            per_launch -= per_launch % (image_w * band_rows)
        else:
            image_w = 0
        box = self.tree.world_box() if rays_world else self.tree.bounds
        for start in range(0, n, per_launch):
            stop = min(n, start + per_launch)
            slots = stop - start
            if image_w:
                rows = slots // image_w
                slots = -(-image_w // 4) * -(-rows // band_rows) * self.packet
            o_part = o[start:stop] if o_step else o
            o_buf, o_offset = self._input_buffer(o_part)
            d_buf, d_offset = self._input_buffer(d[start:stop])
            # rays in no order of their own are taken in one (kdray.ray_order)
            order = None if image_w else ray_order(
                self, o_part, d[start:stop], *box, o_step,
                ((o_buf, o_offset), (d_buf, d_offset)))
            order_buf = None if order is None else self._input_buffer(order)[0]
            t_buf, t_offset = self._input_buffer(t_ranges[start:stop] if t_step else t_ranges)
            # with world rays the kernel takes the tree's origin and shifts them itself
            origin = tuple(np.float64(x) for x in self._origin) if rays_world else ()
            # t in the tree's units is t / scale (directions are not scaled)
            self._launch("trace_rays", outputs, slots,
                         (o_buf, d_buf, np.uint32(o_offset), np.uint32(d_offset),
                          np.uint32(o_step), np.uint32(stop - start), np.uint32(image_w),
                          order_buf, t_buf, np.uint32(t_offset), np.uint32(t_step),
                          np.uint32(self._item_runs), *origin),
                         {k: v[start:stop] for k, v in out.items()}, stats=stats,
                         rays_world=rays_world, while_running=while_running,
                         any_hit=any_hit, wide=wide)
            while_running = None
        # u and v are views of the kernel's interleaved (N, 2) output: no copies
        uv = out.get("UV")
        hits = Hits(t=out.get("T"), prim=out["ID"], u=None if uv is None else uv[:, 0],
                    v=None if uv is None else uv[:, 1], normal=out.get("NORMAL"),
                    object_table=self.tree.objects)
        return hits, out.get("STATS")

    # -- cameras -------------------------------------------------------------------------

    def camera_rays(self, camera):
        """The rays `render` traces, computed on the host with the kernel's float32
        arithmetic: (origins (H*W, 3) float64 world, directions (H*W, 3) float32),
        row-major (row j, then column i). `trace(*camera_rays(c))` equals render(c).
        A pixel with no ray has NaN directions. A central camera's origins are its one
        eye broadcast, a read-only view (np.array(origins) for a writable copy)."""
        check_class(camera, Camera, "camera")
        return _render.camera_rays(camera, self._origin, self._scale)

    def render(self, camera, aovs=DEFAULT_AOVS, precision="single"):
        """Primary-ray images of `camera` (kdray.Camera: width, height, K, cam_to_world).

        aovs : names from AOVS (or one comma-separated string). Returns a dict, in the
        order asked: depth (H, W) z-depth, +inf on a miss; distance (H, W) along the
        ray; normal (H, W, 3); bary (H, W, 2) u, v; id (H, W) uint32; position (H, W, 3)
        world hit point (NaN on a miss); object (H, W) uint32, the tree's object of
        each pixel's triangle (KdTree.objects), 0xFFFFFFFF on a miss. Only what is
        asked is computed and stored (object from the kernel's ids, looked up here).
        precision : "single" (float32 images) or "double": the same hits, and depth,
        distance, position and bary in float64 from each pixel's exact float64 ray
        (Camera.rays) and the tree's float64 triangles (render.double_images).
        A camera of another model than the pinhole (opencv, fisheye, equirectangular,
        orthographic: kdray.lens) adds `valid` to its images: (H, W) bool, the pixels
        that have a ray (the others are misses). Its depth is the z-depth for opencv
        and orthographic cameras, the distance along the ray for fisheye and
        equirectangular ones. The render kernel makes every model's rays: the opencv,
        fisheye and equirectangular cameras' from a ray map (render.MAP_MODELS: the lens
        inverted once per intrinsics on the host, in float64, then rounded to float32
        like a pinhole's directions), the orthographic camera's from K and the pose;
        with precision="double" the opencv, fisheye and equirectangular models are
        traced from their float64 rays (Camera.rays), and the orthographic's hits are
        its single render's (t, u, v from its rays relative to the tree's origin).
        """
        check_class(camera, Camera, "camera")
        double = wants_double(precision, self.tree)
        aovs = _render.parse_aovs(aovs)
        if camera.model != "pinhole" and double:
            return self._render_model(camera, aovs, precision)
        if double:
            # the kernel finds the triangles (ids, objects) and the normals; the rest is
            # float64
            kernel_aovs = tuple(dict.fromkeys(
                [a for a in aovs if a in ("normal", "id", "object")] + ["id"]))
            w, h = int(camera.width), int(camera.height)
            check_host_memory(w * h * (_render.host_bytes_per_pixel(kernel_aovs)
                                       + _render.double_bytes_per_pixel(aovs)),
                              f"a {w}x{h} render of {', '.join(aovs)} in double precision")
            images = self.render(camera, kernel_aovs)
            exact = _render.double_images(images["id"].reshape(-1), camera,
                                          self.tree.triangles64, aovs, tree=self.tree)
            return {a: exact[a] if a in exact else images[a] for a in aovs}
        w, h = int(camera.width), int(camera.height)
        if w < 1 or h < 1:
            raise KdrayError(f"camera size must be at least 1x1, got {w}x{h}")
        n = w * h
        tile_slots = _render.tile_slots
        if n >= 1 << 32 or tile_slots(w, min(h, max(1, MAX_RAYS_PER_LAUNCH // w))) >= 1 << 32:
            raise KdrayError(f"{w}x{h} pixels are too many for one render (at most 2^32 - 1, "
                             f"rows padded to {_render.RENDER_TILE[0]} columns)")
        check_host_memory(n * (_render.host_bytes_per_pixel(aovs)
                               + (_render.MAP_BYTES if camera.model in _render.MAP_MODELS else 0)),
                          f"a {w}x{h} render of {', '.join(aovs)}")
        outputs = _render.kernel_outputs(aovs)
        out = {k: page_aligned_empty(shape, dtype)
               for k, (shape, dtype) in _render.output_shapes(n, outputs).items()}
        camera_buf = self._buffer(_render.camera_values(camera, self._origin, self._scale))
        lens = self._ray_map(camera) if camera.model in _render.MAP_MODELS else None
        map_buf = None if lens is None else lens[1]
        rays = "map" if lens is not None else camera.model
        self._render_rows(camera_buf, map_buf, w, h, outputs, out, rays)
        if lens is None:
            images = _render.images(out, camera, self._origin, aovs, self._scale,
                                    objects=self.tree.objects)
            if camera.model == "orthographic":          # every pixel has a ray
                images["valid"] = np.ones((h, w), dtype=bool)
            return images
        map32, _, valid = lens
        none = ~valid                   # pixels with no ray: the kernel left them out
        for name, array in out.items():
            array[none] = np.inf if name == "T" else (MISS if name == "ID" else 0)
        images = _render.images(out, camera, self._origin, aovs, self._scale,
                                objects=self.tree.objects, map32=map32)
        images["valid"] = valid.reshape(h, w).copy()     # the caller's own, not the kept map's
        return images

    def _render_rows(self, camera_buf, map_buf, w, h, outputs, out, rays):
        """Launch render_camera over h rows of w pixels, its rays made as `rays` says
        (`_program`; map_buf: the ray map of rays="map", else None), writing `out` (dict
        output -> (h*w, ...) host array): as many whole rows a launch as fit on the
        device, MAX_RAYS_PER_LAUNCH pixels or one row at most."""
        # packets walk the wide nodes (render.cl, trace_packet), made before a
        # launch's size, which their bytes bound
        wide = self.packet > 1 and self._wide_fits()
        rows_per_launch = self._launch_size([w * OUTPUT_WIDTH[k][0] * 4 for k in outputs],
                                            what=f"row of {w} pixels",
                                            cap=max(1, MAX_RAYS_PER_LAUNCH // w))
        for row0 in range(0, h, rows_per_launch):
            n_rows = min(h - row0, rows_per_launch)
            start, stop = row0 * w, (row0 + n_rows) * w
            self._launch("render_camera", outputs, _render.tile_slots(w, n_rows),
                         (camera_buf, map_buf, np.uint32(w), np.uint32(row0), np.uint32(n_rows)),
                         {k: v[start:stop] for k, v in out.items()}, rays=rays, wide=wide)

    def _ray_map(self, camera):
        """(map32 (H*W, 3) float32, its device buffer, valid (H*W,) bool) of a camera of
        render.MAP_MODELS: made on the host once per intrinsics (kdray.lens keeps the
        float64 maps) and kept on the device for the MAPS_KEPT most recent ones."""
        key = (camera.model, camera.K.tobytes(), tuple(camera.distortion), camera.width,
               camera.height)
        return self._kept_map(key, lambda: _render.ray_map(camera))

    def _kept_map(self, key, make):
        """(map32, its device buffer, valid) kept under `key` (the MAPS_KEPT most
        recently used); make() -> (map32 (n, 3) float32, valid (n,) bool or None) when
        it is not kept."""
        # the maps are shared with with_tree's Tracers and threads: changed under the
        # lock, made outside it (a lens's inversion takes a while)
        with self._lock:
            entry = self._maps.get(key)
        if entry is None:
            map32, valid = make()
            entry = (map32, self._buffer(map32.reshape(-1)), valid)
        with self._lock:
            entry = self._maps.pop(key, entry)      # another thread's, made meanwhile
            while len(self._maps) >= MAPS_KEPT:
                self._maps.pop(next(iter(self._maps)))
            self._maps[key] = entry                 # the most recent last
        return entry

    def _render_model(self, camera, aovs, precision):
        """`render` of a camera that is not a pinhole (kdray.lens) in double precision:
        its float64 rays (Camera.rays) made on the host, traced by `trace` (an
        orthographic camera's hits taken from its single render), and a `valid`
        image."""
        w, h = int(camera.width), int(camera.height)
        check_host_memory(w * h * (_render.host_bytes_per_pixel(aovs) + _render.MODEL_RAY_BYTES
                                   + (_render.ORTHOGRAPHIC_BYTES
                                      if camera.model == "orthographic" else 0)),
                          f"a {w}x{h} {camera.model} render of {', '.join(aovs)}")
        o, d, valid = camera._model_rays(valid=True, copy=False)   # one origin: no copy
        if camera.model == "orthographic":          # its world origins lose digits
            hits = _render.orthographic_hits(self.tree, camera, d,
                                             self.render(camera, ("id", "normal")))
        else:
            # image-shaped: traced in blocks of pixels, as render_camera traces them
            hits = self.trace(camera.eye, d.reshape(h, w, 3), precision=precision,
                              outputs=TRACE_OUTPUTS)._reshaped((h * w,))
        return _render.ray_images(hits, o, d, valid, camera, aovs)

    def render_many(self, cameras, aovs=DEFAULT_AOVS, precision="single"):
        """The images of each camera of an iterable, one dict at a time, as `render`
        gives them: a generator, so that a long list of views holds one view's images at
        a time. The programs are built once, at the first view."""
        aovs = _render.parse_aovs(aovs)
        for camera in cameras:
            yield self.render(camera, aovs, precision)

    def __reduce__(self):
        """A Tracer is not pickled or deep-copied (its OpenCL context, queue and buffers
        belong to this process): its tree is, and another process makes its own Tracer
        of it. copy.copy shares everything (`with_tree`)."""
        raise TypeError("a kdray.Tracer holds this process's OpenCL context and cannot be "
                        "pickled or deep-copied; pickle its tree (Tracer.tree) and make a "
                        "Tracer of it in the other process")

    def __copy__(self):
        other = object.__new__(type(self))
        other.__dict__.update(self.__dict__)
        return other

    def with_tree(self, tree):
        """A Tracer of another tree on this one's device, context and queue, with its
        packet width, work sizes and refinement, sharing its compiled programs (a tree
        of another depth or scale may still need programs of its own): the cost of a
        new scene is its upload, not a context and a compile. Stack sizes are the new
        tree's defaults. KdrayError when the new tree is so deep that the work-group no
        longer fits (`max_local_size`)."""
        other = copy.copy(self)           # shallow: the program cache is shared
        other.tree = tree
        other.stack_size = other.packet_stack_size = default_stack_size(tree)
        other._check_local_size()
        other._upload(tree)
        return other

    def scan(self, lidar, pose, precision="single"):
        """A lidar scan: the range image of `lidar` (kdray.lidar.Lidar) at `pose`.

        pose : (4, 4) sensor-to-world rigid transform, sensor axes of ROS REP 103
            (x forward, y left, z up); checked like a camera pose (CameraError).
        precision : "single" or "double" (as `trace`; range float64).
        Returns a dict of (B, C) images, row i beam i (row 0 the highest), column j
        azimuth step j (kdray.lidar): range float32 (float64 with "double"), metres
        along the unit beam, +inf on a miss or at max_range and beyond; id uint32, the
        hit triangle, and object uint32, its object (KdTree.objects), both 0xFFFFFFFF
        on a miss; points (B, C, 3) float64 world hit points, NaN on a miss.
        The render kernel makes the rays, as a camera model's (RAY_MAP): the Lidar's
        sensor-frame directions, rounded to float32 once and kept on the device, turned
        by the pose; hits are refined in double where the device has it. With
        precision="double" the float64 rays (Lidar.rays) are traced from the host.
        """
        return _lidar.scan(self, lidar, pose, precision)


def rays_per_launch(global_mem, max_alloc, tree_bytes, widths, cap=None):
    """How many rays a launch takes: at most `cap` (default MAX_RAYS_PER_LAUNCH), and
    so many that the tree's buffers (tree_bytes) and the launch's (widths: bytes per
    ray of each buffer, a list of ints) fit in global_mem, and each launch buffer in
    max_alloc (the device's largest allocation). 0 when not one ray fits. A "ray" may
    be a row of pixels: widths and cap are then per row."""
    cap = MAX_RAYS_PER_LAUNCH if cap is None else cap
    free = global_mem - tree_bytes
    n = min(cap, free // max(sum(widths), 1), max_alloc // max(max(widths), 1))
    return max(int(n), 0)
