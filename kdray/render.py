"""Camera renders: the AOV vocabulary, the pixel rays the render kernel makes, and the
images made from its outputs. `Tracer.render` launches the kernel; this module holds
what is the same on every device.

    aovs = parse_aovs("depth,id")                      # ('depth', 'id')
    kernel_outputs(aovs)                               # ('T', 'ID'): all the kernel computes
    kernel_outputs(("object",))                        # ('ID',): objects are looked up
    M, eye = camera_constants(camera, origin, scale)   # float32, as the kernel gets them
    origins, directions = camera_rays(camera, origin, scale)   # the kernel's rays, on the host

Pixel (i, j) (column i, row j) is sampled at its centre: its ray leaves the eye with
direction M @ (i + 0.5, j + 0.5, 1), M = R K^-1 rounded to float32 and the product
taken in float32 (kernels/render.cl), so its camera-z is 1 and t is the z-depth.
"""
import numpy as np

from .errors import KdrayError
from .layout import KERNEL_OUTPUTS, MISS, OUTPUT_WIDTH
from .tree import object_ids
from .validate import check_float32

AOVS = ("depth", "distance", "normal", "bary", "id", "position", "object")
"""Every output `render` knows."""

DEFAULT_AOVS = ("depth", "normal", "bary", "id")

AOV_OUTPUT = {"depth": "T", "distance": "T", "position": "T", "bary": "UV", "normal": "NORMAL",
              "id": "ID", "object": "ID"}
"""The kernel output each AOV is made from (`object` on the host: the tree's object
of each triangle id, kdray.tree.object_ids)."""

RENDER_TILE = (64, 8)
"""(columns, rows) of the tiles the render kernel takes pixels in (kernels/render.cl):
neighbours in both directions are traced one after another and share the tree's nodes
in the cache. Columns are a multiple of the packet width (8)."""


def parse_aovs(aovs):
    """Validated AOV names, in the order given, duplicates dropped.

    aovs : a sequence of names, or one comma-separated string ('all' = every AOV, with
        other names too: they are in it).
    Raises KdrayError naming the valid AOVs for an unknown name or an empty list.
    """
    if isinstance(aovs, str):
        aovs = aovs.split(",")
    if not (isinstance(aovs, (list, tuple)) and all(isinstance(a, str) for a in aovs)):
        raise KdrayError(f"aovs must be names or one comma-separated string, got {aovs!r:.80}; "
                         f"valid AOVs are {', '.join(AOVS)} (or 'all').")
    names = [a.strip().lower() for a in aovs]
    names = [n for n in names if n]
    if "all" in names and all(n in AOVS or n == "all" for n in names):
        return AOVS
    unknown = [n for n in names if n not in AOVS]
    if unknown or not names:
        what = f"unknown AOV {', '.join(repr(n) for n in unknown)}" if unknown else "no AOV given"
        raise KdrayError(f"{what}; valid AOVs are {', '.join(AOVS)} (or 'all').")
    return tuple(dict.fromkeys(names))


def kernel_outputs(aovs):
    """The kernel outputs a render of `aovs` (names from AOVS) compiles in, in
    KERNEL_OUTPUTS order: depth, distance and position need T, bary UV, normal NORMAL,
    id and object ID. The others are neither computed nor stored."""
    wanted = {AOV_OUTPUT[a] for a in parse_aovs(aovs)}
    return tuple(name for name in KERNEL_OUTPUTS if name in wanted)


MAP_MODELS = ("opencv", "fisheye", "equirectangular")
"""The central camera models whose rays the render kernel makes from a ray map
(RAY_MAP): each pixel's camera-axis direction, computed once per intrinsics on the
host (kdray.lens), turned by the pose on the device. The render kernel makes the
orthographic camera's rays itself (ORTHOGRAPHIC); precision="double" renders of every
model but the pinhole trace the camera's float64 rays."""


