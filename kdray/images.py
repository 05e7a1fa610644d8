"""AOV images -> one multi-channel OpenEXR file, and an 8-bit PNG preview for people.

    images = tracer.render(camera, aovs=("depth", "normal", "bary", "id"))
    write_exr("out.exr", images, camera)  # Z, N.X N.Y N.Z, bary.U bary.V, id + camera
    write_preview("out.png", images)      # depth colour map | normals as RGB
    images = read_exr("out.exr")          # the same dict back, ids exact
    camera = read_camera("out.exr")       # the same kdray.Camera back, exactly
    write_exr("out.exr", images, camera, object_names=tree.object_names)
    names = read_object_names("out.exr")  # the tuple of names back, or None
    scan = tracer.scan(lidar, pose)       # a lidar's range image (kdray.lidar)
    write_exr("scan.exr", {k: scan[k] for k in ("range", "id", "object")},
              lidar=lidar, sensor_to_world=pose)
    lidar, pose = read_lidar("scan.exr")  # the same Lidar and pose back, or None

`images` maps AOV names to arrays that share one (H, W):

    depth    : (H, W) float32       channel Z              miss: +inf
    distance : (H, W) float32       channel T              miss: +inf
    normal   : (H, W, 3) float32    channels N.X N.Y N.Z   miss: 0
    bary     : (H, W, 2) float32    channels bary.U bary.V miss: 0
    id       : (H, W) uint32        channel id (UINT)      miss: 0xFFFFFFFF
    position : (H, W, 3) float32    channels P.X P.Y P.Z   miss: NaN
    object   : (H, W) uint32        channel object (UINT)  miss: 0xFFFFFFFF
    valid    : (H, W) bool          channel valid (UINT 0/1): a camera model's pixels
                                    that have a ray (Tracer.render, kdray.lens)
    range    : (H, W) float32       channel range          miss: +inf (a scan's: H beams, W columns)

The EXR is a single-part scanline file, full float32 (never half) plus 32-bit
unsigned integer channels for ids and objects, ZIP-compressed (lossless). It is
written with the OpenEXR package (the format's own library), which stores float32 and
uint32 numpy arrays as they are; OpenImageIO's Python bindings would convert a buffer
to the per-channel file types through float, rounding ids above 2**24. Files are read
with OpenImageIO, channel group by channel group, so ids come back as exact uint32.
Given object names (with `id` or `object`), the header holds them as a JSON array
(OBJECT_NAMES_ATTRIBUTE).

Given the camera, the header also holds it (see `CAMERA_ATTRIBUTES`): OpenEXR's
standard worldToCamera and worldToNDC (float32, OpenEXR's conventions) and kdray's own
exact float64 K and camera-to-world, so that a depth image is self-describing.
docs/exr.md documents every channel and attribute.

Both writers are atomic: the data goes to a temporary file in the destination folder
that is renamed over the destination only once complete, so a failure or Ctrl-C never
leaves a half-written file and never damages an existing one.
"""
import json
import mmap
import os
import struct

import numpy as np

from .camera import Camera
from .errors import KdrayError, OutputError
from .files import atomic_write
from .validate import FLOAT32_MAX, parse_json
from .layout import MISS
from .render import AOVS

CHANNELS = {
    "depth": ("Z",),
    "distance": ("T",),
    "normal": ("N.X", "N.Y", "N.Z"),
    "bary": ("bary.U", "bary.V"),
    "id": ("id",),
    "position": ("P.X", "P.Y", "P.Z"),
    "object": ("object",),
    "valid": ("valid",),
    "range": ("range",),
}
"""Each AOV's EXR channel names (the public contract). `range` is a lidar scan's
(Tracer.scan), not a render's."""

UINT_AOVS = ("id", "object")
"""The AOVs stored as 32-bit unsigned integers (exact)."""

UINT_CHANNELS = UINT_AOVS + ("valid",)
"""The images stored as 32-bit unsigned integers: the AOVs of UINT_AOVS and `valid`
(a camera model's pixels that have a ray, 1, and those that do not, 0; read back as
bool)."""

OBJECT_NAMES_ATTRIBUTE = "kdray/objectNames"
"""The header attribute (a string: a JSON array of strings) that holds the objects'
names, object i's at index i, when `write_exr` is given them."""

# Checking the images dict ----------------------------------------------------------


