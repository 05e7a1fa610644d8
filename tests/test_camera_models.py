"""Camera models beyond the pinhole (kdray.lens, Camera.model / distortion): rays against
OpenCV's projections (cv2.projectPoints, cv2.fisheye.projectPoints) and against the
analytic directions of the equirectangular and orthographic cameras; renders whose hit
points project back onto their pixel centres; the valid mask; bad input."""
import json
import math
import warnings

import numpy as np
import pytest

import kdray
from kdray import Camera, lens
from kdray.errors import CameraError

cv2 = pytest.importorskip("cv2")

W, H = 160, 120
MODERATE = (-0.28, 0.07, 0.0008, -0.0011, 0.01)
STRONG = (0.9, 0.45, -0.004, 0.003, 0.12, 0.35, 0.08, 0.02)        # rational model
FISHEYE = (0.08, -0.02, 0.004, -0.0005)


def _pose(eye=(0.2, -0.1, 0.3), target=(0.0, 0.0, 3.0)):
    return Camera.look_at(eye, target, (0.1, -1.0, 0.0), 60, W, H).cam_to_world


def _K(f=110.0):
    return np.array([[f, 0.0, W / 2 + 3.25], [0.0, 1.03 * f, H / 2 - 1.5], [0.0, 0.0, 1.0]])


def _rvec_tvec(camera):
    R = camera.rotation.T                       # world -> camera
    rvec, _ = cv2.Rodrigues(R)
    return rvec, -R @ camera.eye


def _pixel_centres(mask):
    j, i = np.divmod(np.flatnonzero(mask.reshape(-1)), W)
    return np.stack([i + 0.5, j + 0.5], axis=1)


def _opencv_project(camera, points):
    rvec, tvec = _rvec_tvec(camera)
    objects = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 1, 3)
    if camera.model == "fisheye":
        pixels, _ = cv2.fisheye.projectPoints(objects, rvec, tvec, camera.K,
                                              np.array(camera.distortion))
    else:
        pixels, _ = cv2.projectPoints(objects, rvec, tvec, camera.K, np.array(camera.distortion))
    return pixels.reshape(-1, 2)


@pytest.mark.parametrize("model, distortion", [
    ("opencv", MODERATE), ("opencv", STRONG), ("opencv", MODERATE[:4]), ("fisheye", FISHEYE)])
def test_rays_land_on_pixel_centres_in_opencv(model, distortion):
    camera = Camera(W, H, _K(), _pose(), model, distortion)
    o, d, valid = camera.rays(valid=True)
    assert valid.all()
    points = o + 2.5 * d
    if model == "fisheye":
        assert np.allclose(np.linalg.norm(d, axis=1), 1.0)
        front = (points - camera.eye) @ camera.forward > 0    # cv2.fisheye: z > 0 only
        assert front.all()
    else:
        assert np.allclose(d @ camera.forward, 1.0)           # camera-z 1: t is z-depth
    error = np.abs(_opencv_project(camera, points) - _pixel_centres(valid)).max()
    assert error < 1e-8
    pixels, _ = camera.project(points)                        # kdray's forward model
    assert np.abs(pixels - _pixel_centres(valid)).max() < 1e-8


def test_fisheye_beyond_180_degrees():
    # f = 40 px on 160 x 120: theta reaches about 2.2 rad (a 250 degree field) in the corners
    camera = Camera(W, H, _K(40.0), _pose(), "fisheye", (0.01, -0.002, 0.0, 0.0))
    o, d, valid = camera.rays(valid=True)
    assert valid.all()
    z = d @ camera.forward
    assert (z < -0.3).any()                                   # rays behind the eye
    theta = np.arccos(np.clip(z, -1, 1))
    a, b = lens.pixel_points(camera.K, W, H)
    k1, k2, k3, k4 = camera.distortion
    theta_d = theta * (1 + k1 * theta**2 + k2 * theta**4 + k3 * theta**6 + k4 * theta**8)
    assert np.abs(theta_d - np.hypot(a, b)).max() < 1e-10
    front = z > 1e-3
    points = o + 3.0 * d
    error = np.abs(_opencv_project(camera, points[front]) - _pixel_centres(front)).max()
    assert error < 1e-8


def test_fisheye_past_its_field_is_not_valid():
    # theta_d(theta) stops growing at theta = 1 rad: pixels beyond are misses, flagged
    k1 = -1.0 / 3.0 / 1.0                                     # d/dtheta (theta + k1 theta^3) = 0 at 1
    camera = Camera(W, H, _K(60.0), _pose(), "fisheye", (k1, 0.0, 0.0, 0.0))
    o, d, valid = camera.rays(valid=True)
    a, b = lens.pixel_points(camera.K, W, H)
    expected = np.hypot(a, b) < 1.0 + k1                      # theta_d(1) = 2 / 3
    assert np.array_equal(valid, expected)
    assert 0.2 < valid.mean() < 0.9
    assert np.isnan(d[~valid]).all() and np.isfinite(d[valid]).all()
    assert np.array_equal(camera.valid().reshape(-1), valid)