def camera_values(camera, origin, scale=1.0):
    """The float32 values of the render kernel's `camera` buffer: M (3, 3) row-major and
    the eye relative to `origin` in units of `scale` (`camera_constants`); for an
    orthographic camera M = R K'^-1 / scale (K^-1 with its last row 0), the eye, then
    the unit forward axis (15 values: kernels/render.cl, ORTHOGRAPHIC)."""
    M, eye = camera_constants(camera, origin, scale)
    if camera.model != "orthographic":
        return np.concatenate([M.reshape(9), eye])
    return np.concatenate([M.reshape(9), eye, _forward(camera)])


def _forward(camera):
    return np.asarray(camera.cam_to_world, dtype=np.float64)[:3, 2].astype(np.float32)


def camera_origins(camera, origin, scale=1.0):
    """(H*W, 3) float64 world: an orthographic camera's ray origins as the kernel makes
    them (eye + M [i + 0.5, j + 0.5, 1] in float32, in the tree's frame, taken back to
    the world); None for a camera whose rays all leave its eye."""
    if camera.model != "orthographic":
        return None
    M, eye = camera_constants(camera, origin, scale)
    x, y = _pixel_centres(camera)
    o = np.empty((len(x), 3))
    for r in range(3):
        o[:, r] = (eye[r] + (M[r, 0] * x + M[r, 1] * y + M[r, 2])).astype(np.float64)
    return np.asarray(origin, dtype=np.float64) + scale * o


def _pixel_centres(camera):
    """(x, y): (H*W,) float32 each, the centres i + 0.5, j + 0.5 of every pixel,
    row-major, as the render kernel makes them."""
    w, h = int(camera.width), int(camera.height)
    x = np.tile(np.arange(w, dtype=np.float32) + np.float32(0.5), h)
    y = np.repeat(np.arange(h, dtype=np.float32) + np.float32(0.5), w)
    return x, y


def turn(M, v):
    """The render kernel's RAY_MAP directions: M (3, 3) float32 times each row of v
    (n, 3) float32, with its float32 arithmetic; a list of three (n,) float32 arrays."""
    x, y, z = v[:, 0], v[:, 1], v[:, 2]
    return [M[r, 0] * x + M[r, 1] * y + M[r, 2] * z for r in range(3)]


def ray_map(camera):
    """(map (H*W, 3) float32, valid (H*W,) bool) of a camera of MAP_MODELS: each pixel's
    camera-axis direction as the kernel reads it, row-major, NaN where the pixel has no
    ray (the float64 directions of kdray.lens rounded once)."""
    from . import lens
    _, d, valid = lens.camera_axis_rays(camera.model, camera.K, camera.distortion,
                                        int(camera.width), int(camera.height))
    return d.astype(np.float32), valid


def camera_constants(camera, origin, scale=1.0):
    """(M, eye): float32 R K^-1 (3, 3) (R for a camera of MAP_MODELS, whose directions
    come from its ray map; R K'^-1 / scale for an orthographic camera, K^-1 with its
    last row 0: the pixels' origins about the eye) and the eye relative to `origin`
    ((3,) float64, the tree's origin) in units of `scale` (the tree's) as (3,)
    float32, exactly as the kernel receives them."""
    c2w = np.asarray(camera.cam_to_world, dtype=np.float64)
    if camera.model in MAP_MODELS:
        M = c2w[:3, :3]
    elif camera.model == "orthographic":
        # pixel (x, y)'s origin is the eye + R (a, b, 0), (a, b, 1) = K^-1 (x, y, 1):
        # K^-1 without its last row, so that no unit of the forward axis is added in
        # float32 and taken off again (which lost a and b where the image spans
        # much less than a unit: a scene of 1e-4 drew 5e-4 of its size off)
        k_inv = np.linalg.inv(np.asarray(camera.K, dtype=np.float64))
        k_inv[2] = 0.0
        M = c2w[:3, :3] @ k_inv / scale
    else:
        M = c2w[:3, :3] @ np.linalg.inv(np.asarray(camera.K, dtype=np.float64))
    eye = (c2w[:3, 3] - np.asarray(origin, dtype=np.float64)) / scale
    # a camera far from a small scene (1e30 from a tree of scale 2^-100): the kernel's
    # float32 cannot hold where it is
    check_float32(M, "the camera's rays in the tree's units", KdrayError)
    check_float32(eye, "the camera's eye relative to the tree (in its units)", KdrayError)
    return M.astype(np.float32), eye.astype(np.float32)


