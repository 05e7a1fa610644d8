"""kdray.camera_files: nerfstudio transforms.json, COLMAP text models and JSON lists of
kdray cameras -> named views. Expected poses and rays are written out by hand (or from
nerfstudio's and COLMAP's own formulas), not taken from the module."""
import json
import math

import numpy as np
import pytest

from kdray import camera_files
from kdray.camera import Camera
from kdray.camera_files import MAX_SIDE, MAX_VIEWS, View, read_cameras
from kdray.errors import CameraError

C45 = math.cos(math.pi / 4)  # = sin(45 degrees)
IDENTITY = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]


def write(tmp_path, data, name="transforms.json"):
    path = tmp_path / name
    path.write_text(data if isinstance(data, str) else json.dumps(data), encoding="utf-8")
    return path


def transforms(frames, **top):
    """A nerfstudio transforms.json: 64 x 48, f 100, principal point at the centre."""
    meta = {"fl_x": 100.0, "fl_y": 100.0, "cx": 32.0, "cy": 24.0, "w": 64, "h": 48}
    meta.update(top)
    return {key: value for key, value in meta.items() if value is not None} | {"frames": frames}


def frame(file_path="images/frame_00000.png", matrix=IDENTITY, **keys):
    return {"file_path": file_path, "transform_matrix": matrix, **keys}


def colmap(tmp_path, cameras, images, folder="sparse"):
    root = tmp_path / folder
    root.mkdir()
    (root / "cameras.txt").write_text(cameras, encoding="utf-8")
    (root / "images.txt").write_text(images, encoding="utf-8")
    return root


CAMERAS_TXT = """# Camera list with one line of data per camera:
#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]
1 PINHOLE 64 48 100 110 32 24
2 SIMPLE_PINHOLE 40 30 50 20 15
3 SIMPLE_RADIAL 64 48 100 32 24 0.01
4 THIN_PRISM_FISHEYE 64 48 100 100 32 24 0 0 0 0 0 0 0 0 0 0 0 0
"""


def image_line(name, camera_id=1, q=(1, 0, 0, 0), t=(0, 0, 0), image_id=1):
    return " ".join(str(v) for v in (image_id, *q, *t, camera_id, name))


def error(path):
    """read_cameras(path)'s CameraError message: one line naming the file."""
    with pytest.raises(CameraError) as info:
        read_cameras(path)
    message = str(info.value)
    assert "\n" not in message and str(path) in message
    return message


# nerfstudio ---------------------------------------------------------------------------


def test_nerfstudio_opengl_pose_becomes_opencv(tmp_path):
    # OpenGL pose: a 90 degree turn about y (camera x -> world -z, camera y (up) -> world
    # +y, camera z (back) -> world +x), eye at (1, 2, 3). The camera looks along world -x.
    gl = [[0, 0, 1, 1], [0, 1, 0, 2], [-1, 0, 0, 3], [0, 0, 0, 1]]
    views = read_cameras(write(tmp_path, transforms([frame("images/frame_00012.png", gl)])))
    assert len(views) == 1 and isinstance(views[0], View)
    view = views[0]
    assert view.name == "frame_00012"
    # OpenCV: x right = world -z, y down = world -y, z forward = world -x.
    expected = [[0, 0, -1, 1], [0, -1, 0, 2], [-1, 0, 0, 3], [0, 0, 0, 1]]
    np.testing.assert_array_equal(view.camera.cam_to_world, expected)
    np.testing.assert_array_equal(view.camera.K, [[100, 0, 32], [0, 100, 24], [0, 0, 1]])
    assert (view.camera.width, view.camera.height) == (64, 48)
    # A point 5 ahead is at the principal point; one above it (world +y) is higher up
    # in the image (smaller row); one to the world -z side is to the right.
    pixels, depth = view.camera.project([[-4, 2, 3], [-4, 3, 3], [-4, 2, 2]])
    np.testing.assert_allclose(pixels, [[32, 24], [32, 4], [52, 24]], atol=1e-12)
    np.testing.assert_allclose(depth, [5, 5, 5], atol=1e-12)


def test_nerfstudio_pixel_rays_are_nerfstudios(tmp_path):
    # nerfstudio samples pixel (i, j) at (i + 0.5, j + 0.5) and its ray in OpenGL camera
    # axes is ((x - cx) / fx, -(y - cy) / fy, -1); with the identity pose these are world.
    fx, fy, cx, cy, w, h = 2.0, 4.0, 2.0, 1.0, 4, 2
    path = write(tmp_path, transforms([frame()], fl_x=fx, fl_y=fy, cx=cx, cy=cy, w=w, h=h))
    camera = read_cameras(path)[0].camera
    origins, directions = camera.rays()
    expected = [((i + 0.5 - cx) / fx, -(j + 0.5 - cy) / fy, -1.0) for j in range(h) for i in range(w)]
    np.testing.assert_allclose(directions, expected, rtol=0, atol=1e-15)
    np.testing.assert_array_equal(origins, np.zeros((w * h, 3)))
    # Pixel (0, 0) in kdray's (OpenCV) camera axes: ((0.5 - cx) / fx, (0.5 - cy) / fy, 1).
    np.testing.assert_allclose(camera.rotation.T @ directions[0], [-0.75, -0.125, 1.0], atol=1e-15)


def test_nerfstudio_per_frame_overrides(tmp_path):
    frames = [
        frame("a.png"),                                       # all top level
        frame("b.png", fl_x=200.0),                           # fl_y follows the frame's fl_x
        frame("c.png", w=32, h=16, cx=16.0, cy=8.0, fl_y=50.0),
    ]
    views = read_cameras(write(tmp_path, transforms(frames, fl_y=None)))
    assert [v.name for v in views] == ["a", "b", "c"]
    np.testing.assert_array_equal(views[0].camera.K, [[100, 0, 32], [0, 100, 24], [0, 0, 1]])
    np.testing.assert_array_equal(views[1].camera.K, [[200, 0, 32], [0, 200, 24], [0, 0, 1]])
    np.testing.assert_array_equal(views[2].camera.K, [[100, 0, 16], [0, 50, 8], [0, 0, 1]])
    assert [(v.camera.width, v.camera.height) for v in views] == [(64, 48), (64, 48), (32, 16)]