def _channel_arrays(images, path):
    """[(channel name, (H, W) array '<f4' or '<u4')] for the AOVs in `images`, and
    their size (H, W); OutputError naming `path` for images that are not AOVs of one
    size and their types."""
    channels = []
    for aov, array in _checked_images(images, path).items():
        names = CHANNELS[aov]
        if aov in UINT_CHANNELS:
            channels.append((names[0], array.astype("<u4")))
        else:
            array = array.astype("<f4")
            if array.ndim == 2:
                array = array[..., None]
            channels.extend((name, array[..., c]) for c, name in enumerate(names))
    return channels, channels[0][1].shape


def _checked_images(images, path):
    """{AOV: array} of `images` (a dict of AOVs, as render returns), in CHANNELS'
    order: OutputError naming `path` unless each is an AOV of its shape, all of one
    size of at least 1 x 1, integers (ids, objects; valid 0 or 1) or reals."""
    if not isinstance(images, dict) or not images:
        raise OutputError(f"cannot write {path}: no images given.")
    unknown = [name for name in images if name not in CHANNELS]
    if unknown:
        raise OutputError(
            f"cannot write {path}: unknown AOV {unknown[0]!r}; valid AOVs are {', '.join(CHANNELS)}."
        )
    size = None
    checked = {}
    for aov in CHANNELS:
        if aov not in images:
            continue
        array = np.asarray(images[aov])
        names = CHANNELS[aov]
        expected = (len(names),) if len(names) > 1 else ()
        if array.ndim != 2 + len(expected) or array.shape[2:] != expected:
            want = "(H, W" + "".join(f", {n}" for n in expected) + ")"
            raise OutputError(f"cannot write {path}: {aov} has shape {array.shape}, expected {want}.")
        if size is None:
            size = array.shape[:2]
        elif array.shape[:2] != size:
            raise OutputError(
                f"cannot write {path}: {aov} is {array.shape[1]}x{array.shape[0]} pixels "
                f"but other AOVs are {size[1]}x{size[0]}."
            )
        if aov in UINT_CHANNELS:
            if array.dtype.kind not in "iub":
                raise OutputError(f"cannot write {path}: {aov} must be an integer array, got {array.dtype}.")
            top = 1 if aov == "valid" else MISS
            if array.size and (array.min() < 0 or array.max() > top):
                raise OutputError(f"cannot write {path}: {aov} values must "
                                  + ("be 0 or 1 (a bool array)." if aov == "valid" else "fit in uint32."))
        elif array.dtype.kind not in "fiub":
            raise OutputError(f"cannot write {path}: {aov} must be a real array, got {array.dtype}.")
        checked[aov] = array
    if size[0] < 1 or size[1] < 1:
        raise OutputError(f"cannot write {path}: images have no pixels ({size[1]}x{size[0]}).")
    return checked


# OpenEXR writing ----------------------------------------------------------------------

DEPTH_CONVENTION = "z-depth along the camera's +z axis (OpenCV axes), in world units; +inf on a miss"
DISTANCE_CONVENTION = (
    "Euclidean distance from the camera centre along the pixel's ray, in world units; +inf on a miss"
)
MODEL_DEPTH_CONVENTION = {
    "opencv": DEPTH_CONVENTION,
    "orthographic": ("distance from the camera's image plane (through the eye) along its +z "
                     "axis (OpenCV axes), in world units; +inf on a miss"),
    "fisheye": ("distance from the camera centre along the pixel's ray (z-depth has no meaning "
                "past 90 degrees), in world units; +inf on a miss"),
    "equirectangular": ("distance from the camera centre along the pixel's ray (z-depth has no "
                        "meaning for a panorama), in world units; +inf on a miss"),
}
"""kdray/depth of a camera that is not a pinhole, by model (docs/exr.md)."""
MODEL_DISTANCE_CONVENTION = ("Euclidean distance from the pixel's ray origin along the ray, in "
                             "world units; +inf on a miss")
"""kdray/distance of an orthographic camera, whose rays leave its image plane."""

CAMERA_ATTRIBUTES = {
    "worldToCamera": "m44f",
    "worldToNDC": "m44f",
    "kdray/K": "m33d",
    "kdray/camToWorld": "m44d",
    "kdray/imageSize": "v2i",
    "kdray/depth": "string",
    "kdray/distance": "string",
    "kdray/version": "string",
}
"""The header attributes `write_exr` adds given a camera (kdray/depth and kdray/distance
only with that AOV; no worldToNDC for a camera that is not a pinhole): name -> OpenEXR
type. OpenImageIO reads each back under the same
name (see docs/exr.md)."""

MODEL_ATTRIBUTES = {"kdray/cameraModel": "string", "kdray/distortion": "string"}
"""The header attributes `write_exr` adds besides CAMERA_ATTRIBUTES given a camera that
is not a pinhole (kdray.lens): its model and its coefficients as a JSON array (exact,
Python's repr of each float64). A file without them holds a pinhole."""

