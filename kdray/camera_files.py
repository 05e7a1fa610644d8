"""Files of many cameras -> a list of named views, in the file's order.

    views = read_cameras("transforms.json")   # nerfstudio
    views = read_cameras("sparse/0")          # COLMAP text model (or its cameras.txt / images.txt)
    views = read_cameras("cameras.json")      # a JSON list of kdray cameras (or one camera)
    for view in views:                        # View(name: str, camera: Camera)
        images = tracer.render(view.camera)   # kdray render writes DIR/<view.name>.exr

Every view is a `Camera` (OpenCV axes, pixel centres at i + 0.5): a pinhole, or an
opencv, fisheye or equirectangular camera (kdray.lens) for the models below. A file
that holds anything else (another camera model, a coefficient kdray's model lacks, a
non-rigid pose, a name that is no file name) raises `CameraError` with one line naming
the file and the frame; nothing is guessed silently. The formats (docs/conventions.md, "Camera files (several views)"):

nerfstudio ``transforms.json``: a JSON object with "frames". Intrinsics ``fl_x fl_y cx cy
w h`` at the top level, each of which a frame may override with its own. ``fl_y``
defaults to ``fl_x`` (as instant-ngp's files allow; nerfstudio's own parser requires
it); ``cx`` and ``cy`` are required, as nerfstudio requires them (instant-ngp would take
the image centre: a guess kdray does not make). ``transform_matrix`` is camera-to-world
with OpenGL/Blender camera axes (x right, y up, z back); kdray's OpenCV axes flip the
camera's y and z: ``cam_to_world = transform_matrix @ diag(1, -1, -1, 1)``. The view's
name is the stem of ``file_path``. ``camera_model`` (per frame, else top level): the
models nerfstudio renders as a perspective camera (PINHOLE, SIMPLE_PINHOLE, OPENCV,
SIMPLE_RADIAL, RADIAL; absent means perspective too) are a pinhole when every
distortion coefficient (k1 k2 k3 k4 p1 p2, or "distortion_params" in that order) is zero
or absent, else kdray's ``opencv`` with (k1, k2, p1, p2[, k3]) (nerfstudio's k4 is an
r^8 term OpenCV's model lacks: refused unless zero); OPENCV_FISHEYE is ``fisheye`` with
(k1, k2, k3, k4) (p1, p2 must be zero); EQUIRECTANGULAR is ``equirectangular`` with
K = [[fl_x / pi, 0, cx], [0, fl_y / pi, cy]] (nerfstudio's longitude pi (x - cx) / fl_x,
latitude -pi (y - cy) / fl_y; no coefficients). Any other model, or instant-ngp's
``is_fisheye``, is refused. Other keys (aabb_scale, mask_path, ...) are ignored.

    Pixel convention: nerfstudio samples pixel (i, j) at (i + 0.5, j + 0.5)
    (``Cameras.get_image_coords``, pixel_offset=0.5) and its perspective ray is
    ((x - cx) / fx, -(y - cy) / fy, -1) in OpenGL camera axes, which is
    ((x - cx) / fx, (y - cy) / fy, 1) in OpenCV axes: kdray's ``R K^-1 [i + 0.5, j + 0.5, 1]``
    with K = [[fl_x, 0, cx], [0, fl_y, cy], [0, 0, 1]]. So fl_x, fl_y, cx, cy go into K
    unchanged, with no half-pixel shift.

    Where a key is given both at the top level and in a frame, the frame's value wins
    here (as in instant-ngp). nerfstudio's parser reads a frame's fl_x, fl_y, cx, cy, w,
    h and distortion only when the top level lacks them, so a file with both, differing,
    renders otherwise there. Distortion coefficients are checked at both levels; the
    camera_model that applies (the frame's, else the top level's) only. NeRF's and
    instant-ngp's camera_angle_x (camera_angle_y) stand for fl_x (fl_y) where it is
    missing: fl = side / 2 / tan(angle / 2), and cx, cy then default to the centre.

COLMAP text model: a folder holding cameras.txt and images.txt (e.g. ``sparse/0``), or
the path of either (the other beside it). cameras.txt: ``CAMERA_ID MODEL WIDTH HEIGHT
PARAMS...``: SIMPLE_PINHOLE (f cx cy), PINHOLE (fx fy cx cy), SIMPLE_RADIAL (f cx cy k),
RADIAL (f cx cy k1 k2), OPENCV (fx fy cx cy k1 k2 p1 p2) and FULL_OPENCV (... k1 k2 p1 p2
k3 k4 k5 k6) as kdray's ``opencv`` (a pinhole when every coefficient is zero), and
OPENCV_FISHEYE (fx fy cx cy k1 k2 k3 k4) as ``fisheye``; COLMAP's distortion models are
OpenCV's, in its order. Any other model is refused. images.txt: two
lines per image, ``IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME`` then the 2D points (a
line that may be empty). (q, t) map world to camera, x_cam = R(q) x_world + t, so
cam_to_world = [R^T | -R^T t]; COLMAP's camera axes are OpenCV's and its pixel (0, 0)
has its centre at (0.5, 0.5), as in kdray: K and the pose are used as they are. The
quaternion is normalized; one whose norm is off 1 by more than QUATERNION_TOL is
refused. The name is the stem of NAME. Lines starting with # are comments.

kdray JSON: a list of the objects `Camera.from_json` reads, each with an optional
"name" (default view_00000, view_00001, ...); or one such object, a single view named
after the file's stem.

Names become file names (DIR/<name>.exr): an empty name, "." or "..", one holding "/",
"\\", a control character (NUL, newline, ...) or, on Windows, ":" is refused, and so
are two views whose names are equal or differ only in case (they would overwrite each
other on a case-insensitive file system).
"""
import dataclasses
import math
import numbers
import os
import re
import unicodedata
from pathlib import Path, PurePosixPath