def test_nerf_fields_of_view(tmp_path):
    """NeRF's and instant-ngp's form: camera_angle_x (and camera_angle_y), radians
    across the image, for fl_x = w / 2 / tan(angle / 2) (fl_y from camera_angle_y,
    else fl_x), the principal point the image's centre unless given; a file without
    its image size (NeRF's synthetic scenes) is told so."""
    a = 0.6911112070083618                                  # NeRF synthetic's lego
    f = 0.5 * 800 / math.tan(0.5 * a)
    meta = {"camera_angle_x": a, "w": 800, "h": 600, "frames": [frame("./train/r_0")]}
    (view,) = read_cameras(write(tmp_path, meta))
    assert view.name == "r_0"
    np.testing.assert_allclose(view.camera.K, [[f, 0, 400], [0, f, 300], [0, 0, 1]], rtol=1e-15)
    b = 0.5
    both = dict(meta, camera_angle_y=b, cx=410.0)
    (view,) = read_cameras(write(tmp_path, both, "b.json"))
    np.testing.assert_allclose(view.camera.K, [[f, 0, 410], [0, 300 / math.tan(0.25), 300],
                                               [0, 0, 1]], rtol=1e-15)
    given = dict(meta, fl_x=500.0, cx=1.0, cy=2.0)          # fl_x wins over the angle
    (view,) = read_cameras(write(tmp_path, given, "c.json"))
    np.testing.assert_array_equal(view.camera.K, [[500, 0, 1], [0, 500, 2], [0, 0, 1]])
    sizeless = {"camera_angle_x": a, "frames": [frame("./train/r_0")]}
    assert "missing 'w' and 'h': a file with camera_angle_x" in error(
        write(tmp_path, sizeless, "d.json"))
    assert "camera_angle_x must be below pi radians" in error(
        write(tmp_path, dict(meta, camera_angle_x=3.5), "e.json"))


def test_nerfstudio_frame_model_applies(tmp_path):
    """A frame's camera_model is the one that applies: a supported one under an
    unsupported top-level one renders; an unsupported one in a frame is refused."""
    (view,) = read_cameras(write(tmp_path, transforms([frame("a.png", camera_model="PINHOLE")],
                                                      camera_model="FISHEYE624")))
    assert view.camera.model == "pinhole"
    assert "camera model FISHEYE624 is not supported" in error(write(tmp_path, transforms(
        [frame("a.png", camera_model="FISHEYE624")]), "b.json"))


def test_nerfstudio_intrinsics_only_per_frame_and_top_level_fl_y(tmp_path):
    frames = [frame("a.png", fl_x=10.0, cx=5.0, cy=4.0, w=10, h=8),
              frame("b.png", fl_x=20.0, fl_y=30.0, cx=6.0, cy=7.0, w=12, h=14)]
    meta = {"frames": frames}
    views = read_cameras(write(tmp_path, meta))
    np.testing.assert_array_equal(views[0].camera.K, [[10, 0, 5], [0, 10, 4], [0, 0, 1]])
    np.testing.assert_array_equal(views[1].camera.K, [[20, 0, 6], [0, 30, 7], [0, 0, 1]])
    # A top-level fl_y stays when a frame overrides only fl_x.
    views = read_cameras(write(tmp_path, transforms([frame(fl_x=300.0)], fl_y=40.0), "b.json"))
    np.testing.assert_array_equal(views[0].camera.K, [[300, 0, 32], [0, 40, 24], [0, 0, 1]])


def test_nerfstudio_tolerates_its_other_keys_and_forms(tmp_path):
    gl = [[1, 0, 0, 0.5], [0, 1, 0, -1], [0, 0, 1, 2]]  # 3x4: [0, 0, 0, 1] implied
    frames = [frame("images/frame_00001.jpg", gl, mask_path="masks/frame_00001.png",
                    depth_file_path="depth/frame_00001.png", colmap_im_id=4)]
    meta = transforms(frames, w=64.0, h=48.0, camera_model="OPENCV", k1=0.0, k2=0, p1=0, p2=0.0,
                      aabb_scale=16, ply_file_path="sparse_pc.ply", applied_scale=1.0,
                      applied_transform=[[1, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, 0]],
                      distortion_params=[0, 0, 0, 0, 0, 0])
    camera = read_cameras(write(tmp_path, meta))[0].camera
    np.testing.assert_array_equal(camera.cam_to_world,
                                  [[1, 0, 0, 0.5], [0, -1, 0, -1], [0, 0, -1, 2], [0, 0, 0, 1]])
    assert (camera.width, camera.height) == (64, 48)
    for model in ("PINHOLE", "SIMPLE_PINHOLE", "OPENCV"):
        path = write(tmp_path, transforms([frame(camera_model=model)], camera_model=model), "m.json")
        assert read_cameras(path)[0].camera.width == 64


