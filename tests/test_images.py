"""kdray.images: the EXR contract (channel names, float32, exact uint32 ids, misses),
the camera in the header, atomic writes, errors, PNG previews and --aov parsing. The
files are written with the OpenEXR package and read back with OpenImageIO (and, for
the pixels, with the OpenEXR package too)."""
import os
import sys

import numpy as np
import OpenEXR
import OpenImageIO as oiio
import pytest

import kdray
from kdray import images
from kdray.camera import Camera
from kdray.errors import KdrayError, OutputError
from kdray.images import read_camera, read_exr, write_exr, write_preview
from kdray.render import AOVS, DEFAULT_AOVS, parse_aovs

SPECIAL_IDS = [0, 1, 2**24 + 1, 0xFFFFFFFE, 0xFFFFFFFF]
CONTRACT_CHANNELS = {
    "depth": ["Z"],
    "distance": ["T"],
    "normal": ["N.X", "N.Y", "N.Z"],
    "bary": ["bary.U", "bary.V"],
    "id": ["id"],
    "position": ["P.X", "P.Y", "P.Z"],
    "object": ["object"],
}


def all_aovs(rng, height=23, width=41):
    """Every AOV with awkward values: misses, +inf, NaN, -0, subnormals, special ids."""
    depth = rng.uniform(0.1, 100, (height, width)).astype(np.float32)
    depth.flat[:4] = [np.inf, np.float32(1e-45), -0.0, np.float32(3.4e38)]
    distance = depth / np.float32(2)
    normal = rng.normal(size=(height, width, 3)).astype(np.float32)
    normal[0, 0] = 0
    normal[0, 1] = np.array([0x7FC00001, 0xFFC00000, 0x80000000], np.uint32).view(np.float32)  # NaN payloads, -NaN, -0
    bary = rng.uniform(0, 1, (height, width, 2)).astype(np.float32)
    ids = rng.integers(0, 2**32, (height, width), dtype=np.uint64).astype(np.uint32)
    ids.flat[: len(SPECIAL_IDS)] = SPECIAL_IDS
    position = rng.normal(size=(height, width, 3)).astype(np.float32) * 1e6
    position[0, 0] = np.nan
    objects = rng.integers(0, 2**32, (height, width), dtype=np.uint64).astype(np.uint32)
    objects.flat[-len(SPECIAL_IDS):] = SPECIAL_IDS
    return {"depth": depth, "distance": distance, "normal": normal, "bary": bary, "id": ids,
            "position": position, "object": objects}


def exr_spec(path):
    inp = oiio.ImageInput.open(str(path))
    assert inp is not None, oiio.geterror()
    try:
        return inp.spec()
    finally:
        inp.close()


def assert_same_bits(a, b):
    """Exact equality including NaN payloads and signed zeros."""
    assert a.dtype == b.dtype and a.shape == b.shape
    np.testing.assert_array_equal(a.view(np.uint32), b.view(np.uint32))


# Round trips and the channel contract ----------------------------------------------


def test_round_trip_every_aov_exactly(tmp_path, rng):
    aovs = all_aovs(rng)
    path = tmp_path / "all.exr"
    write_exr(path, aovs)
    back = read_exr(path)
    assert set(back) == set(aovs)
    for name, array in aovs.items():
        assert_same_bits(back[name], array)
    assert back["id"].dtype == np.uint32
    assert back["id"].flat[: len(SPECIAL_IDS)].tolist() == SPECIAL_IDS
    assert back["object"].dtype == np.uint32
    assert back["object"].flat[-len(SPECIAL_IDS):].tolist() == SPECIAL_IDS
    assert np.isposinf(back["depth"].flat[0]) and np.isnan(back["position"][0, 0]).all()


def test_ids_read_independently_with_oiio(tmp_path, rng):
    ids = rng.integers(0, 2**32, (16, 16), dtype=np.uint64).astype(np.uint32)
    ids.flat[: len(SPECIAL_IDS)] = SPECIAL_IDS
    path = tmp_path / "ids.exr"
    write_exr(path, {"id": ids})
    inp = oiio.ImageInput.open(str(path))
    pixels = inp.read_image(0, 0, 0, 1, oiio.UINT)
    inp.close()
    np.testing.assert_array_equal(pixels[..., 0], ids)


def test_pixels_read_with_the_openexr_package(tmp_path, rng):
    # A second reader: every channel's bits, as the format's own library sees them.
    aovs = all_aovs(rng)
    path = tmp_path / "all.exr"
    write_exr(path, aovs)
    with OpenEXR.File(str(path), separate_channels=True) as exr:
        assert len(exr.parts) == 1
        pixels = {name: channel.pixels for name, channel in exr.channels().items()}
    assert sorted(pixels) == sorted(n for names in CONTRACT_CHANNELS.values() for n in names)
    for aov, names in CONTRACT_CHANNELS.items():
        want = aovs[aov] if len(names) > 1 else aovs[aov][..., None]
        for c, name in enumerate(names):
            assert pixels[name].dtype == (np.uint32 if aov in ("id", "object") else np.float32), name
            np.testing.assert_array_equal(pixels[name].view(np.uint32), want[..., c].view(np.uint32))
    assert pixels["id"].flat[: len(SPECIAL_IDS)].tolist() == SPECIAL_IDS


