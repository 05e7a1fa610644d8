"""Lidar scans (kdray.lidar, Tracer.scan, kdray scan): beam directions against the
analytic formula, ranges in a box room against analytic ray/plane distances, the EXR
and PLY files, and one clear line for every bad spec."""
import json

import numpy as np
import pytest

import kdray
from kdray.errors import CameraError, ParameterError
from kdray.images import read_exr, read_lidar
from kdray.layout import MISS
from kdray.lidar import MAX_BEAMS, MAX_COLUMNS, PLY_FIELDS, Lidar
from helpers import run

# -- the box room: 10 x 6 x 3 m, far from the world origin, three objects -------------------

ROOM_ORIGIN = np.array([1000.0, -500.0, 20.0])
ROOM_SIZE = np.array([10.0, 6.0, 3.0])
CORNERS = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], dtype=np.float64)
QUADS = {   # (axis, side) -> corner indices 4x + 2y + z, counter-clockwise seen from inside
    (2, 0): (0, 2, 6, 4), (2, 1): (1, 5, 7, 3),                        # floor, ceiling
    (0, 0): (0, 1, 3, 2), (0, 1): (4, 6, 7, 5), (1, 0): (0, 4, 5, 1), (1, 1): (2, 3, 7, 6),
}
OBJECT_OF = {(2, 0): 0, (2, 1): 2}   # floor 0, ceiling 2, the walls 1
NAMES = ("floor", "walls", "ceiling")


def room():
    """(vertices (8, 3), faces (12, 3), objects (12,), face_key (12,) of (axis, side))."""
    vertices = ROOM_ORIGIN + CORNERS * ROOM_SIZE
    faces, objects, keys = [], [], []
    for key, (a, b, c, d) in QUADS.items():
        faces += [(a, b, c), (a, c, d)]
        objects += [OBJECT_OF.get(key, 1)] * 2
        keys += [key, key]
    return vertices, np.array(faces), np.array(objects, dtype=np.uint32), keys


def rotation(yaw, pitch, roll):
    """R = Rz(yaw) Ry(pitch) Rx(roll), degrees."""
    y, p, r = np.deg2rad([yaw, pitch, roll])
    Rz = np.array([[np.cos(y), -np.sin(y), 0], [np.sin(y), np.cos(y), 0], [0, 0, 1]])
    Ry = np.array([[np.cos(p), 0, np.sin(p)], [0, 1, 0], [-np.sin(p), 0, np.cos(p)]])
    Rx = np.array([[1, 0, 0], [0, np.cos(r), -np.sin(r)], [0, np.sin(r), np.cos(r)]])
    return Rz @ Ry @ Rx


SENSOR = np.array([6.3, 2.1, 1.7])          # off-centre, in the room's frame


def sensor_pose():
    pose = np.eye(4)
    pose[:3, :3] = rotation(30.0, 10.0, -5.0)
    pose[:3, 3] = ROOM_ORIGIN + SENSOR
    return pose


SPEC = {"channels": 32, "fov_up": 30.0, "fov_down": -40.0, "columns": 1000, "max_range": 100.0}
"""32 x 1000 = 32,000 rays: not a multiple of any work size."""


def analytic(origin, d):
    """(range (N,), (axis, side) of the wall hit (N, 2), margin (N,)) of rays from a point
    inside the room, float64: the nearest of the six planes. margin: the relative gap to
    the second nearest (near 0 at an edge of the room, where the face is ambiguous)."""
    o = origin - ROOM_ORIGIN
    with np.errstate(divide="ignore", invalid="ignore"):
        far = np.where(d > 0, ROOM_SIZE, 0.0)
        t = np.where(d != 0, (far - o) / d, np.inf)
    order = np.sort(t, axis=1)
    axis = np.argmin(t, axis=1)
    side = (d[np.arange(len(d)), axis] > 0).astype(int)
    return order[:, 0], np.stack([axis, side], axis=1), order[:, 1] / order[:, 0] - 1


@pytest.fixture(scope="module")
def room_tree():
    vertices, faces, objects, _ = room()
    return kdray.build(vertices, faces, keep_double=True).with_objects(objects, NAMES)


# -- directions ---------------------------------------------------------------------------