import numpy as np

from .camera import MAX_SIDE, Camera, _check_pose, _is_nested_numbers
from .errors import CameraError
from .files import name_problem
from .validate import read_json, read_text

MAX_VIEWS = 1_000_000
"""Most views one file may name. Each is a render and an output file, and a View takes
about 0.7 KB and 50-100 us to read, so a million is already hours of rendering, most of
a gigabyte and a minute of reading: a file naming more is refused on its count alone,
before any Camera is built."""

QUATERNION_TOL = 1e-3
"""A COLMAP quaternion whose norm is off 1 by more than this is refused, not normalized:
COLMAP writes unit quaternions, so such a norm means a damaged or hand-made file, not
rounding."""

_WINDOWS = os.name == "nt"
"""On Windows a ':' in a name would make DIR/<name>.exr a drive-relative path or a stream."""

_PERSPECTIVE_MODELS = ("PINHOLE", "SIMPLE_PINHOLE", "OPENCV", "SIMPLE_RADIAL", "RADIAL")
"""nerfstudio camera_model values that nerfstudio renders as a perspective camera
(cameras.CAMERA_MODEL_TO_TYPE), undistorting with k1 k2 k3 k4 p1 p2 whatever the
name: with zero distortion a pinhole, else kdray's `opencv` (k1 k2 p1 p2 k3)."""

_NERFSTUDIO_MODELS = _PERSPECTIVE_MODELS + ("OPENCV_FISHEYE", "EQUIRECTANGULAR")
"""nerfstudio camera_model values kdray renders."""

_DISTORTION_KEYS = ("k1", "k2", "k3", "k4", "p1", "p2")
"""nerfstudio's distortion coefficients, in the order of its "distortion_params"."""

