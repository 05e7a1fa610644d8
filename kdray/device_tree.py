"""DeviceTree: a KdTree on one OpenCL device, the programs built for it and their
launches; the device step of kdray's flow, under kdray.Tracer and the query modules.

    dt = DeviceTree(tree, device=None)             # context, queue, the tree's buffers
    entry = dt._built("points.cl", defines, ("closest_points",))   # built once, kept
    buf, offset = dt._input_buffer(array)          # on a CPU host memory in place (a page on)
    dt._enqueue(entry, "closest_points", global_size, local_size, args)

`kdray.Tracer` is a DeviceTree with the queries' faces (kdray.trace); the query modules
(rays, hit_lists, query_rays, points, ray_order, point_order, lidar) take a Tracer and
launch their kernels through these methods, which are theirs and the tests', not a
user's. What lives here: the work sizes and their checks, the tree's buffers (and its
wide nodes, made when first needed: kdray.wide), the cache of built programs (keyed by
their -D options), host arrays made into buffers without copies on a CPU device,
launch sizes that fit the device's memory, render.cl's `trace_rays` and
`render_camera` launches, and the lock that makes each launch one thread's at a time.
"""
import ctypes
import functools
import logging
import threading
import time

import numpy as np

from . import device as _device
from . import host as _host
from . import ray_input
from . import render as _render
from .errors import DeviceError, KdrayError
from .host import PAGE, huge_page_copy, huge_page_empty, page_aligned_empty
from .layout import (KERNEL_OUTPUTS, MAX_DEPTH_LIMIT, MISS, OUTPUT_WIDTH, TRI_BLOCK,
                     device_sizes, device_triangles, n_triangle_blocks, triangle_blocks,
                     triangle_copies)
from .tree import KdTree
from .validate import check_bool, check_class, whole_or_none
from .wide import stack_groups, wide_nodes
from .work_sizes import (PACKETS, default_packet, default_stack_size, default_work_sizes,
                         max_local_size, thread_stack_bytes)

log = logging.getLogger(__name__)

MAX_RAYS_PER_LAUNCH = 1 << 22
"""Rays per kernel launch at most: keeps the 32-bit batch counter far from overflow and
a launch's buffers (at most 92 bytes a ray) near 400 MB. Smaller devices take fewer
rays a launch (`rays_per_launch`)."""


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

class DeviceTree:
    """A KdTree uploaded to one OpenCL device: what kdray.Tracer launches its kernels
    through (its public attributes: Tracer's docstring)."""

    def __init__(self, tree, device=None, stack_size=None, local_size=None, batch_size=None,
                 groups=None, packet=None, refine=True):
        """The tree uploaded to `device` with these work sizes: the arguments as
        kdray.Tracer takes them (its docstring says what each means)."""
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
        # whether the device is a CPU (`device.is_cpu`), asked once: each ask is an
        # OpenCL call or two, and a small query's launches ask again and again
        self._cpu = _device.is_cpu(self.device)
        self._item_runs = self._cpu
        # A CPU device works on host memory: buffers over numpy arrays need no copies
        self._zero_copy = self._cpu
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
        # (lo, hi) (3,) float64, the scene box in world coordinates: every call asks for
        # it, so it is made once, read-only
        self._world_box = tree.world_box()
        for bound in self._world_box:
            bound.flags.writeable = False
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
        # the key: the (name, value) pairs of the defines and the source, in any order
        key = frozenset({**defines, "source": source}.items())
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
        types = tuple([a.dtype if isinstance(a, np.generic) else None for a in args])
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
        no element offset: `_input_buffer`'s (in place from host.COPY_BELOW bytes on where it
        starts on a page, or where the runtime takes any address), else a copy of it."""
        if self._page_inputs and array.ctypes.data % PAGE:
            return self._buffer(array)
        return self._input_buffer(array)[0]


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
        their host arrays (host_out, by the same names; an array may be a buffer's
        first part) and wait for it: a map where the buffer is the array itself, else
        a copy."""
        cl = _device._cl()
        for name, buf in device_out.items():
            if buf.hostbuf is not None:
                # the buffer is the host array: a map makes the kernel's writes visible
                mapped, _ = cl.enqueue_map_buffer(self.queue, buf, cl.map_flags.READ, 0,
                                                  host_out[name].shape, host_out[name].dtype)
                mapped.base.release(self.queue)
            else:
                cl.enqueue_copy(self.queue, host_out[name], buf, is_blocking=False)
        self.queue.finish()

    def _input_buffer(self, array):
        """(buffer, offset): a read-only device buffer holding a contiguous host array
        from element `offset` on. On a CPU device the buffer is the host's memory
        (USE_HOST_PTR, no copy) from host.COPY_BELOW bytes on, else a copy with offset 0.

        Intel's CPU runtime works in place only on memory that starts on a page, and
        copies anything else itself, slowly. So an array that does not start on a page
        is passed from the start of its page, with its offset in elements: the runtime
        and the kernel only read from it, and the page is mapped (the array is in it).
        The caller keeps `array` alive until the launch has finished."""
        cl = _device._cl()
        if not self._in_place(array):
            return cl.Buffer(self.context, cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR,
                             hostbuf=array), 0
        offset = 0
        lead = array.ctypes.data % PAGE
        if self._page_inputs and lead:
            if lead % array.itemsize == 0:
                region = (ctypes.c_uint8 * (lead + array.nbytes)).from_address(
                    array.ctypes.data - lead)
                offset = lead // array.itemsize
                array = np.frombuffer(region, dtype=np.uint8)
            else:
                aligned = page_aligned_empty(array.shape, array.dtype)
                np.copyto(aligned, array)
                array = aligned
        return cl.Buffer(self.context, cl.mem_flags.READ_ONLY | cl.mem_flags.USE_HOST_PTR,
                         hostbuf=array), offset

    def _in_place(self, array):
        """Whether a launch's buffer over host `array` is the array itself: on a CPU
        device, from host.COPY_BELOW bytes on (smaller arrays are copied; the rule
        host.page_aligned_empty follows, read at each call)."""
        return self._zero_copy and array.nbytes >= _host.COPY_BELOW

    def _output_buffer(self, array, read=False):
        """A write-only device buffer for a contiguous host array (read: the kernel
        reads it too): on a CPU device the array itself from host.COPY_BELOW bytes on, so
        nothing is copied back (`_read_outputs` maps it), else the device's own memory,
        copied back. Poisoned first when asked."""
        cl = _device._cl()
        access = cl.mem_flags.READ_WRITE if read else cl.mem_flags.WRITE_ONLY
        # 4-byte elements get _POISON, bytes (occluded's) 0xAD
        poison = _POISON if array.itemsize % 4 == 0 else np.uint8(0xAD)
        if self._poison_outputs:
            array.reshape(-1).view(poison.dtype)[:] = poison
        if self._in_place(array):
            return cl.Buffer(self.context, access | cl.mem_flags.USE_HOST_PTR, hostbuf=array)
        buf = cl.Buffer(self.context, access, array.nbytes)
        if self._poison_outputs:
            cl.enqueue_fill_buffer(self.queue, buf, poison, 0, array.nbytes)
        return buf

    # -- cameras' and lidars' launches -------------------------------------------------

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

    # -- copies --------------------------------------------------------------------------

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