def camera_directions(camera, map32=None):
    """The kernel's float32 ray directions of every pixel, row-major (row j, then
    column i): a list of three (H*W,) float32 arrays (x, y, z components). For a camera
    of MAP_MODELS, from its ray map (`ray_map`, or map32 when given); a pixel with no
    ray gets the optical axis, so that its miss has distance +inf, not NaN."""
    if camera.model == "orthographic":
        n = int(camera.width) * int(camera.height)
        return [np.full(n, c, dtype=np.float32) for c in _forward(camera)]
    M, _ = camera_constants(camera, np.zeros(3))
    if camera.model in MAP_MODELS:
        v = (ray_map(camera)[0] if map32 is None else map32).copy()
        v[np.isnan(v[:, 0])] = (0.0, 0.0, 1.0)
        return turn(M, v)
    x, y = _pixel_centres(camera)
    return [M[r, 0] * x + M[r, 1] * y + M[r, 2] for r in range(3)]


def camera_eye(camera, origin, scale=1.0):
    """(3,) float64 world: the eye as the kernel has it, its float32 coordinates in the
    tree's frame (origin, scale) taken back to the world."""
    return origin + scale * camera_constants(camera, origin, scale)[1].astype(np.float64)


def camera_rays(camera, origin, scale=1.0):
    """The rays the render kernel traces, computed on the host with its float32
    arithmetic: (origins (H*W, 3) float64 world, directions (H*W, 3) float32),
    row-major. Tracing them gives the render's hits (a pixel of a MAP_MODELS camera
    with no ray: a NaN direction, which misses)."""
    if camera.model in MAP_MODELS:
        map32, valid = ray_map(camera)
        d = np.stack(camera_directions(camera, map32), axis=1)
        d[~valid] = np.nan
    else:
        d = np.stack(camera_directions(camera), axis=1)
    origins = camera_origins(camera, origin, scale)
    if origins is not None:
        return origins, d
    origins = np.broadcast_to(camera_eye(camera, origin, scale), d.shape)
    return origins, d