def test_channel_names_and_types(tmp_path, rng):
    path = tmp_path / "all.exr"
    write_exr(path, all_aovs(rng, 5, 7))
    spec = exr_spec(path)
    expected = [name for names in CONTRACT_CHANNELS.values() for name in names]
    assert sorted(spec.channelnames) == sorted(expected)
    formats = dict(zip(spec.channelnames, spec.channelformats))
    for name in expected:
        want = oiio.UINT if name in ("id", "object") else oiio.FLOAT  # never HALF
        assert formats[name].basetype == want, name
    assert (spec.width, spec.height, spec.nchannels) == (7, 5, 12)
    assert spec.get_string_attribute("compression") == "zip"
    assert spec.tile_width == 0 and spec.deep is False  # scanline, not tiled or deep
    assert spec.getattribute("oiio:subimages") == 1  # single-part
    assert not any(a.name == "worldToCamera" or a.name.startswith("kdray/") for a in spec.extra_attribs)


@pytest.mark.parametrize("aov", AOVS)
def test_each_aov_alone(tmp_path, rng, aov):
    array = all_aovs(rng, 3, 2)[aov]
    path = tmp_path / f"{aov}.exr"
    write_exr(path, {aov: array})
    assert list(exr_spec(path).channelnames) == CONTRACT_CHANNELS[aov]
    back = read_exr(path)
    assert list(back) == [aov]
    assert_same_bits(back[aov], array)


def test_default_aovs_and_one_pixel(tmp_path):
    one = {"depth": np.full((1, 1), 2.5, np.float32), "normal": np.array([[[0, 0, 1]]], np.float32),
           "bary": np.array([[[0.25, 0.5]]], np.float32), "id": np.array([[7]], np.uint32)}
    assert set(one) == set(DEFAULT_AOVS)
    write_exr(tmp_path / "one.exr", one)
    back = read_exr(tmp_path / "one.exr")
    for name in one:
        np.testing.assert_array_equal(back[name], one[name])


def test_other_input_dtypes_are_converted(tmp_path):
    depth = np.linspace(0, 1, 12).reshape(3, 4)  # float64 -> float32
    ids = np.arange(12, dtype=np.int64).reshape(3, 4)
    write_exr(tmp_path / "x.exr", {"depth": depth, "id": ids})
    back = read_exr(tmp_path / "x.exr")
    np.testing.assert_array_equal(back["depth"], depth.astype(np.float32))
    np.testing.assert_array_equal(back["id"], ids.astype(np.uint32))


def test_zip_compression_shrinks_smooth_images(tmp_path):
    y, x = np.mgrid[0:200, 0:300]
    aovs = {"depth": (1 + 0.01 * x + 0.02 * y).astype(np.float32), "id": (y // 4 * 300 + x // 4).astype(np.uint32)}
    path = tmp_path / "smooth.exr"
    write_exr(path, aovs)
    assert os.path.getsize(path) < 200 * 300 * 8 / 4
    back = read_exr(path)
    for name in aovs:
        np.testing.assert_array_equal(back[name], aovs[name])


def test_same_input_same_bytes(tmp_path, rng):
    aovs = all_aovs(rng, 40, 30)
    write_exr(tmp_path / "a.exr", aovs)
    write_exr(tmp_path / "b.exr", aovs)
    assert (tmp_path / "a.exr").read_bytes() == (tmp_path / "b.exr").read_bytes()


def test_reads_an_exr_written_by_oiio(tmp_path):
    # An independent writer (OIIO, one float type) with kdray's channel names.
    path = tmp_path / "oiio.exr"
    spec = oiio.ImageSpec(4, 3, 4, oiio.FLOAT)
    spec.channelnames = ("Z", "N.X", "N.Y", "N.Z")
    data = np.arange(48, dtype=np.float32).reshape(3, 4, 4)
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), spec) and out.write_image(data) and out.close()
    back = read_exr(path)
    np.testing.assert_array_equal(back["depth"], data[..., 0])
    np.testing.assert_array_equal(back["normal"], data[..., 1:])


def test_read_errors(tmp_path):
    with pytest.raises(KdrayError, match="nope.exr"):
        read_exr(tmp_path / "nope.exr")
    path = tmp_path / "partial.exr"
    spec = oiio.ImageSpec(2, 2, 2, oiio.FLOAT)
    spec.channelnames = ("N.X", "N.Y")
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), spec) and out.write_image(np.zeros((2, 2, 2), np.float32)) and out.close()
    with pytest.raises(KdrayError, match="N.Z"):
        read_exr(path)


# Atomic writes ---------------------------------------------------------------------------


class _FakeOpenEXR:
    """Stands in for the OpenEXR package: its File(header, channels).write(path) calls
    write(path, header, channels)."""

    ZIP_COMPRESSION = OpenEXR.ZIP_COMPRESSION
    scanlineimage = OpenEXR.scanlineimage

    def __init__(self, write):
        self.write = write

    def File(self, header, channels):
        write = self.write

        class File:
            def __enter__(self):
                return self

            def __exit__(self, *exc):
                return False

            def write(self, path):
                write(path, header, channels)

        return File()