def test_opencv_non_monotonic_distortion_is_masked(caplog):
    # r (1 + k1 r^2) stops growing at r = sqrt(-1 / (3 k1)): 0.745 for k1 = -0.6
    k1 = -0.6
    camera = Camera(W, H, _K(130.0), _pose(), "opencv", (k1, 0.0, 0.0, 0.0))
    with caplog.at_level("WARNING", logger="kdray.lens"):
        o, d, valid = camera.rays(valid=True)
    r_max = math.sqrt(-1.0 / (3.0 * k1))
    a, b = lens.pixel_points(camera.K, W, H)
    expected = np.hypot(a, b) < r_max * (1 + k1 * r_max**2)
    assert np.array_equal(valid, expected)
    assert 0.3 < valid.mean() < 0.95
    assert "of the pixels have a ray" in caplog.text
    assert np.isnan(d[~valid]).all()
    error = np.abs(_opencv_project(camera, (o + d)[valid]) - _pixel_centres(valid)).max()
    assert error < 1e-8


def test_equirectangular_directions_are_analytic():
    camera = Camera.panorama(_pose(), W, H)
    o, d, valid = camera.rays(valid=True)
    assert valid.all() and np.allclose(o, camera.eye)
    j, i = np.divmod(np.arange(W * H), W)
    lon = -math.pi + (i + 0.5) * 2 * math.pi / W
    lat = math.pi / 2 - (j + 0.5) * math.pi / H
    local = np.stack([np.cos(lat) * np.sin(lon), -np.sin(lat), np.cos(lat) * np.cos(lon)], 1)
    assert np.abs(d - local @ camera.rotation.T).max() < 1e-14
    pixels, depth = camera.project(camera.eye + 2.0 * d)
    assert np.abs(pixels - np.stack([i + 0.5, j + 0.5], 1)).max() < 1e-9
    assert np.allclose(depth, 2.0)


def test_equirectangular_partial_range_and_past_the_poles():
    camera = Camera.panorama(_pose(), W, H, longitude=(-1.0, 0.5), latitude=(0.4, -0.2))
    o, d, valid = camera.rays(valid=True)
    assert valid.all()
    local = d @ camera.rotation
    lon = np.arctan2(local[:, 0], local[:, 2])
    lat = -np.arcsin(local[:, 1])
    assert lon.min() == pytest.approx(-1.0 + 0.75 / W, abs=1e-12)
    assert lon.max() == pytest.approx(0.5 - 0.75 / W, abs=1e-12)
    assert lat.max() == pytest.approx(0.4 - 0.3 / H, abs=1e-12)
    # ranges that do not hold longitude 0 in their middle (from 0 to 2 pi, across the
    # back): project takes each direction's longitude by whole turns into the image's
    for longitude in ((0.0, 2 * np.pi), (-2 * np.pi, 0.0), (2.0, 4.5)):
        camera = Camera.panorama(_pose(), W, H, longitude=longitude)
        o, d = camera.rays()
        pixels, _ = camera.project(o + d)
        centres = np.stack(np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5), axis=-1)
        assert np.allclose(pixels, centres.reshape(-1, 2), rtol=0, atol=1e-9), longitude
    # latitudes beyond the poles have no direction
    camera = Camera.panorama(_pose(), W, H, latitude=(2.0, -2.0))
    valid = camera.valid()
    rows = valid.all(axis=1)
    assert rows.any() and not rows.all() and np.array_equal(valid.any(axis=1), rows)


def test_orthographic_rays():
    K = np.array([[40.0, 0.0, W / 2], [0.0, 40.0, H / 2], [0.0, 0.0, 1.0]])   # 40 px per unit
    camera = Camera(W, H, K, _pose(), "orthographic")
    o, d, valid = camera.rays(valid=True)
    assert valid.all()
    assert np.abs(d - camera.forward).max() < 1e-15
    j, i = np.divmod(np.arange(W * H), W)
    local = np.stack([(i + 0.5 - W / 2) / 40.0, (j + 0.5 - H / 2) / 40.0, np.zeros(W * H)], 1)
    assert np.abs(o - (camera.eye + local @ camera.rotation.T)).max() < 1e-14
    pixels, depth = camera.project(o + 1.5 * d)
    assert np.abs(pixels - np.stack([i + 0.5, j + 0.5], 1)).max() < 1e-9
    assert np.allclose(depth, 1.5)


def test_pinhole_is_unchanged():
    a = Camera.look_at((0, 1, 4), (0, 1, 0), fov_deg=40, width=W, height=H)
    b = Camera(W, H, a.K, a.cam_to_world, "pinhole", ())
    assert a == b and a.model == "pinhole" and a.distortion == ()
    (o1, d1), (o2, d2, valid) = a.rays(), b.rays(valid=True)
    assert np.array_equal(d1, d2) and np.array_equal(o1, o2) and valid.all()
    assert a != Camera(W, H, a.K, a.cam_to_world, "opencv", (0, 0, 0, 0))


