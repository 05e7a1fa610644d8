"""Camera: a camera with OpenCV axes (a pinhole, or one of kdray.lens's models), and
the rays of its pixels.

    camera = Camera.look_at(eye=(0, 1, 4), target=(0, 1, 0), fov_deg=40,
                            width=640, height=480)
    camera = Camera.from_intrinsics(K, cam_to_world, width, height)
    camera = Camera.frame(mesh_min, mesh_max, 640, 480)      # automatic 3/4 view
    camera = Camera.from_json("camera.json")
    origins, directions = camera.rays()                     # (H*W, 3) float64 each

Conventions (the public contract, docs/conventions.md):

- Camera frame: OpenCV, x right, y down, z forward. ``cam_to_world`` is a (4, 4)
  float64 matrix whose upper-left (3, 3) block R is a rotation (orthonormal, det +1)
  and whose last column holds the eye.
- ``K`` is the (3, 3) float64 intrinsic matrix [[fx, s, cx], [0, fy, cy], [0, 0, 1]],
  in pixels. Pixel (i, j) (i = column, j = row) is sampled at its centre:
  ``direction = R @ inv(K) @ [i + 0.5, j + 0.5, 1]``. Directions are not normalized:
  their camera-z is 1, so a ray parameter t is the z-depth of the point it reaches.
- ``look_at``'s field of view is vertical: fy = (H / 2) / tan(fov / 2), fx = fy,
  cx = W / 2, cy = H / 2.

Camera files (JSON) hold one object in either of two forms::

    {"width": 640, "height": 480,
     "eye": [0, 1, 4], "target": [0, 1, 0], "up": [0, 1, 0], "fov": 40}

    {"width": 640, "height": 480,
     "K": [[500, 0, 320], [0, 500, 240], [0, 0, 1]],
     "cam_to_world": [[1, 0, 0, 0], [0, -1, 0, 1], [0, 0, -1, 4], [0, 0, 0, 1]]}

``up`` (default [0, 1, 0]) and ``fov`` (vertical, degrees, default 45) are optional in
the first form; ``K`` may also be given as {"fx": .., "fy": .., "cx": .., "cy": ..}.
Either form may add ``"model"`` and ``"distortion"`` (kdray.lens: "opencv" with k1 k2 p1
p2 [k3 [k4 k5 k6]], "fisheye" with k1 k2 k3 k4, "equirectangular", "orthographic").
``to_json`` writes the second form, which round-trips exactly.

Models other than the pinhole (docs/conventions.md, "Camera models"):

    camera = Camera(640, 480, K, pose, model="opencv", distortion=(k1, k2, p1, p2, k3))
    camera = Camera.panorama(pose, 2048, 1024)              # 360 x 180 degrees
    origins, directions, valid = camera.rays(valid=True)    # NaN where no ray

Pose files (``pose_from_file``) hold a (4, 4) camera-to-world matrix: a ``.npy``
array, or text with 16 numbers separated by whitespace or commas, row by row
(lines starting with ``#`` are comments).
"""
import dataclasses
import json
import math
import numbers
from pathlib import Path

import numpy as np

from . import lens
from .errors import CameraError, one_line
from .files import atomic_write
from .validate import check_bool, check_float32, check_numbers, read_json, read_npy, read_text

ORTHONORMAL_TOL = 1e-6
"""Largest |R^T R - I| entry and |det R - 1| accepted for a pose's rotation."""

PARALLEL_TOL = 1e-6
"""look_at refuses an `up` whose sine of angle with the view direction is below this."""

DEFAULT_FOV_DEG = 45.0
DEFAULT_UP = (0.0, 1.0, 0.0)

DEFAULT_VIEW = (-0.5, -0.4, -0.75)
"""`frame`'s default viewing direction: from the front-right-above (+x, +y, +z) of the
box towards its centre, about 34 degrees round and 24 degrees down: a 3/4 view of a
y-up model facing +z."""

FRAME_FILL = 0.9
"""`frame` keeps the box inside this fraction of the image's half-width and half-height."""

MAX_SIDE = 65536
"""Largest width or height of a camera, in pixels. A render holds at most 2^32 - 1
pixels (its pixel index is 32-bit: `Tracer.render` checks the product), about 65536 on
each side; a larger side is a typo or a wrong unit, refused by every camera (a camera
file, a file of views, the API) before any rendering starts."""