_COLMAP_MODELS = {
    "SIMPLE_PINHOLE": ("f", "cx", "cy"),
    "PINHOLE": ("fx", "fy", "cx", "cy"),
    "SIMPLE_RADIAL": ("f", "cx", "cy", "k"),
    "RADIAL": ("f", "cx", "cy", "k1", "k2"),
    "OPENCV": ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2"),
    "FULL_OPENCV": ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"),
    "OPENCV_FISHEYE": ("fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4"),
}
"""COLMAP camera models kdray renders, with their PARAMS (COLMAP's camera_models.h).
The distortion coefficients follow the focal lengths and principal point in OpenCV's
order; the radial models are OpenCV's with the missing coefficients zero."""

# images.txt's second line of an image: X Y POINT3D_ID triples, X and Y numbers and the
# ID a whole number (-1: no 3D point). An image line in its place fails this unless its
# QX, TX and its name's words are numbers, the third word and the QX and TX whole ones.
_NUMBER = r"[-+]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][-+]?[0-9]+)?"
_POINTS_2D = re.compile(rf"(?:{_NUMBER}\s+{_NUMBER}\s+-?[0-9]+(?:\s+|$))*")

_NOT_SUPPORTED = ("is not supported yet (kdray renders pinhole, OpenCV, OpenCV fisheye and "
                  "equirectangular cameras)")


@dataclasses.dataclass(frozen=True)
class View:
    """One view of a camera file: `name` (a safe file name stem) and its `camera`."""

    name: str
    camera: Camera


def read_cameras(path):
    """Read a file of cameras: a list of `View`, in the file's order.

    path : a nerfstudio transforms.json, a COLMAP text model (its folder, cameras.txt
    or images.txt), a JSON list of kdray cameras or a single kdray camera file.
    Raises CameraError (one line naming the file and the frame) for anything that is
    not a valid set of views of the cameras kdray renders; see the module docstring.
    """
    path = Path(path)
    try:
        folder = path.is_dir()
    except OSError:         # a name the system cannot look up (too long): reading it says so
        folder = False
    if folder:
        where = path / "images.txt"
        views, origins = _read_colmap(path, path / "cameras.txt", where)
    elif path.name in ("cameras.txt", "images.txt"):
        where = path.with_name("images.txt")
        views, origins = _read_colmap(path, path.with_name("cameras.txt"), where)
    else:
        where = path
        views, origins = _read_json_views(path)
    _check_unique(views, origins, where)
    return views


def _read_json_views(path):
    data = _read_json(path)
    if isinstance(data, dict) and "frames" in data:
        return _nerfstudio_views(data, path)
    if isinstance(data, list):
        return _list_views(data, path)
    if isinstance(data, dict):
        camera = _camera_from_dict(data, path, f"camera file {path}")
        _check_name(path.stem, path, "the file's stem")
        return [View(path.stem, camera)], [str(path)]
    raise CameraError(
        f"camera file {path} holds a JSON {_json_type(data)}; expected a nerfstudio "
        "transforms.json (an object with \"frames\"), a list of kdray cameras or one "
        "kdray camera object."
    )


# Reading ----------------------------------------------------------------------------


def _read_text(path, shown):
    return read_text(path, shown, CameraError)


def _read_json(path):
    return read_json(path, f"camera file {path}", CameraError)


def _json_type(value):
    names = {dict: "object", list: "array", str: "string", bool: "boolean", type(None): "null"}
    return names.get(type(value), "number")


def _show(value, limit=60):
    """repr(value), cut to about `limit` characters: messages quote what a file holds."""
    text = repr(value)
    return text if len(text) <= limit else text[:limit] + "..."


def _fail(path, label, detail):
    return CameraError(f"camera file {path}: {label}: {detail}")


def _check_count(count, path):
    if count > MAX_VIEWS:
        raise CameraError(
            f"camera file {path} names {count} views; at most {MAX_VIEWS} (MAX_VIEWS) are "
            "read from one file: split it."
        )
    if count == 0:
        raise CameraError(f"camera file {path} names no views.")


