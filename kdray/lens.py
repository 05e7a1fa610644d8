"""Camera models beyond the pinhole: pixel -> ray in camera axes, and back.

    origins, directions, valid = model_rays("fisheye", K, (k1, k2, k3, k4), width, height)
    # camera axes (world axes given R); origins None: every ray leaves the eye
    pixels, depth = project_camera("opencv", K, distortion, points_cam)

Every model uses OpenCV's camera axes (x right, y down, z forward) and kdray's pixels
(pixel (i, j) sampled at its centre (i + 0.5, j + 0.5)). With (a, b, 1) = K^-1 (u, v, 1)
the normalized image coordinates of the pixel point (u, v) (docs/conventions.md,
"Camera models"):

- ``pinhole``: direction (a, b, 1).
- ``opencv``: OpenCV's radial-tangential model, coefficients (k1, k2, p1, p2[, k3[,
  k4, k5, k6]]) in OpenCV's order. (a, b) is the *distorted* point; the ray goes
  through the undistorted (x, y) whose distortion is (a, b), found in float64 by a
  safeguarded Newton iteration and checked (`opencv_rays`); direction (x, y, 1).
- ``fisheye``: OpenCV's fisheye (Kannala-Brandt) model, (k1, k2, k3, k4): the distorted
  radius theta_d = |(a, b)| is theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4
  theta^8) of the angle theta from the optical axis, which may pass pi / 2 (a field of
  view over 180 degrees) up to pi; unit direction (sin theta (a, b) / theta_d, cos theta).
- ``equirectangular``: longitude a and latitude -b, in radians (b is positive down);
  unit direction (cos b sin a, sin b, cos b cos a): longitude 0 is +z, pi / 2 is +x;
  b = -pi / 2 is straight up (-y). The full panorama of a W x H image has
  K = [[W / (2 pi), 0, W / 2], [0, H / pi, H / 2], [0, 0, 1]] (`equirectangular_K`).
- ``orthographic``: K is in pixels per world unit; the ray leaves the point (a, b, 0)
  of the camera's image plane (through the eye) along +z.

A pixel with no ray (outside the domain where a model is invertible and monotonic, past
a fisheye's field, a latitude beyond +-pi / 2) is not valid: its direction is NaN, and
`valid` says so.
"""
import concurrent.futures
import functools
import logging
import math
import numbers
import os

import numpy as np

from .errors import CameraError
from .validate import check_numbers

log = logging.getLogger(__name__)

MODELS = ("pinhole", "opencv", "fisheye", "equirectangular", "orthographic")
"""The camera models a kdray.Camera knows."""

OPENCV_LENGTHS = (4, 5, 8)
"""How many coefficients an `opencv` camera takes: k1 k2 p1 p2 [k3 [k4 k5 k6]]."""

FISHEYE_LENGTH = 4
"""A `fisheye` camera's coefficients: k1 k2 k3 k4."""

CONVERGENCE_TOL = 1e-12
"""An inverted pixel counts as valid when its distortion is within CONVERGENCE_TOL *
(1 + |(a, b)|) of the pixel's normalized point (about 1e-9 pixel at f = 1000)."""

MAX_ITERATIONS = 100
"""Newton steps at most for one pixel's inversion; one that has not converged by then
is not valid."""

_STOP = 1e-2
"""The iterations go on until the error is _STOP times the tolerance checked (or stops
changing), so that a pixel never fails the check by a rounding."""

SCAN_STEPS = 4096
"""Samples per interval of the scan for the radius where a model stops being monotonic."""