def test_json_round_trip_of_every_model(tmp_path):
    cameras = [Camera(W, H, _K(), _pose(), "opencv", STRONG),
               Camera(W, H, _K(), _pose(), "fisheye", FISHEYE),
               Camera.panorama(_pose(), W, H, longitude=(-1.0, 0.5)),
               Camera(W, H, _K(), _pose(), "orthographic")]
    for camera in cameras:
        camera.to_json(tmp_path / "c.json")
        data = json.loads((tmp_path / "c.json").read_text())
        assert data["model"] == camera.model
        assert Camera.from_json(tmp_path / "c.json") == camera
    pinhole = Camera(W, H, _K(), _pose())
    pinhole.to_json(tmp_path / "p.json")
    assert set(json.loads((tmp_path / "p.json").read_text())) == {"width", "height", "K", "cam_to_world"}


def test_json_look_at_form_with_a_model(tmp_path):
    path = tmp_path / "c.json"
    path.write_text(json.dumps({"width": W, "height": H, "eye": [0, 0, 0], "target": [0, 0, 1],
                                "fov": 90, "model": "fisheye", "distortion": list(FISHEYE)}))
    camera = Camera.from_json(path)
    assert camera.model == "fisheye" and camera.distortion == FISHEYE
    assert camera.K[1, 1] == pytest.approx(H / 2)
    path.write_text(json.dumps({"width": W, "height": H, "eye": [0, 0, 0], "target": [0, 0, 1],
                                "model": "equirectangular"}))
    assert np.allclose(Camera.from_json(path).K, lens.equirectangular_K(W, H))


@pytest.mark.parametrize("model, distortion, match", [
    ("opencv", (0.1, float("nan"), 0, 0), r"distortion coefficients must be finite, got \[0.1, nan"),
    ("fisheye", (0.1, 0.0, float("inf"), 0.0), r"must be finite"),
    ("opencv", (0.1, 0.2, 0.0), r"an opencv camera takes 4, 5 or 8 distortion coefficients"),
    ("fisheye", (0.1,), r"a fisheye camera takes 4 distortion coefficients \(k1 k2 k3 k4\), got 1"),
    ("pinhole", (0.1, 0, 0, 0), r"a pinhole camera takes no distortion coefficients"),
    ("orthographic", (0.0,), r"an? orthographic camera takes no distortion"),
    ("kannala", (), r"unknown camera model 'kannala'; expected one of pinhole, opencv"),
    ("opencv", "0.1 0.2", r"distortion must be a sequence of numbers"),
    ("opencv", ((0.1, 0.2), (0.0, 0.0)), r"distortion must be a flat sequence"),
    # strings and bools are refused, not converted (numpy would read '1e3' as 1000.0)
    ("fisheye", (0.0, "1e3", 0.0, 0.0), r"distortion must hold numbers only, got '1e3'"),
    ("opencv", (0.1, True, 0.0, 0.0), r"distortion must hold numbers only, got True"),
    ("opencv", np.array(["0.1", "0", "0", "0"]), r"distortion must be a sequence of numbers"),
])
def test_bad_models_and_coefficients(model, distortion, match):
    with pytest.raises(CameraError, match=match) as info:
        Camera(W, H, _K(), _pose(), model, distortion)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("model, distortion", [
    ("opencv", (-1e308, 0.0, 0.0, 0.0)), ("opencv", (0.0, -1e308, 0.0, 0.0, 1e308)),
    ("fisheye", (0.0, 0.0, 0.0, 1e308)),
])
def test_huge_coefficients_give_misses_not_warnings(model, distortion):
    """Coefficients near float64's largest overflow the monotonic radius' scan: its
    values are then not finite, the pixels misses, and numpy says nothing."""
    from kdray import lens
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        _, d, valid = lens.model_rays(model, _K(), distortion, W, H)
    assert not valid.any() and np.isnan(d).all()


@pytest.mark.parametrize("width, height", [(0, H), (W, -3), (2.5, H)])
def test_bad_sizes(width, height):
    with pytest.raises(CameraError, match="a whole number of pixels >= 1") as info:
        Camera(width, height, _K(), _pose(), "fisheye", FISHEYE)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("extra, match", [
    ({"model": 3}, r"model must be a string, got 3"),
    ({"model": "opencv", "distortion": [0.1, "x", 0, 0]}, r"distortion must be a list of numbers"),
    ({"model": "opencv", "distortion": [0.1, 0, 0]}, r"takes 4, 5 or 8"),
    ({"model": "fisheye", "distortion": [0.1, 0, 0, float("nan")]}, r"must be finite"),
    ({"model": "orthographic", "eye": [0, 0, 0], "target": [0, 0, 1]}, r"orthographic camera needs K"),
])
def test_bad_json_models(tmp_path, extra, match):
    data = {"width": W, "height": H, "K": _K().tolist(), "cam_to_world": _pose().tolist()}
    if "eye" in extra:
        del data["K"], data["cam_to_world"]
    data.update(extra)
    path = tmp_path / "c.json"
    path.write_text(json.dumps(data))
    with pytest.raises(CameraError, match=match) as info:
        Camera.from_json(path)
    assert "\n" not in str(info.value)