@pytest.mark.parametrize("top, per_frame, match", [
    ({"camera_model": "FISHEYE624"}, {},
     r": frame frame_00012: camera model FISHEYE624 is not supported yet "
     r"\(kdray renders pinhole, OpenCV, OpenCV fisheye and equirectangular cameras\)\.$"),
    ({}, {"camera_model": "VR180_L"}, r"frame frame_00012: camera model VR180_L is not"),
    ({"camera_model": "OPENCV", "k4": 0.01}, {},
     r"frame frame_00012: top-level distortion coefficient k4 = 0.01 is not zero: camera model "
     r"OPENCV's k4 \(nerfstudio's r\^8 term\) is not in OpenCV's model"),
    ({"camera_model": "OPENCV_FISHEYE"}, {"p2": -1e-9},
     r"frame frame_00012: distortion coefficient p2 = -1e-09 is not zero: OpenCV's fisheye model"),
    ({"camera_model": "EQUIRECTANGULAR"}, {"k1": 0.5},
     r"distortion coefficient k1 = 0.5 is not zero: an equirectangular camera has no distortion"),
    ({"distortion_params": [0, 0, 0, 0.2, 0, 0]}, {}, r"distortion_params k4 = 0.2 is not zero"),
    ({"distortion_params": [0, 0]}, {}, r"distortion_params must be a list of 6 numbers"),
    ({}, {"k1": "0.1"}, r"k1 must be a number, got '0.1'"),
    ({}, {"k1": float("nan")}, r"k1 must be finite, got nan"),
    ({"is_fisheye": True}, {}, r"top-level is_fisheye is set: instant-ngp's fisheye camera is not"),
    ({"camera_model": 7}, {}, r"top-level camera_model must be a string, got 7"),
])
def test_nerfstudio_refuses_what_is_not_a_pinhole(tmp_path, top, per_frame, match):
    path = write(tmp_path, transforms([frame("images/frame_00012.png", **per_frame)], **top))
    assert pytest.raises(CameraError, read_cameras, path).match(match)


@pytest.mark.parametrize("top, per_frame, match", [
    ({"fl_x": None, "fl_y": None}, {}, r"frame frame_00012: missing 'fl_x' or camera_angle_x \(give it at the top level or in the frame\)"),
    ({"cx": None}, {}, r"frame frame_00012: missing 'cx'"),
    ({"h": None}, {}, r"frame frame_00012: missing 'h'"),
    ({}, {"transform_matrix": None}, r"frame frame_00012: missing 'transform_matrix'\.$"),
    ({}, {"transform_matrix": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}, r"must be a 4x4 \(or 3x4\)"),
    ({}, {"transform_matrix": [[1, 0, 0, True]] * 4}, r"must be a 4x4 \(or 3x4\) array of numbers"),
    ({"fl_x": 0}, {}, r"frame frame_00012: top-level fl_x must be positive, got 0.0"),
    ({}, {"fl_y": -5}, r"fl_y must be positive, got -5.0"),
    ({"cx": "32"}, {}, r"top-level cx must be a number, got '32'"),
    ({}, {"cy": float("nan")}, r"frame frame_00012: cy must be finite, got nan"),
    ({"w": 0}, {}, r"top-level w must be a whole number of pixels from 1 to 65536 \(MAX_SIDE\), got 0"),
    ({}, {"h": -4}, r"frame frame_00012: h must be a whole number of pixels .* got -4"),
    ({}, {"w": 64.5}, r"w must be a whole number of pixels .* got 64.5"),
    ({}, {"w": MAX_SIDE + 1}, r"w must be a whole number of pixels from 1 to 65536 \(MAX_SIDE\), got 65537"),
    ({}, {"h": 10**30}, r"h must be a whole number of pixels .* got 1000000000000000000000000000000"),
    ({}, {"w": True}, r"w must be a whole number of pixels .* got True"),
    ({}, {"w": "64"}, r"w must be a whole number of pixels .* got '64'"),
])
def test_nerfstudio_bad_fields(tmp_path, top, per_frame, match):
    f = frame("images/frame_00012.png")
    f.update(per_frame)
    f = {k: v for k, v in f.items() if v is not None}
    path = write(tmp_path, transforms([f], **top))
    assert pytest.raises(CameraError, read_cameras, path).match(match)
    error(path)


def test_nerfstudio_nan_and_infinity_are_refused(tmp_path):
    gl = [[1, 0, 0, float("nan")], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]
    path = write(tmp_path, transforms([frame("x.png", gl)]))  # json.dumps writes NaN
    assert "NaN" in path.read_text()
    assert "frame x: transform_matrix must be finite" in error(path)
    text = json.dumps(transforms([frame("x.png")])).replace('"fl_x": 100.0', '"fl_x": Infinity')
    assert "frame x: top-level fl_x must be finite, got inf" in error(write(tmp_path, text))
    text = json.dumps(transforms([frame("x.png")])).replace('"cx": 32.0', '"cx": 1e999')
    assert "frame x: top-level cx must be finite, got inf" in error(write(tmp_path, text))


@pytest.mark.parametrize("rotation, lengths", [
    ([[2, 0, 0], [0, 2, 0], [0, 0, 2]], "2, 2, 2"),            # a scale folded into the pose
    ([[0, 0, 0], [0, 0, 0], [0, 0, 0]], "0, 0, 0"),            # singular
    ([[1, 0.5, 0], [0, 1, 0], [0, 0, 1]], "1, 1.11803, 1"),    # sheared
    ([[-1, 0, 0], [0, 1, 0], [0, 0, 1]], "1, 1, 1"),           # a reflection
])
def test_nerfstudio_non_rigid_pose(tmp_path, rotation, lengths):
    gl = [row + [t] for row, t in zip(rotation, (1, 2, 3))] + [[0, 0, 0, 1]]
    message = error(write(tmp_path, transforms([frame("images/frame_00003.png", gl)])))
    assert ": frame frame_00003: the rotation part of transform_matrix must be orthonormal" in message
    assert f"columns have lengths {lengths}: a scale folded into the pose (common in nerfstudio" in message


def test_nerfstudio_bad_last_row(tmp_path):
    gl = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 1, 1]]
    message = error(write(tmp_path, transforms([frame("a.png", gl)])))
    assert message.endswith("frame a: transform_matrix must have last row [0, 0, 0, 1], "
                            "got [0.0, 0.0, 1.0, 1.0].")