def tile_slots(width, n_rows):
    """Work slots of the render kernel's tiling of `n_rows` rows of `width` pixels:
    whole RENDER_TILE tiles."""
    tw, th = RENDER_TILE
    return -(-width // tw) * tw * (-(-n_rows // th) * th)


def host_bytes_per_pixel(aovs):
    """Host bytes a render of `aovs` needs per pixel: kernel outputs, images, and the
    float64 rays that `distance` and `position` are computed from."""
    size = {"depth": 4, "distance": 4, "normal": 12, "bary": 8, "id": 4, "position": 12,
            "object": 8}                # the image and its lookup's temporary
    total = sum(size[a] for a in aovs) + 4
    if "object" in aovs and "id" not in aovs:
        total += 4                      # the kernel's ids it is looked up from
    if "distance" in aovs or "position" in aovs:
        total += 12 + 8 + 24 + 24
    return total


MAP_BYTES = 80
"""Host bytes per pixel that making a camera model's ray map takes at its peak
(`ray_map`: kdray.lens's float64 pixel points, directions and their temporaries, the
float32 map and the valid mask; an equirectangular camera's about 70, measured by
tracemalloc)."""


def output_shapes(n, outputs):
    """{output: (shape, dtype)} of the host arrays of n pixels' kernel outputs."""
    return {k: ((n,) if OUTPUT_WIDTH[k][0] == 1 else (n, OUTPUT_WIDTH[k][0]), OUTPUT_WIDTH[k][1])
            for k in outputs}


def images(out, camera, origin, aovs, scale=1.0, objects=None, map32=None):
    """The AOV images of a render from the kernel's outputs.

    out : {output: array} of H*W rows each (T (H*W,) float32, UV (H*W, 2), NORMAL
        (H*W, 3), ID (H*W,) uint32), as `kernel_outputs(aovs)` asked
    objects : the tree's object table (KdTree.objects: (n_input_tris,) uint32, or None:
        one object, 0), for `object`
    map32 : a MAP_MODELS camera's ray map (`ray_map`), when the caller has it
    Returns a dict in the order of `aovs`: depth (H, W) z-depth, +inf on a miss;
    distance (H, W) along the ray; normal (H, W, 3); bary (H, W, 2) u, v; id (H, W)
    uint32; position (H, W, 3) world hit point (NaN on a miss); object (H, W) uint32
    (0xFFFFFFFF on a miss). Arrays from `out` are reshaped, not copied.
    """
    w, h = int(camera.width), int(camera.height)
    result = {}
    if "distance" in aovs or "position" in aovs:
        # float64 from the kernel's float32 rays, column by column (numpy's loops
        # over rows of 3 are slow): |d| = sqrt((dx^2 + dy^2) + dz^2), p = o + t d
        d = [c.astype(np.float64) for c in camera_directions(camera, map32)]
        t = out["T"].astype(np.float64)
    for name in aovs:
        if name == "depth":
            result[name] = out["T"].reshape(h, w)
        elif name == "distance":
            dist = t * np.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
            result[name] = dist.astype(np.float32).reshape(h, w)
        elif name == "position":
            eye = camera_origins(camera, origin, scale)
            eye = camera_eye(camera, origin, scale) if eye is None else eye.T
            p = np.empty((w * h, 3), dtype=np.float32)
            with np.errstate(invalid="ignore"):
                for k in range(3):
                    p[:, k] = eye[k] + t * d[k]
            p[~np.isfinite(t)] = np.nan
            result[name] = p.reshape(h, w, 3)
        elif name == "normal":
            result[name] = out["NORMAL"].reshape(h, w, 3)
        elif name == "bary":
            result[name] = out["UV"].reshape(h, w, 2)
        elif name == "id":
            result[name] = out["ID"].reshape(h, w)
        elif name == "object":
            result[name] = object_ids(out["ID"], objects).reshape(h, w)
    return result


MODEL_RAY_BYTES = 3 * 24 + 1 + 104
"""Host bytes per pixel of a camera model's rays in double precision (Camera.rays:
float64 origins and directions, and the camera-axis directions they are made from),
its valid mask, and the float64 hits traced from them with their temporaries."""

ORTHOGRAPHIC_BYTES = 128
"""Host bytes per pixel an orthographic camera's double render adds (`orthographic_hits`:
its single render's ids and normals, and the float64 planes' arithmetic)."""


def ray_images(hits, origins, directions, valid, camera, aovs):
    """The AOV images of a camera traced from its own rays (a model that is not the
    pinhole: Tracer.render), and `valid`.

    hits : Hits of the H*W rays (float32 or, precision="double", float64 t, u, v);
    origins, directions : (H*W, 3) float64, the rays traced (Camera.rays: NaN
        directions for the pixels with no ray); valid : (H*W,) bool.
    Returns a dict in the order of `aovs`, then valid (H, W) bool: depth (H, W) the
    ray's t (z-depth for opencv and orthographic cameras, whose directions have
    camera-z 1; the distance along the unit ray for fisheye and equirectangular
    ones), +inf on a miss; distance (H, W) t |d|; position (H, W, 3) o + t d (NaN on a
    miss); normal, bary, id, object as `images`. float32, or float64 where hits are.
    """
    w, h = int(camera.width), int(camera.height)
    t = hits.t
    hit = hits.hit
    dtype = t.dtype
    result = {}
    for name in aovs:
        if name == "depth":
            result[name] = t.reshape(h, w)
        elif name == "distance":
            dist = np.full(w * h, np.inf)
            dd = directions[hit]
            dist[hit] = t[hit] * np.sqrt(dd[:, 0] ** 2 + dd[:, 1] ** 2 + dd[:, 2] ** 2)
            result[name] = dist.astype(dtype).reshape(h, w)
        elif name == "position":
            p = np.full((w * h, 3), np.nan)
            th = t[hit].astype(np.float64)
            for k in range(3):
                p[hit, k] = origins[hit, k] + th * directions[hit, k]
            result[name] = p.astype(dtype).reshape(h, w, 3)
        elif name == "normal":
            result[name] = hits.normal.reshape(h, w, 3)
        elif name == "bary":
            result[name] = np.stack([hits.u, hits.v], axis=-1).reshape(h, w, 2)
        elif name == "id":
            result[name] = hits.prim.reshape(h, w)
        elif name == "object":
            result[name] = hits.object.reshape(h, w)
    result["valid"] = np.asarray(valid, dtype=bool).reshape(h, w)
    return result


DOUBLE_AOVS = ("depth", "distance", "position", "bary")
"""The AOVs precision="double" computes in float64 (`double_images`)."""


def double_bytes_per_pixel(aovs):
    """Host bytes per pixel that `double_images` needs for `aovs` beside the kernel's
    images: the float64 rays (Camera.rays: origins, directions and the camera-axis
    directions they are made from), t and uv (depth and bary are views of them), the
    hit mask, the float64 hits' arithmetic (t, u, v and their temporaries: 64, by
    tracemalloc), and distance and position with their numpy temporaries
    (kdray.double's own are bounded by its CHUNK)."""
    size = {"distance": 8 + 24 + 8, "position": 24 + 4 * 24}
    return 72 + 24 + 1 + 64 + sum(size.get(a, 0) for a in aovs)


def orthographic_hits(tree, camera, directions, found):
    """Hits of an orthographic camera's pixels in double precision (Tracer.render):
    the triangles and normals its single render `found` (images "id" and "normal")
    names, whose kernel makes the rays relative to the tree's origin (a pixel's world
    float64 origin far from the world's origin loses its offset's last digits: a 1e-4
    at 1e12), and t, u, v from those rays relative to it (Camera._model_rays) and the
    tree's float64 triangles (kdray.double.hits_double). directions : (H*W, 3)."""
    from .double import hits_double
    from .hits import Hits
    prim = found["id"].reshape(-1)
    c = tree.origin
    o_rel = camera._model_rays(valid=False, origin=c)[0]
    t, uv = hits_double(tree.triangles64, prim, o_rel, directions, origin=c, tree=tree)
    return Hits(t, prim, uv[:, 0], uv[:, 1], found["normal"].reshape(-1, 3),
                object_table=tree.objects)


def double_images(ids, camera, triangles64, aovs, tree=None):
    """The AOVs of DOUBLE_AOVS in `aovs` in float64, from each pixel's exact float64
    ray (Camera.rays) and the float64 triangle the kernel found (kdray.double).

    ids : (H*W,) uint32 input triangle id per pixel, MISS on a miss;
    triangles64 : (n_input_tris, 3, 3) float64 world (KdTree.triangles64); tree: as
    kdray.double.hits_double takes it (where a float64 triangle has no plane).
    Returns {name: array}: depth, distance (H, W) float64 (+inf on a miss), position
    (H, W, 3) float64 (NaN on a miss), bary (H, W, 2) float64 (0 on a miss).
    """
    from .double import hits_double
    w, h = int(camera.width), int(camera.height)
    o, d = camera.rays()
    hit = ids != MISS
    t, uv = hits_double(triangles64, ids, o, d, tree=tree)
    result = {}
    for name in aovs:
        if name == "depth":
            result[name] = t.reshape(h, w)
        elif name == "distance":
            result[name] = (t * np.linalg.norm(d, axis=1)).reshape(h, w)
        elif name == "position":
            p = np.full((w * h, 3), np.nan)
            p[hit] = o[hit] + t[hit, None] * d[hit]
            result[name] = p.reshape(h, w, 3)
        elif name == "bary":
            result[name] = uv.reshape(h, w, 2)
    return result
