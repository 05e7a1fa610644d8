"""AOV images -> one multi-channel OpenEXR file, and an 8-bit PNG preview for people.

    images = tracer.render(camera, aovs=("depth", "normal", "bary", "id"))
    write_exr("out.exr", images)          # Z, N.X N.Y N.Z, bary.U bary.V, id
    write_preview("out.png", images)      # depth colour map | normals as RGB
    images = read_exr("out.exr")          # the same dict back, ids exact

`images` maps AOV names to arrays that share one (H, W):

    depth    : (H, W) float32       channel Z              miss: +inf
    distance : (H, W) float32       channel T              miss: +inf
    normal   : (H, W, 3) float32    channels N.X N.Y N.Z   miss: 0
    bary     : (H, W, 2) float32    channels bary.U bary.V miss: 0
    id       : (H, W) uint32        channel id (UINT)      miss: 0xFFFFFFFF
    position : (H, W, 3) float32    channels P.X P.Y P.Z   miss: NaN

The EXR is a single-part scanline file, full float32 (never half) plus one 32-bit
unsigned integer channel for ids, ZIP-compressed (lossless). It is written by this
module (numpy + zlib) rather than by OpenImageIO: OIIO's Python bindings accept only
buffers of one pixel type and convert them to per-channel file types through float,
which would round ids above 2**24. Files are read back with OpenImageIO, channel group
by channel group, so ids come back as exact uint32.

Both writers are atomic: the data goes to a temporary file in the destination folder
that is renamed over the destination only once complete, so a failure or Ctrl-C never
leaves a half-written file and never damages an existing one.
"""
import concurrent.futures
import os
import struct
import zlib

import numpy as np

from .errors import KdrayError, OutputError
from .files import atomic_write, atomic_write_bytes
from .layout import MISS
from .render import AOVS

CHANNELS = {
    "depth": ("Z",),
    "distance": ("T",),
    "normal": ("N.X", "N.Y", "N.Z"),
    "bary": ("bary.U", "bary.V"),
    "id": ("id",),
    "position": ("P.X", "P.Y", "P.Z"),
}
"""Each AOV's EXR channel names (the public contract)."""

ZIP_LEVEL = 4
"""zlib level for EXR chunks (OpenEXR's own default)."""


# Checking the images dict ----------------------------------------------------------


def _channel_arrays(images, path):
    """[(channel name, (H, W) array '<f4' or '<u4')] for the AOVs in `images`."""
    if not isinstance(images, dict) or not images:
        raise OutputError(f"cannot write {path}: no images given.")
    unknown = [name for name in images if name not in CHANNELS]
    if unknown:
        raise OutputError(
            f"cannot write {path}: unknown AOV {unknown[0]!r}; valid AOVs are {', '.join(AOVS)}."
        )
    size = None
    channels = []
    for aov in AOVS:
        if aov not in images:
            continue
        array = np.asarray(images[aov])
        names = CHANNELS[aov]
        expected = (len(names),) if len(names) > 1 else ()
        if array.ndim != 2 + len(expected) or array.shape[2:] != expected:
            want = "(H, W" + "".join(f", {n}" for n in expected) + ")"
            raise OutputError(f"cannot write {path}: {aov} has shape {array.shape}, expected {want}.")
        if size is None:
            size = array.shape[:2]
        elif array.shape[:2] != size:
            raise OutputError(
                f"cannot write {path}: {aov} is {array.shape[1]}x{array.shape[0]} pixels "
                f"but other AOVs are {size[1]}x{size[0]}."
            )
        if aov == "id":
            if array.dtype.kind not in "iu":
                raise OutputError(f"cannot write {path}: id must be an integer array, got {array.dtype}.")
            if array.size and (array.min() < 0 or array.max() > MISS):
                raise OutputError(f"cannot write {path}: id values must fit in uint32.")
            channels.append(("id", array.astype("<u4")))
        else:
            if array.dtype.kind not in "fiub":
                raise OutputError(f"cannot write {path}: {aov} must be a real array, got {array.dtype}.")
            array = array.astype("<f4")
            if array.ndim == 2:
                array = array[..., None]
            channels.extend((name, array[..., c]) for c, name in enumerate(names))
    if size[0] < 1 or size[1] < 1:
        raise OutputError(f"cannot write {path}: images have no pixels ({size[1]}x{size[0]}).")
    return channels, size