def test_nerfstudio_bad_frames(tmp_path):
    def message(frames, **top):
        return error(write(tmp_path, transforms(frames, **top)))

    assert 'transforms.json: "frames" must be a list of frame objects, got a JSON object.' in message({})
    assert message([]).endswith("transforms.json names no views.")
    assert message([frame(), 3]).endswith("frames[1]: expected a frame object, got a JSON number.")
    assert message([{"transform_matrix": IDENTITY}]).endswith("frames[0]: missing 'file_path'.")
    assert message([frame(["a.png"])]).endswith("frames[0]: file_path must be a string, got ['a.png'].")
    assert message([frame("img.png", None)]).endswith(
        "frame img: transform_matrix must be a 4x4 (or 3x4) array of numbers.")
    no_matrix = {"file_path": "img.png"}
    assert message([no_matrix]).endswith("frame img: missing 'transform_matrix'.")


def test_nerfstudio_names(tmp_path):
    frames = [frame("images/frame_00001.png"), frame("frame_00002"), frame("a.b.c.jpg"),
              frame("images\\sub\\frame_00003.png"), frame("./x/.hidden")]
    views = read_cameras(write(tmp_path, transforms(frames)))
    assert [v.name for v in views] == ["frame_00001", "frame_00002", "a.b.c", "frame_00003", ".hidden"]


def test_nerfstudio_duplicate_names(tmp_path):
    frames = [frame("images/a/frame_00001.png"), frame("images/b.png"), frame("images/b/frame_00001.jpg")]
    message = error(write(tmp_path, transforms(frames)))
    assert message.endswith(
        "transforms.json: frames[0] ('images/a/frame_00001.png') and frames[2] "
        "('images/b/frame_00001.jpg') have the same name 'frame_00001'; each view is written "
        "to <name>.exr, so names must differ (ignoring case).")
    message = error(write(tmp_path, transforms([frame("Frame.png"), frame("x/frame.png")])))
    assert "frames[0] ('Frame.png') and frames[1] ('x/frame.png') have names that differ only in case" in message


@pytest.mark.parametrize("file_path, why", [
    ("", r"'' cannot be a file name \(<name>.exr\): it is not a file name"),
    ("images/..", r"'..' cannot be a file name"),
    ("a\0b.png", r"it contains NUL"),
    ("a\nb.png", r"it contains the control character U\+000A"),
    ("a\u2028b.png", r"it contains the line separator U\+2028"),
    ("a\ud800b.png", r"it contains the lone surrogate U\+D800"),
    # the longest name written is the temporary .<name>.exr.<8 hex>.tmp (kdray.files)
    ("x" * 238 + ".png", r"it is too long: its temporary file's name \(.NAME.<8 hex>.tmp\) "
                         r"would be 256 bytes, more than the 255"),
])
def test_nerfstudio_unsafe_names(tmp_path, file_path, why):
    path = write(tmp_path, transforms([frame("ok.png"), frame(file_path)]))
    assert pytest.raises(CameraError, read_cameras, path).match(r": frames\[1\] \(file_path .*\): the view name .*" + why)
    error(path)
    read_cameras(write(tmp_path, transforms([frame("x" * 237 + ".png")]), "ok.json"))  # 255 bytes


def test_windows_refuses_colons(tmp_path, monkeypatch):
    path = write(tmp_path, transforms([frame("images/12:30:01.png")]))
    assert read_cameras(path)[0].name == "12:30:01"
    monkeypatch.setattr(camera_files, "_WINDOWS", True)
    assert "it contains ':' (on Windows a drive or a stream)" in error(path)


# COLMAP -------------------------------------------------------------------------------


def test_colmap_pose_from_quaternion(tmp_path):
    # q = (cos 45, 0, sin 45, 0): 90 degrees about y, R = [[0, 0, 1], [0, 1, 0], [-1, 0, 0]]
    # (world -> camera). t = (1, 2, 3). cam_to_world's rotation is R^T = [[0, 0, -1],
    # [0, 1, 0], [1, 0, 0]] and the centre -R^T t = -(-3, 2, 1) = (3, -2, -1).
    images = ("# Image list with two lines of data per image:\n"
              "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n"
              "#   POINTS2D[] as (X, Y, POINT3D_ID)\n"
              f"{image_line('images/frame_00012.png', 1, (C45, 0, C45, 0), (1, 2, 3), 7)}\n"
              "10.5 20.25 -1 30 40.5 12\n")
    root = colmap(tmp_path, CAMERAS_TXT, images)
    views = read_cameras(root)
    assert [v.name for v in views] == ["frame_00012"]
    camera = views[0].camera
    np.testing.assert_allclose(camera.rotation, [[0, 0, -1], [0, 1, 0], [1, 0, 0]], atol=1e-15)
    np.testing.assert_allclose(camera.eye, [3, -2, -1], atol=1e-15)
    np.testing.assert_array_equal(camera.K, [[100, 0, 32], [0, 110, 24], [0, 0, 1]])
    assert (camera.width, camera.height) == (64, 48)
    # x_cam = R x_world + t: world (-2, -2, -1) -> (-1, -2, 2) + (1, 2, 3) = (0, 0, 5), the
    # principal point at depth 5; world (-2, -2, -2) -> (-2, -2, 2) + (1, 2, 3) = (-1, 0, 5),
    # at pixel x = 32 + 100 * (-1 / 5) = 12.
    pixels, depth = camera.project([[-2, -2, -1], [-2, -2, -2]])
    np.testing.assert_allclose(pixels, [[32, 24], [12, 24]], atol=1e-12)
    np.testing.assert_allclose(depth, [5, 5], atol=1e-12)
    # The model folder, its cameras.txt and its images.txt all read the same.
    for path in (root / "cameras.txt", root / "images.txt", str(root)):
        assert read_cameras(path) == views