def _FailingOpenEXR(error):
    """The OpenEXR package writing half a file, then failing like it."""
    def write(path, header, channels):
        with open(path, "wb") as f:
            f.write(b"v/1\x01 half a file")
        raise error
    return _FakeOpenEXR(write)


@pytest.mark.parametrize("error", [RuntimeError("disk on fire"), KeyboardInterrupt()])
def test_failed_write_keeps_the_existing_file(tmp_path, rng, monkeypatch, error):
    path = tmp_path / "out.exr"
    first = all_aovs(rng)
    write_exr(path, first)
    before = path.read_bytes()

    monkeypatch.setattr(images, "_openexr", lambda: _FailingOpenEXR(error))
    expected = OutputError if isinstance(error, RuntimeError) else KeyboardInterrupt
    with pytest.raises(expected) as info:
        write_exr(path, all_aovs(rng))
    if expected is OutputError:
        assert str(path) in str(info.value) and "disk on fire" in str(info.value)
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.exr"]


@pytest.mark.parametrize("error", [OSError(28, "No space left on device"), KeyboardInterrupt()])
def test_interrupted_file_write_keeps_the_existing_file(tmp_path, rng, monkeypatch, error):
    path = tmp_path / "out.exr"
    write_exr(path, all_aovs(rng))
    before = path.read_bytes()

    def failing_fsync(fd):
        raise error

    monkeypatch.setattr(os, "fsync", failing_fsync)  # as kdray.files calls it
    expected = OutputError if isinstance(error, OSError) else KeyboardInterrupt
    with pytest.raises(expected) as info:
        write_exr(path, all_aovs(rng))
    if expected is OutputError:
        assert str(path) in str(info.value) and "No space left" in str(info.value)
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.exr"]


def _ShortOpenEXR(lost):
    """The OpenEXR package writing the real file, then losing its last `lost` bytes and
    reporting success, as the library's stream does on a full disk (its last flush, at
    close, fails in silence)."""
    def write(path, header, channels):
        with OpenEXR.File(header, channels) as real:
            real.write(path)
        data = open(path, "rb").read()
        open(path, "wb").write(data[:max(0, len(data) - lost)])
    return _FakeOpenEXR(write)


class _ShortOIIO:
    """Stands in for OpenImageIO's PNG writer as _ShortOpenEXR for the OpenEXR package:
    its close() loses the file's last `lost` bytes and reports success."""

    def __init__(self, lost):
        import OpenImageIO
        self.real, self.lost = OpenImageIO, lost
        self.ImageSpec, self.UINT8 = OpenImageIO.ImageSpec, OpenImageIO.UINT8

    def geterror(self):
        return self.real.geterror()

    @property
    def ImageOutput(self):
        outer = self

        class ImageOutput:
            @staticmethod
            def create(kind):
                out = outer.real.ImageOutput.create(kind)

                class Short:
                    def open(self, path, spec):
                        self.path = path
                        return out.open(path, spec)

                    def write_image(self, pixels):
                        return out.write_image(pixels)

                    def close(self):
                        ok = out.close()
                        data = open(self.path, "rb").read()
                        open(self.path, "wb").write(data[:max(0, len(data) - outer.lost)])
                        return ok

                    def geterror(self):
                        return out.geterror()
                return Short()
        return ImageOutput


@pytest.mark.parametrize("lost", [1, 100, 10 ** 9])
def test_a_file_the_disk_cut_short_is_refused(tmp_path, rng, monkeypatch, lost):
    """The EXR and the PNG are checked whole before they replace anything: a file the
    library wrote short (no error from it) is an OutputError, the old file kept."""
    for name, write in (("out.exr", write_exr), ("out.png", write_preview)):
        path = tmp_path / name
        write(path, all_aovs(rng))
        before = path.read_bytes()
        with monkeypatch.context() as m:
            if name.endswith(".exr"):
                m.setattr(images, "_openexr", lambda: _ShortOpenEXR(lost))
            else:
                m.setattr(images, "_oiio", lambda: _ShortOIIO(lost))
            with pytest.raises(OutputError, match="incomplete") as info:
                write(path, all_aovs(rng))
        assert str(path) in str(info.value)
        assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.exr", "out.png"]


def test_failed_preview_keeps_the_existing_file(tmp_path, rng, monkeypatch):
    path = tmp_path / "out.png"
    aovs = all_aovs(rng)
    write_preview(path, aovs)
    before = path.read_bytes()
    monkeypatch.setattr(images, "preview_rgb", lambda imgs: np.zeros((4, 4, 3), np.uint8))
    monkeypatch.setattr(os, "replace", lambda *a: (_ for _ in ()).throw(KeyboardInterrupt()))
    with pytest.raises(KeyboardInterrupt):
        write_preview(path, aovs)
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.png"]


def test_written_file_has_ordinary_permissions(tmp_path, rng):
    path = tmp_path / "out.exr"
    write_exr(path, {"depth": np.ones((2, 2), np.float32)})
    umask = os.umask(0)
    os.umask(umask)
    assert path.stat().st_mode & 0o777 == 0o666 & ~umask


# The camera in the header --------------------------------------------------------------