def _camera_from_dict(data, path, label):
    """A kdray camera object -> Camera (sides at most MAX_SIDE, as every Camera's),
    errors prefixed with `label`."""
    try:
        return Camera._from_dict(data)
    except CameraError as exc:
        raise CameraError(f"{label}: {exc}") from None


# Names ------------------------------------------------------------------------------


def _name_problem(name):
    """Why `name` cannot be the stem of an output file DIR/<name>.exr, or None."""
    if name in ("", ".", ".."):
        return "is not a file name"
    for ch, what in (("/", "'/'"), ("\\", "'\\'"), ("\0", "NUL")):
        if ch in name:
            return f"contains {what}"
    if _WINDOWS and ":" in name:
        return "contains ':' (on Windows a drive or a stream)"
    for ch in name:
        category = unicodedata.category(ch)
        if category == "Cc":
            return f"contains the control character U+{ord(ch):04X}"
        if category == "Cs":
            return f"contains the lone surrogate U+{ord(ch):04X} (not Unicode text)"
        if category in ("Zl", "Zp"):
            return f"contains the line separator U+{ord(ch):04X}"
    # the longest name written is the temporary one of <name>.exr (kdray.files)
    problem = name_problem(name + ".exr")
    return f"is too long: {problem}" if problem else None


def _check_name(name, path, label):
    problem = _name_problem(name)
    if problem:
        raise _fail(path, label, f"the view name {_show(name)} cannot be a file name "
                                 f"(<name>.exr): it {problem}.")


def _check_unique(views, origins, path):
    seen = {}
    for view, origin in zip(views, origins):
        key = view.name.casefold()
        if key in seen:
            other, first = seen[key]
            how = ("the same name" if other == view.name
                   else f"names that differ only in case ({_show(other)})")
            raise CameraError(
                f"camera file {path}: {first} and {origin} have {how} {_show(view.name)}; each "
                "view is written to <name>.exr, so names must differ (ignoring case)."
            )
        seen[key] = (view.name, origin)


# nerfstudio transforms.json ---------------------------------------------------------


def _nerfstudio_views(meta, path):
    frames = meta["frames"]
    if not isinstance(frames, list):
        raise CameraError(f"camera file {path}: \"frames\" must be a list of frame objects, "
                          f"got a JSON {_json_type(frames)}.")
    _check_count(len(frames), path)
    views, origins = [], []
    for index, frame in enumerate(frames):
        views.append(_nerfstudio_view(meta, frame, index, path))
        origins.append(f"frames[{index}] ({_show(frame['file_path'])})")
    return views, origins