def _vector(value, name, n=3):
    """`value` as a finite (n,) float64 array within float32's range (positions and
    directions go to the kernels in float32), or CameraError naming it."""
    check_numbers(value, name, CameraError)
    try:
        array = np.array(value)
        if array.dtype.kind not in "fiu":       # strings, bools, None: refused, not converted
            raise TypeError(array.dtype)
        array = array.astype(np.float64)
    except (TypeError, ValueError, OverflowError):
        raise CameraError(f"{name} must be {n} numbers, got {value!r}.") from None
    if array.shape != (n,):
        raise CameraError(f"{name} must be {n} numbers, got {value!r}.")
    if not np.all(np.isfinite(array)):
        raise CameraError(f"{name} must be finite, got {array.tolist()}.")
    check_float32(array, name, CameraError)
    return array


def _size(value, name):
    """A width or height: an integer (not a bool, not a float) from 1 to MAX_SIDE."""
    if (isinstance(value, bool) or not isinstance(value, numbers.Integral)
            or not 1 <= value <= MAX_SIDE):
        raise CameraError(f"{name} must be a whole number of pixels >= 1 and at most "
                          f"{MAX_SIDE} (MAX_SIDE), got {value!r}.")
    return int(value)


def _matrix(value, shape, name):
    check_numbers(value, name, CameraError)
    try:
        array = np.array(value)
        if array.dtype.kind not in "fiu":       # strings, bools, None: refused, not converted
            raise TypeError(array.dtype)
        array = array.astype(np.float64)
    except (TypeError, ValueError, OverflowError):
        raise CameraError(f"{name} must be a {shape[0]}x{shape[1]} matrix of numbers.") from None
    if array.shape != shape:
        raise CameraError(
            f"{name} must be a {shape[0]}x{shape[1]} matrix, got shape {array.shape}."
        )
    if not np.all(np.isfinite(array)):
        raise CameraError(f"{name} must be finite, got {array.tolist()}.")
    return array


def _check_intrinsics(K):
    """K checked: finite, fx and fy positive, upper triangular with last row [0, 0, 1],
    and K and its inverse within float32's range (the kernels turn pixels into rays
    with R K^-1 in float32): no camera has a focal length of 1e300 or 1e-300."""
    K = _matrix(K, (3, 3), "K")
    if not (K[0, 0] > 0 and K[1, 1] > 0):
        raise CameraError(f"K must have positive fx and fy, got fx={K[0, 0]}, fy={K[1, 1]}.")
    if K[1, 0] != 0 or K[2, 0] != 0 or K[2, 1] != 0 or K[2, 2] != 1:
        raise CameraError(
            f"K must be upper triangular with last row [0, 0, 1], got {K.tolist()}."
        )
    check_float32(K, "K", CameraError)
    with np.errstate(all="ignore"):              # checked below, not warned about
        inverse = np.linalg.inv(K)
    if not np.all(np.isfinite(inverse)):
        raise CameraError(f"K must be invertible, got {K.tolist()}.")
    check_float32(inverse, "K's inverse (fx or fy too small)", CameraError)
    return K


def _check_pose(cam_to_world, name="cam_to_world"):
    M = _matrix(cam_to_world, (4, 4), name)
    if not np.array_equal(M[3], [0.0, 0.0, 0.0, 1.0]):
        raise CameraError(f"{name} must have last row [0, 0, 0, 1], got {M[3].tolist()}.")
    # the eye goes to the kernels (and to EXR headers) in float32
    check_float32(M[:3, 3], f"the translation of {name}", CameraError)
    R = M[:3, :3]
    with np.errstate(all="ignore"):             # entries of 1e308 overflow: refused below
        error = np.abs(R.T @ R - np.eye(3)).max()
        det = np.linalg.det(R)
    if not (error <= ORTHONORMAL_TOL and abs(det - 1.0) <= ORTHONORMAL_TOL):
        raise CameraError(
            f"the rotation part of {name} must be orthonormal with determinant +1 "
            f"(tolerance {ORTHONORMAL_TOL:g}); got |R^T R - I| = {error:.3g}, det = {det:.9g}."
        )
    return M