def awkward_camera(width=37, height=23):
    """Non-square pixels, skew, an off-centre principal point, a rotated pose away from
    the origin: float64 values that float32 cannot hold."""
    K = np.array([[41.0 / 3, 0.1, 17.2], [0.0, 43.0 / 7, 10.9], [0.0, 0.0, 1.0]])
    q = np.array([0.3, -0.5, 0.7, 0.4])
    q /= np.linalg.norm(q)
    w, x, y, z = q
    R = np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])
    pose = np.eye(4)
    pose[:3, :3] = R
    pose[:3, 3] = [3.25, -1.0 / 3, 12.5]
    return Camera.from_intrinsics(K, pose, width, height)


def images_for(camera, aovs=("depth", "id")):
    shape = (camera.height, camera.width)
    out = {"depth": np.full(shape, 2.5, np.float32), "distance": np.full(shape, 3.0, np.float32),
           "normal": np.zeros(shape + (3,), np.float32), "id": np.zeros(shape, np.uint32)}
    return {name: out[name] for name in aovs}


def header_attributes(path):
    """name -> (OpenImageIO's type name, value) of every header attribute."""
    return {a.name: (str(a.type), a.value) for a in exr_spec(path).extra_attribs}


def row_matrix(value):
    return np.array(value, dtype=np.float64).reshape(4, 4)


def expected_world_to_camera(camera):
    """OpenEXR's worldToCamera, float64, row vectors: [p 1] M = [x y z 1] with x right,
    y up, z forward; OpenCV's camera is R^T (p - eye) with y down."""
    R, eye = camera.cam_to_world[:3, :3], camera.cam_to_world[:3, 3]
    flip = np.diag([1.0, -1.0, 1.0])
    M = np.zeros((4, 4))
    M[:3, :3] = R @ flip  # (p @ R)_k = (R^T p)_k
    M[3, :3] = -(eye @ R) @ flip
    M[3, 3] = 1.0
    return M


def expected_world_to_ndc(camera):
    """OpenEXR's worldToNDC, float64, row vectors: x = u / W, y = v / H (kdray's pixel
    coordinates, pixel (i, j) covering [i, i + 1) x [j, j + 1)), z = 1 / depth, w = depth."""
    R, eye = camera.cam_to_world[:3, :3], camera.cam_to_world[:3, 3]
    K = camera.K
    to_cv = np.zeros((4, 4))  # [p 1] -> [x y z 1] in OpenCV's camera, row vectors
    to_cv[:3, :3] = R
    to_cv[3, :3] = -(eye @ R)
    to_cv[3, 3] = 1.0
    project = np.zeros((4, 4))  # [x y z 1] -> [u/W z, v/H z, 1, z], row vectors
    project[:3, 0] = K[0] / camera.width
    project[:3, 1] = K[1] / camera.height
    project[3, 2] = 1.0
    project[:3, 3] = K[2]
    return to_cv @ project


def assert_float32_of(stored, expected):
    """stored (float32 values) is expected (float64) rounded to float32."""
    stored, expected = np.asarray(stored, np.float64), np.asarray(expected, np.float64)
    ulp = np.spacing(np.abs(expected).astype(np.float32)).astype(np.float64)
    assert np.all(np.abs(stored - expected) <= ulp), (stored, expected)


def ndc(M, points):
    """World points (n, 3) -> NDC (n, 3) with a row-vector matrix, divided by w."""
    h = np.column_stack([points, np.ones(len(points))]) @ M
    return h[:, :3] / h[:, 3:]


@pytest.mark.parametrize("camera", [awkward_camera(), Camera.look_at((0, 1, 4), (0, 1, 0), width=64, height=48)],
                         ids=["awkward", "look_at"])
def test_camera_attributes_read_with_oiio(tmp_path, camera):
    path = tmp_path / "cam.exr"
    write_exr(path, images_for(camera, ("depth", "distance", "id")), camera=camera)
    attributes = header_attributes(path)
    types = {name: type_name for name, (type_name, _) in attributes.items()}
    assert {name: types.get(name) for name in images.CAMERA_ATTRIBUTES} == {
        "worldToCamera": "matrix", "worldToNDC": "matrix",  # m44f
        "kdray/K": "matrix33d", "kdray/camToWorld": "matrixd",  # m33d, m44d
        "kdray/imageSize": "vector2i",
        "kdray/depth": "string", "kdray/distance": "string", "kdray/version": "string",
    }
    value = {name: v for name, (_, v) in attributes.items()}
    assert_float32_of(row_matrix(value["worldToCamera"]), expected_world_to_camera(camera))
    assert_float32_of(row_matrix(value["worldToNDC"]), expected_world_to_ndc(camera))
    # kdray's own: exact float64
    assert value["kdray/K"] == tuple(camera.K.ravel().tolist())
    assert value["kdray/camToWorld"] == tuple(camera.cam_to_world.ravel().tolist())
    assert tuple(value["kdray/imageSize"]) == (camera.width, camera.height)
    assert value["kdray/version"] == kdray.__version__
    assert value["kdray/depth"] == images.DEPTH_CONVENTION
    assert value["kdray/depth"] == "z-depth along the camera's +z axis (OpenCV axes), in world units; +inf on a miss"
    assert value["kdray/distance"] == images.DISTANCE_CONVENTION
    # getattribute by name gives the same values
    spec = exr_spec(path)
    assert spec.getattribute("kdray/K") == value["kdray/K"]
    assert spec.getattribute("worldToNDC") == value["worldToNDC"]