def _nerfstudio_view(meta, frame, index, path):
    label = f"frames[{index}]"
    if not isinstance(frame, dict):
        raise _fail(path, label, f"expected a frame object, got a JSON {_json_type(frame)}.")
    if "file_path" not in frame:
        raise _fail(path, label, "missing 'file_path'.")
    file_path = frame["file_path"]
    if not isinstance(file_path, str):
        raise _fail(path, label, f"file_path must be a string, got {_show(file_path)}.")
    name = PurePosixPath(file_path.replace("\\", "/")).stem
    _check_name(name, path, f"{label} (file_path {_show(file_path)})")
    label = f"frame {name}"
    model, distortion = _nerfstudio_model(meta, frame, path, label)

    def given(key):
        return key in frame or key in meta

    angles = not given("fl_x") and given("camera_angle_x")   # NeRF's and instant-ngp's form

    def value(key):
        """(value, how to name it) from the frame, else the top level."""
        if key in frame:
            return frame[key], key
        if key in meta:
            return meta[key], f"top-level {key}"
        hint = {"fl_x": " or camera_angle_x",
                "w": " and 'h': a file with camera_angle_x (NeRF's synthetic scenes) does "
                     "not say its image size" if angles else ""}.get(key, "")
        raise _fail(path, label, f"missing '{key}'{hint} (give it at the top level or in the "
                                 f"frame).")

    width, height = (_side(*value(key), path, label) for key in ("w", "h"))

    def focal(key, angle_key, side):
        """fl_x or fl_y, or one from a field of view (camera_angle_x, camera_angle_y:
        radians across the image's width, height), or None where neither is given."""
        if given(key):
            return _number(*value(key), path, label, positive=True)
        if not given(angle_key):
            return None
        angle = _number(*value(angle_key), path, label, positive=True)
        if not angle < math.pi:
            raise _fail(path, label, f"{angle_key} must be below pi radians, got {angle!r}.")
        return 0.5 * side / math.tan(0.5 * angle)

    fx = focal("fl_x", "camera_angle_x", width)
    if fx is None:
        value("fl_x")                           # missing: say so
    fy = focal("fl_y", "camera_angle_y", height) or fx
    if angles:                                  # the centre, where not given
        cx, cy = (_number(*value(key), path, label) if given(key) else 0.5 * side
                  for key, side in (("cx", width), ("cy", height)))
    else:
        cx, cy = (_number(*value(key), path, label) for key in ("cx", "cy"))
    if model == "equirectangular":
        # nerfstudio: longitude pi (x - cx) / fl_x, latitude -pi (y - cy) / fl_y
        fx, fy = fx / math.pi, fy / math.pi
    K = [[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]]
    gl_to_world = _transform_matrix(frame, path, label)
    cam_to_world = gl_to_world @ np.diag([1.0, -1.0, -1.0, 1.0])  # OpenGL -> OpenCV axes
    try:
        return View(name, Camera(width, height, K, cam_to_world, model, distortion))
    except CameraError as exc:
        raise _fail(path, label, str(exc)) from None


def _nerfstudio_model(meta, frame, path, label):
    """(kdray model, distortion) of a frame: its camera_model (the frame's, else the top
    level's, else PINHOLE) and coefficients (each the frame's, else the top level's; a
    level's "distortion_params" before its keys), as nerfstudio renders them."""
    levels = ((meta, "top-level "), (frame, ""))
    # the frame's camera_model and is_fisheye, else the top level's: only those apply
    source, where = (frame, "") if "camera_model" in frame else (meta, "top-level ")
    model = source.get("camera_model", "PINHOLE")
    if not isinstance(model, str):
        raise _fail(path, label, f"{where}camera_model must be a string, got {_show(model)}.")
    if model not in _NERFSTUDIO_MODELS:
        raise _fail(path, label, f"camera model {model} {_NOT_SUPPORTED}.")
    source, where = (frame, "") if "is_fisheye" in frame else (meta, "top-level ")
    if source.get("is_fisheye", False):
        raise _fail(path, label, f"{where}is_fisheye is set: instant-ngp's fisheye camera "
                                 f"{_NOT_SUPPORTED}.")
    coefficients = dict.fromkeys(_DISTORTION_KEYS, (0.0, None))
    for source, where in levels:
        found = {key: (source[key], where + key) for key in _DISTORTION_KEYS if key in source}
        if "distortion_params" in source:
            params = source["distortion_params"]
            if not (isinstance(params, list) and len(params) == len(_DISTORTION_KEYS)):
                raise _fail(path, label, f"{where}distortion_params must be a list of 6 numbers "
                                         f"(k1 k2 k3 k4 p1 p2), got {_show(params)}.")
            found = {key: (v, f"{where}distortion_params {key}")
                     for key, v in zip(_DISTORTION_KEYS, params)}
        for key, (v, name) in found.items():
            coefficients[key] = (_number(v, name, path, label), name)
    k = {key: v for key, (v, _) in coefficients.items()}

    def refuse(keys, why):
        for key in keys:
            if k[key] != 0.0:
                name = coefficients[key][1]
                where = "top-level " if name.startswith("top-level ") else ""
                raise _fail(path, label, f"{where}distortion coefficient {name[len(where):]} = "
                                         f"{k[key]!r} is not zero: {why}.")

    if model == "EQUIRECTANGULAR":
        refuse(_DISTORTION_KEYS, "an equirectangular camera has no distortion (nerfstudio "
                                 "ignores it; kdray does not guess)")
        return "equirectangular", ()
    if model == "OPENCV_FISHEYE":
        refuse(("p1", "p2"), "OpenCV's fisheye model has no tangential distortion")
        return "fisheye", (k["k1"], k["k2"], k["k3"], k["k4"])
    refuse(("k4",), f"camera model {model}'s k4 (nerfstudio's r^8 term) is not in OpenCV's "
                    f"model, which kdray renders")
    if not any(k.values()):
        return "pinhole", ()
    distortion = (k["k1"], k["k2"], k["p1"], k["p2"], k["k3"])
    return "opencv", distortion if k["k3"] else distortion[:4]


