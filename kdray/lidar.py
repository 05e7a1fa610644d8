"""Lidar: a spinning (or partial field of view) range sensor's beams, from a JSON spec.

    lidar = Lidar.from_json("os1-128.json")         # or Lidar.from_dict({...})
    d = lidar.directions()                          # (B*C, 3) float64 unit, sensor frame
    origin, d = lidar.rays(pose)                    # (3,), (B*C, 3) float64 world
    images = tracer.scan(lidar, pose)               # range, id, object, points (B, C)
    write_points_ply("scan.ply", images)            # the hit points, binary PLY

Sensor frame (ROS REP 103): x forward, y left, z up. Beam i (row i of a range image,
row 0 the highest) has elevation `elevations[i]` degrees above the xy plane; column j
has azimuth

    360 j / columns                                  degrees, horizontal_fov == 360
    -horizontal_fov / 2 + j horizontal_fov / (columns - 1)   horizontal_fov < 360
                                                     (both edges included; 0 for 1 column)

counter-clockwise about +z from +x (so a partial field of view is centred on +x and
column 0 is its right-hand edge), plus the beam's `azimuth_offsets[i]`. The ray of
beam i, column j is (cos el cos az, cos el sin az, sin el): unit length, so a hit's t
is its range in metres (world units).

The spec (JSON object; every key but these is an error):

    elevations       list of B degrees, strictly decreasing, in [-90, 90]     } one of
    channels, fov_up, fov_down   B beams evenly spaced from fov_up down to    } the two
                     fov_down, both included (fov_up >= fov_down; equal for 1)
    columns          azimuth steps, 1 .. MAX_COLUMNS
    horizontal_fov   degrees, (0, 360]; default 360
    max_range        metres, > 0, finite: hits at max_range or beyond are misses
    azimuth_offsets  optional list of B degrees, finite: each beam's azimuth shift

Bad specs raise ParameterError (a KdrayError and ValueError) of one line naming the
spec and what is wrong.
"""
import dataclasses
import functools
import json
import math

import numpy as np

from .errors import ParameterError
from .files import atomic_write
from .host import check_host_memory
from .layout import MISS
from .validate import read_json

MAX_BEAMS = 1024
"""The most beams a spec may have: 8 times the largest sensors sold (128 beams: Ouster
OS-128, Hesai Pandar128), so that a spec of a million beams (a typo, or columns and
channels swapped) is refused before it allocates rays."""

MAX_COLUMNS = 1 << 16
"""The most azimuth steps: 0.0055 degrees at 360, finer than any spinning lidar's
(2048 columns: 0.18 degrees); with MAX_BEAMS, 2^26 rays a scan at most."""

SCAN_BYTES_PER_BEAM = 140
"""Host bytes a scan holds at once per beam (Tracer.scan, kdray.scan_images): the
float64 directions (24) and their float32 copy for the device (12), t and the
triangle (8), the kernel's rays on the host (24 and 12 for its float32 components),
copies of t and the triangle, the far mask and t in float64 (17), the points (24),
the objects (4), and the PLY of `kdray scan --points` (42) less what is freed by then."""

SPEC_KEYS = ("elevations", "channels", "fov_up", "fov_down", "columns", "horizontal_fov",
             "max_range", "azimuth_offsets")
"""The keys a spec may hold."""