NAMES = ("floor", "ball, \"B\"", "ünïcode ☃", "", "a\nb")


def test_object_names_read_with_oiio(tmp_path):
    """The names are one string attribute, a JSON array (commas, quotes, newlines and
    non-ASCII survive); OpenImageIO reads it back; read_object_names gives the tuple."""
    import json
    objects = np.array([[0, 1, 0xFFFFFFFF], [2, 3, 4]], np.uint32)
    path = tmp_path / "o.exr"
    write_exr(path, {"object": objects}, camera=None, object_names=NAMES)
    attributes = header_attributes(path)
    assert attributes[images.OBJECT_NAMES_ATTRIBUTE][0] == "string"
    assert images.OBJECT_NAMES_ATTRIBUTE == "kdray/objectNames"
    assert json.loads(attributes["kdray/objectNames"][1]) == list(NAMES)
    assert json.loads(exr_spec(path).getattribute("kdray/objectNames")) == list(NAMES)
    assert images.read_object_names(path) == NAMES
    back = read_exr(path)
    assert back["object"].dtype == np.uint32 and np.array_equal(back["object"], objects)
    with OpenEXR.File(str(path)) as exr:                # the format's own library too
        assert json.loads(exr.header()["kdray/objectNames"]) == list(NAMES)


def test_object_names_with_ids_and_camera(tmp_path):
    camera = Camera.look_at((0, 1, 4), (0, 1, 0), width=3, height=2)
    path = tmp_path / "o.exr"
    write_exr(path, images_for(camera, ("depth", "id")), camera=camera, object_names=["a", "b"])
    assert images.read_object_names(path) == ("a", "b")
    assert read_camera(path) == camera


@pytest.mark.parametrize("aovs, names", [(("depth",), ["a", "b"]), (("id",), None), (("id",), [])])
def test_no_object_names_without_ids_or_names(tmp_path, aovs, names):
    camera = Camera.look_at((0, 1, 4), (0, 1, 0), width=3, height=2)
    path = tmp_path / "o.exr"
    write_exr(path, images_for(camera, aovs), camera=camera, object_names=names)
    assert images.read_object_names(path) is None
    assert "kdray/objectNames" not in header_attributes(path)


@pytest.mark.parametrize("objects, names, match", [
    (np.array([[0, 2]], np.uint32), ["a", "b"], "object 2 has no name"),
    (np.array([[0, 1]], np.uint32), "ab", "sequence of strings"),
    (np.array([[0, 1]], np.uint32), 5, "sequence of strings"),
    (np.array([[0, 1]], np.uint32), ["a", 1], "sequence of strings"),
    (np.array([[0, 1]], np.uint32), ["a", "\ud800"], "Unicode"),
])
def test_bad_object_names(tmp_path, objects, names, match):
    path = tmp_path / "o.exr"
    with pytest.raises(OutputError, match=match):
        write_exr(path, {"object": objects}, object_names=names)
    assert not path.exists()


def test_read_object_names_errors(tmp_path):
    path = tmp_path / "o.exr"
    for value in ("not json", '{"a": 1}', '["a", 2]'):
        header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage,
                  "kdray/objectNames": value}
        with OpenEXR.File(header, {"object": np.zeros((2, 2), np.uint32)}) as exr:
            exr.write(str(path))
        with pytest.raises(KdrayError, match="kdray/objectNames"):
            images.read_object_names(path)


def test_preview_of_objects_like_ids(tmp_path):
    objects = np.array([[0, 1, 0xFFFFFFFF], [1, 0, 2]], np.uint32)
    write_preview(tmp_path / "o.png", {"object": objects})
    write_preview(tmp_path / "i.png", {"id": objects})
    assert np.array_equal(read_png(tmp_path / "o.png")[1], read_png(tmp_path / "i.png")[1])


def test_world_to_camera_axes(tmp_path):
    camera = awkward_camera()
    path = tmp_path / "cam.exr"
    write_exr(path, images_for(camera), camera=camera)
    M = row_matrix(exr_spec(path).getattribute("worldToCamera"))
    R, eye = camera.rotation, camera.eye

    def to_camera(p):
        return (np.append(p, 1.0) @ M)[:3]

    np.testing.assert_allclose(to_camera(eye), 0, atol=1e-5)
    np.testing.assert_allclose(to_camera(eye + 2 * R[:, 2]), [0, 0, 2], atol=1e-5)  # forward: +z
    np.testing.assert_allclose(to_camera(eye + R[:, 0]), [1, 0, 0], atol=1e-5)  # image right: +x
    np.testing.assert_allclose(to_camera(eye - R[:, 1]), [0, 1, 0], atol=1e-5)  # image up: +y
    assert np.linalg.det(M[:3, :3]) == pytest.approx(-1.0)  # left-handed
    np.testing.assert_array_equal(M[:, 3], [0, 0, 0, 1])


@pytest.mark.parametrize("camera", [awkward_camera(), Camera.look_at((0, 1, 4), (0, 1, 0), width=64, height=48)],
                         ids=["awkward", "look_at"])