def test_directions_against_the_analytic_formula():
    el = [15.0, 2.5, -1.0, -30.0]
    offsets = [0.5, -1.25, 0.0, 2.0]
    lidar = Lidar.from_dict({"elevations": el, "columns": 7, "max_range": 10,
                             "azimuth_offsets": offsets})
    d = lidar.directions().reshape(4, 7, 3)
    for i in range(4):
        for j in range(7):
            az = 2 * np.pi * j / 7 + np.radians(offsets[i])
            e = np.radians(el[i])
            want = [np.cos(e) * np.cos(az), np.cos(e) * np.sin(az), np.sin(e)]
            np.testing.assert_allclose(d[i, j], want, rtol=0, atol=1e-15)
    np.testing.assert_allclose(np.linalg.norm(d, axis=2), 1.0, rtol=0, atol=1e-15)
    assert np.all(np.diff(d[:, 0, 2]) < 0)                  # row 0 the highest beam
    # column 0 along +x (elevation 0, no offset); a quarter turn later +y (left)
    flat = Lidar.from_dict({"elevations": [0.0], "columns": 4, "max_range": 1}).directions()
    np.testing.assert_allclose(flat, [[1, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0]], atol=1e-15)


def test_channels_and_partial_field_of_view():
    lidar = Lidar.from_dict({"channels": 5, "fov_up": 10, "fov_down": -10, "columns": 5,
                             "horizontal_fov": 90, "max_range": 1})
    assert lidar.elevations.tolist() == [10.0, 5.0, 0.0, -5.0, -10.0]   # both ends exact
    np.testing.assert_allclose(np.degrees(lidar.azimuths()), [-45, -22.5, 0, 22.5, 45],
                               rtol=0, atol=1e-12)
    middle = lidar.directions().reshape(5, 5, 3)[2]
    assert middle[0, 1] < 0 < middle[4, 1]                  # column 0 the right-hand edge
    np.testing.assert_allclose(middle[2], [1, 0, 0], atol=1e-15)
    one = Lidar.from_dict({"channels": 1, "fov_up": -3, "fov_down": -3, "columns": 1,
                           "horizontal_fov": 30, "max_range": 1})
    np.testing.assert_allclose(one.directions(), [[np.cos(np.radians(3)), 0,
                                                   -np.sin(np.radians(3))]], atol=1e-15)


def test_spaced_channels_end_exactly_at_fov_down():
    """Channels spaced over [fov_down, fov_up] are fov_up - i (fov_up - fov_down) /
    (channels - 1), the last exactly fov_down: with the step rounded first, 64 channel
    counts from 2 to 1024 put the last of (90, -90) at -90.00000000000003, refused as
    out of [-90, 90], and others 3e-14 off fov_down."""
    for up, down in ((90.0, -90.0), (15.0, -25.0), (2.0, -24.8), (10.67, -30.67)):
        for channels in range(2, 1025):
            e = Lidar.from_dict({"channels": channels, "fov_up": up, "fov_down": down,
                                 "columns": 4, "max_range": 10}).elevations
            i = np.arange(channels)
            assert e[0] == up and e[-1] == down
            assert np.array_equal(e[:-1], (up - (i * (up - down)) / (channels - 1))[:-1])


def test_spec_round_trips_exactly():
    lidar = Lidar.from_dict({**SPEC, "azimuth_offsets": list(np.linspace(-1.1, 3.3, 32))})
    assert Lidar.from_dict(json.loads(lidar.to_json())) == lidar
    assert Lidar.from_dict(lidar.to_dict()).directions().tobytes() == lidar.directions().tobytes()


# -- ranges in the box room ----------------------------------------------------------------


def test_box_room_ranges_against_analytic_distances(tracers, room_tree):
    lidar = Lidar.from_dict({**SPEC, "azimuth_offsets": list(np.linspace(-1.1, 3.3, 32))})
    pose = sensor_pose()
    scan = tracers(room_tree).scan(lidar, pose)
    assert scan["range"].shape == (32, 1000) and scan["range"].dtype == np.float32
    assert scan["id"].dtype == scan["object"].dtype == np.uint32
    assert scan["points"].shape == (32, 1000, 3) and scan["points"].dtype == np.float64
    origin, d = pose[:3, 3], lidar.directions() @ pose[:3, :3].T
    want, face, margin = analytic(origin, d)
    got = scan["range"].reshape(-1).astype(np.float64)
    assert np.all(np.isfinite(got)), "a closed room: every beam hits"
    rel = np.abs(got - want) / want
    p99, worst = np.percentile(rel, 99), rel.max()
    print(f"box room: relative range error p99 {p99:.3g}, max {worst:.3g} ({len(rel)} beams)")
    assert p99 <= 1e-6, f"p99 {p99:.3g}, max {worst:.3g}"
    assert worst <= 1e-5, f"max {worst:.3g}"
    # the triangle and its object: those of the wall the analytic ray hits (off the edges)
    _, _, objects, keys = room()
    clear = margin > 1e-4
    ids = scan["id"].reshape(-1)[clear]
    hit_key = np.array([keys[i] for i in ids])
    np.testing.assert_array_equal(hit_key, face[clear])
    np.testing.assert_array_equal(scan["object"].reshape(-1), objects[scan["id"].reshape(-1)])
    # the points: on the wall, at origin + range * direction
    points = scan["points"].reshape(-1, 3)
    np.testing.assert_allclose(points, origin + want[:, None] * d, rtol=0, atol=2e-5)