def _number(value, what):
    """A finite float from a JSON number (not a bool); ParameterError otherwise."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ParameterError(f"{what} must be a number, got {value!r}")
    try:
        value = float(value)
    except OverflowError:                       # an int beyond float64's range
        raise ParameterError(f"{what} must be finite, got an integer of "
                             f"{len(str(abs(value)))} digits") from None
    if not math.isfinite(value):
        raise ParameterError(f"{what} must be finite, got {value}")
    return value


def _integer(value, what, lo, hi):
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ParameterError(f"{what} must be an integer, got {value!r}")
    if not lo <= value <= hi:
        raise ParameterError(f"{what} must be from {lo} to {hi}, got {value}")
    return int(value)


def _degrees(values, what):
    """(B,) float64 of a list of finite numbers, 1 .. MAX_BEAMS of them."""
    if isinstance(values, (str, bytes, dict)) or not hasattr(values, "__len__"):
        raise ParameterError(f"{what} must be a list of numbers, got {values!r}")
    if not 1 <= len(values) <= MAX_BEAMS:
        raise ParameterError(f"{what} must hold 1 to {MAX_BEAMS} beams (MAX_BEAMS), "
                             f"got {len(values)}")
    return np.array([_number(v, f"{what}[{i}]") for i, v in enumerate(values)], dtype=np.float64)


def _readonly(array):
    array = np.array(array, dtype=np.float64)
    array.flags.writeable = False
    return array


@dataclasses.dataclass(frozen=True, eq=False)
class Lidar:
    """A lidar's beams (see the module docstring for the frame and the spec).

    elevations : (B,) float64 degrees, strictly decreasing (row 0 the highest beam),
        in [-90, 90]; 1 <= B <= MAX_BEAMS
    columns : int, azimuth steps, 1 .. MAX_COLUMNS
    max_range : float, metres (world units), > 0 and finite; returns at max_range or
        beyond are misses
    horizontal_fov : float degrees in (0, 360]; 360 (default): column j at azimuth
        360 j / columns; less: columns from -fov/2 to +fov/2, both included
    azimuth_offsets : (B,) float64 degrees added to each beam's azimuth, default 0
    Constructing one validates it (ParameterError)."""

    elevations: np.ndarray
    columns: int
    max_range: float
    horizontal_fov: float = 360.0
    azimuth_offsets: np.ndarray = None

    def __post_init__(self):
        el = _degrees(self.elevations, "elevations")
        if np.any(np.abs(el) > 90):
            bad = el[np.abs(el) > 90][0]
            raise ParameterError(f"elevations must be in [-90, 90] degrees, got {bad}")
        if np.any(np.diff(el) >= 0):
            i = int(np.flatnonzero(np.diff(el) >= 0)[0])
            raise ParameterError(f"elevations must be strictly decreasing (row 0 the highest "
                                 f"beam), got {el[i]} then {el[i + 1]} at beams {i} and {i + 1}")
        columns = _integer(self.columns, "columns", 1, MAX_COLUMNS)
        max_range = _number(self.max_range, "max_range")
        if max_range <= 0:
            raise ParameterError(f"max_range must be positive, got {max_range}")
        fov = _number(self.horizontal_fov, "horizontal_fov")
        if not 0 < fov <= 360:
            raise ParameterError(f"horizontal_fov must be in (0, 360] degrees, got {fov}")
        if self.azimuth_offsets is None:
            offsets = np.zeros(len(el))
        else:
            offsets = _degrees(self.azimuth_offsets, "azimuth_offsets")
            if len(offsets) != len(el):
                raise ParameterError(f"azimuth_offsets must hold one angle per beam ({len(el)}), "
                                     f"got {len(offsets)}")
        object.__setattr__(self, "elevations", _readonly(el))
        object.__setattr__(self, "columns", columns)
        object.__setattr__(self, "max_range", max_range)
        object.__setattr__(self, "horizontal_fov", fov)
        object.__setattr__(self, "azimuth_offsets", _readonly(offsets))

    def __eq__(self, other):
        if not isinstance(other, Lidar):
            return NotImplemented
        return (np.array_equal(self.elevations, other.elevations) and self.columns == other.columns
                and self.max_range == other.max_range
                and self.horizontal_fov == other.horizontal_fov
                and np.array_equal(self.azimuth_offsets, other.azimuth_offsets))

    __hash__ = None

    @property
    def beams(self):
        """B, the number of beams (rows)."""
        return len(self.elevations)

    @property
    def shape(self):
        """(beams, columns): a range image's shape."""
        return self.beams, self.columns

    def check_memory(self):
        """KdrayError, before anything is allocated, when a scan of this lidar needs more
        host memory than is available (SCAN_BYTES_PER_BEAM a beam; kdray.host). The
        largest spec, MAX_BEAMS x MAX_COLUMNS, needs about 9 GB."""
        beams, columns = self.shape
        check_host_memory(beams * columns * SCAN_BYTES_PER_BEAM,
                          f"a scan of {beams} x {columns} beams",
                          "ask for fewer channels or columns")

    # -- the spec ------------------------------------------------------------------------

    @classmethod
    def from_dict(cls, spec, source="lidar spec"):
        """A Lidar from a spec dict (the module docstring lists its keys).
        ParameterError "<source>: <what is wrong>" for a bad one."""
        try:
            if not isinstance(spec, dict):
                raise ParameterError(f"must be a JSON object, got {type(spec).__name__}")
            unknown = [k for k in spec if k not in SPEC_KEYS]
            if unknown:
                raise ParameterError(f"unknown key {unknown[0]!r}; the keys are "
                                     f"{', '.join(SPEC_KEYS)}")
            missing = [k for k in ("columns", "max_range") if k not in spec]
            if missing:
                raise ParameterError(f"{missing[0]} is missing")
            spaced = [k for k in ("channels", "fov_up", "fov_down") if k in spec]
            if "elevations" in spec:
                if spaced:
                    raise ParameterError(f"give elevations or channels, fov_up and fov_down, "
                                         f"not both ({spaced[0]} with elevations)")
                elevations = spec["elevations"]
            elif spaced:
                elevations = _spaced(spec)
            else:
                raise ParameterError("elevations (a list of degrees) or channels, fov_up and "
                                     "fov_down is missing")
            if "azimuth_offsets" in spec and spec["azimuth_offsets"] is None:
                # as horizontal_fov's null: leave the key out for no offsets
                raise ParameterError("azimuth_offsets must be a list of degrees, got null")
            return cls(elevations, spec["columns"], spec["max_range"],
                       spec.get("horizontal_fov", 360.0), spec.get("azimuth_offsets"))
        except ParameterError as e:
            raise ParameterError(f"{source}: {e}") from None

    @classmethod
    def from_json(cls, path):
        """A Lidar from a JSON spec file; ParameterError naming the file for a missing or
        unreadable file, bad JSON or a bad spec."""
        source = f"lidar spec {path}"
        return cls.from_dict(read_json(path, source, ParameterError), source)

    def to_dict(self):
        """The spec in the list form (from_dict(to_dict()) == self, exactly)."""
        return {"elevations": self.elevations.tolist(), "columns": self.columns,
                "horizontal_fov": self.horizontal_fov, "max_range": self.max_range,
                "azimuth_offsets": self.azimuth_offsets.tolist()}

    def to_json(self):
        """to_dict() as a JSON string (floats as Python writes them: exact)."""
        return json.dumps(self.to_dict())

    # -- rays ----------------------------------------------------------------------------

    def azimuths(self):
        """(C,) float64 radians: each column's azimuth before the beams' offsets."""
        j = np.arange(self.columns, dtype=np.float64)
        if self.horizontal_fov == 360.0:
            return 2.0 * np.pi * j / self.columns
        half = np.deg2rad(self.horizontal_fov) / 2.0
        if self.columns == 1:
            return np.zeros(1)
        return -half + j * (2.0 * half / (self.columns - 1))

    @functools.cached_property
    def _directions(self):
        # the first large array of a scan (Tracer.scan, both precisions): the memory of
        # the whole scan is checked here
        self.check_memory()
        el = np.deg2rad(self.elevations)[:, None]
        az = self.azimuths()[None, :] + np.deg2rad(self.azimuth_offsets)[:, None]
        d = np.empty((self.beams, self.columns, 3))
        cos_el = np.cos(el)
        d[..., 0] = cos_el * np.cos(az)
        d[..., 1] = cos_el * np.sin(az)
        d[..., 2] = np.sin(el)
        d = d.reshape(-1, 3)
        d.flags.writeable = False
        return d

    @functools.cached_property
    def _components(self):
        """The directions' x, y and z as three contiguous (B*C,) arrays."""
        return np.ascontiguousarray(self._directions.T)

    def directions(self):
        """(B*C, 3) float64 unit vectors in the sensor frame, row-major: ray i*C + j is
        beam i (row 0 the highest), column j. Computed once per Lidar (read-only)."""
        return self._directions

    def rays(self, pose):
        """(origin (3,) float64, directions (B*C, 3) float64) in world coordinates for
        a (4, 4) sensor-to-world rigid transform (REP 103 sensor axes; validated like a
        camera pose: CameraError). The directions are rotated and renormalised in
        float64, so a hit's t is its range."""
        pose = check_pose(pose)
        R = beam_rotation(pose)
        s = self._components
        # R d, component by component: numpy's matmul would call BLAS, whose threads
        # go on spinning after it returns and take cores from the trace that follows
        # (a 128 x 2048 scan on 2 cores: 79 ms instead of 51)
        w = np.empty((3, len(s[0])))
        for k in range(3):
            np.multiply(s[0], R[k, 0], out=w[k])
            w[k] += s[1] * R[k, 1]
            w[k] += s[2] * R[k, 2]
        w /= np.sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2])
        return pose[:3, 3].copy(), np.ascontiguousarray(w.T)