def check_distortion(model, distortion):
    """`distortion` as a tuple of finite floats of the length `model` takes, or
    CameraError (one line)."""
    if model not in MODELS:
        raise CameraError(f"unknown camera model {model!r}; expected one of {', '.join(MODELS)}.")
    if isinstance(distortion, (str, bytes)) or (
            isinstance(distortion, np.ndarray) and distortion.dtype.kind not in "fiu"):
        raise CameraError(f"distortion must be a sequence of numbers, got {distortion!r}.")
    check_numbers(distortion, "distortion", CameraError)    # no '1e3' or True among them
    try:
        values = tuple(float(c) for c in np.asarray(distortion, dtype=np.float64).reshape(-1))
    except (TypeError, ValueError):
        raise CameraError(f"distortion must be a sequence of numbers, got {distortion!r}.") from None
    if np.ndim(distortion) > 1:
        raise CameraError(f"distortion must be a flat sequence of numbers, got {distortion!r}.")
    if not all(math.isfinite(c) for c in values):
        raise CameraError(f"distortion coefficients must be finite, got {list(values)}.")
    if model == "opencv" and len(values) not in OPENCV_LENGTHS:
        raise CameraError(f"an opencv camera takes 4, 5 or 8 distortion coefficients (k1 k2 p1 "
                          f"p2 [k3 [k4 k5 k6]], OpenCV's order), got {len(values)}.")
    if model == "fisheye" and len(values) != FISHEYE_LENGTH:
        raise CameraError(f"a fisheye camera takes 4 distortion coefficients (k1 k2 k3 k4), "
                          f"got {len(values)}.")
    if model not in ("opencv", "fisheye") and values:
        raise CameraError(f"a {model} camera takes no distortion coefficients, got {len(values)}.")
    return values


def equirectangular_K(width, height, longitude=(-math.pi, math.pi),
                      latitude=(math.pi / 2, -math.pi / 2)):
    """K of an equirectangular camera whose image spans `longitude` (left edge, right
    edge) and `latitude` (top edge, bottom edge), radians: the full panorama by default."""
    pairs = []
    for name, pair in (("longitude", longitude), ("latitude", latitude)):
        try:
            a, b = pair
        except (TypeError, ValueError):
            raise CameraError(f"{name} must be two numbers (radians), got {pair!r}.") from None
        if not all(isinstance(x, numbers.Real) and not isinstance(x, bool) and math.isfinite(x)
                   for x in (a, b)):
            raise CameraError(f"{name} must be two finite numbers (radians), got {pair!r}.")
        pairs.append((float(a), float(b)))
    (lon0, lon1), (lat0, lat1) = pairs
    if not (lon1 > lon0 and lat0 > lat1):
        raise CameraError(f"an equirectangular image needs longitudes increasing to the right and "
                          f"latitudes decreasing downwards, got {longitude}, {latitude}.")
    fx, fy = width / (lon1 - lon0), height / (lat0 - lat1)
    return np.array([[fx, 0.0, -lon0 * fx], [0.0, fy, lat0 * fy], [0.0, 0.0, 1.0]])


# OpenCV's radial-tangential model ----------------------------------------------------


def _opencv_coefficients(distortion):
    k = list(distortion) + [0.0] * (8 - len(distortion))
    k1, k2, p1, p2, k3, k4, k5, k6 = k
    return k1, k2, p1, p2, k3, k4, k5, k6


def opencv_distort(x, y, distortion):
    """OpenCV's distortion of undistorted normalized points (x, y) -> (xd, yd), float64."""
    k1, k2, p1, p2, k3, k4, k5, k6 = _opencv_coefficients(distortion)
    r2 = x * x + y * y
    radial = (1 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1 + r2 * (k4 + r2 * (k5 + r2 * k6)))
    xy = x * y
    return (x * radial + 2 * p1 * xy + p2 * (r2 + 2 * x * x),
            y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * xy)


def _radial(distortion):
    """(g, dg, den): the radial distortion r -> r * radial(r^2), its derivative, and the
    rational model's denominator."""
    k1, k2, _, _, k3, k4, k5, k6 = _opencv_coefficients(distortion)

    def num(s):
        return 1 + s * (k1 + s * (k2 + s * k3))

    def den(r):
        s = r * r
        return 1 + s * (k4 + s * (k5 + s * k6))

    def g(r):
        return r * num(r * r) / den(r)

    def dg(r):
        s = r * r
        n, d = num(s), den(r)
        dn = 2 * r * (k1 + s * (2 * k2 + 3 * s * k3))
        dd = 2 * r * (k4 + s * (2 * k5 + 3 * s * k6))
        return (n + r * dn) / d - r * n * dd / (d * d)

    return g, dg, den


def _monotonic_limit(g, dg, need, cap, den=None):
    """(limit, g(limit), reach): limit the first r > 0 where g stops increasing (g' <=
    0, or `den` <= 0) found by a scan, or `cap`; g is monotonic increasing on [0,
    limit). reach: the first r scanned where g passes `need` (every pixel's radius), at
    most limit: the radial inversions' bracket (a tangential part may still take a
    pixel's point beyond it, which the limit, not the reach, decides). Values that
    overflow (coefficients near float64's largest) are not finite, and so not > 0: bad."""
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        return _scan_limit(g, dg, need, cap, den)