_OPENCV_TO_EXR_CAMERA = np.diag([1.0, -1.0, 1.0, 1.0])
"""OpenCV camera axes (y down) -> OpenEXR's (x right, y up, z forward: left-handed)."""


def _openexr():
    try:
        import OpenEXR
    except ImportError as exc:
        raise KdrayError(f"the OpenEXR package is needed to write EXR files ({exc}).") from None
    return OpenEXR


def compress_on_threads(n=None):
    """Let the OpenEXR library compress a file's blocks on `n` threads (default: the
    CPUs this process may use) instead of the calling thread alone. The library's
    thread pool is one per process, so this is a process-wide setting; it never lowers
    a count already set. A 640 x 480 file of depth, normal and id: 23 -> 16 ms on 2
    cores. The bytes written are the same."""
    openexr = _openexr()
    if not hasattr(openexr, "set_global_thread_count"):        # OpenEXR before 3.3
        return
    if n is None:
        n = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    if openexr.global_thread_count() < n:
        openexr.set_global_thread_count(int(n))


def _world_to_opencv(camera):
    """(4, 4) float64 world -> OpenCV camera, column vectors: the rigid inverse of
    cam_to_world (R^T, -R^T eye), exact for the rotation part."""
    R, eye = camera.rotation, camera.eye
    M = np.eye(4)
    M[:3, :3] = R.T
    M[:3, 3] = -(R.T @ eye)
    return M


def exr_camera_matrices(camera):
    """OpenEXR's (worldToCamera, worldToNDC) of `camera`: (4, 4) float64 each, in
    OpenEXR's row-vector convention (p' = [x y z 1] M, then divide by p'[3]).

    worldToCamera maps world points to OpenEXR camera space: x right, y up, z forward
    (OpenCV's camera with y negated). worldToNDC maps them to (x, y) = (u / W, v / H),
    where (u, v) are kdray's pixel coordinates (Camera.project: pixel (i, j) covers
    [i, i + 1) x [j, j + 1)), so (0, 0) and (1, 1) are the image's upper-left and
    lower-right corners; its z is 1 / z-depth, which keeps the matrix invertible.
    """
    world_to_cv = _world_to_opencv(camera)
    K = camera.K
    projection = np.zeros((4, 4))  # OpenCV camera -> homogeneous NDC, column vectors
    projection[0, :3] = K[0] / camera.width
    projection[1, :3] = K[1] / camera.height
    projection[2, 3] = 1.0  # z' = 1, w = z: NDC z is 1 / depth
    projection[3, :3] = K[2]  # w = z (K's last row is [0, 0, 1])
    world_to_camera = _OPENCV_TO_EXR_CAMERA @ world_to_cv
    world_to_ndc = projection @ world_to_cv
    return world_to_camera.T, world_to_ndc.T


def check_camera_header(camera, path="the EXR file"):
    """OutputError when a camera's EXR matrices (worldToCamera, and a pinhole's
    worldToNDC: the header holds no other model's; float32 in the header: docs/exr.md)
    hold a value beyond float32's range; the command line asks before it renders. A
    camera within float32 (kdray.camera's checks) may still have one: a far eye's -R^T
    t, or a focal length of 1e30 times the eye's 1e10."""
    with np.errstate(all="ignore"):             # overflows are inf: refused below
        matrices = exr_camera_matrices(camera)
    written = 2 if camera.model == "pinhole" else 1
    for name, matrix in list(zip(("worldToCamera", "worldToNDC"), matrices))[:written]:
        big = ~(np.abs(matrix) <= FLOAT32_MAX)
        if big.any():
            raise OutputError(f"cannot write {path}: the camera's {name} matrix holds "
                              f"{float(matrix[big][0]):.4g}, beyond float32's range, in which "
                              f"the EXR header holds it (docs/exr.md)")


def _camera_header(camera, aovs):
    from . import __version__  # here: kdray's __init__ may one day import this module

    world_to_camera, world_to_ndc = exr_camera_matrices(camera)
    # C-ordered copies: the binding reads an array's buffer in C order whatever its
    # strides (a transposed view would be stored transposed).
    header = {
        "worldToCamera": np.array(world_to_camera, dtype=np.float32, order="C"),
        "kdray/K": np.array(camera.K, dtype=np.float64, order="C"),
        "kdray/camToWorld": np.array(camera.cam_to_world, dtype=np.float64, order="C"),
        "kdray/imageSize": np.array([camera.width, camera.height], dtype=np.int32),
        "kdray/version": str(__version__),
    }
    if "depth" in aovs:
        header["kdray/depth"] = DEPTH_CONVENTION
    if "distance" in aovs:
        header["kdray/distance"] = DISTANCE_CONVENTION
    if camera.model == "pinhole":
        # a pinhole's projection, the only model's that is one
        header["worldToNDC"] = np.array(world_to_ndc, dtype=np.float32, order="C")
    else:
        header["kdray/cameraModel"] = camera.model
        header["kdray/distortion"] = json.dumps(list(camera.distortion))   # exact: repr
        if "depth" in aovs:
            header["kdray/depth"] = MODEL_DEPTH_CONVENTION[camera.model]
        if "distance" in aovs and camera.model == "orthographic":
            header["kdray/distance"] = MODEL_DISTANCE_CONVENTION
    return header