def _spaced(spec):
    """Elevations of the channels form: `channels` from fov_up down to fov_down."""
    for key in ("channels", "fov_up", "fov_down"):
        if key not in spec:
            raise ParameterError(f"{key} is missing (channels, fov_up and fov_down go together)")
    channels = _integer(spec["channels"], "channels", 1, MAX_BEAMS)
    up, down = _number(spec["fov_up"], "fov_up"), _number(spec["fov_down"], "fov_down")
    for key, value in (("fov_up", up), ("fov_down", down)):
        if abs(value) > 90:
            raise ParameterError(f"{key} must be in [-90, 90] degrees, got {value}")
    if up < down or (channels > 1 and up == down):
        raise ParameterError(f"fov_up ({up}) must be above fov_down ({down})")
    if channels == 1:
        if up != down:
            raise ParameterError(f"one channel needs fov_up == fov_down, got {up} and {down}")
        return [up]
    # in the documented order, fov_up - i (fov_up - fov_down) / (channels - 1), and the
    # last exactly fov_down (the step rounded first put it 3e-14 past -90: refused)
    elevations = up - (np.arange(channels) * (up - down)) / (channels - 1)
    elevations[-1] = down
    return elevations.tolist()


ORTHONORMAL = 1e-12
"""How far from orthonormal (max |R^T R - I|) a pose's rotation may be and still turn
the beams as it is; the check lets through 1e-6 (`check_pose`)."""