def _look_at_rotation(eye, target, up):
    """R (columns: camera x right, y down, z forward in world space) for look_at."""
    view = target - eye
    distance = np.linalg.norm(view)
    if distance == 0:
        raise CameraError(f"eye and target are the same point {eye.tolist()}.")
    if not np.isfinite(distance):
        raise CameraError("eye and target are too far apart to compute a view direction.")
    z = view / distance
    up_norm = np.linalg.norm(up)
    if up_norm == 0:
        raise CameraError("up must not be the zero vector.")
    x = np.cross(z, up / up_norm)
    sine = np.linalg.norm(x)
    if not sine >= PARALLEL_TOL:
        raise CameraError(
            f"up {up.tolist()} is parallel to the view direction {z.tolist()}; "
            "choose an up that is not along target - eye."
        )
    x /= sine
    y = np.cross(z, x)  # image down
    return np.column_stack([x, y / np.linalg.norm(y), z])


def _fov_intrinsics(fov_deg, width, height):
    try:
        if isinstance(fov_deg, (bool, str, bytes)):     # a type kept, never converted
            raise TypeError
        fov = float(fov_deg)
    except (TypeError, ValueError, OverflowError):
        raise CameraError(f"fov must be a number of degrees, got {fov_deg!r}.") from None
    if not (0.0 < fov < 180.0):
        raise CameraError(f"fov must be between 0 and 180 degrees (exclusive), got {fov_deg!r}.")
    half = math.tan(math.radians(fov) / 2.0)
    # a fov below float64's smallest angle, or so small that the focal length overflows
    f = (height / 2.0) / half if half > 0.0 else math.inf
    if not math.isfinite(f):
        raise CameraError(f"fov {fov_deg!r} degrees is too small for a focal length.")
    return np.array([[f, 0.0, width / 2.0], [0.0, f, height / 2.0], [0.0, 0.0, 1.0]])


def _readonly(array):
    array = np.array(array, dtype=np.float64)
    array.setflags(write=False)
    return array