# Renders ---------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def room():
    """(tree, tracer): the teapot inside a closed box around the cameras, so that every
    direction hits something (a fisheye of more than 180 degrees included)."""
    from helpers import real_mesh_arrays
    from kdray.trace import Tracer
    vertices, faces = real_mesh_arrays("teapot.obj")
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    vertices = (vertices - (lo + hi) / 2) / np.abs(hi - lo).max() + [0.0, 0.0, 2.5]
    box = np.array([[x, y, z] for x in (-4, 4) for y in (-3.5, 3) for z in (-3, 6)], float)
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    box_faces = np.array([f for a, b, c, d in quads for f in ((a, b, c), (a, c, d))]) + len(vertices)
    tree = kdray.build(np.vstack([vertices, box]), np.vstack([faces, box_faces]), keep_double=True)
    return tree, Tracer(tree)


def _render_and_project(tracer, camera, precision="single"):
    images = tracer.render(camera, aovs="depth,distance,position,id", precision=precision)
    valid = images["valid"]
    hit = images["id"] != 0xFFFFFFFF
    assert np.array_equal(hit, valid)                  # the box is closed: every ray hits
    points = images["position"].reshape(-1, 3)[hit.reshape(-1)].astype(np.float64)
    return images, hit, points


@pytest.mark.parametrize("model, distortion, f", [
    ("opencv", MODERATE, 110.0), ("opencv", STRONG, 110.0), ("fisheye", FISHEYE, 70.0),
    ("fisheye", (0.01, -0.002, 0.0, 0.0), 40.0)])              # the last: 250 degrees
def test_render_hit_points_project_to_pixel_centres(room, model, distortion, f):
    tree, tracer = room
    camera = Camera(W, H, _K(f), _pose(), model, distortion)
    images, hit, points = _render_and_project(tracer, camera)
    assert hit.all()
    centres = _pixel_centres(hit)
    cam = (points - camera.eye) @ camera.rotation
    front = cam[:, 2] > 1e-3 * np.linalg.norm(cam, axis=1)
    error = np.abs(_opencv_project(camera, points[front]) - centres[front])
    assert error.max() < 5e-4, error.max()
    if not front.all():                                # behind the eye: kdray's own model
        pixels, _ = camera.project(points[~front])
        assert np.abs(pixels - centres[~front]).max() < 5e-4
    o, d = camera.rays()
    depth = images["depth"].reshape(-1).astype(np.float64)
    assert np.allclose(o + depth[:, None] * d, points, atol=1e-5)
    distance = np.linalg.norm(points - o, axis=1)
    assert np.allclose(images["distance"].reshape(-1), distance, rtol=1e-6)
    if model == "opencv":                              # depth is the z-depth
        assert np.allclose(depth, cam[:, 2], rtol=1e-6)
    else:                                              # depth is the distance
        assert np.allclose(depth, distance, rtol=1e-6)


def test_render_masks_what_has_no_ray(room):
    tree, tracer = room
    camera = Camera(W, H, _K(130.0), _pose(), "opencv", (-0.6, 0.0, 0.0, 0.0))
    images = tracer.render(camera, aovs="all")
    valid = images["valid"]
    assert valid.dtype == bool and np.array_equal(valid, camera.valid())
    assert 0.3 < valid.mean() < 0.95
    out = ~valid
    assert np.all(images["id"][out] == 0xFFFFFFFF) and np.all(images["object"][out] == 0xFFFFFFFF)
    assert np.all(images["depth"][out] == np.inf) and np.all(images["distance"][out] == np.inf)
    assert np.isnan(images["position"][out]).all()
    assert np.all(images["normal"][out] == 0) and np.all(images["bary"][out] == 0)
    assert np.all(images["id"][valid] != 0xFFFFFFFF)


def test_render_equirectangular_and_orthographic(room):
    tree, tracer = room
    camera = Camera.panorama(_pose(), W, H)
    images, hit, points = _render_and_project(tracer, camera, precision="double")
    assert hit.all() and images["depth"].dtype == np.float64
    pixels, depth = camera.project(points)
    assert np.abs(pixels - _pixel_centres(hit)).max() < 1e-6
    assert np.allclose(images["depth"].reshape(-1), depth, rtol=1e-12)
    K = np.array([[40.0, 0.0, W / 2], [0.0, 40.0, H / 2], [0.0, 0.0, 1.0]])
    camera = Camera(W, H, K, _pose(), "orthographic")
    images, hit, points = _render_and_project(tracer, camera)
    pixels, depth = camera.project(points)
    assert np.abs(pixels - _pixel_centres(hit)).max() < 1e-4
    assert np.allclose(images["depth"].reshape(-1), depth, rtol=1e-6)