def beam_rotation(pose):
    """(3, 3) float64: the rotation that turns a scan's beams, for a checked pose: its
    rotation part, or where that is orthonormal only to more than ORTHONORMAL, the
    nearest rotation (the polar factor U V^T of its SVD), so that every beam stays of
    length 1 and its range is metres in both precisions (a rotation scaled by 1 + 1e-6
    lengthened the float32 beams, whose t fell that much short of the range)."""
    R = np.asarray(pose, dtype=np.float64)[:3, :3]
    if np.abs(R.T @ R - np.eye(3)).max() <= ORTHONORMAL:
        return R
    U, _, Vt = np.linalg.svd(R)
    return U @ Vt


def check_pose(pose, name="the sensor pose"):
    """(4, 4) float64 sensor-to-world rigid transform, checked as camera poses are
    (kdray.camera: finite, last row [0, 0, 0, 1], orthonormal rotation with det +1
    to 1e-6); CameraError otherwise."""
    from .camera import _check_pose
    return _check_pose(pose, name=name)


def scan_images(lidar, origin, directions, t, prim, objects):
    """The images of a scan from its hits: dict of (B, C) arrays range (t's dtype:
    float32, or float64 for precision="double"; +inf on a miss), id and object (uint32,
    MISS on a miss), points (B, C, 3) float64 world (NaN on a miss). Hits at
    max_range or beyond are made misses here, with the exact t."""
    from .tree import object_ids
    t = np.array(t)
    prim = np.array(prim, dtype=np.uint32)
    # beyond max_range, a miss (inf), or NaN; compared in float64 (numpy would round
    # max_range to a float32 t's precision, and miss a return just below it)
    far = ~(t.astype(np.float64) < lidar.max_range)
    np.copyto(t, np.inf, where=far)         # (faster than t[far] = inf)
    np.copyto(prim, MISS, where=far)
    shape = lidar.shape
    # origin + t d, column by column (a third of the time of the (N, 3) expression);
    # NaN where there is no return
    t64 = t.astype(np.float64)
    np.copyto(t64, np.nan, where=far)
    points = np.empty((len(t), 3))
    for k in range(3):
        np.multiply(directions[:, k], t64, out=points[:, k])
        points[:, k] += origin[k]
    return {"range": t.reshape(shape), "id": prim.reshape(shape),
            "object": object_ids(prim, objects).reshape(shape),
            "points": points.reshape(shape + (3,))}



def scan(tracer, lidar, pose, precision="single"):
    """Tracer.scan: the range image of `lidar` at `pose` (its docstring) on `tracer`
    (kdray.Tracer). The render kernel makes the rays from the Lidar's direction map;
    with precision="double" the float64 rays are traced from the host."""
    from .double import double_hits, wants_double
    from .validate import check_class
    check_class(lidar, Lidar, "lidar")
    if not wants_double(precision, tracer.tree):
        return _scan_on_device(tracer, lidar, check_pose(pose))
    origin, directions = lidar.rays(pose)
    # a little beyond max_range, so that the kernel's float32 t cannot lose a hit
    # just inside it; scan_images cuts at max_range with the final t. Only t and
    # the triangle are computed: a scan has no normal or barycentric image. The
    # beams are an image (rows beams, columns azimuth steps): traced in blocks.
    hits, _ = tracer._trace(origin, directions, t_max=lidar.max_range * (1 + 2.0**-16),
                            outputs=("T", "ID"), image_w=lidar.shape[1])
    hits, _ = double_hits(tracer.tree, hits, origin, directions)
    return scan_images(lidar, origin, directions, hits.t, hits.prim, tracer.tree.objects)


