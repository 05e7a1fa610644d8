"""kdray.camera: conventions (fov, pixel centres, OpenCV axes), constructors, files,
framing and errors. Oracles are written out by hand here, not taken from the module."""
import json
import math

import numpy as np
import pytest

from kdray.camera import Camera, pose_from_file
from kdray.errors import CameraError, KdrayError


def project(K, cam_to_world, points):
    """Hand-written pinhole projection: world points -> (pixel x, pixel y, depth)."""
    R, eye = cam_to_world[:3, :3], cam_to_world[:3, 3]
    cam = (np.atleast_2d(points) - eye) @ R  # rows of R^T (p - eye)
    uvw = cam @ K.T
    return uvw[:, 0] / uvw[:, 2], uvw[:, 1] / uvw[:, 2], cam[:, 2]


def unit(v):
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v)


# Conventions ------------------------------------------------------------------------


@pytest.mark.parametrize("fov, width, height", [(60.0, 640, 480), (45.0, 33, 17), (120.0, 1, 1)])
def test_fov_formula(fov, width, height):
    cam = Camera.look_at((0, 0, 5), (0, 0, 0), fov_deg=fov, width=width, height=height)
    f = (height / 2) / math.tan(math.radians(fov) / 2)
    expected = np.array([[f, 0, width / 2], [0, f, height / 2], [0, 0, 1]])
    np.testing.assert_allclose(cam.K, expected, rtol=1e-15, atol=0)
    assert cam.K.dtype == np.float64 and cam.cam_to_world.dtype == np.float64


def test_vertical_fov_spans_the_image_height():
    # A point on the upper edge of a 60 degree view lies exactly at the image's top row edge.
    cam = Camera.look_at((0, 0, 0), (0, 0, -1), fov_deg=60, width=200, height=100)
    top = np.array([0.0, math.tan(math.radians(30)), -1.0])
    x, y, _ = project(cam.K, cam.cam_to_world, top)
    assert x[0] == pytest.approx(100.0) and y[0] == pytest.approx(0.0, abs=1e-12)


def test_centre_pixel_looks_at_target():
    eye, target = np.array([1.0, 2.0, 3.0]), np.array([-2.0, 0.5, -4.0])
    cam = Camera.look_at(eye, target, fov_deg=50, width=641, height=481)
    origins, directions = cam.rays()
    centre = 240 * 641 + 320  # row 240, column 320: sampled at (320.5, 240.5) = (cx, cy)
    np.testing.assert_allclose(unit(directions[centre]), unit(target - eye), atol=1e-15)
    np.testing.assert_array_equal(origins[centre], eye)
    np.testing.assert_allclose(cam.forward, unit(target - eye), atol=1e-15)
    # With an even size the target projects onto the corner between the four middle pixels.
    even = Camera.look_at(eye, target, fov_deg=50, width=640, height=480)
    x, y, depth = project(even.K, even.cam_to_world, target)
    assert (x[0], y[0]) == (pytest.approx(320.0), pytest.approx(240.0))
    assert depth[0] == pytest.approx(np.linalg.norm(target - eye))


def test_pixel_centres_half_pixel_convention():
    cam = Camera.look_at((0.3, -1.0, 2.0), (0.1, 0.2, -1.0), up=(0.2, 1, 0.1), fov_deg=70, width=7, height=5)
    origins, directions = cam.rays()
    assert origins.shape == directions.shape == (35, 3)
    assert origins.dtype == directions.dtype == np.float64
    for j in range(5):
        for i in range(7):
            d = directions[j * 7 + i]  # row-major: row j, then column i
            x, y, depth = project(cam.K, cam.cam_to_world, cam.eye + 2.5 * d)
            assert x[0] == pytest.approx(i + 0.5, abs=1e-12)
            assert y[0] == pytest.approx(j + 0.5, abs=1e-12)
            assert depth[0] == pytest.approx(2.5, abs=1e-12)  # camera-z of d is 1