@pytest.mark.parametrize("size", [1.0, 1e-4, 2.0**-50, 3e12])
def test_orthographic_render_at_any_scale(size):
    """An orthographic camera's float32 render of a sphere of any size: its pixels'
    origins are the eye + R (a, b, 0) (K^-1 (x, y, 1) = (a, b, 1)) and its depths the
    float64 render's to float32's precision. They came from eye - forward + R K^-1 (x,
    y, 1) in float32, the forward axis added and taken off again, which lost a and b
    below a unit: a sphere of 1e-4 drew its depths 2.5e-4 off, one of 2^-50 gave every
    pixel the same ray."""
    from helpers import icosphere
    v, f = icosphere(3)
    tree = kdray.build(np.asarray(v) * size, f, keep_double=True)
    tracer = kdray.Tracer(tree)
    pose = np.eye(4)
    pose[:3, :3] = np.diag([1.0, -1.0, -1.0])         # looking down -z, y up in the image
    pose[2, 3] = 3.0 * size
    K = np.array([[10.0 / size, 0.0, 16.5], [0.0, 10.0 / size, 12.0], [0.0, 0.0, 1.0]])
    camera = Camera(33, 24, K, pose, "orthographic")
    single = tracer.render(camera, aovs="depth,id")
    double = tracer.render(camera, aovs="depth,id", precision="double")
    hit = single["id"] != 0xFFFFFFFF
    assert 200 < hit.sum() < 33 * 24 and np.array_equal(hit, np.isfinite(double["depth"]))
    assert np.allclose(single["depth"][hit], double["depth"][hit], rtol=2e-6)
    o = tracer.camera_rays(camera)[0]
    x, y = np.meshgrid(np.arange(33) + 0.5, np.arange(24) + 0.5)
    want = pose[:3, 3] + np.stack([(x - 16.5) * size / 10, -(y - 12.0) * size / 10,
                                   np.zeros_like(x)], axis=-1).reshape(-1, 3)
    assert np.abs(o - want).max() < 1e-6 * size


@pytest.mark.parametrize("offset", [1e9, 1e12])
def test_orthographic_double_render_far_from_the_origin(offset):
    """precision="double" renders of an orthographic camera far from the world's origin
    keep every digit of their depths: t is taken again from the pixels' origins and the
    triangles relative to the tree's origin. From world float64 origins (the offset's
    last digits lost: 1.2e-4 at 1e12) the depths were 9e-4 off at 1e12, worse than the
    float32 render's 2e-6; against a float64 reference in the sphere's own frame."""
    from helpers import icosphere
    from kdray.reference import brute_force
    v, f = icosphere(3)
    world = np.asarray(v, dtype=np.float64) + offset
    tree = kdray.build(world, f, keep_double=True)
    tracer = kdray.Tracer(tree)
    pose = np.eye(4)
    pose[:3, :3] = np.diag([1.0, -1.0, -1.0])         # looking down -z, y up in the image
    pose[:3, 3] = offset
    pose[2, 3] += 3.0
    K = np.array([[10.0, 0.0, 16.5], [0.0, 10.0, 12.0], [0.0, 0.0, 1.0]])
    camera = Camera(33, 24, K, pose, "orthographic")
    double = tracer.render(camera, aovs="depth,id", precision="double")
    single = tracer.render(camera, aovs="depth,id")
    x, y = np.meshgrid(np.arange(33) + 0.5, np.arange(24) + 0.5)
    o = np.stack([(x - 16.5) / 10, -(y - 12.0) / 10, np.full_like(x, 3.0)], axis=-1)
    o = o.reshape(-1, 3)                                # the pixels' origins, sphere's frame
    d = np.tile([0.0, 0.0, -1.0], (len(o), 1))
    ref = brute_force((world - offset)[np.asarray(f)], o, d)
    hit = (ref.prim >= 0) & (double["id"].reshape(-1) == ref.prim)
    assert hit.sum() > 0.95 * (ref.prim >= 0).sum() > 200
    assert np.abs(double["depth"].reshape(-1)[hit] - ref.t[hit]).max() < 1e-12
    assert np.abs(single["depth"].reshape(-1)[hit] - ref.t[hit]).max() < 1e-5


def test_pinhole_render_has_no_valid_image(room):
    tree, tracer = room
    camera = Camera(W, H, _K(), _pose())
    images = tracer.render(camera, aovs="depth,id")
    assert list(images) == ["depth", "id"]


def test_valid_images_are_the_callers_own(room):
    """A render's `valid` image is a writable array of its own, like every other image:
    it was the Tracer's kept ray map's mask, read-only, shared by every render of
    that camera."""
    tree, tracer = room
    camera = Camera(W, H, _K(40.0), _pose(), "fisheye", FISHEYE)
    first = tracer.render(camera, aovs="depth")
    want = first["valid"].copy()
    assert first["valid"].flags.writeable and not want.all()
    first["valid"][:] = True                                   # the caller's to change
    again = tracer.render(camera, aovs="depth")["valid"]
    assert np.array_equal(again, want) and not np.shares_memory(again, first["valid"])


def test_cull_keeps_every_face_for_a_camera_model(room):
    tree, _ = room
    v, f = np.zeros((3, 3)), np.array([[0, 1, 2]] * 5)
    v[1, 0] = v[2, 1] = 1.0
    v += [0.0, 0.0, -10.0]                                    # behind a pinhole
    pose = np.eye(4)
    assert len(kdray.cull.cull_faces(v, f, Camera(W, H, _K(), pose))) == 0
    fisheye = Camera(W, H, _K(40.0), pose, "fisheye", (0.0, 0.0, 0.0, 0.0))
    assert np.array_equal(kdray.cull.cull_faces(v, f, fisheye), np.arange(5))