# OpenEXR encoding ----------------------------------------------------------------------
# A single-part scanline file: magic, version, header attributes, a table of chunk
# offsets, then chunks of 16 scanlines: int32 y, int32 byte count, data. Within a chunk
# the uncompressed data is, for each scanline, each channel (sorted by name) in turn.
# ZIP compression reorders the bytes (even-indexed first), delta-encodes them and
# deflates them; a chunk that would not shrink is stored raw (OpenEXR's rule).

_EXR_MAGIC = 20000630
_EXR_VERSION = 2
_EXR_UINT, _EXR_FLOAT = 0, 2
_EXR_ZIP = 3
_ZIP_LINES = 16


def _attribute(name, type_name, value):
    head = name.encode() + b"\0" + type_name.encode() + b"\0"
    return head + struct.pack("<i", len(value)) + value


def _exr_header(channels, width, height):
    chlist = b"".join(
        name.encode() + b"\0" + struct.pack("<iB3xii", pixel_type, 0, 1, 1)
        for name, pixel_type in channels
    ) + b"\0"
    window = struct.pack("<4i", 0, 0, width - 1, height - 1)
    return b"".join(
        [
            struct.pack("<ii", _EXR_MAGIC, _EXR_VERSION),
            _attribute("channels", "chlist", chlist),
            _attribute("compression", "compression", bytes([_EXR_ZIP])),
            _attribute("dataWindow", "box2i", window),
            _attribute("displayWindow", "box2i", window),
            _attribute("lineOrder", "lineOrder", bytes([0])),  # increasing y
            _attribute("pixelAspectRatio", "float", struct.pack("<f", 1.0)),
            _attribute("screenWindowCenter", "v2f", struct.pack("<2f", 0.0, 0.0)),
            _attribute("screenWindowWidth", "float", struct.pack("<f", 1.0)),
            b"\0",
        ]
    )


def _zip_chunk(raw):
    """OpenEXR ZIP compression of one chunk's bytes (or the raw bytes if no smaller)."""
    data = np.frombuffer(raw, dtype=np.uint8)
    reordered = np.concatenate([data[0::2], data[1::2]])
    predicted = reordered.copy()
    predicted[1:] = reordered[1:] - reordered[:-1] + np.uint8(128)  # wraps mod 256
    packed = zlib.compress(predicted.tobytes(), ZIP_LEVEL)
    return packed if len(packed) < len(raw) else raw


def _encode_exr(channels, width, height):
    """The bytes of an EXR file holding `channels`: [(name, (H, W) '<f4' or '<u4')]."""
    channels = sorted(channels, key=lambda item: item[0].encode())
    header = _exr_header(
        [(name, _EXR_UINT if a.dtype == np.dtype("<u4") else _EXR_FLOAT) for name, a in channels],
        width,
        height,
    )
    # (H, C, W) 32-bit words: scanline by scanline, channel by channel.
    words = np.empty((height, len(channels), width), dtype="<u4")
    for c, (_, array) in enumerate(channels):
        words[:, c, :] = array.view("<u4")
    starts = range(0, height, _ZIP_LINES)
    raws = [words[y : y + _ZIP_LINES].tobytes() for y in starts]
    workers = min(len(raws), os.cpu_count() or 1)
    if workers > 1:  # zlib releases the GIL
        with concurrent.futures.ThreadPoolExecutor(workers) as pool:
            packed = list(pool.map(_zip_chunk, raws))
    else:
        packed = [_zip_chunk(raw) for raw in raws]
    offset = len(header) + 8 * len(packed)
    offsets = []
    for chunk in packed:
        offsets.append(offset)
        offset += 8 + len(chunk)
    parts = [header, np.array(offsets, dtype="<u8").tobytes()]
    for y, chunk in zip(starts, packed):
        parts.append(struct.pack("<ii", y, len(chunk)))
        parts.append(chunk)
    return b"".join(parts)