def test_opencv_axes():
    # Looking down -z with y up: image x is world +x, image y (down) is world -y.
    cam = Camera.look_at((0, 0, 5), (0, 0, 0), up=(0, 1, 0), width=4, height=4)
    np.testing.assert_allclose(cam.rotation, [[1, 0, 0], [0, -1, 0], [0, 0, -1]], atol=1e-15)
    _, d = cam.rays()
    top_left, bottom_right = d[0], d[15]
    assert top_left[0] < 0 and top_left[1] > 0
    assert bottom_right[0] > 0 and bottom_right[1] < 0


def test_look_at_is_orthonormal(rng):
    for _ in range(50):
        eye, target, up = rng.normal(size=(3, 3)) * 10
        cam = Camera.look_at(eye, target, up, fov_deg=rng.uniform(1, 179), width=9, height=4)
        R = cam.rotation
        np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
        assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-12)
        np.testing.assert_allclose(R[:, 2], unit(target - eye), atol=1e-12)
        assert np.dot(R[:, 1], up) < 0  # image down is against up
        assert abs(np.dot(R[:, 0], up)) < 1e-9 * np.linalg.norm(up)  # no roll
        np.testing.assert_array_equal(cam.eye, eye)
        np.testing.assert_array_equal(cam.cam_to_world[3], [0, 0, 0, 1])


def test_camera_is_frozen_and_copies_its_arrays():
    K = np.array([[100.0, 0, 5], [0, 100, 5], [0, 0, 1]])
    cam = Camera.from_intrinsics(K, np.eye(4), 10, 10)
    K[0, 0] = 1.0
    assert cam.K[0, 0] == 100.0
    with pytest.raises(ValueError):
        cam.K[0, 0] = 2.0
    with pytest.raises(AttributeError):
        cam.width = 3


def test_one_pixel_camera():
    cam = Camera.look_at((0, 0, 0), (0, 0, 1), up=(0, -1, 0), width=1, height=1)
    origins, directions = cam.rays()
    np.testing.assert_allclose(directions, [[0, 0, 1]], atol=1e-15)
    np.testing.assert_array_equal(origins, [[0, 0, 0]])


# Other constructors and files --------------------------------------------------------


def test_from_intrinsics_matches_look_at():
    # Hand-built: eye on +z looking at the origin, y up, 90 degree vertical fov.
    W, H = 64, 48
    f = (H / 2) / math.tan(math.radians(45))
    K = np.array([[f, 0, W / 2], [0, f, H / 2], [0, 0, 1]])
    pose = np.array([[1, 0, 0, 0], [0, -1, 0, 0], [0, 0, -1, 5], [0, 0, 0, 1]], dtype=float)
    by_hand = Camera.from_intrinsics(K, pose, W, H)
    looked = Camera.look_at((0, 0, 5), (0, 0, 0), (0, 1, 0), 90, W, H)
    np.testing.assert_allclose(looked.K, by_hand.K, rtol=1e-15)
    np.testing.assert_allclose(looked.cam_to_world, by_hand.cam_to_world, atol=1e-15)
    np.testing.assert_allclose(looked.rays()[1], by_hand.rays()[1], atol=1e-14)
    again = Camera.from_intrinsics(looked.K, looked.cam_to_world, W, H)
    assert again == looked
    np.testing.assert_array_equal(again.rays()[1], looked.rays()[1])


def test_json_round_trip(tmp_path):
    cam = Camera.look_at((1.5, 2.25, -3.0), (0.1, 0.2, 0.3), (0, 0, 1), 33.3, 123, 45)
    path = tmp_path / "cam.json"
    cam.to_json(path)
    back = Camera.from_json(path)
    assert back == cam
    assert not list(tmp_path.glob(".*"))  # no temporary file left behind
    data = json.loads(path.read_text())
    assert set(data) == {"width", "height", "K", "cam_to_world"}


def test_json_look_at_form(tmp_path):
    path = tmp_path / "cam.json"
    path.write_text(json.dumps({"width": 32, "height": 24, "eye": [0, 1, 4], "target": [0, 1, 0], "fov": 40}))
    assert Camera.from_json(path) == Camera.look_at((0, 1, 4), (0, 1, 0), (0, 1, 0), 40, 32, 24)
    path.write_text(json.dumps({"width": 32, "height": 24, "eye": [0, 1, 4], "target": [0, 1, 0]}))
    assert Camera.from_json(path) == Camera.look_at((0, 1, 4), (0, 1, 0), (0, 1, 0), 45, 32, 24)