def test_colmap_pixel_centres_simple_pinhole_and_empty_points_lines(tmp_path):
    # SIMPLE_PINHOLE f cx cy: K = [[f, 0, cx], [0, f, cy], [0, 0, 1]].
    cameras = "7 SIMPLE_PINHOLE 4 2 2 2 1\n\n2 PINHOLE 40 30 50 60 20 15\n"
    images = ("\n# comment\n"
              f"{image_line('b.jpg', 7)}\n"
              "\n"                                  # image b has no 2D points
              f"{image_line('a.jpg', 2, (1, 0, 0, 0), (0, 0, 0), 9)}\n"
              "1 2 -1\n"
              f"{image_line('c.jpg', 7, (-1, 0, 0, 0), (0, 0, 1), 3)}\n")   # -q is the same rotation
    views = read_cameras(colmap(tmp_path, cameras, images))
    assert [v.name for v in views] == ["b", "a", "c"]   # the file's order
    b, a, c = (v.camera for v in views)
    np.testing.assert_array_equal(b.K, [[2, 0, 2], [0, 2, 1], [0, 0, 1]])
    np.testing.assert_array_equal(a.K, [[50, 0, 20], [0, 60, 15], [0, 0, 1]])
    np.testing.assert_array_equal(b.cam_to_world, IDENTITY)
    np.testing.assert_array_equal(c.eye, [0, 0, -1])
    # Pixel (0, 0)'s ray: ((0.5 - cx) / fx, (0.5 - cy) / fy, 1), camera = world axes here.
    _, directions = b.rays()
    np.testing.assert_allclose(directions[0], [(0.5 - 2) / 2, (0.5 - 1) / 2, 1], atol=1e-15)
    np.testing.assert_allclose(directions[7], [(3.5 - 2) / 2, (1.5 - 1) / 2, 1], atol=1e-15)


def test_colmap_quaternion_is_normalized(tmp_path):
    q = (2 * C45 * 1.0005, 0, 2 * C45 * 1.0005, 0)  # norm 2.001: refused
    root = colmap(tmp_path, CAMERAS_TXT, image_line("x.png", q=q) + "\n\n")
    assert "quaternion (QW QX QY QZ)" in error(root / "images.txt")
    q = (C45 * 1.0005, 0, C45 * 1.0005, 0)          # norm 1.0005: normalized
    root = colmap(tmp_path, CAMERAS_TXT, image_line("x.png", q=q) + "\n\n", "ok")
    np.testing.assert_allclose(read_cameras(root)[0].camera.rotation,
                               [[0, 0, -1], [0, 1, 0], [1, 0, 0]], atol=1e-15)


@pytest.mark.parametrize("line, match", [
    (image_line("images/frame_00012.png", 4),
     r"images.txt: line 2: image frame_00012: camera model THIN_PRISM_FISHEYE of camera 4 "
     r"\(cameras.txt line 6\) is not supported yet \(kdray renders pinhole, OpenCV, OpenCV "
     r"fisheye and equirectangular cameras\)\.$"),
    (image_line("f.png", 5), r"line 2: image f: camera 5 is not in .*cameras.txt\.$"),
    (image_line("f.png", q=(0, 0, 0, 0)), r"line 2: image f: the quaternion \(QW QX QY QZ\) = "
     r"\(0.0, 0.0, 0.0, 0.0\) has norm 0; a rotation's is 1 \(to 0.001\)\.$"),
    (image_line("f.png", q=(1.01, 0, 0, 0)), r"image f: the quaternion .* has norm 1.01;"),
    (image_line("f.png", q=("nan", 0, 0, 0)), r"image f: QW must be finite, got 'nan'\.$"),
    (image_line("f.png", t=(0, "inf", 0)), r"image f: TY must be finite, got 'inf'\.$"),
    (image_line("f.png", t=(0, 0, "x")), r"image f: TZ must be a number, got 'x'\.$"),
    ("1 1 0 0 0 0 0 0 1", r"images.txt: line 2: expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID "
     r"NAME, found 9 values\.$"),
    (image_line("..", 1), r"line 2 \(NAME '..'\): the view name '..' cannot be a file name"),
])
def test_colmap_bad_images(tmp_path, line, match):
    root = colmap(tmp_path, CAMERAS_TXT, "# header\n" + line + "\n\n")
    assert pytest.raises(CameraError, read_cameras, root).match(match)
    error(root / "images.txt")


@pytest.mark.parametrize("camera, match", [
    ("1 OPENCV 64 48 100 100 32 24 0 0 0", r"camera 1 \(cameras.txt line 1\): a OPENCV camera has 8 PARAMS \(fx fy cx cy k1 k2 p1 p2\), found 7\.$"),
    ("1 OPENCV_FISHEYE 64 48 100 100 32 24 0.1 0 nan 0", r"camera 1 \(cameras.txt line 1\): k3 must be finite, got 'nan'\.$"),
    ("1 RADIAL 64 48 100 32 24 -0.5 x", r"k2 must be a number, got 'x'\.$"),
    ("1 PINHOLE 64 48 100 100 32", r"camera 1 \(cameras.txt line 1\): a PINHOLE camera has 4 PARAMS \(fx fy cx cy\), found 3\.$"),
    ("1 PINHOLE 64.5 48 100 100 32 24", r"camera 1 \(cameras.txt line 1\): WIDTH must be a whole number of pixels from 1 to 65536 \(MAX_SIDE\), got '64.5'\.$"),
    ("1 PINHOLE 64 0 100 100 32 24", r"HEIGHT must be a whole number of pixels .* got '0'\.$"),
    ("1 PINHOLE 64 -48 100 100 32 24", r"HEIGHT must be a whole number of pixels .* got '-48'\.$"),
    ("1 PINHOLE 65537 48 100 100 32 24", r"WIDTH must be a whole number of pixels .* got '65537'\.$"),
    ("1 PINHOLE 64 48 100 nan 32 24", r"image f: camera 1 \(cameras.txt line 1\): fy must be finite, got 'nan'\.$"),
    ("1 PINHOLE 64 48 -100 100 32 24", r"image f: camera 1 \(cameras.txt line 1\): K must have positive fx and fy"),
    ("1 PINHOLE 64", r"cameras.txt: line 1: expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS\.\.\., found 3 values\.$"),
    ("1 PINHOLE 64 48 1 1 1 1\n1 PINHOLE 64 48 1 1 1 1", r"cameras.txt: line 2: camera 1 is already on line 1\.$"),
])
def test_colmap_bad_cameras(tmp_path, camera, match):
    root = colmap(tmp_path, camera + "\n", image_line("f.png") + "\n\n")
    assert pytest.raises(CameraError, read_cameras, root).match(match)
    error(root)