def write_exr(path, images):
    """Write the AOV images of one render as one multi-channel EXR file, atomically.

    images : dict of AOV name -> array (see the module docstring). Raises OutputError
    naming `path` for bad arrays, a missing or unwritable folder, or a failed write.
    """
    channels, (height, width) = _channel_arrays(images, path)
    data = _encode_exr(channels, width, height)

    atomic_write_bytes(path, data)


def _oiio():
    try:
        import OpenImageIO
    except ImportError as exc:  # pragma: no cover - a dependency
        raise KdrayError(f"OpenImageIO is needed to read EXR and write PNG files ({exc}).") from None
    return OpenImageIO


def read_exr(path):
    """Read an EXR written by `write_exr` (or any with kdray's channel names) -> dict.

    Returns the AOVs whose channels are all present: float32 arrays, ids as exact uint32.
    Raises KdrayError if the file cannot be read or holds part of an AOV's channels.
    """
    oiio = _oiio()
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise KdrayError(f"cannot read EXR {path}: {oiio.geterror() or 'unknown error'}.")
    try:
        spec = inp.spec()
        names = list(spec.channelnames)
        formats = list(spec.channelformats) or [spec.format] * len(names)
        images = {}
        for aov in AOVS:
            present = [name in names for name in CHANNELS[aov]]
            if not any(present):
                continue
            if not all(present):
                missing = [n for n, p in zip(CHANNELS[aov], present) if not p]
                raise KdrayError(f"EXR {path} has part of {aov} but no channel {missing[0]}.")
            planes = []
            for name in CHANNELS[aov]:
                c = names.index(name)
                if aov == "id" and formats[c].basetype == oiio.UINT:
                    plane = inp.read_image(0, 0, c, c + 1, oiio.UINT)
                else:
                    plane = inp.read_image(0, 0, c, c + 1, oiio.FLOAT)
                if plane is None:
                    raise KdrayError(f"cannot read channel {name} of EXR {path}: {inp.geterror()}.")
                planes.append(np.asarray(plane).reshape(spec.height, spec.width))
            if aov == "id":
                plane = planes[0]
                if plane.dtype.kind != "u":  # an id channel stored as float elsewhere
                    plane = np.rint(plane)
                images[aov] = plane.astype(np.uint32)
            elif len(planes) == 1:
                images[aov] = planes[0].astype(np.float32)
            else:
                images[aov] = np.stack(planes, axis=-1).astype(np.float32)
        return images
    finally:
        inp.close()


# PNG previews ----------------------------------------------------------------------------

_VIRIDIS = np.array(
    [
        (68, 1, 84), (72, 36, 117), (65, 68, 135), (53, 95, 141), (42, 120, 142),
        (33, 145, 140), (34, 168, 132), (68, 191, 112), (122, 209, 81), (189, 223, 38),
        (253, 231, 37),
    ],
    dtype=np.float64,
)
"""viridis (perceptually uniform) at 0, 0.1, ..., 1; linearly interpolated between."""


def _colormap(t):
    """t in [0, 1], any shape -> uint8 RGB of shape t.shape + (3,)."""
    x = np.clip(t, 0.0, 1.0) * (len(_VIRIDIS) - 1)
    i = np.minimum(x.astype(np.int64), len(_VIRIDIS) - 2)
    f = (x - i)[..., None]
    return np.rint(_VIRIDIS[i] * (1 - f) + _VIRIDIS[i + 1] * f).astype(np.uint8)