def _scan_limit(g, dg, need, cap, den):
    lo, hi = 0.0, max(min(2.0 * need, cap), 1e-6)
    reach = None
    while True:
        r = np.linspace(lo, hi, SCAN_STEPS + 1)[1:]
        bad = ~(dg(r) > 0)
        if den is not None:
            bad |= ~(den(r) > 0)
        if bad.any():
            i = int(np.argmax(bad))
            a, b = (r[i - 1] if i else lo), r[i]
            for _ in range(200):              # bisect to the first bad radius
                m = 0.5 * (a + b)
                if m in (a, b):
                    break
                ok = dg(m) > 0 and (den is None or den(m) > 0)
                a, b = (m, b) if ok else (a, m)
            return a, float(g(a)), a if reach is None else min(reach, a)
        top = float(g(hi))
        if reach is None and top > need:
            reach = hi
        if hi >= cap:
            return hi, top, hi if reach is None else reach
        lo, hi = hi, min(2.0 * hi, cap)


def opencv_rays(K, distortion, width, height, R=None):
    """Directions R (x, y, 1) of every pixel (row-major, (H*W, 3) float64), where (x, y)
    is the undistorted point whose OpenCV distortion is the pixel's (a, b), and `valid`
    (H*W,) bool. Invalid where no such point lies inside the radius up to which the
    radial distortion is monotonic (and its denominator positive), where the iteration
    does not converge, or where the Jacobian there is not positive; NaN there."""
    g, dg, den = _radial(distortion)
    Kinv = np.linalg.inv(np.asarray(K, dtype=np.float64))
    limit, g_limit, reach = _monotonic_limit(g, dg, _corner_radius(Kinv, width, height),
                                             cap=1e8, den=den)
    n = width * height
    d = np.empty((n, 3))
    valid = np.empty(n, dtype=bool)
    k = np.array(_opencv_coefficients(distortion), dtype=np.float64)
    _on_threads(_kernels().opencv_rays, n, Kinv, width, _rotation(R), k, limit, g_limit,
                reach, CONVERGENCE_TOL, _STOP, MAX_ITERATIONS, d, valid)
    _report(valid, "opencv", distortion, f"monotonic up to the radius {limit:.6g} "
            f"(distorted {g_limit:.6g}) of the normalized image plane")
    return d, valid


def _corner_radius(Kinv, width, height):
    """The largest |(a, b)| of the image's pixel centres: at a corner (a norm of an
    affine map of the pixel is convex)."""
    u = np.array([0.5, width - 0.5, 0.5, width - 0.5])
    v = np.array([0.5, 0.5, height - 0.5, height - 0.5])
    a = Kinv[0, 0] * u + Kinv[0, 1] * v + Kinv[0, 2]
    b = Kinv[1, 1] * v + Kinv[1, 2]
    return float(np.hypot(a, b).max())


def _rotation(R):
    return np.eye(3) if R is None else np.ascontiguousarray(R, dtype=np.float64)


def _report(valid, model, distortion, domain):
    """Log (warning) the fraction of the pixels that have a ray, when not all do."""
    if valid.size and not valid.all():
        log.warning("%s camera %s: %.4g%% of the pixels have a ray (%s); the others are "
                    "misses, flagged in `valid`.", model, list(distortion),
                    100.0 * valid.mean(), domain)


# OpenCV's fisheye model -----------------------------------------------------------------


def _fisheye_polynomial(distortion):
    k1, k2, k3, k4 = distortion

    def f(t):
        s = t * t
        return t * (1 + s * (k1 + s * (k2 + s * (k3 + s * k4))))

    def df(t):
        s = t * t
        return 1 + s * (3 * k1 + s * (5 * k2 + s * (7 * k3 + s * 9 * k4)))

    return f, df