def test_double_precision_ranges(tracers, room_tree):
    lidar = Lidar.from_dict(SPEC)
    pose = sensor_pose()
    scan = tracers(room_tree).scan(lidar, pose, precision="double")
    assert scan["range"].dtype == np.float64
    origin, d = pose[:3, 3], lidar.directions() @ pose[:3, :3].T
    want, _, _ = analytic(origin, d)
    rel = np.abs(scan["range"].reshape(-1) - want) / want
    assert rel.max() <= 1e-12, f"max {rel.max():.3g}"


def test_ranges_of_a_pose_orthonormal_to_1e6_only(tracers, room_tree):
    """A pose whose rotation is scaled by 1 + 3.2e-7 (the check lets it through: it is
    orthonormal to 1e-6) turns the beams by its nearest rotation (lidar.beam_rotation),
    so single-precision ranges stay within float32's precision of the float64 beams'
    (they were 3.2e-7 short: t along float32 beams that much longer than 1)."""
    lidar = Lidar.from_dict(SPEC)
    pose = sensor_pose()
    pose[:3, :3] *= 1 + 3.2e-7
    scan = tracers(room_tree).scan(lidar, pose)
    d = lidar.directions() @ pose[:3, :3].T
    d /= np.linalg.norm(d, axis=1, keepdims=True)           # Lidar.rays' beams
    want, _, margin = analytic(pose[:3, 3], d)
    rel = np.abs(scan["range"].reshape(-1).astype(np.float64) - want) / want
    assert np.percentile(rel[margin > 1e-4], 99) < 2e-7, np.percentile(rel, 99)


def test_beyond_max_range_is_a_miss(tracers, room_tree):
    lidar = Lidar.from_dict({**SPEC, "max_range": 5.0})
    pose = sensor_pose()
    scan = tracers(room_tree).scan(lidar, pose)
    origin, d = pose[:3, 3], lidar.directions() @ pose[:3, :3].T
    want, _, _ = analytic(origin, d)
    got = scan["range"].reshape(-1)
    near, far = want < 5.0 * (1 - 1e-6), want > 5.0 * (1 + 1e-6)
    assert near.sum() > 1000 and far.sum() > 1000
    np.testing.assert_allclose(got[near], want[near], rtol=1e-6)
    assert np.all(np.isposinf(got[far]))
    assert np.all(scan["id"].reshape(-1)[far] == MISS)
    assert np.all(scan["object"].reshape(-1)[far] == MISS)
    assert np.all(np.isnan(scan["points"].reshape(-1, 3)[far]))
    # no return at max_range or beyond, whatever the rounding
    assert np.all(got[np.isfinite(got)] < 5.0)


def test_a_return_at_max_range_is_a_miss(tracers, room_tree):
    # the range the scan reports, then that range as max_range: a miss; a hair more: a hit
    pose = sensor_pose()
    spec = {"elevations": [0.0], "columns": 4, "max_range": 100.0}
    t = tracers(room_tree).scan(Lidar.from_dict(spec), pose)["range"][0, 0]
    at = tracers(room_tree).scan(Lidar.from_dict({**spec, "max_range": float(t)}), pose)
    assert np.isposinf(at["range"][0, 0]) and at["id"][0, 0] == MISS
    above = float(np.nextafter(np.float32(t), np.float32(np.inf)))
    assert tracers(room_tree).scan(Lidar.from_dict({**spec, "max_range": above}),
                                   pose)["range"][0, 0] == t
    # the least float64 above the range (below the next float32 in single precision):
    # a hit, in both precisions
    for precision in ("single", "double"):
        lidar = Lidar.from_dict(spec)
        r = tracers(room_tree).scan(lidar, pose, precision=precision)["range"][0, 0]
        hair = float(np.nextafter(float(r), np.inf))
        got = tracers(room_tree).scan(Lidar.from_dict({**spec, "max_range": hair}), pose,
                                      precision=precision)["range"][0, 0]
        assert got == r, precision