def test_colmap_one_line_per_image_is_refused(tmp_path):
    # Without the 2D points lines every other image would be taken for points.
    images = "\n".join(image_line(f"{i}.png", image_id=i) for i in range(4)) + "\n"
    message = error(colmap(tmp_path, CAMERAS_TXT, images) / "images.txt")
    assert message.endswith("images.txt: line 2: expected the 2D points of image '0.png' (X Y "
                            "POINT3D_ID triples, each ID a whole number; the line may be "
                            "empty), found 10 values; "
                            "images.txt holds two lines per image.")
    # Names of three words make an image line 12 values, as four triples would be: the
    # IDs' places hold 0.0 (QX) and a word, not whole numbers.
    images = "\n".join(image_line(f"shot {i} left.png", q=(1.0, 0.0, 0.0, 0.0), image_id=i)
                       for i in range(4)) + "\n"
    message = error(colmap(tmp_path, CAMERAS_TXT, images, "names") / "images.txt")
    assert message.endswith("images.txt: line 2: expected the 2D points of image 'shot 0 left"
                            ".png' (X Y POINT3D_ID triples, each ID a whole number; the line "
                            "may be empty), found '0.0' where the first POINT3D_ID belongs; "
                            "images.txt holds two lines per image.")
    images = image_line("a.png") + "\n" + "1.5 2.5 -1 3 4 x\n"
    message = error(colmap(tmp_path, CAMERAS_TXT, images, "words") / "images.txt")
    assert message.endswith("found values that are not X Y POINT3D_ID triples; images.txt "
                            "holds two lines per image.")
    # Numbers in any of C's forms, IDs of any size: a points line as COLMAP writes it.
    images = image_line("a.png") + "\n" + "2362.39 248.498 -1 1.5e3 .5 123456789012 -7 +8. 0\n"
    assert [v.name for v in read_cameras(colmap(tmp_path, CAMERAS_TXT, images, "ok"))] == ["a"]
    # The last image may lack its points line altogether.
    views = read_cameras(colmap(tmp_path, CAMERAS_TXT, image_line("last.png"), "b"))
    assert [v.name for v in views] == ["last"]


def test_colmap_camera_ids_are_integers(tmp_path):
    """COLMAP reads CAMERA_ID as an integer: an image's 07 is camera 7, and 7 and 07 in
    cameras.txt are one camera twice."""
    cameras = "7 SIMPLE_PINHOLE 4 2 2 2 1\n"
    views = read_cameras(colmap(tmp_path, cameras, f"{image_line('b.jpg', '07')}\n\n"))
    np.testing.assert_array_equal(views[0].camera.K, [[2, 0, 2], [0, 2, 1], [0, 0, 1]])
    twice = colmap(tmp_path, cameras + "07 PINHOLE 4 2 2 2 2 1\n",
                   f"{image_line('b.jpg', 7)}\n\n", "twice")
    assert error(twice).endswith("line 2: camera 07 is already on line 1.")


def test_colmap_duplicates_and_missing_files(tmp_path):
    images = f"{image_line('cam0/0001.png')}\n\n{image_line('cam1/0001.jpg', image_id=2)}\n\n"
    message = error(colmap(tmp_path, CAMERAS_TXT, images))
    assert message.endswith("images.txt: line 1 ('cam0/0001.png') and line 3 ('cam1/0001.jpg') "
                            "have the same name '0001'; each view is written to <name>.exr, so "
                            "names must differ (ignoring case).")
    empty = colmap(tmp_path, CAMERAS_TXT, "# no images\n", "empty")
    assert error(empty).endswith("images.txt names no views.")

    folder = tmp_path / "sparse1"
    folder.mkdir()
    assert error(folder).endswith("sparse1 is a folder without cameras.txt and images.txt "
                                  "(a COLMAP text model).")
    (folder / "cameras.bin").write_bytes(b"")
    (folder / "images.bin").write_bytes(b"")
    assert error(folder).endswith("(a COLMAP text model); it holds a binary model (cameras.bin, "
                                  "images.bin): convert it with colmap model_converter "
                                  "--output_type TXT.")
    (folder / "images.txt").write_text(image_line("a.png") + "\n\n")
    assert error(folder / "images.txt").endswith(
        "images.txt: cameras.txt is not beside it (a COLMAP text model is cameras.txt and "
        "images.txt); it holds a binary model (cameras.bin, images.bin): convert it with colmap "
        "model_converter --output_type TXT.")
    assert error(tmp_path / "nowhere" / "cameras.txt").endswith("cameras.txt does not exist.")


def test_colmap_too_many_views_before_any_camera(tmp_path, monkeypatch):
    monkeypatch.setattr(camera_files, "MAX_VIEWS", 3)
    images = "".join(f"{image_line(f'{i}.png', camera_id=99)}\n\n" for i in range(4))
    message = error(colmap(tmp_path, "", images))   # no cameras at all: never looked at
    assert message.endswith("images.txt names 4 views; at most 3 (MAX_VIEWS) are read from one "
                            "file: split it.")


# JSON lists of kdray cameras ----------------------------------------------------------