def test_world_to_ndc_projects_like_the_camera(tmp_path, rng, camera):
    path = tmp_path / "cam.exr"
    write_exr(path, images_for(camera), camera=camera)
    M = row_matrix(exr_spec(path).getattribute("worldToNDC"))
    size = np.array([camera.width, camera.height], np.float64)

    # World points in front of the camera: NDC = camera.project's pixels / (W, H).
    cam_points = rng.uniform([-3, -3, 0.5], [3, 3, 20], (200, 3))
    points = cam_points @ camera.rotation.T + camera.eye
    pixels, depth = camera.project(points)
    got = ndc(M, points)
    np.testing.assert_allclose(got[:, :2], pixels / size, rtol=0, atol=2e-6)
    np.testing.assert_allclose(got[:, 2], 1 / depth, rtol=1e-5)  # z: 1 / depth

    # Pixel centres: the point at depth 3 on pixel (i, j)'s ray is at ((i + .5) / W, (j + .5) / H).
    origins, directions = camera.rays()
    got = ndc(M, origins + 3.0 * directions)
    j, i = np.divmod(np.arange(camera.width * camera.height), camera.width)
    np.testing.assert_allclose(got[:, 0], (i + 0.5) / camera.width, atol=2e-6)
    np.testing.assert_allclose(got[:, 1], (j + 0.5) / camera.height, atol=2e-6)

    # The image's corners are NDC (0, 0) and (1, 1).
    corners = np.array([[0.0, 0.0, 1.0], [camera.width, camera.height, 1.0]])
    corner_points = camera.eye + 5.0 * (corners @ np.linalg.inv(camera.K).T) @ camera.rotation.T
    np.testing.assert_allclose(ndc(M, corner_points)[:, :2], [[0, 0], [1, 1]], atol=2e-6)

    # Invertible: (NDC x, NDC y, 1 / depth) and the depth image give the world point back.
    back = ndc(np.linalg.inv(M), ndc(M, points))
    np.testing.assert_allclose(back, points, rtol=1e-5, atol=1e-4)


@pytest.mark.parametrize("camera", [awkward_camera(), awkward_camera(1, 1),
                                    Camera.look_at((0, 1, 4), (0, 1, 0), fov_deg=33, width=640, height=480),
                                    Camera.frame((-1, -2, -3), (1e3, 2, 3), width=5, height=700)],
                         ids=["awkward", "one_pixel", "look_at", "frame"])
def test_read_camera_round_trip(tmp_path, camera):
    path = tmp_path / "cam.exr"
    write_exr(path, images_for(camera), camera=camera)
    back = read_camera(path)
    assert isinstance(back, Camera) and back == camera
    assert back.K.dtype == np.float64 and back.cam_to_world.dtype == np.float64
    np.testing.assert_array_equal(back.K.view(np.uint64), camera.K.view(np.uint64))
    np.testing.assert_array_equal(back.cam_to_world.view(np.uint64), camera.cam_to_world.view(np.uint64))
    assert_same_bits(read_exr(path)["depth"], images_for(camera)["depth"])  # the pixels unchanged


def test_conventions_only_for_the_aovs_present(tmp_path):
    camera = awkward_camera()
    path = tmp_path / "ids.exr"
    write_exr(path, images_for(camera, ("normal", "id")), camera=camera)
    attributes = header_attributes(path)
    assert "kdray/depth" not in attributes and "kdray/distance" not in attributes
    assert read_camera(path) == camera
    write_exr(path, images_for(camera, ("distance",)), camera=camera)
    attributes = header_attributes(path)
    assert "kdray/depth" not in attributes and attributes["kdray/distance"][1] == images.DISTANCE_CONVENTION


def test_no_camera_no_camera_attributes(tmp_path, rng):
    path = tmp_path / "plain.exr"
    write_exr(path, all_aovs(rng, 4, 5))
    assert not set(images.CAMERA_ATTRIBUTES) & set(header_attributes(path))
    assert read_camera(path) is None


def write_with_openexr(path, header):
    """An EXR with one depth channel and `header`'s extra attributes."""
    channels = {"Z": np.ones((2, 3), np.float32)}
    with OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, **header}, channels) as exr:
        exr.write(str(path))


def test_read_camera_errors(tmp_path):
    with pytest.raises(KdrayError, match="nope.exr"):
        read_camera(tmp_path / "nope.exr")
    K = np.array([[2.0, 0, 1.5], [0, 2.0, 1.0], [0, 0, 1]])
    path = tmp_path / "partial.exr"
    write_with_openexr(path, {"kdray/K": K})
    with pytest.raises(KdrayError, match="partial.exr.*kdray/camToWorld"):
        read_camera(path)
    path = tmp_path / "float32.exr"
    write_with_openexr(path, {"kdray/K": K.astype(np.float32), "kdray/camToWorld": np.eye(4),
                              "kdray/imageSize": np.array([3, 2], np.int32)})
    with pytest.raises(KdrayError, match="kdray/K is a matrix33, expected a matrix33d"):
        read_camera(path)
    path = tmp_path / "invalid.exr"
    write_with_openexr(path, {"kdray/K": K, "kdray/camToWorld": 2 * np.eye(4),
                              "kdray/imageSize": np.array([3, 2], np.int32)})
    with pytest.raises(KdrayError, match="invalid.exr holds an invalid camera"):
        read_camera(path)