def _scan_on_device(tracer, lidar, pose):
    """`scan` with the rays made by render_camera from the Lidar's direction map:
    rows are beams, columns azimuth steps; only t and the triangle are computed."""
    from . import render
    from .errors import KdrayError
    from .host import page_aligned_empty
    from .validate import check_float32
    rows, columns = lidar.shape
    map32, map_buf, _ = tracer._kept_map(
        ("lidar", lidar.to_json()),
        lambda: (np.ascontiguousarray(lidar.directions(), dtype=np.float32), None))
    M = beam_rotation(pose).astype(np.float32)
    eye = (pose[:3, 3] - tracer._origin) / tracer._scale
    # a lidar far from a small scene: the kernel's float32 cannot hold where it is
    check_float32(eye, "the lidar's position relative to the tree (in its units)", KdrayError)
    eye = eye.astype(np.float32)
    camera_buf = tracer._buffer(np.concatenate([M.reshape(9), eye]))
    n = rows * columns
    outputs = ("T", "ID")
    out = {k: page_aligned_empty(shape, dtype)
           for k, (shape, dtype) in render.output_shapes(n, outputs).items()}
    tracer._render_rows(camera_buf, map_buf, columns, rows, outputs, out, "map")
    # the kernel's rays on the host, for the hit points: the map turned by M in
    # float32 with the kernel's arithmetic, from the eye as the kernel has it
    d = np.empty((n, 3))
    for r, component in enumerate(render.turn(M, map32)):
        d[:, r] = component
    origin = tracer._origin + tracer._scale * eye.astype(np.float64)
    return scan_images(lidar, origin, d, out["T"], out["ID"], tracer.tree.objects)

# -- PLY ---------------------------------------------------------------------------------

PLY_FIELDS = (("x", "<f8", "double"), ("y", "<f8", "double"), ("z", "<f8", "double"),
              ("ring", "<u2", "ushort"), ("column", "<u4", "uint"), ("range", "<f4", "float"),
              ("id", "<u4", "uint"), ("object", "<u4", "uint"))
"""The PLY vertex properties of `write_points_ply`: (name, numpy dtype, PLY type), 42
bytes a point. x y z are float64: world coordinates far from the origin (a georeferenced
scene at 1e6 m) keep their precision (float32 would be 6 cm there)."""

PLY_DTYPE = np.dtype([(name, dtype) for name, dtype, _ in PLY_FIELDS])


def points_array(images):
    """The hit points of a scan's images as a PLY_DTYPE structured array, row-major
    (ring 0 first, then columns in order); misses left out."""
    hit = images["id"] != MISS
    ring, column = np.nonzero(hit)
    out = np.empty(len(ring), dtype=PLY_DTYPE)
    p = images["points"][hit]
    out["x"], out["y"], out["z"] = p[:, 0], p[:, 1], p[:, 2]
    out["ring"], out["column"] = ring, column
    out["range"] = images["range"][hit]
    out["id"], out["object"] = images["id"][hit], images["object"][hit]
    return out


PLY_CHUNK = 1 << 18
"""Beams `write_points_ply` turns into points at a time: its temporaries (some 100
bytes a beam) stay within a few tens of MB however large the scan."""


def write_points_ply(path, scan):
    """Write the hit points of a scan (`Tracer.scan`'s dict) as a binary
    little-endian PLY of one `vertex` element with the properties of PLY_FIELDS,
    atomically (kdray.files). Returns the number of points written. OutputError naming
    `path` on failure. Written a band of rings at a time (PLY_CHUNK beams), so that it
    holds no more than the scan's memory check counts."""
    count = int(np.count_nonzero(scan["id"] != MISS))
    header = ["ply", "format binary_little_endian 1.0", "comment written by kdray scan",
              f"element vertex {count}"]
    header += [f"property {ply} {name}" for name, _, ply in PLY_FIELDS]
    header.append("end_header")
    head = ("\n".join(header) + "\n").encode("ascii")
    rows, columns = scan["id"].shape
    band = max(1, PLY_CHUNK // max(columns, 1))

    def write(tmp):
        with open(tmp, "wb") as f:
            f.write(head)
            for r in range(0, rows, band):
                part = points_array({k: scan[k][r:r + band] for k in
                                     ("id", "points", "range", "object")})
                part["ring"] += r
                f.write(memoryview(part).cast("B"))

    atomic_write(path, write)
    return count