LOOK = {"width": 32, "height": 24, "eye": [0, 0, 5], "target": [0, 0, 0], "fov": 40}
MATRIX = {"width": 640, "height": 480, "K": {"fx": 500, "fy": 510, "cx": 320, "cy": 240},
          "cam_to_world": [[1, 0, 0, 0], [0, -1, 0, 1], [0, 0, -1, 4], [0, 0, 0, 1]]}


def test_json_list_with_and_without_names(tmp_path):
    views = read_cameras(write(tmp_path, [LOOK, MATRIX | {"name": "front"}, MATRIX], "cams.json"))
    assert [v.name for v in views] == ["view_00000", "front", "view_00002"]
    assert views[0].camera == Camera.look_at((0, 0, 5), (0, 0, 0), fov_deg=40, width=32, height=24)
    np.testing.assert_array_equal(views[1].camera.K, [[500, 0, 320], [0, 510, 240], [0, 0, 1]])
    np.testing.assert_array_equal(views[2].camera.eye, [0, 1, 4])
    assert views[1].camera == views[2].camera


def test_json_list_default_names_have_digits_for_the_count(tmp_path, monkeypatch):
    camera = Camera.look_at((0, 0, 5), (0, 0, 0), width=2, height=2)
    monkeypatch.setattr(Camera, "_from_dict", classmethod(lambda cls, data: camera))
    views = read_cameras(write(tmp_path, "[" + ",".join(["{}"] * 100001) + "]", "many.json"))
    assert (views[0].name, views[-1].name) == ("view_000000", "view_100000")


def test_single_camera_object_is_one_view(tmp_path):
    views = read_cameras(write(tmp_path, MATRIX, "hero.json"))
    assert [v.name for v in views] == ["hero"]
    assert views[0] == View("hero", Camera(640, 480, [[500, 0, 320], [0, 510, 240], [0, 0, 1]],
                                           MATRIX["cam_to_world"]))


@pytest.mark.parametrize("items, match", [
    ([LOOK, LOOK | {"fl_x": 3}], r"cams.json: \[1\] \(view_00001\): unknown keys \['fl_x'\]"),
    ([LOOK, 5], r"cams.json: \[1\]: expected a camera object, got a JSON number\.$"),
    ([LOOK | {"name": 5}], r"cams.json: \[0\]: name must be a string, got 5\.$"),
    ([LOOK | {"eye": [0, float("nan"), 5]}], r"cams.json: \[0\] \(view_00000\): eye must be finite"),
    ([LOOK | {"width": 70000}], r"\[0\] \(view_00000\): width must be a whole number of pixels >= 1 and at most 65536 \(MAX_SIDE\), got 70000\.$"),
    ([LOOK | {"height": 0}], r"\[0\] \(view_00000\): height must be a whole number of pixels >= 1"),
    ([LOOK | {"height": 2.5}], r"\[0\] \(view_00000\): height must be a whole number"),
    ([LOOK | {"name": "a"}, LOOK | {"name": "a"}], r"cams.json: \[0\] and \[1\] have the same name 'a'"),
    ([LOOK | {"name": "view_00001"}, LOOK], r"\[0\] and \[1\] have the same name 'view_00001'"),
    ([LOOK | {"name": "x/y"}], r"cams.json: \[0\]: the view name 'x/y' cannot be a file name \(<name>.exr\): it contains '/'\.$"),
    ([LOOK | {"name": "x\\y"}], r"it contains '\\'\.$"),
    ([LOOK | {"name": "."}], r"the view name '.' cannot be a file name \(<name>.exr\): it is not a file name\.$"),
    ([LOOK | {"name": ""}], r"the view name '' cannot be a file name"),
    ([LOOK | {"name": "x\0"}], r"it contains NUL\.$"),
    ([], r"cams.json names no views\.$"),
])
def test_json_list_bad_items(tmp_path, items, match):
    path = write(tmp_path, items, "cams.json")
    assert pytest.raises(CameraError, read_cameras, path).match(match)
    error(path)


def test_ten_million_views_are_refused_on_their_count(tmp_path):
    path = write(tmp_path, "[" + ",".join(["{}"] * 10**7) + "]", "huge.json")
    assert error(path).endswith(f"huge.json names 10000000 views; at most {MAX_VIEWS} (MAX_VIEWS) "
                                "are read from one file: split it.")


def test_nerfstudio_too_many_views(tmp_path, monkeypatch):
    monkeypatch.setattr(camera_files, "MAX_VIEWS", 3)
    assert "names 4 views; at most 3 (MAX_VIEWS)" in error(write(tmp_path, transforms([{}] * 4)))
    assert len(read_cameras(write(tmp_path, transforms([frame(f"{i}") for i in range(3)]), "b.json"))) == 3


# Files that are not camera files ------------------------------------------------------


def test_files_that_are_not_camera_files(tmp_path):
    assert error(tmp_path / "missing.json").endswith("missing.json does not exist.")
    # a name the system cannot look up (ENAMETOOLONG from the folder test too)
    assert error(tmp_path / ("x" * 300 + ".json")).endswith("cannot be read: File name too long.")
    assert "is not valid JSON: Expecting value: line 1 column 1" in error(write(tmp_path, "fl_x: 3", "a.json"))
    assert "is not valid JSON" in error(write(tmp_path, "[1, 2", "b.json"))
    assert "JSON nested more than 32 deep (JSON_MAX_DEPTH)" in error(write(tmp_path, "[" * 100000 + "]" * 100000, "c.json"))
    for data, kind in ((3, "number"), ("x", "string"), (None, "null"), (True, "boolean")):
        assert error(write(tmp_path, json.dumps(data), "d.json")).endswith(
            f"d.json holds a JSON {kind}; expected a nerfstudio transforms.json (an object with "
            "\"frames\"), a list of kdray cameras or one kdray camera object.")
    assert error(write(tmp_path, {"fl_x": 3, "w": 4}, "e.json")).startswith(
        f"camera file {tmp_path / 'e.json'}: unknown keys ['fl_x', 'w']")
    bad_utf8 = tmp_path / "f.json"
    bad_utf8.write_bytes(b"[\xff]")
    assert "f.json cannot be read: 'utf-8' codec can't decode" in error(bad_utf8)