def test_json_intrinsics_object_form(tmp_path):
    pose = np.eye(4)
    pose[:3, 3] = [1, 2, 3]
    path = tmp_path / "cam.json"
    path.write_text(json.dumps({"width": 8, "height": 6, "K": {"fx": 10, "fy": 12, "cx": 4, "cy": 3},
                                "cam_to_world": pose.tolist()}))
    cam = Camera.from_json(path)
    np.testing.assert_array_equal(cam.K, [[10, 0, 4], [0, 12, 3], [0, 0, 1]])
    np.testing.assert_array_equal(cam.eye, [1, 2, 3])


def test_shipped_cornell_camera_sees_the_room():
    from helpers import SCENES

    cam = Camera.from_json(SCENES / "cornell.json")
    back_corners = np.array([[x, y, -0.5] for x in (-0.5, 0.5) for y in (0.0, 1.0)])
    x, y, depth = project(cam.K, cam.cam_to_world, back_corners)
    assert np.all(depth > 0)
    assert np.all((x > 0) & (x < cam.width) & (y > 0) & (y < cam.height))


def test_pose_from_text_and_npy(tmp_path):
    pose = Camera.look_at((1, 2, 3), (0, 0, 0)).cam_to_world
    text = tmp_path / "pose.txt"
    text.write_text("# camera to world\n" + "\n".join(", ".join(repr(float(v)) for v in row) for row in pose))
    np.testing.assert_array_equal(pose_from_file(text), pose)
    spaces = tmp_path / "pose2.txt"
    spaces.write_text(" ".join(repr(float(v)) for v in pose.ravel()))
    np.testing.assert_array_equal(pose_from_file(spaces), pose)
    npy = tmp_path / "pose.npy"
    np.save(npy, pose)
    np.testing.assert_array_equal(pose_from_file(npy), pose)


# Errors ---------------------------------------------------------------------------------


@pytest.mark.parametrize("fov", [0, 180, -10, 200, float("nan"), float("inf"), 5e-324, 1e-320])
def test_bad_fov(fov):
    with pytest.raises(CameraError, match="fov"):
        Camera.look_at((0, 0, 1), (0, 0, 0), fov_deg=fov)


def test_eye_equals_target():
    with pytest.raises(CameraError, match="same point"):
        Camera.look_at((1e7, 2, 3), (1e7, 2, 3))


@pytest.mark.parametrize(
    "eye, target, up",
    [
        ((0, 0, 0), (0, 5, 0), (0, 1, 0)),
        ((0, 0, 0), (0, -5, 0), (0, 1, 0)),  # antiparallel
        ((0, 0, 0), (0, 1e-30, 0), (0, 1e30, 0)),  # relative to the norms, not absolute
        ((1, 1, 1), (2, 2, 2), (3e-9, 3e-9, 3e-9)),
    ],
)
def test_up_parallel_to_view(eye, target, up):
    with pytest.raises(CameraError, match="parallel"):
        Camera.look_at(eye, target, up)


def test_small_but_valid_vectors_work():
    cam = Camera.look_at((0, 0, 0), (0, 0, 1e-30), up=(0, 1e-30, 0))
    assert np.all(np.isfinite(cam.cam_to_world))


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"eye": (0, float("nan"), 0)}, "eye"),
        ({"target": (0, 0, float("inf"))}, "target"),
        ({"up": (0, 0, 0)}, "up"),
        ({"up": (1, 2)}, "up"),
        ({"width": 0}, "width"),
        ({"height": -3}, "height"),
        ({"width": 1.5}, "width"),
        ({"width": True}, "width"),
    ],
)
def test_look_at_errors(kwargs, match):
    args = {"eye": (0, 0, 1), "target": (0, 0, 0), "up": (0, 1, 0)} | kwargs
    with pytest.raises(CameraError, match=match):
        Camera.look_at(**args)


GOOD_K = np.array([[100.0, 0, 32], [0, 100, 24], [0, 0, 1]])


def _pose(R=np.eye(3), t=(0, 0, 0)):
    M = np.eye(4)
    M[:3, :3] = R
    M[:3, 3] = t
    return M