def test_pose_is_checked(tracers, room_tree):
    pose = sensor_pose()
    pose[0, 0] *= 1.01
    with pytest.raises(CameraError, match="orthonormal"):
        tracers(room_tree).scan(Lidar.from_dict(SPEC), pose)


# -- the command: EXR and PLY ----------------------------------------------------------------


def write_room(folder):
    """The room as an OBJ file of three objects, a spec and a pose file."""
    vertices, faces, objects, _ = room()
    lines = [f"v {float(x)!r} {float(y)!r} {float(z)!r}" for x, y, z in vertices]
    for k, name in enumerate(NAMES):
        lines.append(f"o {name}")
        lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in faces[objects == k]]
    (folder / "room.obj").write_text("\n".join(lines) + "\n")
    (folder / "spec.json").write_text(json.dumps({**SPEC, "max_range": 8.0}))
    np.savetxt(folder / "pose.txt", sensor_pose())
    return folder / "room.obj", folder / "spec.json", folder / "pose.txt"


def read_ply(path):
    """(header lines, structured array) of a binary little-endian PLY, by numpy alone."""
    data = path.read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    header = data[:end].decode("ascii").splitlines()
    types = {"double": "<f8", "float": "<f4", "ushort": "<u2", "uint": "<u4"}
    fields = [(line.split()[2], types[line.split()[1]]) for line in header
              if line.startswith("property")]
    n = int(next(line for line in header if line.startswith("element vertex")).split()[2])
    points = np.frombuffer(data[end:], dtype=np.dtype(fields))
    assert len(points) == n
    return header, points


def test_scan_command_writes_the_range_image_and_points(tmp_path, capsys):
    from kdray.load import load
    scene, spec, pose_file = write_room(tmp_path)
    code, out, err = run(capsys, "scan", scene, "--lidar", spec, "--pose", pose_file,
                         "-o", tmp_path / "scan.exr", "--points", tmp_path / "scan.ply")
    assert code == 0, err
    images = read_exr(tmp_path / "scan.exr")
    assert sorted(images) == ["id", "object", "range"]
    rng_img, ids, objs = images["range"], images["id"], images["object"]
    assert rng_img.shape == (32, 1000)
    hit = ids != MISS
    assert f"32 beams x 1000 columns, {hit.sum()} of 32000 beams hit" in out
    lidar, pose = read_lidar(tmp_path / "scan.exr")
    assert lidar == Lidar.from_json(spec) and np.array_equal(pose, sensor_pose())
    # ranges: analytic, +inf from max_range (8 m) on
    d = lidar.directions() @ pose[:3, :3].T
    want, _, _ = analytic(pose[:3, 3], d)
    want = want.reshape(32, 1000)
    assert np.array_equal(hit, np.isfinite(rng_img)) and np.all(rng_img[~hit] == np.inf)
    clear = np.abs(want / 8.0 - 1) > 1e-6
    np.testing.assert_array_equal(hit[clear], want[clear] < 8.0)
    np.testing.assert_allclose(rng_img[hit], want[hit], rtol=1e-6)
    # ids index the mesh as loaded; objects are theirs
    mesh = load(scene)
    np.testing.assert_array_equal(objs[hit], mesh.objects[ids[hit]])
    assert np.all(objs[~hit] == MISS)
    # the PLY: the hits, ring-major, with their pixel's values
    header, points = read_ply(tmp_path / "scan.ply")
    assert header[1] == "format binary_little_endian 1.0"
    assert [line.split()[2] for line in header if line.startswith("property")] == \
        [name for name, _, _ in PLY_FIELDS]
    ring, column = np.nonzero(hit)
    assert len(points) == hit.sum()
    np.testing.assert_array_equal(points["ring"], ring)
    np.testing.assert_array_equal(points["column"], column)
    np.testing.assert_array_equal(points["range"], rng_img[hit])
    np.testing.assert_array_equal(points["id"], ids[hit])
    np.testing.assert_array_equal(points["object"], objs[hit])
    xyz = np.stack([points["x"], points["y"], points["z"]], axis=1)
    rays = d.reshape(32, 1000, 3)[hit]
    np.testing.assert_allclose(xyz, pose[:3, 3] + want[hit][:, None] * rays, rtol=0, atol=1e-5)