def test_camera_must_match_the_images(tmp_path):
    camera = awkward_camera(8, 6)
    path = tmp_path / "bad.exr"
    with pytest.raises(OutputError, match=r"bad.exr.*camera is 8x6 pixels but the images are 5x6"):
        write_exr(path, {"depth": np.ones((6, 5), np.float32)}, camera=camera)
    with pytest.raises(OutputError, match=r"bad.exr.*kdray.Camera"):
        write_exr(path, {"depth": np.ones((6, 8), np.float32)}, camera={"K": camera.K})
    assert not path.exists()


# Errors ------------------------------------------------------------------------------------


def test_missing_openexr_package(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "OpenEXR", None)  # any import of it now fails
    with pytest.raises(KdrayError, match="OpenEXR package is needed"):
        write_exr(tmp_path / "out.exr", {"depth": np.ones((2, 2), np.float32)})
    assert not (tmp_path / "out.exr").exists()


def test_missing_folder(tmp_path):
    path = tmp_path / "no" / "such" / "out.exr"
    with pytest.raises(OutputError) as info:
        write_exr(path, {"depth": np.ones((2, 2), np.float32)})
    assert str(path) in str(info.value)
    with pytest.raises(OutputError, match="out.png"):
        write_preview(tmp_path / "no" / "out.png", {"depth": np.ones((2, 2), np.float32)})


def test_unwritable_destinations(tmp_path):
    not_a_folder = tmp_path / "file"
    not_a_folder.write_text("x")
    with pytest.raises(OutputError, match="file/out.exr"):
        write_exr(not_a_folder / "out.exr", {"depth": np.ones((2, 2), np.float32)})
    folder = tmp_path / "folder.exr"
    folder.mkdir()
    with pytest.raises(OutputError, match="folder.exr"):
        write_exr(folder, {"depth": np.ones((2, 2), np.float32)})
    assert folder.is_dir() and sorted(p.name for p in tmp_path.iterdir()) == ["file", "folder.exr"]


@pytest.mark.parametrize(
    "aovs, match",
    [
        ({}, "no images"),
        ({"colour": np.ones((2, 2))}, "unknown AOV 'colour'"),
        ({"depth": np.ones((2, 2, 1))}, r"expected \(H, W\)"),
        ({"normal": np.ones((2, 2))}, r"expected \(H, W, 3\)"),
        ({"bary": np.ones((2, 2, 3))}, r"expected \(H, W, 2\)"),
        ({"depth": np.ones((2, 2)), "id": np.ones((2, 3), np.uint32)}, "3x2 pixels"),
        ({"id": np.ones((2, 2), np.float32)}, "integer"),
        ({"id": np.full((2, 2), -1)}, "uint32"),
        ({"id": np.full((2, 2), 2**32)}, "uint32"),
        ({"object": np.ones((2, 2), np.float32)}, "object must be an integer"),
        ({"object": np.full((2, 2), -1)}, "object values must fit in uint32"),
        ({"depth": np.ones((0, 3))}, "no pixels"),
        ({"depth": np.full((2, 2), "x")}, "real"),
        ({"depth": np.ones((2, 2)), "valid": np.full((2, 2), 2)}, "valid values must be 0 or 1"),
        ({"depth": np.ones((2, 2)), "normal": np.ones((3, 3, 3))}, "3x3 pixels but other"),
        ([("depth", np.ones((2, 2)))], "no images"),
    ],
)
def test_bad_images(tmp_path, aovs, match):
    """write_exr and write_preview refuse the same images with the same OutputError
    (write_preview once passed them to numpy: a ValueError, or a PNG of panels of two
    sizes)."""
    for write, name in ((write_exr, "bad.exr"), (write_preview, "bad.png")):
        path = tmp_path / name
        with pytest.raises(OutputError, match=match) as info:
            write(path, aovs)
        assert name in str(info.value)
        assert not path.exists()


# Previews -----------------------------------------------------------------------------------


def read_png(path):
    inp = oiio.ImageInput.open(str(path))
    assert inp is not None, oiio.geterror()
    spec = inp.spec()
    pixels = inp.read_image(oiio.UINT8)
    inp.close()
    return spec, pixels


def test_preview_depth_and_normals_side_by_side(tmp_path, rng):
    aovs = all_aovs(rng, 23, 41)
    write_preview(tmp_path / "p.png", aovs)
    spec, pixels = read_png(tmp_path / "p.png")
    assert (spec.width, spec.height, spec.nchannels) == (82, 23, 3)
    assert spec.format == oiio.UINT8
    assert pixels.dtype == np.uint8


def test_preview_colours(tmp_path):
    depth = np.array([[1.0, 2.0, 3.0, np.inf]], np.float32)
    normal = np.array([[[0, 0, 1], [1, 0, 0], [0, -1, 0], [0, 0, 0]]], np.float32)
    write_preview(tmp_path / "p.png", {"depth": depth, "normal": normal})
    _, rgb = read_png(tmp_path / "p.png")
    luminance = rgb[0, :4].astype(float) @ [0.2126, 0.7152, 0.0722]
    assert luminance[0] > luminance[1] > luminance[2] > 0  # near is bright
    assert rgb[0, 3].tolist() == [0, 0, 0]  # a miss is black
    assert rgb[0, 4].tolist() == [128, 128, 255]  # +z
    assert rgb[0, 5].tolist() == [255, 128, 128]  # +x
    assert rgb[0, 6].tolist() == [128, 0, 128]  # -y
    assert rgb[0, 7].tolist() == [0, 0, 0]  # a miss is black