@pytest.mark.parametrize(
    "K, pose, match",
    [
        (np.eye(2), _pose(), "3x3"),
        (GOOD_K, np.eye(3), "4x4"),
        (np.where(GOOD_K == 100, np.nan, GOOD_K), _pose(), "finite"),
        (np.diag([-100.0, 100, 1]), _pose(), "positive fx"),
        (np.diag([100.0, 0, 1]), _pose(), "positive fx"),
        (np.array([[100.0, 0, 32], [0, 100, 24], [0, 0, 2]]), _pose(), r"\[0, 0, 1\]"),
        (GOOD_K, _pose(R=np.diag([1.01, 1, 1])), "orthonormal"),
        (GOOD_K, _pose(R=np.diag([1.0, 1, -1])), "determinant"),
        (GOOD_K, _pose(t=(0, 0, np.inf)), "finite"),
        (GOOD_K, np.vstack([_pose()[:3], [0, 0, 1, 1]]), "last row"),
    ],
)
def test_from_intrinsics_errors(K, pose, match):
    with pytest.raises(CameraError, match=match):
        Camera.from_intrinsics(K, pose, 64, 48)


def test_rotation_tolerance():
    c, s = math.cos(0.3), math.sin(0.3)
    R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    Camera.from_intrinsics(GOOD_K, _pose(R + 1e-8), 64, 48)  # within 1e-6: accepted
    with pytest.raises(CameraError, match="1e-06"):
        Camera.from_intrinsics(GOOD_K, _pose(R + 1e-5), 64, 48)


@pytest.mark.parametrize(
    "content, match",
    [
        ("{not json", "not valid JSON"),
        ("[1, 2]", "JSON object"),
        ('{"width": 4, "eye": [0,0,1], "target": [0,0,0]}', "missing 'height'"),
        ('{"width": 4, "height": 4, "eye": [0,0,1]}', "missing 'target'"),
        ('{"width": 4, "height": 4}', "missing a pose"),
        ('{"width": 4, "height": 4, "eye": [0,0,1], "target": [0,0,0], "fov_deg": 3}', "unknown keys"),
        ('{"width": 4, "height": 4, "eye": [0,0,1], "target": [0,0,0], "K": [[1,0,0],[0,1,0],[0,0,1]]}', "not both"),
        ('{"width": 4, "height": 4, "eye": [0,0,1], "target": [0,0,0], "fov": "wide"}', "fov"),
        ('{"width": 4, "height": 4, "K": "big", "cam_to_world": []}', "K must be"),
        ('{"width": 4, "height": 4, "K": {"fx": 1}, "cam_to_world": []}', "fx, fy, cx, cy"),
        ('{"width": "4", "height": 4, "eye": [0,0,1], "target": [0,0,0]}', "width"),
        ('{"width": 4, "height": 4, "eye": [0,0,1], "target": [0,0,1]}', "same point"),
    ],
)
def test_json_errors_name_the_file(tmp_path, content, match):
    path = tmp_path / "broken_camera.json"
    path.write_text(content)
    with pytest.raises(CameraError, match=match) as info:
        Camera.from_json(path)
    assert "broken_camera.json" in str(info.value)


def test_json_missing_file(tmp_path):
    with pytest.raises(CameraError, match="does not exist"):
        Camera.from_json(tmp_path / "nope.json")


def test_to_json_unwritable(tmp_path):
    from kdray.errors import OutputError

    cam = Camera.look_at((0, 0, 1), (0, 0, 0))
    with pytest.raises(OutputError, match="missing"):
        cam.to_json(tmp_path / "missing" / "cam.json")


@pytest.mark.parametrize(
    "name, content, match",
    [
        ("short.txt", "1 0 0 0 0 1 0 0 0 0 1 0", "16 numbers"),
        ("words.txt", "1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 one", "not a number"),
        ("scaled.txt", "2 0 0 0 0 2 0 0 0 0 2 0 0 0 0 1", "orthonormal"),
        ("nan.txt", "1 0 0 nan 0 1 0 0 0 0 1 0 0 0 0 1", "finite"),
    ],
)
def test_pose_file_errors(tmp_path, name, content, match):
    path = tmp_path / name
    path.write_text(content)
    with pytest.raises(CameraError, match=match) as info:
        pose_from_file(path)
    assert name in str(info.value)