def test_exr_holds_valid_model_and_coefficients(room, tmp_path):
    import OpenImageIO as oiio
    from kdray.images import read_camera, read_exr, write_exr
    tree, tracer = room
    camera = Camera(W, H, _K(130.0), _pose(), "opencv", (-0.6, 0.0, 1e-17, 0.0, 0.01 / 3))
    images = tracer.render(camera, aovs="depth,id")
    assert not images["valid"].all()
    write_exr(tmp_path / "m.exr", images, camera)
    back = read_exr(tmp_path / "m.exr")
    assert back["valid"].dtype == bool and np.array_equal(back["valid"], images["valid"])
    assert np.array_equal(back["id"], images["id"])
    assert read_camera(tmp_path / "m.exr") == camera              # model and coefficients exact
    spec = oiio.ImageInput.open(str(tmp_path / "m.exr")).spec()
    assert spec.getattribute("kdray/cameraModel") == "opencv"
    assert json.loads(spec.getattribute("kdray/distortion")) == list(camera.distortion)
    assert spec.getattribute("worldToNDC") is None                 # a pinhole's projection
    assert "distance along" not in spec.getattribute("kdray/depth")
    assert spec.channelformats[spec.channelnames.index("valid")].basetype == oiio.UINT
    fisheye = Camera(W, H, _K(), _pose(), "fisheye", FISHEYE)
    write_exr(tmp_path / "f.exr", tracer.render(fisheye, aovs="depth"), fisheye)
    assert read_camera(tmp_path / "f.exr") == fisheye
    spec = oiio.ImageInput.open(str(tmp_path / "f.exr")).spec()
    assert spec.getattribute("kdray/depth").startswith("distance from the camera centre")
    pinhole = Camera(W, H, _K(), _pose())
    write_exr(tmp_path / "p.exr", tracer.render(pinhole, aovs="depth"), pinhole)
    spec = oiio.ImageInput.open(str(tmp_path / "p.exr")).spec()
    assert spec.getattribute("kdray/cameraModel") is None
    assert "valid" not in spec.channelnames
    assert read_camera(tmp_path / "p.exr") == pinhole
    # only the matrices written must fit float32: an eye 1e38 from the origin with a
    # focal length of 500 has a worldToNDC of -7.8e38, a pinhole's only
    pose = np.eye(4)
    pose[:3, 3] = (1e38, 0.0, 0.0)
    K = np.array([[500.0, 0, 32], [0, 500.0, 24], [0, 0, 1]])
    depth = {"depth": np.full((48, 64), np.inf, np.float32)}
    from kdray.errors import OutputError
    with pytest.raises(OutputError, match="worldToNDC matrix holds"):
        write_exr(tmp_path / "far.exr", depth, Camera(64, 48, K, pose))
    for model, distortion in (("opencv", (0.1, 0.0, 0.0, 0.0)), ("fisheye", FISHEYE),
                              ("orthographic", ())):
        far = Camera(64, 48, K, pose, model, distortion)
        write_exr(tmp_path / "far.exr", depth, far)
        assert read_camera(tmp_path / "far.exr") == far


def test_tracer_camera_rays_are_the_renders(room):
    tree, tracer = room
    camera = Camera(W, H, _K(130.0), _pose(), "opencv", (-0.6, 0.0, 1e-3, 0.0))
    images = tracer.render(camera, aovs="depth,id")
    hits = tracer.trace(*tracer.camera_rays(camera))
    assert np.array_equal(hits.prim.reshape(H, W), images["id"])
    assert np.array_equal(hits.t.reshape(H, W), images["depth"])


def test_opencv_strong_barrel_inverts_every_pixel_inside_its_limit():
    # strong barrel distortion: r / rd grows fast towards the monotonic limit; every
    # pixel inside it is found, to the tolerance, and none outside
    k1 = -0.25
    camera = Camera(W, H, _K(60.0), np.eye(4), "opencv", (k1, 0.0, 0.0, 0.0))
    o, d, valid = camera.rays(valid=True)
    r_max = math.sqrt(-1.0 / (3.0 * k1))
    a, b = lens.pixel_points(camera.K, W, H)
    rd = np.hypot(a, b)
    expected = rd < r_max * (1 + k1 * r_max**2)
    assert np.array_equal(valid, expected) and 0.3 < valid.mean() < 0.99
    x, y = d[valid, 0], d[valid, 1]
    r = np.hypot(x, y)
    assert np.abs(r * (1 + k1 * r**2) - rd[valid]).max() < 1e-12