def _number(value, name, path, label, positive=False):
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise _fail(path, label, f"{name} must be a number, got {_show(value)}.")
    number = float(value)
    if not math.isfinite(number):
        raise _fail(path, label, f"{name} must be finite, got {number!r}.")
    if positive and not number > 0.0:
        raise _fail(path, label, f"{name} must be positive, got {number!r}.")
    return number


def _side(value, name, path, label):
    """A width or height: a whole number (640 or 640.0) from 1 to MAX_SIDE."""
    whole = (isinstance(value, numbers.Integral)
             or (isinstance(value, float) and math.isfinite(value) and value.is_integer()))
    if isinstance(value, bool) or not whole or not 1 <= value <= MAX_SIDE:
        raise _fail(path, label, f"{name} must be a whole number of pixels from 1 to "
                                 f"{MAX_SIDE} (MAX_SIDE), got {_show(value)}.")
    return int(value)


def _transform_matrix(frame, path, label):
    """The frame's transform_matrix (4x4, or 3x4 with [0, 0, 0, 1] implied), checked
    rigid; float64."""
    if "transform_matrix" not in frame:
        raise _fail(path, label, "missing 'transform_matrix'.")
    rows = frame["transform_matrix"]
    if not (isinstance(rows, list) and len(rows) in (3, 4) and _is_nested_numbers(rows)
            and all(isinstance(r, list) and len(r) == 4 for r in rows)):
        raise _fail(path, label, "transform_matrix must be a 4x4 (or 3x4) array of numbers.")
    M = np.array(rows, dtype=np.float64)
    if len(rows) == 3:
        M = np.vstack([M, [0.0, 0.0, 0.0, 1.0]])
    if not np.all(np.isfinite(M)):
        raise _fail(path, label, f"transform_matrix must be finite, got {M.tolist()}.")
    try:
        return _check_pose(M, name="transform_matrix")
    except CameraError as exc:
        if not np.array_equal(M[3], [0.0, 0.0, 0.0, 1.0]):
            raise _fail(path, label, str(exc)) from None
        with np.errstate(all="ignore"):        # columns of 1e300: inf, said as such
            lengths = ", ".join(f"{n:.6g}" for n in np.linalg.norm(M[:3, :3], axis=0))
        raise _fail(path, label, f"{exc} Its rotation's columns have lengths {lengths}: a "
                                 "scale folded into the pose (common in nerfstudio exports) or a "
                                 "singular matrix is not a camera; kdray needs a rigid "
                                 "camera-to-world matrix.") from None


# A JSON list of kdray cameras -------------------------------------------------------


def _list_views(items, path):
    _check_count(len(items), path)
    digits = max(5, len(str(len(items) - 1)))
    views, origins = [], []
    for index, item in enumerate(items):
        label = f"camera file {path}: [{index}]"
        if not isinstance(item, dict):
            raise CameraError(f"{label}: expected a camera object, got a JSON {_json_type(item)}.")
        fields = dict(item)
        name = fields.pop("name", f"view_{index:0{digits}d}")
        if not isinstance(name, str):
            raise CameraError(f"{label}: name must be a string, got {_show(name)}.")
        _check_name(name, path, f"[{index}]")
        views.append(View(name, _camera_from_dict(fields, path, f"{label} ({name})")))
        origins.append(f"[{index}]")
    return views, origins