def test_points_ply_is_written_in_bands_within_the_memory_check(tmp_path, monkeypatch):
    """write_points_ply turns a band of rings into points at a time: the same bytes as
    one band, and no more memory than a fraction of the scan's own (the memory check's
    SCAN_BYTES_PER_BEAM counts one array of 42 bytes a beam for it; three whole copies
    of the points once pushed a scan past it)."""
    import tracemalloc
    from kdray import lidar as klidar
    rng = np.random.default_rng(3)
    shape = (1024, 1024)
    ids = rng.integers(0, 50, shape).astype(np.uint32)
    ids[rng.random(shape) < 0.2] = MISS
    images = {"id": ids, "object": ids // 7, "range": rng.random(shape, np.float32),
              "points": rng.normal(size=shape + (3,))}
    tracemalloc.start()
    n = klidar.write_points_ply(tmp_path / "bands.ply", images)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert n == np.count_nonzero(ids != MISS)
    # a band's temporaries (about 100 bytes a beam of PLY_CHUNK), whatever the scan's
    # size: here a quarter of it (three whole copies of the points took 100 a beam)
    assert peak < 120 * klidar.PLY_CHUNK
    monkeypatch.setattr(klidar, "PLY_CHUNK", 1 << 40)
    klidar.write_points_ply(tmp_path / "whole.ply", images)
    whole = (tmp_path / "whole.ply").read_bytes()
    assert (tmp_path / "bands.ply").read_bytes() == whole
    monkeypatch.setattr(klidar, "PLY_CHUNK", 1000)  # bands of one ring
    klidar.write_points_ply(tmp_path / "rings.ply", images)
    assert (tmp_path / "rings.ply").read_bytes() == whole
    _, points = read_ply(tmp_path / "rings.ply")
    hit = ids != MISS
    np.testing.assert_array_equal(points["ring"], np.nonzero(hit)[0])
    np.testing.assert_array_equal(points["x"], images["points"][hit][:, 0])


def test_scan_command_with_a_dumped_tree(tmp_path, capsys):
    scene, spec, pose_file = write_room(tmp_path)
    assert run(capsys, "build", scene, "--dump", tmp_path / "room.kdt")[0] == 0
    for name, extra in (("built", ()), ("dumped", ("--tree", tmp_path / "room.kdt"))):
        code, _, err = run(capsys, "scan", scene, "--lidar", spec, "--pose", pose_file,
                           "-o", tmp_path / f"{name}.exr", *extra)
        assert code == 0, err
    built, dumped = read_exr(tmp_path / "built.exr"), read_exr(tmp_path / "dumped.exr")
    for key in ("range", "id", "object"):
        np.testing.assert_array_equal(built[key], dumped[key])
    assert np.count_nonzero(np.isfinite(built["range"])) > 10000


BAD_SPECS = {
    "no beams": ({"elevations": []}, "must hold 1 to 1024 beams"),
    "a million beams": ({"elevations": list(np.linspace(10, -10, 10**6))},
                        "must hold 1 to 1024 beams"),
    "zero channels": ({"channels": 0, "fov_up": 10, "fov_down": -10}, "channels must be from 1"),
    "a million channels": ({"channels": 10**6, "fov_up": 10, "fov_down": -10},
                           "channels must be from 1 to 1024"),
    "unsorted": ({"elevations": [10, -5, 0]}, "strictly decreasing"),
    "repeated": ({"elevations": [10, 0, 0]}, "strictly decreasing"),
    "above 90": ({"elevations": [91, 0]}, r"in \[-90, 90\]"),
    "fov_up below fov_down": ({"channels": 8, "fov_up": -10, "fov_down": 10},
                              "must be above fov_down"),
    "fov_down below -90": ({"channels": 8, "fov_up": 10, "fov_down": -95}, r"in \[-90, 90\]"),
    "channels without fov": ({"channels": 8, "fov_up": 10}, "fov_down is missing"),
    "both forms": ({"elevations": [1], "channels": 1}, "not both"),
    "neither form": ({}, "is missing"),
    "NaN elevation": ({"elevations": [10, float("nan")]}, "must be finite"),
    "zero columns": ({"columns": 0}, "columns must be from 1"),
    "too many columns": ({"columns": MAX_COLUMNS + 1}, "columns must be from 1 to 65536"),
    "fractional columns": ({"columns": 2.5}, "columns must be an integer"),
    "zero max_range": ({"max_range": 0}, "max_range must be positive"),
    "infinite max_range": ({"max_range": float("inf")}, "max_range must be finite"),
    "fov above 360": ({"horizontal_fov": 400}, "horizontal_fov must be in"),
    "offsets of another length": ({"azimuth_offsets": [0, 1]}, "one angle per beam"),
    "unknown key": ({"rings": 3}, "unknown key 'rings'"),
}