@pytest.mark.parametrize("distortion, width, height, f", [
    ((-0.3, 0.043, 0.001, 0.0005, 0.0), 256, 192, 155.0),    # radial: increasing everywhere
    ((-0.45, 0.0, -0.014, 0.002), 64, 48, 44.0),              # folds at 0.8607
])
def test_opencv_tangential_keeps_every_pixel_with_a_point_inside_the_fold(
        distortion, width, height, f):
    """A pixel has a ray wherever its undistorted point lies inside the radius where the
    radial distortion stops growing, also where the tangential part takes that point
    beyond the inversion's search bracket (a map increasing everywhere, whose bracket
    ends where it passes the corner's radius) or the pixel beyond the radial map's
    largest value: an independent Newton iteration finds each such pixel's point, and
    kdray's ray is that point (cv2.projectPoints lands it on the pixel's centre)."""
    k1, k2, p1, p2 = distortion[:4]
    K = np.array([[f, 0.0, width / 2], [0.0, f, height / 2], [0.0, 0.0, 1.0]])
    camera = Camera(width, height, K, np.eye(4), "opencv", distortion)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        o, d, valid = camera.rays(valid=True)
    g = np.polynomial.Polynomial([0, 1, 0, k1, 0, k2])            # r (1 + k1 r^2 + k2 r^4)
    fold = min([r.real for r in g.deriv().roots() if abs(r.imag) < 1e-12 and r.real > 0],
               default=np.inf)

    def distort(x, y):
        r2 = x * x + y * y
        radial = 1 + k1 * r2 + k2 * r2 * r2
        return (x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x),
                y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y)

    def jacobian(x, y, h=1e-7):
        (ax, ay), (bx, by) = distort(x + h, y), distort(x - h, y)
        (cx, cy), (dx, dy) = distort(x, y + h), distort(x, y - h)
        return (ax - bx) / (2 * h), (cx - dx) / (2 * h), (ay - by) / (2 * h), (cy - dy) / (2 * h)

    jj, ii = np.mgrid[0:height, 0:width]
    a, b = (ii.ravel() + 0.5 - K[0, 2]) / f, (jj.ravel() + 0.5 - K[1, 2]) / f
    x, y = a.copy(), b.copy()
    with np.errstate(all="ignore"):
        for _ in range(100):
            fx, fy = distort(x, y)
            j00, j01, j10, j11 = jacobian(x, y)
            det = j00 * j11 - j01 * j10
            x, y = (x - (j11 * (fx - a) - j01 * (fy - b)) / det,
                    y - (j00 * (fy - b) - j10 * (fx - a)) / det)
        fx, fy = distort(x, y)
        j00, j01, j10, j11 = jacobian(x, y)
    found = ((np.hypot(fx - a, fy - b) < 1e-12 * (1 + np.hypot(a, b)))
             & (j00 * j11 - j01 * j10 > 0) & (np.hypot(x, y) < fold))
    assert found.sum() > 0.5 * found.size
    assert not (found & ~valid).any()
    assert np.allclose(d[found, :2], np.stack([x, y], 1)[found], rtol=0, atol=1e-10)
    pixels, _ = cv2.projectPoints(d[valid].reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K,
                                  np.array(distortion))
    centres = np.stack([ii.ravel() + 0.5, jj.ravel() + 0.5], 1)[valid]
    assert np.abs(pixels.reshape(-1, 2) - centres).max() < 1e-8


@pytest.mark.parametrize("model, distortion, f", [("opencv", MODERATE, 110.0),
                                                  ("fisheye", FISHEYE, 70.0),
                                                  ("equirectangular", (), None)])
def test_models_at_any_offset_and_scale(room, model, distortion, f):
    """The room moved 3e6 from the world origin, and scaled by 2^70: the same hits,
    depths as accurate relative to the scene, and (opencv, fisheye) hit points (from
    the depth) that project back onto their pixel centres there too."""
    from kdray.trace import Tracer
    tree, tracer = room
    v = tree.triangles64.reshape(-1, 3)
    faces = np.arange(len(v)).reshape(-1, 3)
    K = lens.equirectangular_K(W, H) if model == "equirectangular" else _K(f)
    pose = _pose()
    base = tracer.render(Camera(W, H, K, pose, model, distortion), "depth,id,position")
    for shift, scale in ((np.array([3e6, -2e6, 1e6]), 1.0), (np.zeros(3), 2.0 ** 70)):
        moved = kdray.build(v * scale + shift, faces)
        p = pose.copy()
        p[:3, 3] = p[:3, 3] * scale + shift
        camera = Camera(W, H, K, p, model, distortion)
        images = Tracer(moved).render(camera, "depth,id,position")
        same = images["id"] == base["id"]
        assert same.mean() > 0.995 and np.array_equal(images["valid"], base["valid"])
        rel = np.abs(images["depth"][same] / scale - base["depth"][same]) / base["depth"][same]
        assert rel.max() < 2e-6, rel.max()
        if model != "equirectangular":
            # hit points in float64 from the float32 depth (the float32 `position` of a
            # point 3e6 from the origin is rounded to 0.25)
            hit = (images["id"] != 0xFFFFFFFF).reshape(-1)
            o, d = camera.rays()
            points = o[hit] + images["depth"].reshape(-1)[hit, None].astype(np.float64) * d[hit]
            cam = (points - camera.eye) @ camera.rotation
            front = cam[:, 2] > 1e-3 * np.linalg.norm(cam, axis=1)
            error = np.abs(_opencv_project(camera, points[front]) - _pixel_centres(hit)[front])
            assert error.max() < 5e-4, error.max()