def _depth_panel(depth):
    """Near bright, far dark (viridis); misses (non-finite) black."""
    depth = np.asarray(depth, dtype=np.float64)
    hit = np.isfinite(depth)
    rgb = np.zeros(depth.shape + (3,), np.uint8)
    if hit.any():
        near, far = depth[hit].min(), depth[hit].max()
        t = (far - depth[hit]) / (far - near) if far > near else np.ones(hit.sum())
        rgb[hit] = _colormap(t)
    return rgb


def _normal_panel(normal):
    """(n + 1) / 2 as RGB; misses (zero or non-finite normals) black."""
    normal = np.asarray(normal, dtype=np.float64)
    hit = np.all(np.isfinite(normal), axis=-1) & np.any(normal != 0, axis=-1)
    rgb = np.zeros(normal.shape, np.uint8)
    rgb[hit] = np.rint(np.clip((normal[hit] + 1.0) / 2.0, 0, 1) * 255).astype(np.uint8)
    return rgb


def _id_panel(ids):
    """A stable pseudo-random colour per id; misses black."""
    x = np.asarray(ids).astype(np.uint32)
    h = x * np.uint32(0x9E3779B1)
    h ^= h >> np.uint32(16)
    h *= np.uint32(0x85EBCA6B)
    h ^= h >> np.uint32(13)
    rgb = np.stack([(h >> np.uint32(s)) & np.uint32(0xFF) for s in (0, 8, 16)], axis=-1)
    rgb = (48 + rgb * 207 // 255).astype(np.uint8)  # never near black
    rgb[x == MISS] = 0
    return rgb


def _bary_panel(bary):
    bary = np.nan_to_num(np.asarray(bary, dtype=np.float64))
    rgb = np.stack([bary[..., 0], bary[..., 1], 1.0 - bary[..., 0] - bary[..., 1]], axis=-1)
    return np.rint(np.clip(rgb, 0, 1) * 255).astype(np.uint8)


def _position_panel(position):
    position = np.asarray(position, dtype=np.float64)
    hit = np.all(np.isfinite(position), axis=-1)
    rgb = np.zeros(position.shape, np.uint8)
    if hit.any():
        lo, hi = position[hit].min(axis=0), position[hit].max(axis=0)
        span = np.where(hi > lo, hi - lo, 1.0)
        rgb[hit] = np.rint(np.clip((position[hit] - lo) / span, 0, 1) * 255).astype(np.uint8)
    return rgb


def preview_rgb(images):
    """(H, W', 3) uint8: depth (or distance) and normals side by side when both are
    present, else the first present of depth, distance, normal, id, bary, position."""
    depth = images.get("depth", images.get("distance"))
    if depth is not None and "normal" in images:
        return np.concatenate([_depth_panel(depth), _normal_panel(images["normal"])], axis=1)
    if depth is not None:
        return _depth_panel(depth)
    panels = {"normal": _normal_panel, "id": _id_panel, "bary": _bary_panel, "position": _position_panel}
    for name, panel in panels.items():
        if name in images:
            return panel(images[name])
    raise OutputError(f"no image to preview; expected some of {', '.join(AOVS)}.")


def write_preview(path, images):
    """Write an 8-bit RGB PNG of `images` for people (see `preview_rgb`), atomically."""
    try:
        rgb = np.ascontiguousarray(preview_rgb(images))
    except OutputError as exc:
        raise OutputError(f"cannot write {path}: {exc}") from None
    if rgb.ndim != 3 or rgb.shape[0] < 1 or rgb.shape[1] < 1:
        raise OutputError(f"cannot write {path}: images have no pixels.")
    oiio = _oiio()

    def write(tmp):
        out = oiio.ImageOutput.create("png")
        if out is None:
            raise OutputError(f"cannot write {path}: OpenImageIO has no PNG writer ({oiio.geterror()}).")
        spec = oiio.ImageSpec(rgb.shape[1], rgb.shape[0], 3, oiio.UINT8)
        ok = out.open(str(tmp), spec) and out.write_image(rgb)
        ok = out.close() and ok
        if not ok:
            raise OutputError(f"cannot write {path}: {out.geterror() or 'OpenImageIO failed'}.")

    atomic_write(path, write)