def fisheye_rays(K, distortion, width, height, R=None):
    """Unit directions R (sin theta (a, b) / |(a, b)|, cos theta) of every pixel
    (row-major, (H*W, 3) float64) and `valid` (H*W,) bool: theta in [0, pi] with
    theta_d(theta) = |(a, b)|, inside the angle up to which theta_d is monotonic; NaN
    where not valid."""
    f, df = _fisheye_polynomial(distortion)
    Kinv = np.linalg.inv(np.asarray(K, dtype=np.float64))
    limit, f_limit, _ = _monotonic_limit(f, df, math.inf, cap=math.pi)
    n = width * height
    d = np.empty((n, 3))
    valid = np.empty(n, dtype=bool)
    k = np.array(distortion, dtype=np.float64)
    _on_threads(_kernels().fisheye_rays, n, Kinv, width, _rotation(R), k, limit, f_limit,
                limit == math.pi, CONVERGENCE_TOL, _STOP, MAX_ITERATIONS, d, valid)
    _report(valid, "fisheye", distortion, f"theta_d is monotonic up to theta = {limit:.6g} rad"
            if limit < math.pi else f"a field of view of 360 degrees ends at theta_d {f_limit:.6g}")
    return d, valid


THREAD_CHUNK = 1 << 16
"""Pixels per piece of an image the inversions hand to a thread (at least one piece a
thread, and only images of more than one piece are split)."""