def test_opencv_tangential_pixel_started_by_a_pole():
    """A pixel of a rational model with strong tangential terms whose radial start lies
    by the rational part's pole, from where the plain 2D Newton iteration did not come
    back (it was marked as having no ray): its point exists inside the monotonic limit
    with a positive Jacobian, and the ray lands on the pixel's centre (cv2)."""
    K = np.array([[4.232683194697468, 0.0, 7.787741417357325],
                  [0.0, 3.6000978948369675, 0.10211359096307993], [0.0, 0.0, 1.0]])
    dist = [0.16867770845857036, -0.05897077463538707, -0.04117635286066404,
            -0.05433603942805479, -0.06255656481057915, 0.42064369202110313,
            -0.09165392346644177, -0.10095228967708235]
    w, h = 15, 20
    cam = Camera(w, h, K, np.eye(4), "opencv", dist)
    _, d, valid = cam.rays(valid=True)
    k = 0 * w + 13
    assert valid[k]
    pixel, _ = cv2.projectPoints(d[k][None], np.zeros(3), np.zeros(3), K, np.array(dist))
    np.testing.assert_allclose(pixel.ravel(), [13.5, 0.5], atol=1e-9)
    ok = np.flatnonzero(valid)
    pixels, _ = cv2.projectPoints(d[ok], np.zeros(3), np.zeros(3), K, np.array(dist))
    centres = np.stack([ok % w + 0.5, ok // w + 0.5], axis=1)
    np.testing.assert_allclose(pixels.reshape(-1, 2), centres, atol=1e-6)


def test_equirectangular_with_skew_projects_its_own_rays_home():
    """With skew the image's left edge moves with the row: every pixel's own ray
    projects onto its centre (a turn away before, for some)."""
    w, h = 64, 32
    K = lens.equirectangular_K(w, h)
    K[0, 1] = 3.0
    cam = Camera(w, h, K, np.eye(4), "equirectangular")
    o, d, valid = cam.rays(valid=True)
    pixels, _ = cam.project(o[valid] + d[valid])
    k = np.flatnonzero(valid)
    np.testing.assert_allclose(pixels, np.stack([k % w + 0.5, k // w + 0.5], axis=1), atol=1e-9)


@pytest.mark.parametrize("points", [[["1", "2", "3"]], [[True, False, True]], "abc",
                                    [1.0, 2.0], np.ones((2, 2, 3)), [[1, 2, 3], [4, 5]]])
def test_project_refuses_what_is_not_points(points):
    """Camera.project takes (n, 3) or (3,) numbers; strings and bools are refused, not
    converted, and other shapes are a CameraError, not numpy's ValueError."""
    cam = Camera(10, 10, [[10, 0, 5], [0, 10, 5], [0, 0, 1]], np.eye(4))
    with pytest.raises(CameraError, match="points to project"):
        cam.project(points)
    pixels, depth = cam.project([0, 0, 1])
    assert pixels.tolist() == [[5.0, 5.0]] and depth.tolist() == [1.0]


@pytest.mark.parametrize("model, distortion, aovs, precision", [
    ("opencv", MODERATE, ("depth",), "single"),
    ("fisheye", FISHEYE, ("depth",), "single"),
    ("equirectangular", (), ("depth",), "single"),
    ("pinhole", (), ("object",), "single"),
    ("fisheye", FISHEYE, ("depth",), "double"),
    ("orthographic", (), ("depth",), "double"),
])
def test_render_memory_check_covers_what_it_takes(room, monkeypatch, model, distortion,
                                                  aovs, precision):
    """The host memory a render checks before its large arrays covers what numpy then
    allocates (tracemalloc's peak): a camera model's ray map, an object image's ids,
    a model's double hits. The check counted 8 bytes a pixel where these took 43 to
    204 (the audit's figures at 1536 x 1024)."""
    import tracemalloc
    from kdray import trace as _trace
    _, tracer = room
    w, h = 640, 480 + len(aovs) + len(distortion)       # a size whose map is not kept
    K = (lens.equirectangular_K(w, h) if model == "equirectangular" else
         np.array([[w / 3, 0, w / 2], [0, w / 3, h / 2], [0, 0, 1.0]]))
    camera = Camera(w, h, K, _pose(), model, distortion)
    checked = []
    real = _trace.check_host_memory
    monkeypatch.setattr(_trace, "check_host_memory",
                        lambda n, *a, **k: (checked.append(n), real(n, *a, **k))[1])
    tracemalloc.start()
    start = tracemalloc.get_traced_memory()[0]
    tracer.render(camera, aovs, precision)
    peak = tracemalloc.get_traced_memory()[1] - start
    tracemalloc.stop()
    # the double path's float64 work is done CHUNK pixels at a time: a fixed part
    from kdray.double import CHUNK
    fixed = 200 * CHUNK if precision == "double" else 0
    assert peak <= max(checked) + fixed