# COLMAP text model ------------------------------------------------------------------


def _read_colmap(path, cameras_path, images_path):
    if not (cameras_path.is_file() and images_path.is_file()):
        if not path.exists():
            raise CameraError(f"camera file {path} does not exist.")
        binary = [n for n in ("cameras.bin", "images.bin") if (cameras_path.parent / n).is_file()]
        hint = (f"; it holds a binary model ({', '.join(binary)}): convert it with colmap "
                "model_converter --output_type TXT" if binary else "")
        if path.is_dir():
            raise CameraError(f"camera file {path} is a folder without cameras.txt and "
                              f"images.txt (a COLMAP text model){hint}.")
        other = cameras_path if path.name == images_path.name else images_path
        raise CameraError(f"camera file {path}: {other.name} is not beside it (a COLMAP text "
                          f"model is cameras.txt and images.txt){hint}.")
    records = _colmap_image_records(_read_text(images_path, f"camera file {images_path}"),
                                    images_path)
    _check_count(len(records), images_path)
    cameras = _colmap_cameras(_read_text(cameras_path, f"camera file {cameras_path}"),
                              cameras_path)
    views, origins = [], []
    for line_no, fields in records:
        views.append(_colmap_view(fields, cameras, images_path, line_no, cameras_path))
        origins.append(f"line {line_no} ({_show(fields[9])})")
    return views, origins


def _colmap_image_records(text, path):
    """(line number, the 10 fields) of each image of images.txt. Its second line (the 2D
    points, possibly empty) is checked for form only, X Y POINT3D_ID triples of numbers,
    each POINT3D_ID whole: an image line there means a file of one line per image, every
    other image of which would otherwise be lost (a name of three words makes an image
    line 12 values, as four triples)."""
    lines = text.split("\n")
    records = []
    i = 0
    while i < len(lines):
        line = lines[i].strip()
        if not line or line.startswith("#"):
            i += 1
            continue
        fields = line.split(maxsplit=9)  # NAME is the rest of the line
        if len(fields) < 10:
            raise CameraError(f"camera file {path}: line {i + 1}: expected IMAGE_ID QW QX QY QZ "
                              f"TX TY TZ CAMERA_ID NAME, found {len(fields)} values.")
        if i + 1 < len(lines):
            points = lines[i + 1].strip()
            if not _POINTS_2D.fullmatch(points):
                values = points.split()
                found = (f"{len(values)} values" if len(values) % 3 else
                         f"{_show(values[2])} where the first POINT3D_ID belongs"
                         if not re.fullmatch(r"-?[0-9]+", values[2]) else
                         "values that are not X Y POINT3D_ID triples")
                raise CameraError(
                    f"camera file {path}: line {i + 2}: expected the 2D points of image "
                    f"{_show(fields[9])} (X Y POINT3D_ID triples, each ID a whole number; the "
                    f"line may be empty), found {found}; images.txt holds two lines per "
                    f"image.")
        records.append((i + 1, fields))
        i += 2
    return records


def _colmap_cameras(text, path):
    """CAMERA_ID (_colmap_id) -> (line number, MODEL, WIDTH, HEIGHT, PARAMS), as text: a
    camera is checked when an image uses it."""
    cameras = {}
    for line_no, line in enumerate(text.split("\n"), 1):
        fields = line.split()
        if not fields or fields[0].startswith("#"):
            continue
        if len(fields) < 4:
            raise CameraError(f"camera file {path}: line {line_no}: expected CAMERA_ID MODEL "
                              f"WIDTH HEIGHT PARAMS..., found {len(fields)} values.")
        camera_id = _colmap_id(fields[0])
        if camera_id in cameras:
            raise CameraError(f"camera file {path}: line {line_no}: camera {fields[0]} is "
                              f"already on line {cameras[camera_id][0]}.")
        cameras[camera_id] = (line_no, *fields[1:4], fields[4:])
    return cameras