def test_preview_ids_only(tmp_path):
    ids = np.array([[0, 1, 0xFFFFFFFF], [1, 0, 2**24 + 1]], np.uint32)
    write_preview(tmp_path / "ids.png", {"id": ids})
    spec, rgb = read_png(tmp_path / "ids.png")
    assert (spec.width, spec.height, spec.nchannels) == (3, 2, 3)
    assert rgb[0, 2].tolist() == [0, 0, 0]  # a miss is black
    assert rgb[0, 0].tolist() == rgb[1, 1].tolist()  # same id, same colour
    assert rgb[0, 1].tolist() == rgb[1, 0].tolist()
    assert rgb[0, 0].tolist() != rgb[0, 1].tolist()
    assert rgb[0, 0].max() > 0 and rgb[0, 1].max() > 0


@pytest.mark.parametrize("aov", AOVS)
def test_preview_of_each_aov_alone(tmp_path, rng, aov):
    write_preview(tmp_path / "p.png", {aov: all_aovs(rng, 5, 6)[aov]})
    spec, _ = read_png(tmp_path / "p.png")
    assert (spec.width, spec.height, spec.nchannels, spec.format) == (6, 5, 3, oiio.UINT8)


def test_preview_errors(tmp_path):
    with pytest.raises(OutputError, match="p.png"):
        write_preview(tmp_path / "p.png", {})


# --aov --------------------------------------------------------------------------------------


def test_parse_aovs():
    assert parse_aovs("depth,normal") == ("depth", "normal")
    assert parse_aovs(" id , depth,id ") == ("id", "depth")
    assert parse_aovs("all") == AOVS
    assert parse_aovs("all,DEPTH") == parse_aovs(["id", "all"]) == AOVS
    assert parse_aovs(",".join(DEFAULT_AOVS)) == DEFAULT_AOVS
    assert AOVS == ("depth", "distance", "normal", "bary", "id", "position", "object")


@pytest.mark.parametrize("text", ["depth,colour", "", " , ", "Z", "all,colour"])
def test_parse_aovs_errors(text):
    with pytest.raises(KdrayError) as info:
        parse_aovs(text)
    assert all(name in str(info.value) for name in AOVS)


def test_files_kdray_does_not_write_are_refused_not_misread(tmp_path):
    """OpenImageIO opens more than kdray writes: a PNG named .exr (read as no AOVs), a
    deep EXR (its empty pixels read as memory left over), a multi-part EXR (its later
    parts unread), an id channel stored as float holding no uint32 (NaN, -1, 2^32:
    cast to wrong ids). Each is a one-line KdrayError naming the file."""
    png = tmp_path / "png.exr"
    out = oiio.ImageOutput.create("png")
    out.open(str(png), oiio.ImageSpec(2, 2, 3, oiio.UINT8))
    out.write_image(np.zeros((2, 2, 3), np.uint8))
    out.close()
    spec = oiio.ImageSpec(2, 2, 1, oiio.FLOAT)
    spec.channelnames = ("Z",)
    spec.deep = True
    deep = oiio.ImageBuf(spec)
    deep.set_deep_samples(0, 0, 0, 1)
    deep.set_deep_value(0, 0, 0, 0, 0, 5.0)
    deep.write(str(tmp_path / "deep.exr"))
    parts = [OpenEXR.Part({"type": OpenEXR.scanlineimage}, {"Z": np.ones((2, 2), np.float32)},
                          name="a"),
             OpenEXR.Part({"type": OpenEXR.scanlineimage}, {"id": np.ones((2, 2), np.uint32)},
                          name="b")]
    with OpenEXR.File(parts) as f:
        f.write(str(tmp_path / "parts.exr"))
    for name, words in (("png.exr", "is not an EXR file"), ("deep.exr", "is a deep EXR"),
                        ("parts.exr", "holds several parts")):
        for read in (read_exr, read_camera):
            with pytest.raises(KdrayError, match=words) as info:
                read(tmp_path / name)
            assert str(tmp_path / name) in str(info.value) and "\n" not in str(info.value)
    for value in (np.nan, -1.0, 2.0 ** 32, 1.5):
        ids = np.full((2, 2), 7.0, np.float32)
        ids[1, 1] = value
        with OpenEXR.File({"type": OpenEXR.scanlineimage}, {"id": ids}) as f:
            f.write(str(tmp_path / "float_id.exr"))
        with pytest.raises(KdrayError, match="channel id holds .*not a uint32 id"):
            read_exr(tmp_path / "float_id.exr")
    ids[1, 1] = 9.0                                   # whole numbers: read as the ids
    with OpenEXR.File({"type": OpenEXR.scanlineimage}, {"id": ids}) as f:
        f.write(str(tmp_path / "float_id.exr"))
    assert read_exr(tmp_path / "float_id.exr")["id"].tolist() == [[7, 7], [7, 9]]