@pytest.mark.parametrize("case", BAD_SPECS, ids=list(BAD_SPECS))
def test_bad_specs_one_line_nothing_written(tmp_path, capsys, case):
    change, message = BAD_SPECS[case]
    scene, spec, pose_file = write_room(tmp_path)
    base = {"elevations": [10, 0, -10], "columns": 16, "max_range": 10.0}
    if "elevations" not in change and any(k in change for k in ("channels", "fov_up")):
        del base["elevations"]
    if change == {}:
        del base["elevations"]
    spec.write_text(json.dumps({**base, **change}))
    out_file = tmp_path / "out.exr"
    code, out, err = run(capsys, "scan", scene, "--lidar", spec, "--pose", pose_file,
                         "-o", out_file, "--points", tmp_path / "out.ply")
    assert code == 1 and out == ""
    assert len(err.strip().splitlines()) == 1, err
    assert err.startswith(f"kdray: error: lidar spec {spec}: "), err
    assert __import__("re").search(message, err), err
    assert not out_file.exists() and not (tmp_path / "out.ply").exists()
    with pytest.raises(ParameterError):
        Lidar.from_json(spec)


@pytest.mark.parametrize("text, message", [("{", "not valid JSON"), ("[1, 2]", "a JSON object")])
def test_unreadable_specs(tmp_path, capsys, text, message):
    scene, spec, pose_file = write_room(tmp_path)
    spec.write_text(text)
    code, _, err = run(capsys, "scan", scene, "--lidar", spec, "--pose", pose_file,
                       "-o", tmp_path / "out.exr")
    assert code == 1 and len(err.strip().splitlines()) == 1 and message in err, err
    assert not (tmp_path / "out.exr").exists()


def test_bad_pose_file_one_line(tmp_path, capsys):
    scene, spec, pose_file = write_room(tmp_path)
    pose = sensor_pose()
    pose[1, 1] = 3.0
    np.savetxt(pose_file, pose)
    code, _, err = run(capsys, "scan", scene, "--lidar", spec, "--pose", pose_file,
                       "-o", tmp_path / "out.exr")
    assert code == 1 and len(err.strip().splitlines()) == 1 and "orthonormal" in err, err
    assert not (tmp_path / "out.exr").exists()


def test_max_beams_is_accepted():
    lidar = Lidar.from_dict({"channels": MAX_BEAMS, "fov_up": 45, "fov_down": -45, "columns": 2,
                             "max_range": 1})
    assert lidar.directions().shape == (2 * MAX_BEAMS, 3)


def test_null_offsets_and_a_scan_header_beside_a_camera_are_refused(tmp_path):
    """azimuth_offsets: null is refused as horizontal_fov: null is (it meant no offsets);
    write_exr refuses a lidar and a camera together (a scan's file holds its lidar
    instead of a camera) and a sensor_to_world without its lidar (dropped before)."""
    from kdray.errors import OutputError
    from kdray.images import write_exr
    with pytest.raises(ParameterError, match="azimuth_offsets must be a list"):
        Lidar.from_dict({**SPEC, "azimuth_offsets": None})
    lidar = Lidar.from_dict({**SPEC, "channels": 2, "columns": 3})
    images = {"range": np.ones((2, 3), np.float32)}
    camera = kdray.Camera(3, 2, [[3, 0, 1.5], [0, 3, 1], [0, 0, 1]], np.eye(4))
    with pytest.raises(OutputError, match="instead of a camera"):
        write_exr(tmp_path / "a.exr", images, camera=camera, lidar=lidar, sensor_to_world=np.eye(4))
    with pytest.raises(OutputError, match="give the lidar with it"):
        write_exr(tmp_path / "b.exr", images, sensor_to_world=np.eye(4))
    assert not list(tmp_path.iterdir())
    write_exr(tmp_path / "c.exr", images, lidar=lidar, sensor_to_world=np.eye(4))
    assert read_lidar(tmp_path / "c.exr")[0] == lidar