def test_reading_writes_nothing(tmp_path, monkeypatch):
    work = tmp_path / "cwd"
    work.mkdir()
    monkeypatch.chdir(work)
    paths = [write(tmp_path, transforms([frame()])), write(tmp_path, [LOOK], "cams.json"),
             colmap(tmp_path, CAMERAS_TXT, image_line("a.png") + "\n\n")]
    before = sorted((p, p.stat().st_mtime_ns) for p in tmp_path.rglob("*"))
    for path in paths:
        assert len(read_cameras(path)) == 1
    assert sorted((p, p.stat().st_mtime_ns) for p in tmp_path.rglob("*")) == before


# Camera models beyond the pinhole -----------------------------------------------------


@pytest.mark.parametrize("top, per_frame, model, distortion", [
    ({"camera_model": "OPENCV", "k1": -0.1, "k2": 0.02, "p1": 1e-3, "p2": -2e-3}, {},
     "opencv", (-0.1, 0.02, 1e-3, -2e-3)),
    ({"camera_model": "OPENCV", "k1": -0.1}, {"k3": 0.005, "k1": -0.2},      # the frame's wins
     "opencv", (-0.2, 0.0, 0.0, 0.0, 0.005)),
    ({"camera_model": "RADIAL", "distortion_params": [0.1, 0.2, 0.3, 0, 0.4, 0.5]}, {},
     "opencv", (0.1, 0.2, 0.4, 0.5, 0.3)),
    ({}, {"camera_model": "SIMPLE_RADIAL", "k1": 0.01}, "opencv", (0.01, 0.0, 0.0, 0.0)),
    ({"camera_model": "OPENCV_FISHEYE", "k1": 0.1, "k2": -0.01, "k3": 0.002, "k4": -1e-4}, {},
     "fisheye", (0.1, -0.01, 0.002, -1e-4)),
    ({"camera_model": "OPENCV_FISHEYE"}, {}, "fisheye", (0.0, 0.0, 0.0, 0.0)),
    ({"camera_model": "OPENCV", "k1": 0.0, "p2": 0}, {}, "pinhole", ()),
])
def test_nerfstudio_camera_models(tmp_path, top, per_frame, model, distortion):
    path = write(tmp_path, transforms([frame("images/frame_00012.png", **per_frame)], **top))
    camera = read_cameras(path)[0].camera
    assert camera.model == model and camera.distortion == distortion


def test_nerfstudio_equirectangular_rays_are_nerfstudios(tmp_path):
    # nerfstudio (cameras.py, EQUIRECTANGULAR): x, y = (u - cx) / fx, -(v - cy) / fy;
    # theta = -pi x, phi = pi (0.5 - y); direction (-sin theta sin phi, cos phi,
    # -cos theta sin phi) in OpenGL camera axes
    w, h = 64, 32
    gl = [[0, 0, 1, 0.5], [1, 0, 0, -1], [0, 1, 0, 2], [0, 0, 0, 1]]
    meta = transforms([{"file_path": "p.png", "transform_matrix": gl}], camera_model="EQUIRECTANGULAR",
                      fl_x=w / 2, fl_y=h, cx=w / 2, cy=h / 2, w=w, h=h)
    camera = read_cameras(write(tmp_path, meta))[0].camera
    assert camera.model == "equirectangular"
    o, d = camera.rays()
    v, u = np.divmod(np.arange(w * h), w) + np.array([[0.5], [0.5]])
    x, y = (u - w / 2) / (w / 2), -(v - h / 2) / h
    theta, phi = -np.pi * x, np.pi * (0.5 - y)
    local = np.stack([-np.sin(theta) * np.sin(phi), np.cos(phi), -np.cos(theta) * np.sin(phi)], 1)
    expected = local @ np.array(gl, dtype=float)[:3, :3].T
    assert np.abs(d - expected).max() < 1e-12
    assert np.allclose(o, [0.5, -1, 2])


@pytest.mark.parametrize("line, model, distortion", [
    ("1 SIMPLE_RADIAL 64 48 100 32 24 0.01", "opencv", (0.01, 0.0, 0.0, 0.0)),
    ("1 RADIAL 64 48 100 32 24 0.01 -0.002", "opencv", (0.01, -0.002, 0.0, 0.0)),
    ("1 OPENCV 64 48 100 110 32 24 0.01 -0.002 1e-4 2e-4", "opencv", (0.01, -0.002, 1e-4, 2e-4)),
    ("1 FULL_OPENCV 64 48 100 110 32 24 0.1 0.2 0.003 0.004 0.05 0.6 0.07 0.08", "opencv",
     (0.1, 0.2, 0.003, 0.004, 0.05, 0.6, 0.07, 0.08)),
    ("1 OPENCV_FISHEYE 64 48 100 110 32 24 0.1 -0.01 0.002 -1e-4", "fisheye", (0.1, -0.01, 0.002, -1e-4)),
    ("1 OPENCV 64 48 100 110 32 24 0 0 0 0", "pinhole", ()),
])
def test_colmap_camera_models(tmp_path, line, model, distortion):
    root = colmap(tmp_path, line + "\n", image_line("f.png") + "\n\n")
    camera = read_cameras(root)[0].camera
    assert (camera.model, camera.distortion) == (model, distortion)
    fx = 100.0
    fy = 100.0 if line.split()[1] in ("SIMPLE_RADIAL", "RADIAL") else 110.0
    np.testing.assert_array_equal(camera.K, [[fx, 0, 32], [0, fy, 24], [0, 0, 1]])