def _colmap_id(text):
    """A CAMERA_ID as COLMAP reads it, an integer (so "01" is camera 1), or where it is
    not one its text."""
    try:
        return int(text)
    except ValueError:
        return text


def _colmap_view(fields, cameras, path, line_no, cameras_path):
    _, *pose, camera_id, raw_name = fields
    name = PurePosixPath(raw_name.replace("\\", "/")).stem
    _check_name(name, path, f"line {line_no} (NAME {_show(raw_name)})")
    label = f"line {line_no}: image {name}"
    if _colmap_id(camera_id) not in cameras:
        raise _fail(path, label, f"camera {camera_id} is not in {cameras_path}.")
    cam_line, model, width, height, params = cameras[_colmap_id(camera_id)]
    camera = f"camera {camera_id} ({cameras_path.name} line {cam_line})"
    if model not in _COLMAP_MODELS:
        raise _fail(path, label, f"camera model {model} of {camera} {_NOT_SUPPORTED}.")
    names = _COLMAP_MODELS[model]
    if len(params) != len(names):
        raise _fail(path, label, f"{camera}: a {model} camera has {len(names)} PARAMS "
                                 f"({' '.join(names)}), found {len(params)}.")
    sides = []
    for key, text in (("WIDTH", width), ("HEIGHT", height)):
        # at most 9 digits: int() of thousands of digits is itself an error
        if not (re.fullmatch(r"[0-9]{1,9}", text) and 1 <= int(text) <= MAX_SIDE):
            raise _fail(path, label, f"{camera}: {key} must be a whole number of pixels from "
                                     f"1 to {MAX_SIDE} (MAX_SIDE), got {_show(text)}.")
        sides.append(int(text))
    values = [_float(text, key, path, f"{label}: {camera}") for key, text in zip(names, params)]
    if names[0] == "f":
        values = [values[0], *values]
    (fx, fy, cx, cy), coefficients = values[:4], values[4:]
    K = [[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]]
    if model == "OPENCV_FISHEYE":
        kind, distortion = "fisheye", tuple(coefficients)
    elif any(coefficients):
        kind, distortion = "opencv", tuple(coefficients + [0.0] * (4 - len(coefficients)))
    else:                                   # a perspective model with no distortion
        kind, distortion = "pinhole", ()

    keys = ("QW", "QX", "QY", "QZ", "TX", "TY", "TZ")
    qw, qx, qy, qz, tx, ty, tz = (_float(text, key, path, label) for key, text in zip(keys, pose))
    norm = math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
    if not abs(norm - 1.0) <= QUATERNION_TOL:
        raise _fail(path, label, f"the quaternion (QW QX QY QZ) = ({qw!r}, {qx!r}, {qy!r}, "
                                 f"{qz!r}) has norm {norm:.9g}; a rotation's is 1 "
                                 f"(to {QUATERNION_TOL:g}).")
    w, x, y, z = qw / norm, qx / norm, qy / norm, qz / norm
    R = np.array([  # world -> camera (Hamilton, w first, as COLMAP and Eigen)
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])
    cam_to_world = np.eye(4)
    cam_to_world[:3, :3] = R.T
    cam_to_world[:3, 3] = -R.T @ np.array([tx, ty, tz])
    try:
        return View(name, Camera(sides[0], sides[1], K, cam_to_world, kind, distortion))
    except CameraError as exc:
        raise _fail(path, label, f"{camera}: {exc}") from None


def _float(text, key, path, label):
    try:
        number = float(text)
    except ValueError:
        raise _fail(path, label, f"{key} must be a number, got {_show(text)}.") from None
    if not math.isfinite(number):
        raise _fail(path, label, f"{key} must be finite, got {_show(text)}.")
    return number