def write_exr(path, images, camera=None, object_names=None, lidar=None, sensor_to_world=None):
    """Write the AOV images of one render as one multi-channel EXR file, atomically.

    images : dict of AOV name -> array (see the module docstring).
    camera : the kdray.Camera the images were rendered with, or None. Given, the header
             holds it (CAMERA_ATTRIBUTES; `read_camera` reads it back exactly) and its
             size must be the images'.
    object_names : the names of the objects the `object` image indexes (a sequence of
             str, KdTree.object_names), or None. Given (not empty) and the images hold
             `object` or `id`, the header holds them (OBJECT_NAMES_ATTRIBUTE;
             `read_object_names` reads them back); every value of `object` but
             0xFFFFFFFF must then index them.
    lidar, sensor_to_world : the kdray.lidar.Lidar and (4, 4) pose of a scan
             (Tracer.scan), or None. Given, the header holds them (LIDAR_ATTRIBUTES;
             `read_lidar` reads them back exactly) and the images must be the lidar's
             (beams, columns).
    Raises OutputError naming `path` for bad arrays, a camera or lidar of another size,
    both a camera and a lidar, a sensor_to_world without its lidar, bad object names, a
    missing or unwritable folder, or a failed write.
    """
    channels, (height, width) = _channel_arrays(images, path)
    names = _object_names_header(images, object_names, path)
    openexr = _openexr()
    header = {"compression": openexr.ZIP_COMPRESSION, "type": openexr.scanlineimage}
    if names is not None:
        header[OBJECT_NAMES_ATTRIBUTE] = names
    if camera is not None:
        if not isinstance(camera, Camera):
            raise OutputError(f"cannot write {path}: camera must be a kdray.Camera, got {type(camera).__name__}.")
        if (camera.width, camera.height) != (width, height):
            raise OutputError(
                f"cannot write {path}: the camera is {camera.width}x{camera.height} pixels "
                f"but the images are {width}x{height}."
            )
        check_camera_header(camera, path)
        header.update(_camera_header(camera, images))
    if lidar is not None and camera is not None:
        raise OutputError(f"cannot write {path}: a scan's file holds its lidar instead of a "
                          "camera; give one of them.")
    if lidar is None and sensor_to_world is not None:
        raise OutputError(f"cannot write {path}: sensor_to_world is a lidar's pose; give "
                          "the lidar with it.")
    if lidar is not None:
        header.update(_lidar_header(lidar, sensor_to_world, (height, width), images, path))
    # The binding reads each array's buffer in C order whatever its strides (openexr
    # issue 1929), so every channel is handed over as its own C-ordered copy.
    pixels = {name: np.ascontiguousarray(array) for name, array in channels}

    def write(tmp):
        try:
            with openexr.File(header, pixels) as exr:
                exr.write(str(tmp))
        except RuntimeError as exc:  # the library's I/O errors
            raise OutputError(f"cannot write {path}: {exc}") from None
        if not _exr_whole(tmp):
            raise OutputError(f"cannot write {path}: the file came out incomplete (is the "
                              f"disk full?).")

    atomic_write(path, write)


_EXR_CHUNK_LINES = {0: 1, 1: 1, 2: 1, 3: 16, 4: 32, 5: 16, 6: 32, 7: 32, 8: 32, 9: 256}
"""Scanlines a chunk of an EXR file holds, by its compression (OpenEXR's numbering:
none, RLE, ZIPS, ZIP, PIZ, PXR24, B44, B44A, DWAA, DWAB)."""


def _exr_whole(path):
    """Whether the single-part scanline EXR file `path` (as write_exr writes them) holds
    every chunk its offset table names, the last ending at the file's end. The library
    writes through a buffered stream whose last flush, at close, fails in silence on a
    full disk (a file of a few kilobytes came out empty, a larger one would lose its
    end): checked here, before the file replaces anything. The file is mapped, not
    read: only its header, offset table and last chunk's head are touched."""
    with open(path, "rb") as f:
        try:
            data = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ)
        except ValueError:                         # an empty file
            return False
    with data:
        try:
            return _exr_chunks_end(data) == len(data)
        except (IndexError, ValueError, struct.error):
            return False


