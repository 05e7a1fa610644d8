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
import copy
import dataclasses

import numpy as np

from . import device_tree as _device_tree
from . import ray_input
from . import hit_lists, query_rays
from . import rays as _rays
from . import points as _points
from . import render as _render
from .camera import Camera
from .device_tree import DeviceTree
from .double import double_hits, wants_double
from .errors import KdrayError
from .hits import TRACE_OUTPUTS, Hits, kernel_outputs  # noqa: F401 (kdray.trace.*, as before)
from .host import check_host_memory, page_aligned_empty
from .layout import KERNEL_OUTPUTS, MISS, OUTPUT_WIDTH  # noqa: F401 (kdray.trace.MISS)
from . import lidar as _lidar
from .ray_grid import ImageWidths
from .ray_order import ray_order
from .render import DEFAULT_AOVS
from .validate import check_class
from .work_sizes import (PACKETS, POCL_ITEM_BYTES, STACK_SIZES,  # noqa: F401 (kdray.trace.* names)
                         default_stack_size, max_local_size, pocl_item_bytes)

IMAGE_SEARCH_MIN_RAYS = 1 << 17
"""`Tracer.trace` looks for an image in (N, 3) rays (`ray_grid.grid_width`) only from
this many rays on: the search costs about 1 ms whatever N, and tracing in blocks saves
a few % of the kernel's time, which repays it from about 2^17 rays of a simple mesh
(BENCHMARKS.md, "(N, 3) rays traced as the image they are"). Image-shaped rays are
traced in blocks at any size."""


class Tracer(DeviceTree):
    """A KdTree uploaded to one OpenCL device, and the queries on it: a DeviceTree
    (kdray.device_tree: the work sizes, the tree's buffers, the programs and their
    launches) with `trace` and `render` here and the faces of the ray queries
    (kdray.rays, kdray.hit_lists), the point queries (kdray.points) and `scan`
    (kdray.lidar).

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
        super().__init__(tree, device, stack_size, local_size, batch_size, groups, packet,
                         refine)
        self._widths = ImageWidths()          # the image widths found (`_image_width`)

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
        box = self._world_box if rays_world else self.tree.bounds
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
            # (trace_rays takes no offset for the order: a buffer from its start)
            order_buf = None if order is None else self._whole_input(order)
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
        rows = max(1, _device_tree.MAX_RAYS_PER_LAUNCH // w)    # a launch's, at most
        if n >= 1 << 32 or tile_slots(w, min(h, rows)) >= 1 << 32:
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

    def _ray_map(self, camera):
        """(map32 (H*W, 3) float32, its device buffer, valid (H*W,) bool) of a camera of
        render.MAP_MODELS: made on the host once per intrinsics (kdray.lens keeps the
        float64 maps) and kept on the device for the MAPS_KEPT most recent ones."""
        key = (camera.model, camera.K.tobytes(), tuple(camera.distortion), camera.width,
               camera.height)
        return self._kept_map(key, lambda: _render.ray_map(camera))

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

