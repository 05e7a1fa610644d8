"""kdray.images: the EXR contract (channel names, float32, exact uint32 ids, misses),
atomic writes, errors, PNG previews and --aov parsing. OpenImageIO (the OpenEXR
library underneath) is the independent reader."""
import os

import numpy as np
import OpenImageIO as oiio
import pytest

from kdray import images
from kdray.errors import KdrayError, OutputError
from kdray.images import read_exr, write_exr, write_preview
from kdray.render import AOVS, DEFAULT_AOVS, parse_aovs

SPECIAL_IDS = [0, 1, 2**24 + 1, 0xFFFFFFFE, 0xFFFFFFFF]
CONTRACT_CHANNELS = {
    "depth": ["Z"],
    "distance": ["T"],
    "normal": ["N.X", "N.Y", "N.Z"],
    "bary": ["bary.U", "bary.V"],
    "id": ["id"],
    "position": ["P.X", "P.Y", "P.Z"],
}


def all_aovs(rng, height=23, width=41):
    """Every AOV with awkward values: misses, +inf, NaN, -0, subnormals, special ids."""
    depth = rng.uniform(0.1, 100, (height, width)).astype(np.float32)
    depth.flat[:4] = [np.inf, np.float32(1e-45), -0.0, np.float32(3.4e38)]
    distance = depth / np.float32(2)
    normal = rng.normal(size=(height, width, 3)).astype(np.float32)
    normal[0, 0] = 0
    bary = rng.uniform(0, 1, (height, width, 2)).astype(np.float32)
    ids = rng.integers(0, 2**32, (height, width), dtype=np.uint64).astype(np.uint32)
    ids.flat[: len(SPECIAL_IDS)] = SPECIAL_IDS
    position = rng.normal(size=(height, width, 3)).astype(np.float32) * 1e6
    position[0, 0] = np.nan
    return {"depth": depth, "distance": distance, "normal": normal, "bary": bary, "id": ids, "position": position}


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


def test_channel_names_and_types(tmp_path, rng):
    path = tmp_path / "all.exr"
    write_exr(path, all_aovs(rng, 5, 7))
    spec = exr_spec(path)
    expected = [name for names in CONTRACT_CHANNELS.values() for name in names]
    assert sorted(spec.channelnames) == sorted(expected)
    formats = dict(zip(spec.channelnames, spec.channelformats))
    for name in expected:
        want = oiio.UINT if name == "id" else oiio.FLOAT  # never HALF
        assert formats[name].basetype == want, name
    assert (spec.width, spec.height, spec.nchannels) == (7, 5, 11)
    assert spec.get_string_attribute("compression") == "zip"


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


def test_failed_write_keeps_the_existing_file(tmp_path, rng, monkeypatch):
    path = tmp_path / "out.exr"
    first = all_aovs(rng)
    write_exr(path, first)
    before = path.read_bytes()

    calls = []

    def failing_zip(raw):
        calls.append(1)
        if len(calls) > 1:
            raise RuntimeError("disk on fire")
        return raw

    monkeypatch.setattr(images, "_zip_chunk", failing_zip)
    with pytest.raises(RuntimeError, match="disk on fire"):
        write_exr(path, all_aovs(rng))
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.exr"]


@pytest.mark.parametrize("error", [OSError(28, "No space left on device"), KeyboardInterrupt()])
def test_interrupted_file_write_keeps_the_existing_file(tmp_path, rng, monkeypatch, error):
    path = tmp_path / "out.exr"
    write_exr(path, all_aovs(rng))
    before = path.read_bytes()

    def failing_fsync(fd):
        raise error

    monkeypatch.setattr(images.os, "fsync", failing_fsync)
    expected = OutputError if isinstance(error, OSError) else KeyboardInterrupt
    with pytest.raises(expected) as info:
        write_exr(path, all_aovs(rng))
    if expected is OutputError:
        assert str(path) in str(info.value) and "No space left" in str(info.value)
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.exr"]


def test_failed_preview_keeps_the_existing_file(tmp_path, rng, monkeypatch):
    path = tmp_path / "out.png"
    aovs = all_aovs(rng)
    write_preview(path, aovs)
    before = path.read_bytes()
    monkeypatch.setattr(images, "preview_rgb", lambda imgs: np.zeros((4, 4, 3), np.uint8))
    monkeypatch.setattr(images.os, "replace", lambda *a: (_ for _ in ()).throw(KeyboardInterrupt()))
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


# Errors ------------------------------------------------------------------------------------


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
        ({"depth": np.ones((0, 3))}, "no pixels"),
        ({"depth": np.full((2, 2), "x")}, "real"),
    ],
)
def test_bad_images(tmp_path, aovs, match):
    path = tmp_path / "bad.exr"
    with pytest.raises(OutputError, match=match) as info:
        write_exr(path, aovs)
    assert "bad.exr" in str(info.value)
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
    assert parse_aovs(",".join(DEFAULT_AOVS)) == DEFAULT_AOVS
    assert AOVS == ("depth", "distance", "normal", "bary", "id", "position")


@pytest.mark.parametrize("text", ["depth,colour", "", " , ", "Z"])
def test_parse_aovs_errors(text):
    with pytest.raises(KdrayError) as info:
        parse_aovs(text)
    assert all(name in str(info.value) for name in AOVS)