def _exr_chunks_end(data):
    """Where the last chunk of the EXR file `data` (bytes-like) ends by its offset table,
    or -1 where its header is not one write_exr writes."""
    if data[:4] != b"\x76\x2f\x31\x01" or data[5:8] != b"\0\0\0":
        return -1
    at, lines, y0, y1 = 8, None, None, None
    while data[at] != 0:                           # attributes: name, type, size, value
        name_end = data.find(b"\0", at)
        type_end = data.find(b"\0", name_end + 1)
        if name_end < 0 or type_end < 0:
            return -1
        (size,) = struct.unpack_from("<i", data, type_end + 1)
        value = type_end + 5
        name = data[at:name_end]
        if name == b"compression":
            lines = _EXR_CHUNK_LINES.get(data[value])
        elif name == b"dataWindow":
            _, y0, _, y1 = struct.unpack_from("<4i", data, value)
        at = value + size
    if lines is None or y0 is None:
        return -1
    chunks = -(-(y1 - y0 + 1) // lines)
    last = max(struct.unpack_from(f"<{chunks}Q", data, at + 1))
    (size,) = struct.unpack_from("<i", data, last + 4)
    return last + 8 + size


def _object_names_header(images, object_names, path):
    """The object names' attribute value (a JSON array), or None when there are none to
    write (no names, or neither `object` nor `id` among the images)."""
    if object_names is None or not any(aov in images for aov in UINT_AOVS):
        return None
    try:
        object_names = list(object_names) if not isinstance(object_names, (str, bytes)) else None
    except TypeError:
        object_names = None
    if object_names is None or not all(isinstance(n, str) for n in object_names):
        raise OutputError(f"cannot write {path}: object_names must be a sequence of strings.")
    if not object_names:
        return None
    if "object" in images:
        obj = np.asarray(images["object"])
        bad = (obj != MISS) & (obj >= len(object_names))
        if np.any(bad):
            raise OutputError(f"cannot write {path}: object {int(obj[bad].flat[0])} has no name "
                              f"({len(object_names)} object names given).")
    value = json.dumps(object_names, ensure_ascii=False)
    try:
        value.encode("utf-8")                   # no lone surrogates
    except UnicodeEncodeError:
        raise OutputError(f"cannot write {path}: an object name is not valid Unicode.") from None
    return value


RANGE_CONVENTION = ("metres (world units) from the sensor along the unit beam; +inf on a "
                    "miss or at max_range and beyond")

LIDAR_ATTRIBUTES = {
    "kdray/lidar": "string",
    "kdray/sensorToWorld": "m44d",
    "kdray/range": "string",
    "kdray/version": "string",
}
"""The header attributes `write_exr` adds given a lidar (kdray/range only with that
channel): kdray/lidar its spec (Lidar.to_json, the list form, exact), kdray/sensorToWorld
the float64 sensor-to-world pose (REP 103 sensor axes). See docs/exr.md."""


def _lidar_header(lidar, pose, size, images, path):
    from . import __version__
    from .errors import CameraError
    from .lidar import Lidar, check_pose
    if not isinstance(lidar, Lidar):
        raise OutputError(f"cannot write {path}: lidar must be a kdray.lidar.Lidar, got "
                          f"{type(lidar).__name__}.")
    if tuple(size) != lidar.shape:
        raise OutputError(f"cannot write {path}: the lidar has {lidar.beams} beams x "
                          f"{lidar.columns} columns but the images are {size[0]} x {size[1]}.")
    try:
        pose = check_pose(pose)
    except CameraError as e:
        raise OutputError(f"cannot write {path}: {e}") from None
    header = {"kdray/lidar": lidar.to_json(),
              "kdray/sensorToWorld": np.array(pose, dtype=np.float64, order="C"),
              "kdray/version": str(__version__)}
    if "range" in images:
        header["kdray/range"] = RANGE_CONVENTION
    return header


def read_lidar(path):
    """(kdray.lidar.Lidar, (4, 4) float64 sensor-to-world pose) stored in the header of
    an EXR written by `write_exr` with a lidar, exactly; None when the file holds none.
    Raises KdrayError if the file cannot be read or holds part of one, or a bad one."""
    from .lidar import Lidar, check_pose
    _, inp = _open_exr(path)
    try:
        spec = inp.spec()
    finally:
        inp.close()
    spec_found = _find_attribute(spec, "kdray/lidar")
    pose_found = _find_attribute(spec, "kdray/sensorToWorld")
    if spec_found is None and pose_found is None:
        return None
    if spec_found is None or pose_found is None:
        missing = "kdray/lidar" if spec_found is None else "kdray/sensorToWorld"
        raise KdrayError(f"EXR {path} holds part of a lidar but no attribute {missing}.")
    if spec_found[0] != "string" or pose_found[0] != "matrixd":
        raise KdrayError(f"EXR {path}: attributes kdray/lidar and kdray/sensorToWorld must be "
                         f"a string and a matrixd, got {spec_found[0]} and {pose_found[0]}.")
    spec_dict = parse_json(spec_found[1], f"EXR {path}: attribute kdray/lidar", KdrayError)
    lidar = Lidar.from_dict(spec_dict, f"EXR {path}: attribute kdray/lidar")
    pose = check_pose(np.array(pose_found[1], dtype=np.float64).reshape(4, 4),
                      f"kdray/sensorToWorld of EXR {path}")
    return lidar, pose


def _oiio():
    try:
        import OpenImageIO
    except ImportError as exc:  # pragma: no cover - a dependency
        raise KdrayError(f"OpenImageIO is needed to read EXR and write PNG files ({exc}).") from None
    return OpenImageIO


def _open_exr(path):
    """(OpenImageIO, an open ImageInput of `path`); KdrayError when it cannot be read."""
    oiio = _oiio()
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise KdrayError(f"cannot read EXR {path}: {oiio.geterror() or 'unknown error'}.")
    # what kdray writes: one part of flat scanlines in OpenEXR (OpenImageIO opens
    # other formats, and would give a deep file's empty pixels as memory left over)
    problem = ("is not an EXR file" if inp.format_name() != "openexr" else
               "is a deep EXR" if inp.spec().deep else
               "holds several parts" if inp.seek_subimage(1, 0) else None)
    if problem:
        inp.close()
        raise KdrayError(f"cannot read EXR {path}: it {problem}; kdray reads one part of "
                         f"flat images, as write_exr writes.")
    inp.seek_subimage(0, 0)
    return oiio, inp


def read_exr(path):
    """Read an EXR written by `write_exr` (or any with kdray's channel names) -> dict.

    Returns the AOVs whose channels are all present: float32 arrays, ids as exact uint32.
    Raises KdrayError if the file cannot be read or holds part of an AOV's channels.
    """
    oiio, inp = _open_exr(path)
    try:
        spec = inp.spec()
        names = list(spec.channelnames)
        formats = list(spec.channelformats) or [spec.format] * len(names)
        images = {}
        for aov in CHANNELS:
            present = [name in names for name in CHANNELS[aov]]
            if not any(present):
                continue
            if not all(present):
                missing = [n for n, p in zip(CHANNELS[aov], present) if not p]
                raise KdrayError(f"EXR {path} has part of {aov} but no channel {missing[0]}.")
            planes = []
            for name in CHANNELS[aov]:
                c = names.index(name)
                if aov in UINT_CHANNELS and formats[c].basetype == oiio.UINT:
                    plane = inp.read_image(0, 0, c, c + 1, oiio.UINT)
                else:
                    plane = inp.read_image(0, 0, c, c + 1, oiio.FLOAT)
                if plane is None:
                    raise KdrayError(f"cannot read channel {name} of EXR {path}: {inp.geterror()}.")
                planes.append(np.asarray(plane).reshape(spec.height, spec.width))
            if aov in UINT_CHANNELS:
                plane = planes[0]
                if plane.dtype.kind != "u":  # an id channel stored as float elsewhere
                    whole = np.isfinite(plane) & (plane >= 0) & (plane < 2.0 ** 32)
                    whole[whole] = plane[whole] == np.rint(plane[whole])
                    if not whole.all():
                        bad = plane[~whole][0]
                        raise KdrayError(f"EXR {path}: channel {CHANNELS[aov][0]} holds "
                                         f"{float(bad)!r}, not a uint32 {aov} (kdray writes them "
                                         f"as UINT).")
                images[aov] = plane.astype(np.uint32) if aov != "valid" else plane != 0
            elif len(planes) == 1:
                images[aov] = planes[0].astype(np.float32)
            else:
                images[aov] = np.stack(planes, axis=-1).astype(np.float32)
        return images
    finally:
        inp.close()


def _find_attribute(spec, name):
    """(OpenImageIO type name, value) of the header attribute `name`, or None."""
    for attribute in spec.extra_attribs:
        if attribute.name == name:
            return str(attribute.type), attribute.value
    return None


def read_object_names(path):
    """The object names stored in the header of an EXR written by `write_exr`
    (OBJECT_NAMES_ATTRIBUTE): a tuple of str, object i's at index i; None when the file
    holds none. Raises KdrayError if the file cannot be read or the attribute is not a
    JSON array of strings."""
    _, inp = _open_exr(path)
    try:
        spec = inp.spec()
    finally:
        inp.close()
    found = _find_attribute(spec, OBJECT_NAMES_ATTRIBUTE)
    if found is None:
        return None
    type_name, value = found
    try:
        names = parse_json(value, "", KdrayError) if type_name == "string" else None
    except KdrayError:
        names = None
    if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
        raise KdrayError(f"EXR {path}: attribute {OBJECT_NAMES_ATTRIBUTE} is not a JSON array "
                         f"of strings.")
    return tuple(names)


_CAMERA_READ = {"kdray/K": ("matrix33d", (3, 3)), "kdray/camToWorld": ("matrixd", (4, 4)),
                "kdray/imageSize": ("vector2i", (2,))}
"""The attributes read_camera needs: name -> (OpenImageIO's type name, shape)."""


def read_camera(path):
    """The kdray.Camera stored in the header of an EXR written by `write_exr`, exactly
    (float64 K and camera-to-world), or None when the file holds no camera.

    Raises KdrayError if the file cannot be read, or holds part of a camera, attributes
    of the wrong type or a camera that is not valid.
    """
    _, inp = _open_exr(path)
    try:
        spec = inp.spec()
    finally:
        inp.close()
    found = {name: _find_attribute(spec, name) for name in _CAMERA_READ}
    if all(value is None for value in found.values()):
        return None
    values = {}
    for name, (type_name, shape) in _CAMERA_READ.items():
        if found[name] is None:
            raise KdrayError(f"EXR {path} holds part of a camera but no attribute {name}.")
        got_type, value = found[name]
        if got_type != type_name:
            raise KdrayError(f"EXR {path}: attribute {name} is a {got_type}, expected a {type_name}.")
        values[name] = np.array(value).reshape(shape)
    width, height = (int(n) for n in values["kdray/imageSize"])
    model, distortion = _camera_model(spec, path)
    try:
        return Camera(width, height, values["kdray/K"], values["kdray/camToWorld"], model,
                      distortion)
    except KdrayError as exc:
        raise KdrayError(f"EXR {path} holds an invalid camera: {exc}") from None


def _camera_model(spec, path):
    """(model, distortion) of the header's kdray/cameraModel and kdray/distortion:
    ("pinhole", ()) when it has neither."""
    model = _find_attribute(spec, "kdray/cameraModel")
    distortion = _find_attribute(spec, "kdray/distortion")
    if model is None and distortion is None:
        return "pinhole", ()
    if model is None or distortion is None or model[0] != "string" or distortion[0] != "string":
        raise KdrayError(f"EXR {path}: attributes kdray/cameraModel and kdray/distortion must "
                         f"both be strings.")
    try:
        coefficients = parse_json(distortion[1], "", KdrayError)
    except KdrayError:
        coefficients = None
    if not isinstance(coefficients, list):
        raise KdrayError(f"EXR {path}: attribute kdray/distortion is not a JSON array of numbers.")
    return model[1], coefficients


# PNG previews ----------------------------------------------------------------------------

_VIRIDIS = np.array(
    [
        (68, 1, 84), (72, 36, 117), (65, 68, 135), (53, 95, 141), (42, 120, 142),
        (33, 145, 140), (34, 168, 132), (68, 191, 112), (122, 209, 81), (189, 223, 38),
        (253, 231, 37),
    ],
    dtype=np.float64,
)
"""viridis (perceptually uniform) at 0, 0.1, ..., 1; linearly interpolated between."""


def _colormap(t):
    """t in [0, 1], any shape -> uint8 RGB of shape t.shape + (3,)."""
    x = np.clip(t, 0.0, 1.0) * (len(_VIRIDIS) - 1)
    i = np.minimum(x.astype(np.int64), len(_VIRIDIS) - 2)
    f = (x - i)[..., None]
    return np.rint(_VIRIDIS[i] * (1 - f) + _VIRIDIS[i + 1] * f).astype(np.uint8)


def _depth_panel(depth):
    """Near bright, far dark (viridis); misses (non-finite) black."""
    depth = np.asarray(depth, dtype=np.float64)
    hit = np.isfinite(depth)
    rgb = np.zeros(depth.shape + (3,), np.uint8)
    if hit.any():
        near, far = depth[hit].min(), depth[hit].max()
        t = (far - depth[hit]) / (far - near) if far > near else np.ones(hit.sum())
        rgb[hit] = _colormap(t)
    return rgb


def _normal_panel(normal):
    """(n + 1) / 2 as RGB; misses (zero or non-finite normals) black."""
    normal = np.asarray(normal, dtype=np.float64)
    hit = np.all(np.isfinite(normal), axis=-1) & np.any(normal != 0, axis=-1)
    rgb = np.zeros(normal.shape, np.uint8)
    rgb[hit] = np.rint(np.clip((normal[hit] + 1.0) / 2.0, 0, 1) * 255).astype(np.uint8)
    return rgb


def _id_panel(ids):
    """A stable pseudo-random colour per id; misses black."""
    x = np.asarray(ids).astype(np.uint32)
    h = x * np.uint32(0x9E3779B1)
    h ^= h >> np.uint32(16)
    h *= np.uint32(0x85EBCA6B)
    h ^= h >> np.uint32(13)
    rgb = np.stack([(h >> np.uint32(s)) & np.uint32(0xFF) for s in (0, 8, 16)], axis=-1)
    rgb = (48 + rgb * 207 // 255).astype(np.uint8)  # never near black
    rgb[x == MISS] = 0
    return rgb


def _bary_panel(bary):
    bary = np.nan_to_num(np.asarray(bary, dtype=np.float64))
    rgb = np.stack([bary[..., 0], bary[..., 1], 1.0 - bary[..., 0] - bary[..., 1]], axis=-1)
    return np.rint(np.clip(rgb, 0, 1) * 255).astype(np.uint8)


def _position_panel(position):
    position = np.asarray(position, dtype=np.float64)
    hit = np.all(np.isfinite(position), axis=-1)
    rgb = np.zeros(position.shape, np.uint8)
    if hit.any():
        lo, hi = position[hit].min(axis=0), position[hit].max(axis=0)
        span = np.where(hi > lo, hi - lo, 1.0)
        rgb[hit] = np.rint(np.clip((position[hit] - lo) / span, 0, 1) * 255).astype(np.uint8)
    return rgb


def preview_rgb(images):
    """(H, W', 3) uint8: depth (or distance) and normals side by side when both are
    present, else the first present of depth, distance, normal, id, object, bary,
    position (ids and objects: a colour each)."""
    depth = images.get("depth", images.get("distance"))
    if depth is not None and "normal" in images:
        return np.concatenate([_depth_panel(depth), _normal_panel(images["normal"])], axis=1)
    if depth is not None:
        return _depth_panel(depth)
    panels = {"normal": _normal_panel, "id": _id_panel, "object": _id_panel, "bary": _bary_panel,
              "position": _position_panel}
    for name, panel in panels.items():
        if name in images:
            return panel(images[name])
    raise OutputError(f"no image to preview; expected some of {', '.join(AOVS)}.")


_PNG_END = b"\0\0\0\0IEND\xaeB`\x82"
"""The last 12 bytes of every PNG file: its empty IEND chunk and that chunk's CRC."""


def write_preview(path, images):
    """Write an 8-bit RGB PNG of `images` for people (see `preview_rgb`), atomically.
    OutputError naming `path` for images write_exr would refuse too."""
    images = _checked_images(images, path)
    try:
        rgb = np.ascontiguousarray(preview_rgb(images))
    except OutputError as exc:
        raise OutputError(f"cannot write {path}: {exc}") from None
    if rgb.ndim != 3 or rgb.shape[0] < 1 or rgb.shape[1] < 1:
        raise OutputError(f"cannot write {path}: images have no pixels.")
    oiio = _oiio()

    def write(tmp):
        out = oiio.ImageOutput.create("png")
        if out is None:
            raise OutputError(f"cannot write {path}: OpenImageIO has no PNG writer ({oiio.geterror()}).")
        spec = oiio.ImageSpec(rgb.shape[1], rgb.shape[0], 3, oiio.UINT8)
        ok = out.open(str(tmp), spec) and out.write_image(rgb)
        ok = out.close() and ok
        if not ok:
            raise OutputError(f"cannot write {path}: {out.geterror() or 'OpenImageIO failed'}.")
        # a PNG ends with its IEND chunk: a full disk, which the writer's last flush
        # meets in silence, leaves a file without it
        with open(tmp, "rb") as f:
            f.seek(0, os.SEEK_END)
            f.seek(max(0, f.tell() - len(_PNG_END)))
            if f.read() != _PNG_END:
                raise OutputError(f"cannot write {path}: the file came out incomplete (is "
                                  f"the disk full?).")

    atomic_write(path, write)