def _on_threads(kernel, n, *args):
    """kernel(*args, start, end) over [0, n) in pieces on threads (the kernels release
    the GIL); each piece starts its iteration from its own first pixel."""
    threads = min(os.cpu_count() or 1, -(-n // THREAD_CHUNK))
    if threads <= 1:
        kernel(*args, 0, n)
        return
    bounds = np.linspace(0, n, threads + 1).astype(np.int64)
    with concurrent.futures.ThreadPoolExecutor(threads) as pool:
        list(pool.map(lambda i: kernel(*args, bounds[i], bounds[i + 1]), range(threads)))


def compile_kernels():
    """Compile the opencv and fisheye inversions (numba) into their on-disk cache, or
    load them from it: what the first such camera of a process would otherwise wait
    for (about 1.5 s once per install, 0.1-0.3 s a process after)."""
    K = np.eye(3)
    opencv_rays(K, (0.0, 0.0, 1e-3, 0.0), 1, 1)
    fisheye_rays(K, (0.0, 0.0, 0.0, 0.0), 1, 1)


def _kernels():
    """kdray._lens_kernels (numba, compiled on first use and cached on disk)."""
    from . import _lens_kernels
    return _lens_kernels


# All models ---------------------------------------------------------------------------


def pixel_points(K, width, height):
    """(a, b): K^-1 (i + 0.5, j + 0.5, 1) of every pixel, row-major, (H*W,) float64 each."""
    Kinv = np.linalg.inv(np.asarray(K, dtype=np.float64))
    u = np.tile(np.arange(width, dtype=np.float64) + 0.5, height)
    v = np.repeat(np.arange(height, dtype=np.float64) + 0.5, width)
    a = Kinv[0, 0] * u + Kinv[0, 1] * v + Kinv[0, 2]
    b = Kinv[1, 1] * v + Kinv[1, 2]
    return a, b


MAPS_KEPT = 4
"""Camera-axis ray maps `model_rays` keeps (the most recently used), each 25 bytes a
pixel: the views of a calibrated camera share its intrinsics, so a dataset inverts its
lens once and every further view only rotates the map (BENCHMARKS.md)."""


def model_rays(model, K, distortion, width, height, R=None):
    """(origins, directions, valid) of every pixel, row-major, float64.

    R : (3, 3) the camera's rotation (Camera.rotation): directions in world axes; None:
        camera axes.
    origins : None for a central model (every ray leaves the eye), else (H*W, 3): the
        orthographic camera's points on its image plane, camera axes (not rotated).
    directions : (H*W, 3), NaN where not valid; camera-z 1 for pinhole and opencv, unit
        otherwise. valid : (H*W,) bool.

    The camera-axis rays of a (model, K, distortion, size) are computed once and kept
    (MAPS_KEPT, read-only); each call rotates them into new arrays.
    """
    origins, d, valid = camera_axis_rays(model, K, distortion, width, height)
    if R is not None:
        R = np.asarray(R, dtype=np.float64)
        world = np.empty_like(d)
        for k in range(3):      # by column: numpy's loops over rows of 3 are slow
            world[:, k] = d[:, 0] * R[k, 0] + d[:, 1] * R[k, 1] + d[:, 2] * R[k, 2]
        d = world
    else:
        d = d.copy()
    return (None if origins is None else origins.copy()), d, valid.copy()


def camera_axis_rays(model, K, distortion, width, height):
    """(origins, directions, valid) in camera axes, as `model_rays` with R None, but the
    kept read-only arrays themselves (no copies)."""
    K = np.asarray(K, dtype=np.float64)
    return _camera_axis_rays(model, K.tobytes(), tuple(map(float, distortion)), int(width),
                             int(height))


@functools.lru_cache(maxsize=MAPS_KEPT)
def _camera_axis_rays(model, K_bytes, distortion, width, height):
    """model_rays in camera axes, kept by lru_cache: read-only arrays."""
    K = np.frombuffer(K_bytes, dtype=np.float64).reshape(3, 3)
    origins, d, valid = _model_rays(model, K, distortion, width, height)
    for array in (origins, d, valid):
        if array is not None:
            array.setflags(write=False)
    return origins, d, valid


def _model_rays(model, K, distortion, width, height):
    """model_rays in camera axes, computed."""
    if model == "opencv":
        d, valid = opencv_rays(K, distortion, width, height)
        return None, d, valid
    if model == "fisheye":
        d, valid = fisheye_rays(K, distortion, width, height)
        return None, d, valid
    a, b = pixel_points(K, width, height)
    n = len(a)
    valid = np.ones(n, dtype=bool)
    origins = None
    if model == "pinhole":
        d = np.stack([a, b, np.ones(n)], axis=1)
    elif model == "equirectangular":
        valid = np.abs(b) <= math.pi / 2
        cb = np.cos(b)
        d = np.stack([cb * np.sin(a), np.sin(b), cb * np.cos(a)], axis=1)
        d[~valid] = np.nan
    elif model == "orthographic":
        origins = np.stack([a, b, np.zeros(n)], axis=1)
        d = np.broadcast_to(np.array([0.0, 0.0, 1.0]), (n, 3)).copy()
    else:
        raise CameraError(f"unknown camera model {model!r}.")
    return origins, d, valid


def _in_longitudes(a, left, span):
    """Longitudes a (n,) in (-pi, pi], each turned by the whole turns that bring it into
    [left, left + span] (left a number or (n,)) where any does (the first such), else
    as they are."""
    turn = 2.0 * math.pi
    moved = a + turn * np.ceil((left - a) / turn)        # the least a + k turn >= left
    return np.where(((a < left) | (a > left + span)) & (moved <= left + span), moved, a)


def project_camera(model, K, distortion, points, width=None):
    """Camera-axis points (n, 3) -> (pixels (n, 2), depth (n,)), float64: the forward
    model. depth is the camera-z for pinhole, opencv and orthographic, the distance
    from the eye for fisheye and equirectangular (the AOV `depth` of each model).
    width (equirectangular): the image's, whose longitudes (left to right edge) a
    point's longitude is taken among, turned by whole turns, where one of them lies
    there (a panorama from 0 to 2 pi, or one across the back)."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        if model in ("pinhole", "opencv"):
            a, b = x / z, y / z
            if model == "opencv":
                a, b = opencv_distort(a, b, distortion)
            depth = z
        elif model == "fisheye":
            rxy = np.hypot(x, y)
            theta = np.arctan2(rxy, z)
            f, _ = _fisheye_polynomial(distortion)
            s = np.where(rxy > 0, f(theta) / rxy, 0.0)
            a, b = x * s, y * s
            depth = np.sqrt(x * x + y * y + z * z)
        elif model == "equirectangular":
            a = np.arctan2(x, z)
            b = np.arctan2(y, np.hypot(x, z))
            if width is not None:
                # the image's left edge at the point's latitude (with skew s it moves
                # with the row: fx a + s b + cx = 0)
                a = _in_longitudes(a, -(K[0, 1] * b + K[0, 2]) / K[0, 0], width / K[0, 0])
            depth = np.sqrt(x * x + y * y + z * z)
        elif model == "orthographic":
            a, b, depth = x, y, z
        else:
            raise CameraError(f"unknown camera model {model!r}.")
    K = np.asarray(K, dtype=np.float64)
    pixels = np.stack([K[0, 0] * a + K[0, 1] * b + K[0, 2], K[1, 1] * b + K[1, 2]], axis=1)
    return pixels, depth