def test_pose_file_missing_and_bad_npy(tmp_path):
    with pytest.raises(CameraError, match="does not exist"):
        pose_from_file(tmp_path / "nope.txt")
    np.save(tmp_path / "small.npy", np.eye(3))
    with pytest.raises(CameraError, match="4x4"):
        pose_from_file(tmp_path / "small.npy")
    (tmp_path / "junk.npy").write_bytes(b"not numpy")
    with pytest.raises(CameraError, match="junk.npy"):
        pose_from_file(tmp_path / "junk.npy")


def test_errors_are_kdray_errors():
    assert issubclass(CameraError, KdrayError)


# Framing --------------------------------------------------------------------------------

BOXES = [
    ((-1, -1, -1), (1, 1, 1)),
    ((0, 0, 0), (1, 0, 1)),  # flat: zero height
    ((0, 0, 0), (0, 1, 0)),  # a segment
    ((-0.5, 0, -0.5), (0.5, 1, 0.5)),  # the Cornell room
    ((1e6, 2e6, -3e6), (1e6 + 2, 2e6 + 1, -3e6 + 1)),  # far from the origin
    ((1e7, 1e7, 1e7), (1e7 + 1e-3, 1e7 + 1e-3, 1e7 + 1e-3)),  # tiny and far
    ((0, 0, 0), (1e-7, 2e-7, 1e-7)),  # tiny
    ((-1e7, -1e7, 0), (1e7, 1e7, 3e7)),  # huge
    ((5, 5, 5), (5, 5, 5)),  # a point
    ((0, 0, 0), (100, 1, 0.01)),  # long and thin
]
DIRECTIONS = [None, (0, -1, 0), (0, 0, -1), (1, 0.2, 0), (-1, -1, -1)]


@pytest.mark.parametrize("lo, hi", BOXES)
@pytest.mark.parametrize("direction", DIRECTIONS)
@pytest.mark.parametrize("size", [(640, 480), (100, 400), (1, 1)])
def test_frame_keeps_the_box_in_view(lo, hi, direction, size):
    kwargs = {} if direction is None else {"direction": direction}
    cam = Camera.frame(lo, hi, size[0], size[1], **kwargs)
    lo, hi = np.array(lo, float), np.array(hi, float)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    x, y, depth = project(cam.K, cam.cam_to_world, corners)
    assert np.all(depth > 0)
    assert np.all((x >= 0) & (x <= cam.width) & (y >= 0) & (y <= cam.height))
    # ... and not absurdly small: some corner reaches beyond the middle 60% of the image.
    reach = np.maximum(np.abs(x / cam.width - 0.5), np.abs(y / cam.height - 0.5)).max()
    offsets = corners - (lo + hi) / 2
    across = offsets - np.outer(offsets @ cam.forward, cam.forward)  # seen side-on
    if np.abs(across).max() > 1e-9 * np.abs(offsets).max():
        assert reach > 0.3
    # The eye is outside the box.
    assert np.any((cam.eye < lo) | (cam.eye > hi))
    if direction is not None:
        np.testing.assert_allclose(cam.forward, unit(direction), atol=1e-9)


def test_frame_default_is_a_three_quarter_view_from_front_right_above():
    cam = Camera.frame((-1, -1, -1), (1, 1, 1), 640, 480)
    assert cam.eye[0] > 1 and cam.eye[1] > 1 and cam.eye[2] > 1
    up_in_image = cam.rotation.T @ np.array([0.0, 1.0, 0.0])
    assert up_in_image[1] < 0  # world up points up in the image
    assert abs(up_in_image[0]) < 1e-12  # no roll


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"bounds_min": (1, 0, 0), "bounds_max": (0, 1, 1)}, "exceeds"),
        ({"bounds_min": (0, 0, np.nan)}, "finite"),
        ({"direction": (0, 0, 0)}, "direction"),
        ({"fov_deg": 180}, "fov"),
        ({"width": 0}, "width"),
    ],
)
def test_frame_errors(kwargs, match):
    args = {"bounds_min": (0, 0, 0), "bounds_max": (1, 1, 1)} | kwargs
    with pytest.raises(CameraError, match=match):
        Camera.frame(**args)