@dataclasses.dataclass(frozen=True, eq=False)
class Camera:
    """A camera: image size, intrinsics, pose (OpenCV axes) and model.

    width, height : int                  image size in pixels, >= 1
    K             : (3, 3) float64       intrinsics, pixels (read-only copy)
    cam_to_world  : (4, 4) float64       camera-to-world rigid transform (read-only copy)
    model         : str                  "pinhole" (default), "opencv", "fisheye",
                                         "equirectangular" or "orthographic" (kdray.lens,
                                         docs/conventions.md "Camera models")
    distortion    : tuple of float       coefficients in OpenCV's order: opencv k1 k2 p1
                                         p2 [k3 [k4 k5 k6]], fisheye k1 k2 k3 k4; () else
    """

    width: int
    height: int
    K: np.ndarray
    cam_to_world: np.ndarray
    model: str = "pinhole"
    distortion: tuple = ()

    def __post_init__(self):
        object.__setattr__(self, "width", _size(self.width, "width"))
        object.__setattr__(self, "height", _size(self.height, "height"))
        if not isinstance(self.model, str):
            raise CameraError(f"model must be a string, one of {', '.join(lens.MODELS)}; "
                              f"got {self.model!r}.")
        object.__setattr__(self, "distortion", lens.check_distortion(self.model, self.distortion))
        K = _check_intrinsics(self.K)
        object.__setattr__(self, "K", _readonly(K))
        object.__setattr__(self, "cam_to_world", _readonly(_check_pose(self.cam_to_world)))

    def __eq__(self, other):
        if not isinstance(other, Camera):
            return NotImplemented
        return (
            self.width == other.width
            and self.height == other.height
            and np.array_equal(self.K, other.K)
            and np.array_equal(self.cam_to_world, other.cam_to_world)
            and self.model == other.model
            and self.distortion == other.distortion
        )

    __hash__ = None

    # Constructors ---------------------------------------------------------------

    @classmethod
    def look_at(cls, eye, target, up=DEFAULT_UP, fov_deg=DEFAULT_FOV_DEG, width=640, height=480):
        """A camera at `eye` looking at `target`, `up` pointing up in the image.

        fov_deg is the vertical field of view in degrees, in (0, 180).
        """
        width, height = _size(width, "width"), _size(height, "height")
        eye = _vector(eye, "eye")
        target = _vector(target, "target")
        up = _vector(up, "up")
        K = _fov_intrinsics(fov_deg, width, height)
        pose = np.eye(4)
        pose[:3, :3] = _look_at_rotation(eye, target, up)
        pose[:3, 3] = eye
        return cls(width, height, K, pose)

    @classmethod
    def from_intrinsics(cls, K, cam_to_world, width, height, model="pinhole", distortion=()):
        """A camera from a (3, 3) intrinsic matrix and a (4, 4) camera-to-world pose
        (and a model and its distortion coefficients, OpenCV's order)."""
        return cls(width, height, K, cam_to_world, model, distortion)

    @classmethod
    def panorama(cls, cam_to_world, width, height, longitude=(-math.pi, math.pi),
                 latitude=(math.pi / 2, -math.pi / 2)):
        """An equirectangular camera whose image spans `longitude` (left, right edge)
        and `latitude` (top, bottom edge), radians, in camera axes (longitude 0 along
        +z, pi / 2 along +x; latitude pi / 2 up, along -y): the full 360 x 180 degree
        panorama by default."""
        width, height = _size(width, "width"), _size(height, "height")
        K = lens.equirectangular_K(width, height, longitude, latitude)
        return cls(width, height, K, cam_to_world, "equirectangular")

    @classmethod
    def frame(
        cls,
        bounds_min,
        bounds_max,
        width=640,
        height=480,
        fov_deg=DEFAULT_FOV_DEG,
        direction=DEFAULT_VIEW,
        up=DEFAULT_UP,
    ):
        """A camera looking along `direction` at the centre of a box, far enough back
        that all 8 corners lie inside the middle `FRAME_FILL` of the image.

        Works for flat boxes (zero extent on some axis), a single point (framed as a
        tiny box), and boxes of any size or distance from the origin.
        """
        lo = _vector(bounds_min, "bounds_min")
        hi = _vector(bounds_max, "bounds_max")
        if np.any(lo > hi):
            raise CameraError(f"bounds_min {lo.tolist()} exceeds bounds_max {hi.tolist()}.")
        view = _vector(direction, "direction")
        if not np.linalg.norm(view) > 0:
            raise CameraError("direction must not be the zero vector (nor so short that its "
                              "length underflows).")
        up = _vector(up, "up")
        if not np.linalg.norm(up) > 0:
            raise CameraError("up must not be the zero vector (nor so short that its length "
                              "underflows).")
        width, height = _size(width, "width"), _size(height, "height")
        K = _fov_intrinsics(fov_deg, width, height)

        centre = (lo + hi) / 2.0
        half = (hi - lo) / 2.0
        radius = np.linalg.norm(half)
        if radius == 0:  # a single point: frame a tiny box around it
            half = np.full(3, 1e-3 * max(np.abs(centre).max(), 1.0))
            radius = np.linalg.norm(half)

        # An up along the view direction: fall back to the world axis least along it.
        view = view / np.linalg.norm(view)
        if np.linalg.norm(np.cross(view, up / np.linalg.norm(up))) < 1e-3:
            up = np.eye(3)[np.argmin(np.abs(view))]
        R = _look_at_rotation(np.zeros(3), view, up)

        # Corners relative to the centre, in camera axes; the eye is at distance D back
        # along z, so a corner's depth is a_z + D. Keep |a_x| <= tan_x (a_z + D), etc.
        signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
        a = (signs * half) @ R  # (8, 3): R^T @ corner offset, row by row
        tan_x = FRAME_FILL * (width / 2.0) / K[0, 0]
        tan_y = FRAME_FILL * (height / 2.0) / K[1, 1]
        need = np.maximum(np.abs(a[:, 0]) / tan_x, np.abs(a[:, 1]) / tan_y) - a[:, 2]
        distance = max(need.max(), 1.01 * radius)  # and the eye outside the box

        pose = np.eye(4)
        pose[:3, :3] = R
        pose[:3, 3] = centre - distance * view
        return cls(width, height, K, pose)

    @classmethod
    def from_json(cls, path):
        """Read a camera file (see the module docstring for its two forms)."""
        data = read_json(path, f"camera file {path}", CameraError)
        try:
            return cls._from_dict(data)
        except CameraError as exc:
            raise CameraError(f"camera file {path}: {exc}") from None

    @classmethod
    def _from_dict(cls, data):
        if not isinstance(data, dict):
            raise CameraError("expected a JSON object with width, height and a pose.")
        look_keys = {"eye", "target", "up", "fov"}
        matrix_keys = {"K", "cam_to_world"}
        unknown = set(data) - look_keys - matrix_keys - {"width", "height", "model", "distortion"}
        if unknown:
            raise CameraError(
                f"unknown keys {sorted(unknown)}; expected width, height, optionally model "
                "and distortion, and either eye, target, up, fov or K, cam_to_world."
            )
        model = data.get("model", "pinhole")
        distortion = data.get("distortion", [])
        if not isinstance(model, str):
            raise CameraError(f"model must be a string, got {model!r}.")
        if not (isinstance(distortion, list) and all(
                isinstance(c, numbers.Real) and not isinstance(c, bool) for c in distortion)):
            raise CameraError(f"distortion must be a list of numbers, got {distortion!r}.")
        for key in ("width", "height"):
            if key not in data:
                raise CameraError(f"missing '{key}'.")
        uses_look = bool(look_keys & set(data))
        uses_matrix = bool(matrix_keys & set(data))
        if uses_look and uses_matrix:
            raise CameraError("give either eye/target/up/fov or K/cam_to_world, not both.")
        if uses_look:
            for key in ("eye", "target"):
                if key not in data:
                    raise CameraError(f"missing '{key}'.")
            if model == "orthographic":
                raise CameraError("an orthographic camera needs K (pixels per world unit): "
                                  "give K and cam_to_world.")
            if model == "equirectangular" and "fov" in data:
                raise CameraError("an equirectangular camera of the look-at form is the full "
                                  "panorama: give no fov (or give K and cam_to_world).")
            camera = cls.look_at(
                data["eye"],
                data["target"],
                data.get("up", DEFAULT_UP),
                _json_number(data.get("fov", DEFAULT_FOV_DEG), "fov"),
                data["width"],
                data["height"],
            )
            K = camera.K
            if model == "equirectangular":
                K = lens.equirectangular_K(camera.width, camera.height)
            return cls(camera.width, camera.height, K, camera.cam_to_world, model, distortion)
        if not uses_matrix:
            raise CameraError("missing a pose: give eye and target, or K and cam_to_world.")
        for key in ("K", "cam_to_world"):
            if key not in data:
                raise CameraError(f"missing '{key}'.")
        K = data["K"]
        if isinstance(K, dict):
            names = {"fx", "fy", "cx", "cy"}
            if set(K) != names:
                raise CameraError(f"K as an object needs the keys fx, fy, cx, cy, got {sorted(K)}.")
            fx, fy, cx, cy = (_json_number(K[n], f"K.{n}") for n in ("fx", "fy", "cx", "cy"))
            K = [[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]]
        elif not _is_nested_numbers(K):
            raise CameraError("K must be a 3x3 array of numbers or {fx, fy, cx, cy}.")
        if not _is_nested_numbers(data["cam_to_world"]):
            raise CameraError("cam_to_world must be a 4x4 array of numbers.")
        return cls(data["width"], data["height"], K, data["cam_to_world"], model, distortion)

    def to_json(self, path):
        """Write this camera as a JSON file (K and cam_to_world form, and model and
        distortion unless a pinhole; exact round trip)."""
        path = Path(path)
        fields = {
            "width": self.width,
            "height": self.height,
            "K": self.K.tolist(),
            "cam_to_world": self.cam_to_world.tolist(),
        }
        if self.model != "pinhole":
            fields.update(model=self.model, distortion=list(self.distortion))
        text = json.dumps(fields, indent=2)
        atomic_write(path, lambda tmp: Path(tmp).write_text(text + "\n", encoding="utf-8"))

    # Properties and rays ---------------------------------------------------------

    @property
    def rotation(self):
        """(3, 3) float64: columns are the camera's x (right), y (down), z (forward)."""
        return self.cam_to_world[:3, :3]

    @property
    def eye(self):
        """(3,) float64: the camera centre in world space."""
        return self.cam_to_world[:3, 3]

    @property
    def forward(self):
        """(3,) float64: the unit optical axis (camera +z) in world space."""
        return self.cam_to_world[:3, 2]

    def rays(self, valid=False):
        """One ray per pixel through its centre, row-major (row j, then column i).

        Returns origins (H*W, 3) float64 (all the eye, but for an orthographic camera)
        and directions (H*W, 3) float64: camera-z 1 (not normalized) for pinhole and
        opencv cameras, unit for the other models; NaN for a pixel with no ray. With
        valid=True also (H*W,) bool: the pixel has a ray (every pixel of a pinhole).
        valid must be True or False (CameraError otherwise).
        """
        valid = check_bool(valid, "valid", CameraError)
        if self.model != "pinhole":
            return self._model_rays(valid)
        M = self.rotation @ np.linalg.inv(self.K)
        u = np.arange(self.width, dtype=np.float64) + 0.5
        v = np.arange(self.height, dtype=np.float64) + 0.5
        uu, vv = np.meshgrid(u, v)  # (H, W): row j, column i
        directions = uu.reshape(-1, 1) * M[:, 0] + vv.reshape(-1, 1) * M[:, 1] + M[:, 2]
        origins = np.broadcast_to(self.eye, directions.shape).copy()
        if valid:
            return origins, directions, np.ones(len(directions), dtype=bool)
        return origins, directions

    def _model_rays(self, valid, copy=True, origin=None):
        """rays() of a model that is not the pinhole; copy=False: a central model's
        origins are a read-only broadcast of the eye (Tracer.render). origin: (3,)
        float64 or None: the origins relative to it (eye - origin, plus an orthographic
        pixel's offset), which keep the offsets' digits far from the world's origin."""
        R = self.rotation
        eye = self.eye if origin is None else self.eye - origin
        o_cam, directions, ok = lens.model_rays(self.model, self.K, self.distortion,
                                                self.width, self.height, R)
        if o_cam is None:
            origins = np.broadcast_to(eye, directions.shape)
            if copy:
                origins = origins.copy()
        else:
            origins = np.empty_like(o_cam)
            for k in range(3):
                origins[:, k] = eye[k] + o_cam[:, 0] * R[k, 0] + o_cam[:, 1] * R[k, 1]
        return (origins, directions, ok) if valid else (origins, directions)

    def valid(self):
        """(H, W) bool: the pixels that have a ray (all of a pinhole's). Costs a
        computation of the rays."""
        if self.model == "pinhole":
            return np.ones((self.height, self.width), dtype=bool)
        return lens.model_rays(self.model, self.K, self.distortion, self.width,
                               self.height)[2].reshape(self.height, self.width)

    def project(self, points):
        """World points (n, 3) -> (pixels (n, 2) float64, depth (n,) float64).

        pixels are continuous image coordinates (x right, y down): pixel (i, j) covers
        [i, i + 1) x [j, j + 1) and its centre is (i + 0.5, j + 0.5). depth is the
        camera-z (negative behind the camera); for a fisheye or equirectangular camera
        the distance from the eye (the model's forward map: kdray.lens.project_camera).
        points: (n, 3) or one point (3,), numbers (integers or floats); CameraError for
        anything else (bools and strings are refused, not converted).
        """
        from .ray_input import numbers
        check_numbers(points, "the points to project", CameraError)   # [[1, True, 2]]
        a = numbers("the points to project", points, CameraError)
        if not (a.shape == (3,) or (a.ndim == 2 and a.shape[1] == 3)):
            raise CameraError(f"the points to project must be an (n, 3) array of numbers, "
                              f"got shape {a.shape}.")
        points = a.astype(np.float64).reshape(-1, 3)
        cam = (points - self.eye) @ self.rotation  # R^T (p - eye), row by row
        if self.model != "pinhole":
            return lens.project_camera(self.model, self.K, self.distortion, cam, self.width)
        depth = cam[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            pixels = (cam @ self.K.T)[:, :2] / depth[:, None]
        return pixels, depth


def _json_number(value, name):
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise CameraError(f"{name} must be a number, got {value!r}.")
    return float(value)


def _is_nested_numbers(value):
    if isinstance(value, list):
        return all(_is_nested_numbers(v) for v in value)
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


def pose_from_file(path):
    """Read a (4, 4) float64 camera-to-world matrix (OpenCV axes) from a .npy or text file.

    Text: 16 numbers separated by whitespace and/or commas, row by row; lines starting
    with '#' are comments. The rotation part must be orthonormal with det +1.
    """
    path = Path(path)
    if path.suffix.lower() == ".npy":
        matrix = read_npy(path, f"pose file {path}", CameraError)
    else:
        lines = read_text(path, f"pose file {path}", CameraError).splitlines()
        text = " ".join(line for line in lines if not line.lstrip().startswith("#"))
        tokens = text.replace(",", " ").split()
        if len(tokens) != 16:
            raise CameraError(f"pose file {path} must hold 16 numbers, found {len(tokens)}.")
        try:
            matrix = np.array([float(t) for t in tokens]).reshape(4, 4)
        except ValueError as exc:
            raise CameraError(f"pose file {path} holds a value that is not a number: "
                              f"{one_line(exc)}.") from None
    return _check_pose(matrix, name=f"the pose in {path}")
