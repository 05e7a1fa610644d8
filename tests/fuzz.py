"""Fuzzing kdray's input surfaces against the error contract of docs/interface.md
(issue 53): a bad input ends in exit 1 with one line `kdray: error: ...` on stderr (2 and
click's usage message for a usage error), never a traceback, a signal, a hang, a numpy
warning or a damaged file; the Python API raises KdrayError (TypeError for a wrong type).

    python tests/fuzz.py --cases 10000 --seed 1            # the long run: counts per surface
    python tests/fuzz.py --cases 300 --surface camera -v   # one surface, failures in full
    python tests/fuzz.py --spawn --cases 40                # each CLI case a fresh `kdray`
    python tests/fuzz.py --save fuzz-failures ...          # each failure's files and command

Each surface's valid examples are mutated with a seeded generator (numpy's PCG64), aware
of their structure:

| surface | examples | mutated through |
|---|---|---|
| mesh | OBJ (plain, gzip), PLY (ASCII, binary), glTF, GLB | `kdray build`/`render`, `kdray.load` + `build` |
| tree | `kdray build --dump` files of versions 1, 2 and 3 | `kdray info --check`/`render --tree`, `KdTree.load` |
| camera | camera files: look-at, K matrix and dict, opencv, fisheye, equirectangular, orthographic | `kdray render --camera`, `Camera.from_json` |
| cameras | nerfstudio, JSON lists, one camera, COLMAP text | `kdray render --cameras`, `read_cameras` |
| lidar | specs of both forms | `kdray scan --lidar`, `Lidar.from_json` |
| pose | text and .npy poses | `kdray scan --pose`, `render --pose`, `pose_from_file` |
| batch | JOBS files | `kdray batch`, `read_jobs` |
| points | `kdray contains --points` files, .npy and text | `kdray contains` |
| argv | every value of every command's options, outputs aliased | each `kdray` command |
| api | arrays and parameters of Tracer, Camera, Lidar, Mesh, build, kdray.sdf | a worker process |

Mutations: JSON values replaced at a random path (huge and tiny numbers, NaN and
Infinity, integers of 5,000 digits, wrong types, unicode and NUL in strings, paths),
keys dropped, added or duplicated, values nested 50,000 deep, lists and sizes made
extreme; text lines dropped, repeated or garbled and numbers replaced; bytes flipped,
cut or appended; tree files' header fields, nodes and floats overwritten, re-sealed
with a recomputed checksum half the time; outputs aliased to inputs or to each other
(also through `./`, `..` and links); virtual arrays of 2^36 rows (np.broadcast_to: no
memory), strided, read-only, of every dtype and shape.

How a case runs and what is checked:

- The command line: in a child forked from a server process that has imported kdray and
  the modules its commands import lazily (a fresh `kdray` process spends about 1 s on
  imports), set up as `preexec_fn` sets up a fresh process: a new session,
  `RLIMIT_AS` (MEMORY_LIMIT), a fresh temporary folder as its working directory, stdin
  from /dev/null, stdout and stderr to files, `KDRAY_CACHE_DIR` of its own; it runs
  `kdray.cli.main` as the console script does. `--spawn` runs the `kdray` script itself
  with subprocess (preexec_fn: the same limits). Checked: exit code 0, 1 or 2, no signal,
  no hang (TIMEOUT of CPU, HARD_TIMEOUT by the clock); exit 1: the last stderr line,
  and only it, starts `kdray: error:` (other lines are kdray's log lines, `kdray:
  ...`); exit 2: click's `Error: ...`; no
  `Traceback`, no Python warning on stderr; every file in the folder hashed before and
  after: on failure none changed or vanished, on success none but the case's outputs, and
  no temporary file (`.NAME.*.tmp`) left; a case the docs promise to refuse (NaN in a
  camera, a JSON file that is not JSON, an output equal to an input, ...) is not exit 0.
- The Python API: in a worker process holding Tracers of cornell.obj and sphere.obj
  (killed and restarted on a hang or a crash, `RLIMIT_AS` set after its set-up): only
  KdrayError, or TypeError for a wrong type; no warning (kdray's OpenMeshWarning aside);
  refusals where the docs promise them; no NaN in an answer that has none by the docs.

`tests/test_fuzz.py` runs a quick seeded subset in `make test` and 10,000+ cases in
`make test-long`; docs/design.md ("Testing") has a long run's counts per surface.
"""
import argparse
import base64
import dataclasses
import gzip
import hashlib
import io
import json
import math
import os
import pickle
import re
import resource
import select
import shutil
import signal
import struct
import subprocess
import sys
import tempfile
import time
import traceback
import warnings
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
SCENES = ROOT / "scenes"
KDRAY = Path(sys.executable).with_name("kdray")

TIMEOUT = 30.0
"""CPU seconds a CLI case (or an API case) may use before it counts as a hang; on a
loaded machine (nice -n 19 beside a benchmark) a case may take longer by the clock, up
to HARD_TIMEOUT, without counting as one."""
HARD_TIMEOUT = 300.0
"""Wall-clock seconds after which a case counts as a hang however little CPU it used
(a deadlock)."""
MEMORY_LIMIT = 4 << 30
"""RLIMIT_AS of a CLI case's process; the API worker gets this much above its set-up."""

SURFACES = ("mesh", "tree", "camera", "cameras", "lidar", "pose", "batch", "points",
            "argv", "api")
CLI_SHARE = {"mesh": 0.25, "tree": 0.25, "camera": 0.2, "cameras": 0.2, "lidar": 0.25,
             "pose": 0.3, "batch": 0.25, "points": 1.0, "argv": 1.0, "api": 0.0}
"""Of a surface's cases, the share run through the command line (the rest through the API)."""

# -- hostile values -------------------------------------------------------------------------

NONFINITE = (math.nan, math.inf, -math.inf)
HUGE = (1e308, -1e308, 1e300, -1e300, 1e39, -1e39, 3.5e38, 1e20, 2**31, 2**32, 2**53 + 1,
        2**63, 2**64, -2**63, 10**30)
TINY = (5e-324, -5e-324, 1e-300, 1e-45, 1e-39, 0.0, -0.0)
SMALL_INTS = (0, -1, 1, 2, 3, 65536, 65537, 1024, 1025, 1000001)
TEXTS = ("", "\x00", "a\x00b", "é", "\u202e", "\U0001f600", "../x", "/", ".", "..", "a/b",
         "x" * 300, "\n", "\u2028", "con", "a\\b", " ", "nan", "20", "1e3")


class Raw:
    """JSON text written as it is (an integer of 5,000 digits, 1e400, -0)."""

    def __init__(self, text):
        self.text = text

    def __repr__(self):
        return f"Raw({self.text[:40]!r}{'...' if len(self.text) > 40 else ''})"


class Dup:
    """A JSON object written with repeated keys: pairs in order."""

    def __init__(self, pairs):
        self.pairs = pairs


def dumps(value):
    """JSON text of `value`; NaN and Infinity as Python writes them, Raw and Dup as above."""
    out = []

    def emit(v):
        if isinstance(v, Raw):
            out.append(v.text)
        elif isinstance(v, Dup):
            out.append("{")
            for i, (k, x) in enumerate(v.pairs):
                out.append(("," if i else "") + json.dumps(k) + ":")
                emit(x)
            out.append("}")
        elif isinstance(v, dict):
            emit(Dup(list(v.items())))
        elif isinstance(v, (list, tuple)):
            out.append("[")
            for i, x in enumerate(v):
                if i:
                    out.append(",")
                emit(x)
            out.append("]")
        elif isinstance(v, float):
            out.append("NaN" if v != v else "Infinity" if v == math.inf else
                       "-Infinity" if v == -math.inf else repr(v))
        else:
            out.append(json.dumps(v))
    emit(value)
    return "".join(out)


def loads(text, **kw):
    """json.loads, integers of any length read (as inf past 4,000 digits)."""
    return json.loads(text, parse_int=lambda s: int(s) if len(s) < 4000 else math.inf, **kw)


def strict_json(data):
    """Whether `data` (bytes) is one JSON document of standard JSON (no NaN/Infinity)."""
    def no_constant(name):
        raise ValueError(name)
    try:
        loads(data.decode("utf-8"), parse_constant=no_constant)
        return True
    except (ValueError, RecursionError):
        return False


def hostile_number(rng):
    """(value, kind): a number no sensor has, or one that is not finite."""
    r = rng.random()
    if r < 0.3:
        return pick(rng, NONFINITE), "nonfinite"
    if r < 0.55:
        return pick(rng, HUGE), "huge"
    if r < 0.7:
        return pick(rng, TINY), "tiny"
    if r < 0.85:
        return pick(rng, SMALL_INTS), "int"
    return Raw(pick(rng, ("1" + "0" * 5000, "1e400", "-1e400", "-0", "1E+2", "0.000000001e-330"))), "raw"


def hostile_other(rng):
    """(value, kind): a wrong type, or a string no field expects."""
    r = rng.random()
    if r < 0.5:
        return pick(rng, ("20", "", "nan", "1e3", None, True, False, [], {}, [1, 2],
                          {"a": 1}, [None], ["x"], [[1, 2], [3, 4]])), "type"
    return pick(rng, TEXTS), "text"


def pick(rng, seq):
    return seq[int(rng.integers(len(seq)))]


# -- structure-aware mutation ---------------------------------------------------------------

def json_paths(value, path=()):
    """Every (path, value) inside a parsed JSON document, the root included."""
    yield path, value
    if isinstance(value, dict):
        for k, v in value.items():
            yield from json_paths(v, path + (k,))
    elif isinstance(value, list):
        for i, v in enumerate(value):
            yield from json_paths(v, path + (i,))


def json_set(doc, path, new):
    if not path:
        return new
    doc = json.loads(json.dumps(doc))  # a copy
    node = doc
    for k in path[:-1]:
        node = node[k]
    node[path[-1]] = new
    return doc


def wrong_type(old, new):
    """Whether `new` is of a type the field of `old` cannot take (a number for a string,
    a string for a number or a list, ...)."""
    def kind(v):
        if isinstance(v, bool) or v is None:
            return "const"
        if isinstance(v, (int, float, Raw)):
            return "number"
        if isinstance(v, str):
            return "string"
        if isinstance(v, list):
            return "list" if not v or all(kind(x) == "number" for x in v) else "other-list"
        return "object"
    a, b = kind(old), kind(new)
    return a in ("number", "string", "list") and b != a and not (a == "list" and b == "other-list")


OPTIONAL_KEYS = ("azimuth_offsets", "horizontal_fov", "up", "fov", "distortion", "model", "name",
                 "aovs", "preview", "precision", "build")
"""Keys a null may stand for the default in (kdray's files read it so or refuse it: either holds)."""


@dataclasses.dataclass
class Mutant:
    """A mutated file: its bytes, what was done, and whether the docs promise a refusal."""
    data: bytes
    what: str
    refuse: bool = False


def mutate_json(doc, rng, strict_keys=True, numeric_refuse=True):
    """One mutation of a parsed JSON document. strict_keys: the format refuses unknown keys
    and wrong types (kdray's own files); numeric_refuse: a NaN or Infinity in any field
    is refused (every field is used)."""
    paths = list(json_paths(doc))
    op = rng.integers(12)
    if op <= 3:                                          # a value replaced
        path, old = paths[int(rng.integers(len(paths)))]
        if isinstance(old, (int, float)) and not isinstance(old, bool) or rng.random() < 0.3:
            new, kind = hostile_number(rng)
        else:
            new, kind = hostile_other(rng)
        refuse = ((kind == "nonfinite" or (isinstance(new, Raw) and "e400" in new.text))
                  and numeric_refuse and path != ())
        refuse |= strict_keys and wrong_type(old, new) and path != () and not (
            new is None and path[-1] in OPTIONAL_KEYS)
        return Mutant(dumps(json_set(doc, path, new)).encode("utf-8", "surrogatepass"),
                      f"{path_name(path)} = {short(new)}", refuse)
    if op == 4 and isinstance(doc, dict) and doc:          # a key dropped
        dicts = [(p, v) for p, v in paths if isinstance(v, dict) and v]
        path, node = dicts[int(rng.integers(len(dicts)))]
        key = pick(rng, list(node))
        new = {k: v for k, v in node.items() if k != key}
        return Mutant(dumps(json_set(doc, path, new)).encode(), f"{path_name(path + (key,))} dropped")
    if op == 5:                                          # a key added
        dicts = [(p, v) for p, v in paths if isinstance(v, dict)]
        if dicts:
            path, node = dicts[int(rng.integers(len(dicts)))]
            key = pick(rng, ("extra", "", "\x00", "width ", "é", "__proto__", "K" * 300))
            new = dict(node)
            new[key] = 1
            return Mutant(dumps(json_set(doc, path, new)).encode(),
                          f"key {short(key)} added at {path_name(path)}",
                          strict_keys and key not in node)
    if op == 6:                                          # a key repeated
        dicts = [(p, v) for p, v in paths if isinstance(v, dict) and v]
        if dicts:
            path, node = dicts[int(rng.integers(len(dicts)))]
            key = pick(rng, list(node))
            new, _ = hostile_number(rng) if rng.random() < 0.5 else hostile_other(rng)
            pairs = list(node.items()) + [(key, new)]
            if rng.random() < 0.5:
                pairs = [(key, new)] + list(node.items())
            text = dumps(json_set(doc, path, "\x00DUP\x00")).replace(
                json.dumps("\x00DUP\x00"), dumps(Dup(pairs)))
            return Mutant(text.encode(), f"key {path_name(path + (key,))} repeated as {short(new)}")
    if op == 7:                                          # deep nesting
        path, old = paths[int(rng.integers(len(paths)))]
        depth = int(pick(rng, (1000, 50000, 200000)))
        deep = "[" * depth + "1" + "]" * depth if rng.random() < 0.5 else \
            '{"a":' * depth + "1" + "}" * depth
        text = dumps(json_set(doc, path, "\x00DEEP\x00")).replace(json.dumps("\x00DEEP\x00"), deep)
        return Mutant(text.encode(), f"{path_name(path)} nested {depth} deep", path != () or True)
    if op == 8:                                          # extreme sizes
        lists = [(p, v) for p, v in paths if isinstance(v, list) and v]
        if lists and rng.random() < 0.5:
            path, node = lists[int(rng.integers(len(lists)))]
            n = int(pick(rng, (0, 1, 2, 5, 1025)))    # more views are work, not an error
            new = (node * (n // len(node) + 1))[:n]
            return Mutant(dumps(json_set(doc, path, new)).encode(), f"{path_name(path)} of {n} items")
        nums = [(p, v) for p, v in paths if isinstance(v, (int, float)) and not isinstance(v, bool)]
        if nums:
            path, _ = nums[int(rng.integers(len(nums)))]
            new = pick(rng, (0, -1, 65536, 65537, 100_000, 10**9, 2**31, 2**40, 0.5, 1.5))
            return Mutant(dumps(json_set(doc, path, new)).encode(), f"{path_name(path)} = {new}")
    text = dumps(doc).encode()
    return mutate_bytes(text, rng, "json")


def mutate_bytes(data, rng, what="bytes"):
    """Byte-level mutations: flips, truncation, NUL and invalid UTF-8, appended junk."""
    b = bytearray(data)
    op = rng.integers(6)
    if op == 0 and b:
        n = int(rng.integers(1, 5))
        for _ in range(n):
            b[int(rng.integers(len(b)))] ^= 1 << int(rng.integers(8))
        desc = f"{n} bits flipped"
    elif op == 1:
        cut = int(rng.integers(len(b) + 1))
        b = b[:cut]
        desc = f"cut to {cut} of {len(data)} bytes"
    elif op == 2:
        at = int(rng.integers(len(b) + 1))
        junk = pick(rng, (b"\x00", b"\xff\xfe", b"\xc3", b"\xed\xa0\x80", "\u2028".encode(), b"\r"))
        b[at:at] = junk
        desc = f"{junk!r} inserted at {at}"
    elif op == 3:
        junk = bytes(rng.integers(256, size=int(rng.integers(1, 64))).astype(np.uint8))
        b += junk
        desc = f"{len(junk)} junk bytes appended"
    elif op == 4:
        b = b[: max(0, len(b) // 2)] + b
        desc = "first half repeated"
    else:
        b = bytearray()
        desc = "emptied"
    return Mutant(bytes(b), f"{what}: {desc}", what == "json" and not strict_json(bytes(b)))


NUMBER = re.compile(rb"-?\d+(?:\.\d*)?(?:[eE][-+]?\d+)?")
TEXT_NUMBERS = (b"nan", b"inf", b"-inf", b"1e309", b"-1e308", b"1e300", b"99999999999999999999",
                b"1" * 5000, b"0x10", b"1,5", b"", b"-0", b"4294967295", b"-4294967296",
                b"2147483648", b"0", b"-1", b"1e-320", b"\x00", "\u0661".encode())


def mutate_text(data, rng, what="text"):
    """Line- and token-level mutations of a text file (OBJ, PLY header, poses, COLMAP)."""
    lines = data.split(b"\n")
    op = rng.integers(9)
    if op <= 2:                                      # a number replaced
        spots = [(i, m) for i, ln in enumerate(lines) for m in NUMBER.finditer(ln)]
        if spots:
            i, m = spots[int(rng.integers(len(spots)))]
            new = pick(rng, TEXT_NUMBERS)
            lines[i] = lines[i][:m.start()] + new + lines[i][m.end():]
            return Mutant(b"\n".join(lines), f"{what}: line {i + 1} number {m.group()[:20]!r} -> {new[:20]!r}")
    if op == 3 and len(lines) > 1:                   # a line dropped
        i = int(rng.integers(len(lines)))
        return Mutant(b"\n".join(lines[:i] + lines[i + 1:]), f"{what}: line {i + 1} dropped")
    if op == 4:                                      # a line repeated
        i = int(rng.integers(len(lines)))
        n = int(pick(rng, (2, 100, 10000)))
        return Mutant(b"\n".join(lines[:i] + [lines[i]] * n + lines[i + 1:]),
                      f"{what}: line {i + 1} x {n}")
    if op == 5:                                      # a line garbled
        i = int(rng.integers(len(lines)))
        junk = pick(rng, (b"", b" ", b"\x00", b"v", b"f 1", b"f 1 2 3 4 5 6 7 8 9", b"f 0 0 0",
                          b"f -1 -2 -3", b"f 99999999 1 2", b"v 1 2", b"v nan nan nan",
                          b"element vertex 4294967295", b"format binary_big_endian 1.0",
                          b"\xff\xfe\x00", b"x" * 100000, "é\u2028".encode(), b"#", b"end_header"))
        lines[i] = junk
        return Mutant(b"\n".join(lines), f"{what}: line {i + 1} -> {junk[:30]!r}")
    if op == 6:                                      # lines shuffled
        order = rng.permutation(len(lines))
        return Mutant(b"\n".join(lines[j] for j in order), f"{what}: lines shuffled")
    if op == 7:                                      # CRLF, tabs, commas
        sep = pick(rng, (b"\r\n", b"\r", b"\t", b","))
        return Mutant(data.replace(b"\n", sep) if sep in (b"\r\n", b"\r") else data.replace(b" ", sep),
                      f"{what}: separators -> {sep!r}")
    return mutate_bytes(data, rng, what)


# -- tree files --------------------------------------------------------------------------------

TREE_HEADER_OFFSETS = (8, 12, 16, 20, 24, 28, 32, 36, 40, 44)
TREE_FLOAT_OFFSETS = (48, 56, 64, 72, 80, 88, 120)


def mutate_tree(data, rng):
    """A tree file mutation; half of them re-seal the checksum (BLAKE2b, 16 bytes), so the
    loader's structural checks are reached, not only its checksum."""
    b = bytearray(data)
    op = rng.integers(7)
    if op == 0:
        off = int(pick(rng, TREE_HEADER_OFFSETS))
        v = int(pick(rng, (0, 1, 2, 3, 4, 127, 129, 2**31, 2**32 - 1, int(rng.integers(2**32)))))
        b[off:off + 4] = v.to_bytes(4, "little")
        desc = f"u32 at {off} = {v}"
    elif op == 1:
        off = int(pick(rng, TREE_FLOAT_OFFSETS))
        v = float(pick(rng, NONFINITE + HUGE[:4] + TINY + (0.0, -1.0, 3.0)))
        b[off:off + 8] = struct.pack("<d", v)
        desc = f"f64 at {off} = {v}"
    elif op == 2:
        off = 96 + 4 * int(rng.integers(6))
        v = float(pick(rng, NONFINITE + (3e38, -3e38, 0.0, 1e-45)))
        b[off:off + 4] = struct.pack("<f", v)
        desc = f"bounds f32 at {off} = {v}"
    elif op == 3:
        n_nodes = int.from_bytes(b[16:20], "little")
        i = 128 + 4 * int(rng.integers(max(1, 2 * n_nodes)))
        v = int(pick(rng, (0, 1, 2, 3, 2**31, 2**32 - 1, int(rng.integers(2**32)))))
        if i + 4 <= len(b) - 16:
            b[i:i + 4] = v.to_bytes(4, "little")
        desc = f"node word at {i} = {v}"
    elif op == 4:
        i = 128 + 4 * int(rng.integers(max(1, (len(b) - 144) // 4)))
        v = float(pick(rng, NONFINITE + (3e38, -3e38)))
        if i + 4 <= len(b) - 16:
            b[i:i + 4] = struct.pack("<f", v)
        desc = f"word at {i} = float {v}"
    else:
        m = mutate_bytes(bytes(b), rng, "tree")
        b = bytearray(m.data)
        desc = m.what
    sealed = rng.random() < 0.5 and len(b) > 16
    if sealed:
        body = bytes(b[:-16])
        b = bytearray(body + hashlib.blake2b(body, digest_size=16).digest())
    return Mutant(bytes(b), f"tree: {desc}" + (", checksum recomputed" if sealed else ""),
                  not sealed and bytes(b) != data)


# -- the valid examples -----------------------------------------------------------------------

def _camera_examples():
    pose = [[1, 0, 0, 0], [0, -1, 0, 0.5], [0, 0, -1, 1.85], [0, 0, 0, 1]]
    K = [[30, 0, 16], [0, 30, 12], [0, 0, 1]]
    return {
        "lookat.json": {"width": 32, "height": 24, "eye": [0, 0.5, 1.85], "target": [0, 0.5, 0],
                        "up": [0, 1, 0], "fov": 40},
        "k.json": {"width": 32, "height": 24, "K": K, "cam_to_world": pose},
        "kdict.json": {"width": 32, "height": 24, "K": {"fx": 30, "fy": 30, "cx": 16, "cy": 12},
                       "cam_to_world": pose},
        "opencv.json": {"width": 32, "height": 24, "K": K, "cam_to_world": pose, "model": "opencv",
                        "distortion": [-0.1, 0.01, 0.001, -0.001, 0.0]},
        "fisheye.json": {"width": 32, "height": 24, "eye": [0, 0.5, 1.85], "target": [0, 0.5, 0],
                         "fov": 60, "model": "fisheye", "distortion": [0.05, -0.01, 0.0, 0.0]},
        "equirect.json": {"width": 32, "height": 16, "eye": [0, 0.5, 0], "target": [0, 0.5, -1],
                          "model": "equirectangular"},
        "ortho.json": {"width": 32, "height": 24, "K": [[30, 0, 16], [0, 30, 12], [0, 0, 1]],
                       "cam_to_world": pose, "model": "orthographic"},
    }


def _cameras_examples():
    frame = lambda i: {"file_path": f"images/frame_{i:05d}.png",
                       "transform_matrix": [[1, 0, 0, 0.1 * i], [0, 1, 0, 0.5], [0, 0, 1, 1.85],
                                            [0, 0, 0, 1]]}
    return {
        "transforms.json": {"camera_model": "OPENCV", "fl_x": 30, "fl_y": 30, "cx": 16, "cy": 12,
                            "w": 32, "h": 24, "k1": 0.01, "k2": 0, "p1": 0, "p2": 0,
                            "frames": [frame(0), frame(1)]},
        "fisheye_transforms.json": {"camera_model": "OPENCV_FISHEYE", "fl_x": 20, "cx": 16,
                                    "cy": 12, "w": 32, "h": 24, "k1": 0.01, "k2": 0, "k3": 0,
                                    "k4": 0, "frames": [frame(0)]},
        "pano_transforms.json": {"camera_model": "EQUIRECTANGULAR", "fl_x": 16, "fl_y": 16,
                                 "cx": 16, "cy": 8, "w": 32, "h": 16, "frames": [frame(2)]},
        "list.json": [dict(_camera_examples()["lookat.json"], name="a"),
                      dict(_camera_examples()["k.json"], name="b")],
        "one.json": _camera_examples()["kdict.json"],
    }


COLMAP = {
    "cameras.txt": b"# CAMERA_ID MODEL WIDTH HEIGHT PARAMS\n1 PINHOLE 32 24 30 30 16 12\n"
                   b"2 OPENCV 32 24 30 30 16 12 0.01 0 0 0\n",
    "images.txt": b"# images\n1 1 0 0 0 0 -0.5 1.85 1 images/a.png\n\n"
                  b"2 0.7071067811865476 0 0.7071067811865476 0 0 -0.5 1.85 2 b.png\n"
                  b"10.0 20.0 -1\n",
}

LIDARS = {
    "os.json": {"channels": 16, "fov_up": 22.5, "fov_down": -22.5, "columns": 64, "max_range": 120},
    "table.json": {"elevations": [15.0, 11.0, 7.0, 3.0, -1.0, -5.0, -9.0, -13.0],
                   "azimuth_offsets": [0.0, -1.2, 0.0, -1.2, 0.0, -1.2, 0.0, -1.2],
                   "columns": 48, "max_range": 100, "horizontal_fov": 270},
}

SENSOR_POSE = b"# sensor-to-world\n1 0 0 0\n0 1 0 0.5\n0 0 1 0\n0 0 0 1\n"
CAMERA_POSE = b"# camera-to-world, OpenCV axes\n1 0 0 0\n0 -1 0 0.5\n0 0 -1 1.85\n0 0 0 1\n"


class Examples:
    """The valid examples of every surface, made once: name -> bytes."""

    def __init__(self):
        import trimesh
        import kdray
        cornell = (SCENES / "cornell.obj").read_bytes()
        self.scene = cornell
        self.sphere = (SCENES / "sphere.obj").read_bytes()
        mesh = trimesh.load(io.BytesIO(cornell), file_type="obj", process=False)
        ply_ascii = trimesh.exchange.ply.export_ply(mesh, encoding="ascii")
        ply_bin = trimesh.exchange.ply.export_ply(mesh, encoding="binary")
        glb = trimesh.Scene({"a": mesh, "b": mesh.copy().apply_translation([2, 0, 0])}).export(file_type="glb")
        files = trimesh.Scene({"a": mesh}).export(file_type="gltf")
        gltf = json.loads(files["model.gltf"].decode())
        for buf in gltf.get("buffers", []):         # the buffer embedded: one file
            if buf.get("uri") in files:
                buf["uri"] = "data:application/octet-stream;base64," + base64.b64encode(files[buf["uri"]]).decode()
        self.meshes = {"cornell.obj": cornell, "quads.obj": (SCENES / "quads.obj").read_bytes(),
                       "tet.obj": b"o a\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\n"
                                  b"o b\nf 1 4 3\nf 2 3 4\n",
                       "cornell.ply": ply_ascii, "binary.ply": ply_bin, "two.glb": glb,
                       "cornell.obj.gz": gzip.compress(cornell, mtime=0)}
        self.meshes["cornell.gltf"] = json.dumps(gltf).encode()
        m = kdray.load(SCENES / "cornell.obj")
        tree = kdray.build(m.vertices, m.faces)
        far = kdray.build(m.vertices * 2.0**50, m.faces)
        objects = tree.with_objects(np.arange(len(m.faces)) % 3, ("a", "b", "é\u2028c"))
        self.trees = {"v1.kdt": tree.to_bytes(), "v2.kdt": far.to_bytes(), "v3.kdt": objects.to_bytes()}
        self.cameras = _camera_examples()
        self.camera_lists = _cameras_examples()
        self.lidars = LIDARS
        pose = np.loadtxt(io.BytesIO(SENSOR_POSE))
        npy = io.BytesIO()
        np.save(npy, pose)
        self.poses = {"sensor.txt": SENSOR_POSE, "camera.txt": CAMERA_POSE, "sensor.npy": npy.getvalue()}
        pts = np.random.default_rng(0).uniform(-1.2, 1.2, (20, 3))
        npy = io.BytesIO()
        np.save(npy, pts)
        self.points = {"points.npy": npy.getvalue(),
                       "points.txt": "\n".join(" ".join(repr(x) for x in p) for p in pts).encode()}
        rays = np.concatenate([pts, np.random.default_rng(1).normal(size=(20, 3))], axis=1)
        npy = io.BytesIO()
        np.save(npy, rays)
        self.rays = {"rays.npy": npy.getvalue()}


# -- cases ---------------------------------------------------------------------------------------

@dataclasses.dataclass
class Case:
    """One run: the files of its folder (relative name -> bytes; a name ending in "/" is a
    folder, `Link(target)` a symbolic link), a command line (argv after `kdray`) or an API
    call (op, args, kwargs), what was mutated, and whether the docs promise a refusal."""
    surface: str
    what: str
    files: dict
    argv: list = None
    op: str = None
    args: tuple = ()
    kwargs: dict = dataclasses.field(default_factory=dict)
    refuse: bool = False
    type_error_ok: bool = False       # TypeError allowed (docs/interface.md, "Errors": only
                                      # for calls that do not fit a signature)
    outputs: tuple = ()

    @property
    def cli(self):
        return self.argv is not None

    def describe(self):
        if self.cli:
            return "kdray " + " ".join(_quote(a) for a in self.argv)
        args = ", ".join([_arg(a) for a in self.args] + [f"{k}={_arg(v)}" for k, v in self.kwargs.items()])
        return f"{self.op}({args})"


@dataclasses.dataclass(frozen=True)
class Link:
    """A symbolic link to `target` (hard=True: a hard link, the same file under two names)."""
    target: str
    hard: bool = False


@dataclasses.dataclass(frozen=True)
class Huge:
    """A virtual array of `shape` filled with `value` (np.broadcast_to: no memory)."""
    shape: tuple
    value: float = 0.5
    dtype: str = "float64"

    def array(self):
        return np.broadcast_to(np.asarray(self.value, dtype=self.dtype), self.shape)


def _quote(a):
    return a if re.fullmatch(r"[\w./,:=+-]+", a) else repr(a)


def _arg(a):
    """An argument for a reproducer line: arrays by dtype and shape (and any NaN/inf)."""
    if isinstance(a, np.ndarray) and a.size > 4:
        odd = ""
        if a.dtype.kind == "f":
            odd = f", nonfinite at {np.argwhere(~np.isfinite(a))[:1].tolist()}" if not np.isfinite(a).all() else \
                f", max |x| {np.abs(a).max():.3g}"
        return f"<{a.dtype} {a.shape}{odd}{', read-only' if not a.flags.writeable else ''}>"
    return short(a, 60)


def short(v, n=40):
    r = repr(v)
    return r if len(r) <= n else r[:n] + f"...({len(r)} chars)"


def path_name(path):
    return "".join(f"[{k!r}]" for k in path) or "the document"


def json_bytes(doc):
    return dumps(doc).encode()


class Generator:
    """Cases of each surface from the examples, seeded."""

    def __init__(self, examples, seed):
        self.ex = examples
        self.rng = np.random.default_rng(seed)

    def cases(self, surface, n, cli_scale=1.0):
        make = getattr(self, "_" + surface)
        share = CLI_SHARE[surface] * (cli_scale if CLI_SHARE[surface] < 1 else 1)
        for _ in range(n):
            yield make(self.rng.random() < share)

    # file surfaces: one mutated file, read by the CLI or by the API

    def _mesh(self, cli):
        rng = self.rng
        name = pick(rng, sorted(self.ex.meshes))
        data = self.ex.meshes[name]
        if name.endswith(".gz") and rng.random() < 0.5:
            m = mutate_text(gzip.decompress(data), rng, "obj in gzip")
            m = Mutant(gzip.compress(m.data, mtime=0), m.what, m.refuse)
        elif name.endswith((".obj", ".ply")) and not name.startswith("binary") and rng.random() < 0.8:
            m = mutate_text(data, rng, name)
        elif name.endswith(".gltf") and rng.random() < 0.7:
            m = mutate_json(json.loads(data), rng, strict_keys=False, numeric_refuse=False)
            m.refuse = False
        elif name.endswith(".ply") and rng.random() < 0.5:       # the binary one's header
            head, sep, body = data.partition(b"end_header\n")
            m = mutate_text(head, rng, "ply header")
            m = Mutant(m.data + sep + body, m.what)
        else:
            m = mutate_bytes(data, rng, name)
            m.refuse = False
        files = {name: m.data}
        if cli:
            if rng.random() < 0.8:
                return Case("mesh", m.what, files, ["build", name])
            return Case("mesh", m.what, files, ["render", name, "--size", "8x6", "-o", "out.exr",
                                                "--aov", "depth"], outputs=("out.exr",))
        return Case("mesh", m.what, files, op="load", args=(name,))

    def _tree(self, cli):
        rng = self.rng
        name = pick(rng, sorted(self.ex.trees))
        m = mutate_tree(self.ex.trees[name], rng)
        files = {name: m.data, "cornell.obj": self.ex.scene}
        if cli:
            if rng.random() < 0.8:
                return Case("tree", m.what, files, ["info", name, "--check"], refuse=m.refuse)
            return Case("tree", m.what, files, ["render", "cornell.obj", "--tree", name, "--size", "8x6",
                                                "-o", "out.exr", "--aov", "depth,id"],
                        refuse=m.refuse, outputs=("out.exr",))
        return Case("tree", m.what, files, op="tree_load", args=(name,), refuse=m.refuse)

    def _camera(self, cli):
        rng = self.rng
        name = pick(rng, sorted(self.ex.cameras))
        doc = self.ex.cameras[name]
        m = mutate_json(doc, rng)
        m = self._size_rule(m, doc)
        files = {name: m.data, "cornell.obj": self.ex.scene}
        if cli:
            return Case("camera", m.what, files, ["render", "cornell.obj", "--camera", name,
                                                  "-o", "out.exr", "--aov", "depth"],
                        refuse=m.refuse, outputs=("out.exr",))
        return Case("camera", m.what, files, op="camera_json", args=(name,), refuse=m.refuse)

    @staticmethod
    def _size_rule(m, doc):
        """A width or height that is not a whole number from 1 to 65,536 is refused, as
        --cameras refuses it (issue 53: one rule for both)."""
        try:
            got = loads(m.data)
        except (ValueError, RecursionError):
            return m
        for obj in (got if isinstance(got, list) else [got]):
            if isinstance(obj, dict):
                for key in ("width", "height", "w", "h"):
                    v = obj.get(key)
                    if isinstance(v, (int, float)) and not isinstance(v, bool) and (
                            not math.isfinite(v) or v != int(v) or not 1 <= v <= 65536):
                        m.refuse = True
        return m

    def _cameras(self, cli):
        rng = self.rng
        if rng.random() < 0.2:                      # COLMAP text
            which = pick(rng, sorted(COLMAP))
            m = mutate_text(COLMAP[which], rng, which)
            files = {"sparse/": None, **{f"sparse/{k}": v for k, v in COLMAP.items()}}
            files[f"sparse/{which}"] = m.data
            path = pick(rng, ("sparse", "sparse/cameras.txt", "sparse/images.txt"))
        else:
            name = pick(rng, sorted(self.ex.camera_lists))
            doc = self.ex.camera_lists[name]
            m = mutate_json(doc, rng, strict_keys=name in ("list.json", "one.json"),
                            numeric_refuse=name in ("list.json", "one.json"))
            if name.endswith("transforms.json"):   # nerfstudio ignores keys it does not know
                m.refuse = not strict_json(m.data) and m.what.startswith("json")
            m = self._size_rule(m, doc)
            files = {name: m.data}
            path = name
        files["cornell.obj"] = self.ex.scene
        if cli:
            return Case("cameras", m.what, files, ["render", "cornell.obj", "--cameras", path,
                                                   "-o", "views", "--aov", "depth", "--no-cache"],
                        refuse=m.refuse, outputs=("views/",))
        return Case("cameras", m.what, files, op="read_cameras", args=(path,), refuse=m.refuse)

    def _lidar(self, cli):
        rng = self.rng
        name = pick(rng, sorted(self.ex.lidars))
        m = mutate_json(self.ex.lidars[name], rng)
        try:
            got = loads(m.data)
            if isinstance(got, dict):
                cols = got.get("columns")
                if isinstance(cols, (int, float)) and not isinstance(cols, bool) and not 1 <= cols <= 65536:
                    m.refuse = True
        except (ValueError, RecursionError):
            pass
        files = {name: m.data, "pose.txt": SENSOR_POSE, "cornell.obj": self.ex.scene}
        if cli:
            return Case("lidar", m.what, files, ["scan", "cornell.obj", "--lidar", name, "--pose",
                                                 "pose.txt", "-o", "scan.exr"],
                        refuse=m.refuse, outputs=("scan.exr",))
        return Case("lidar", m.what, files, op="lidar_json", args=(name,), refuse=m.refuse)

    def _pose(self, cli):
        rng = self.rng
        name = pick(rng, sorted(self.ex.poses))
        data = self.ex.poses[name]
        if name.endswith(".npy"):
            if rng.random() < 0.5:
                arr = np.loadtxt(io.BytesIO(SENSOR_POSE))
                i, j = int(rng.integers(4)), int(rng.integers(4))
                v, kind = hostile_number(rng)
                if isinstance(v, Raw):
                    v = math.inf
                arr[i, j] = float(v)
                dtype = pick(rng, ("float64", "float32", "float16", "int64", "complex128", "object", "U8"))
                buf = io.BytesIO()
                try:
                    with np.errstate(all="ignore"):
                        np.save(buf, arr.astype(dtype), allow_pickle=True)
                except (OverflowError, ValueError):
                    np.save(buf, arr)
                m = Mutant(buf.getvalue(), f"npy pose [{i},{j}] = {v}, {dtype}",
                           dtype.startswith("float") and not math.isfinite(float(v))
                           or dtype in ("object", "U8", "complex128"))
            else:
                m = mutate_bytes(data, rng, "npy pose")
        else:
            m = mutate_text(data, rng, name)
            try:
                text = m.data.decode()
                nums = [float(x) for x in re.sub(r"#[^\n]*", "", text).replace(",", " ").split()]
                m.refuse = len(nums) == 16 and not all(math.isfinite(x) for x in nums)
            except (ValueError, UnicodeDecodeError):
                pass
        files = {name: m.data, "cornell.obj": self.ex.scene}
        if cli:
            if rng.random() < 0.5:
                files["lidar.json"] = json_bytes(LIDARS["os.json"])
                return Case("pose", m.what, files, ["scan", "cornell.obj", "--lidar", "lidar.json",
                                                    "--pose", name, "-o", "scan.exr"],
                            refuse=m.refuse, outputs=("scan.exr",))
            return Case("pose", m.what, files, ["render", "cornell.obj", "--intrinsics", "30,30,16,12",
                                                "--pose", name, "--size", "32x24", "-o", "out.exr",
                                                "--aov", "depth"], refuse=m.refuse, outputs=("out.exr",))
        return Case("pose", m.what, files, op="pose_file", args=(name,), refuse=m.refuse)

    def _batch(self, cli):
        rng = self.rng
        jobs = [{"scene": "cornell.obj", "cameras": "cams.json", "output": "out/a"},
                {"scene": "cornell.obj", "cameras": "cams.json", "output": "out/b",
                 "aovs": ["depth", "id"], "preview": True, "precision": "single",
                 "build": {"K_T": 15, "K_I": 20, "empty_bonus": 0.8, "max_depth": 0, "leaf_size": 1}}]
        op = rng.integers(6)
        refuse = False
        if op <= 2:
            i = int(rng.integers(2))
            m = mutate_json(jobs[i], rng)
            lines = [json_bytes(j) for j in jobs]
            lines[i] = m.data
            what, refuse = f"job {i + 1}: {m.what}", m.refuse
            if b"\n" in m.data or b"\r" in m.data or "\u2028".encode() in m.data or not m.data.strip():
                refuse = False                     # a new line or a blank one: another count of jobs
            data = b"\n".join(lines) + b"\n"
        elif op == 3:                               # two jobs, one output; outputs on inputs
            alias = pick(rng, ("out/a", "./out/a", "out/../out/a", "cornell.obj", "cams.json",
                               "jobs.jsonl", "out/a/", "OUT/A" if False else "out//a"))
            jobs[1]["output"] = alias
            data = b"\n".join(json_bytes(j) for j in jobs) + b"\n"
            what, refuse = f"job 2's output {alias!r}", True
            if not cli:        # read_jobs checks the folders' names; `kdray batch` the files too
                refuse = os.path.normpath(alias) == "out/a"
        else:
            m = mutate_text(b"\n".join(json_bytes(j) for j in jobs) + b"\n", rng, "jobs")
            data, what = m.data, m.what
        files = {"jobs.jsonl": data, "cornell.obj": self.ex.scene,
                 "cams.json": json_bytes([dict(_camera_examples()["lookat.json"], width=8, height=6)])}
        if cli:
            return Case("batch", what, files, ["batch", "jobs.jsonl", "--no-cache"], refuse=refuse,
                        outputs=("out/",))
        return Case("batch", what, files, op="read_jobs", args=("jobs.jsonl",), refuse=refuse)

    def _points(self, cli):
        rng = self.rng
        name = pick(rng, sorted(self.ex.points))
        data = self.ex.points[name]
        refuse = False
        if name.endswith(".npy") and rng.random() < 0.6:
            shape = pick(rng, ((20, 3), (0, 3), (20, 2), (3,), (20, 3, 1), (1, 3), (5, 4)))
            dtype = pick(rng, ("float64", "float32", "float16", "int8", "uint64", "bool",
                               "complex64", "U4", "object", "datetime64[s]"))
            arr = np.zeros(shape)
            if arr.size and rng.random() < 0.5:
                arr.flat[int(rng.integers(arr.size))] = pick(rng, NONFINITE + HUGE[:4])
            buf = io.BytesIO()
            try:
                with np.errstate(all="ignore"):
                    a = arr.astype(dtype)
                np.save(buf, a, allow_pickle=True)
            except (OverflowError, ValueError, TypeError):
                np.save(buf, arr)
                dtype = "float64"
            data = buf.getvalue()
            what = f"points {shape} {dtype}"
            refuse = dtype.startswith("float") and len(shape) == 2 and shape[1] == 3 and \
                not np.isfinite(arr).all()
            refuse |= shape[-1:] != (3,) or len(shape) != 2 or dtype in ("U4", "object", "datetime64[s]", "complex64")
        elif name.endswith(".txt"):
            m = mutate_text(data, rng, name)
            data, what = m.data, m.what
        else:
            m = mutate_bytes(data, rng, name)
            data, what = m.data, m.what
        files = {name: data, "sphere.obj": self.ex.sphere}
        argv = ["contains", "sphere.obj", "--points", name, "-o", "in.npy"]
        if rng.random() < 0.3:
            argv += ["--count", pick(rng, ("1,0,0", "0,0,0", "nan,0,0", "1e309,0,0", "1,2", "0,1e-300,0"))]
            refuse |= argv[-1] in ("0,0,0", "nan,0,0", "1e309,0,0", "1,2")
        return Case("points", what, files, argv, refuse=refuse, outputs=("in.npy",))

    # every command's values

    def _argv(self, cli):
        rng = self.rng
        files = {"cornell.obj": self.ex.scene, "sphere.obj": self.ex.sphere,
                 "cam.json": json_bytes(self.ex.cameras["lookat.json"]),
                 "cams.json": json_bytes(self.ex.camera_lists["list.json"]),
                 "lidar.json": json_bytes(LIDARS["os.json"]), "pose.txt": SENSOR_POSE,
                 "campose.txt": CAMERA_POSE, "t.kdt": self.ex.trees["v1.kdt"],
                 "pts.npy": self.ex.points["points.npy"], "rays.npy": self.ex.rays["rays.npy"],
                 "sub/": None,
                 "link.obj": Link("cornell.obj"), "hard.obj": Link("cornell.obj", hard=True),
                 "old.exr": b"not an exr, but it was here",
                 "jobs.jsonl": json_bytes({"scene": "cornell.obj", "cameras": "cams.json",
                                           "output": "out/a"}) + b"\n"}
        base = pick(rng, ARGV_TEMPLATES)
        argv = list(base["argv"])
        outputs = tuple(base.get("outputs", ()))
        op = rng.integers(10)
        refuse = False
        if op <= 5 and base["values"]:              # one option's value made hostile
            opt = pick(rng, sorted(base["values"]))
            kind = base["values"][opt]
            value, refuse = hostile_option(rng, kind)
            value = value.replace("\x00", "")     # no command line can carry a NUL byte
            if kind == "out":                       # an existing file asked for: it may change
                outputs += (value, value.rstrip("/") + "/")
            if opt in argv:
                i = argv.index(opt)
                argv[i + 1] = value
            else:
                argv += [opt, value]
            what = f"{opt} {short(value)}"
        elif op == 6 and base.get("aliases"):       # an output on an input or another output
            opt, alias = pick(rng, base["aliases"])
            alias = pick(rng, (alias, "./" + alias, "sub/../" + alias)) if "/" not in alias else alias
            if opt in argv:
                argv[argv.index(opt) + 1] = alias
            else:
                argv += [opt, alias]
            what, refuse = f"{opt} {alias} (an input or another output)", True
        elif op == 7:                               # an option repeated, a flag or option added
            extra = pick(rng, (["--size", "8x6"], ["-o", "sub/x.exr"], ["--bogus"], ["-v"], ["-q"],
                               ["--aov", "depth"], ["--device", "0:0"], ["--overwrite"], ["--cull"],
                               ["--precision", "double"], ["--occupancy"], ["--check"], ["--samples", "3"]))
            argv += extra
            what = f"{' '.join(extra)} added"
        elif op == 8 and len(argv) > 1:             # an option's value dropped, or an argument
            i = int(rng.integers(1, len(argv)))
            argv = argv[:i] + argv[i + 1:]
            what = f"{base['argv'][i]!r} left out"
        else:                                       # a global option in the wrong place, or none
            g = pick(rng, (["-v"], ["-vv"], ["-q"], ["-q", "-v"]))
            argv = g + argv if rng.random() < 0.7 else argv[:1] + g + argv[1:]
            what = f"global {' '.join(g)}"
        return Case("argv", what, files, argv, refuse=refuse, outputs=outputs)

    # the Python API

    def _api(self, cli):
        return api_case(self.rng)


def hostile_option(rng, kind):
    """(value, refused by the docs) for an option of `kind`."""
    if kind == "float":
        v = pick(rng, ("nan", "inf", "-inf", "1e309", "-1e308", "1e300", "0", "-0", "-1", "1e-320",
                       "abc", "", "1,2", "9" * 5000, "0x10", "1_000", " 5", "\u0661"))
        try:
            refuse = not math.isfinite(float(v))
        except ValueError:
            refuse = True
        return v, refuse
    if kind == "int":
        v = pick(rng, ("0", "-1", "1", "2", "65537", "4097", "1025", "2147483648", "9" * 30,
                       "9" * 5000, "1.5", "nan", "", "abc", "1e3", "0x10"))
        try:
            int(v)
            refuse = False
        except ValueError:
            refuse = True
        return v, refuse
    if kind == "t":                 # t_min, t_max, a distance limit: >= 0, inf allowed
        v = pick(rng, ("nan", "inf", "-inf", "1e309", "-1", "0", "-0", "1", "1e-320", "abc", "",
                       "1,2"))
        try:
            refuse = not float(v) >= 0
        except ValueError:
            refuse = True
        return v, refuse
    if kind == "count":             # work asked for: large counts are slow, not wrong
        v = pick(rng, ("0", "-1", "1", "2", "1.5", "nan", "", "abc", "9" * 5000, "0x10"))
        try:
            refuse = int(v) < 1
        except ValueError:
            refuse = True
        return v, refuse
    if kind in ("vec3", "vec4"):
        n = int(kind[-1])
        v = pick(rng, ("nan,0,0", "inf,1,1", "1e309,0,0", "0,0,0", "1e300,1e300,1e300", "1,2",
                       "1,2,3,4", "", "a,b,c", "1e-320,0,0", "0,1e39,0", ",,", "30,30,16,nan",
                       "1e308,1e308,16,12", "30,30,1e300,12", "-30,30,16,12", "0,0,0,0", "30,30,16,12,1"))
        try:
            nums = [float(x) for x in v.split(",")]
            refuse = len(nums) != n or not all(math.isfinite(x) for x in nums)
        except ValueError:
            refuse = True
        return v, refuse
    if kind == "size":
        v = pick(rng, ("0x3", "1x1", "65536x1", "65537x1", "100000x100000", "65536x65536",
                       "-1x5", "8x", "x", "8X6", "1e3x2", "9" * 5000 + "x1", "8x6x2", "", "8 x 6"))
        m = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", v)
        refuse = not m or min(int(g) if len(g) < 20 else 2**64 for g in m.groups()) < 1 \
            or max(len(g) for g in m.groups()) >= 20
        return v, refuse
    if kind == "aov":
        return pick(rng, ("", ",", "depth,,id", "DEPTH", "all", "nope", "depth,nope", "é", "id" * 1000,
                          "depth\u2028id")), False
    if kind == "path":
        return pick(rng, ("missing.json", "sub", ".", "", "/dev/null", "sub/", "é.json",
                          "x" * 300, "\u2028", "link.obj", "old.exr", "/proc/self/status")), False
    if kind == "out":
        return pick(rng, ("sub", ".", "", "/", "missing/x.exr", "x" * 300 + ".exr", "é.exr",
                          "sub/", "/dev/null", "old.exr", ".old.exr.tmp", "-")), False
    if kind == "device":
        return pick(rng, ("nonsense", "99", "99:99", "", "0:99", "-1", "é", ":", "1:", "oclgrind:9")), False
    if kind == "sign":
        return pick(rng, ("", "WINDING", "x")), False
    return pick(rng, TEXTS[:8]), False


ARGV_TEMPLATES = (
    {"argv": ["build", "cornell.obj"],
     "values": {"--k-t": "float", "--k-i": "float", "--empty-bonus": "float",
                "--max-depth": "int", "--leaf-size": "int", "--dump": "out"},
     "aliases": [("--dump", "cornell.obj"), ("--dump", "link.obj")], "outputs": ("x.kdt",)},
    {"argv": ["info", "t.kdt"], "values": {}, "aliases": []},
    {"argv": ["render", "cornell.obj", "--size", "8x6", "-o", "x.exr", "--aov", "depth"],
     "values": {"--size": "size", "--eye": "vec3", "--target": "vec3",
                "--fov": "float", "--aov": "aov", "-o": "out", "--preview": "out",
                "--camera": "path", "--tree": "path", "--device": "device", "--k-t": "float",
                "--max-depth": "int"},
     "aliases": [("-o", "cornell.obj"), ("--preview", "x.exr"), ("-o", "link.obj"),
                 ("--preview", "cornell.obj"), ("-o", "hard.obj"), ("--preview", "hard.obj")],
     "outputs": ("x.exr", "x.png")},
    {"argv": ["render", "cornell.obj", "--eye", "0,0.5,1.85", "--target", "0,0.5,0", "--size", "8x6",
              "-o", "x.exr", "--aov", "depth", "--preview", "x.png"],
     "values": {"--eye": "vec3", "--target": "vec3", "--up": "vec3", "--fov": "float",
                "--size": "size"},
     "aliases": [("--preview", "x.exr"), ("-o", "x.png")],
     "outputs": ("x.exr", "x.png")},
    {"argv": ["render", "cornell.obj", "--intrinsics", "30,30,16,12", "--pose", "campose.txt",
              "--size", "32x24", "-o", "x.exr", "--aov", "depth"],
     "values": {"--intrinsics": "vec4", "--pose": "path", "--size": "size"},
     "aliases": [("-o", "campose.txt"), ("--preview", "campose.txt")], "outputs": ("x.exr", "x.png")},
    {"argv": ["render", "cornell.obj", "--tree", "t.kdt", "--camera", "cam.json", "-o", "x.exr",
              "--aov", "depth"],
     "values": {"--tree": "path", "--camera": "path", "--aov": "aov"},
     "aliases": [("-o", "t.kdt"), ("-o", "cam.json"), ("--preview", "t.kdt")], "outputs": ("x.exr", "x.png")},
    {"argv": ["render", "cornell.obj", "--cameras", "cams.json", "-o", "views", "--aov", "depth",
              "--no-cache"],
     "values": {"--cameras": "path", "-o": "out", "--workers": "int", "--aov": "aov"},
     "aliases": [("-o", "cornell.obj"), ("-o", "cams.json")], "outputs": ("views/",)},
    {"argv": ["scan", "cornell.obj", "--lidar", "lidar.json", "--pose", "pose.txt", "-o", "s.exr"],
     "values": {"--lidar": "path", "--pose": "path", "-o": "out", "--points": "out",
                "--device": "device"},
     "aliases": [("--points", "s.exr"), ("-o", "lidar.json"), ("--points", "pose.txt"),
                 ("-o", "cornell.obj")], "outputs": ("s.exr", "s.ply")},
    {"argv": ["contains", "sphere.obj", "--points", "pts.npy", "-o", "in.npy"],
     "values": {"--points": "path", "-o": "out", "--count": "vec3", "--tree": "path"},
     "aliases": [("-o", "pts.npy"), ("-o", "sphere.obj")], "outputs": ("in.npy",)},
    {"argv": ["cast", "sphere.obj", "--rays", "rays.npy", "-o", "h.npz", "--query", "all"],
     "values": {"--rays": "path", "-o": "out", "--max-hits": "count", "--t-min": "t",
                "--t-max": "t", "--tree": "path"},
     "aliases": [("-o", "rays.npy"), ("-o", "sphere.obj")], "outputs": ("h.npz",)},
    {"argv": ["points", "sphere.obj", "--points", "pts.npy", "-o", "q.npz", "--query", "closest"],
     "values": {"--points": "path", "-o": "out", "--max-distance": "t", "--tree": "path"},
     "aliases": [("-o", "pts.npy"), ("-o", "sphere.obj")], "outputs": ("q.npz",)},
    {"argv": ["sdf", "sphere.obj", "-o", "g.npz", "--resolution", "8"],
     "values": {"--resolution": "int", "--padding": "float", "--sign": "sign", "-o": "out"},
     "aliases": [("-o", "sphere.obj")], "outputs": ("g.npz",)},
    {"argv": ["sdf", "sphere.obj", "-o", "g.npz", "--samples", "50"],
     "values": {"--samples": "int", "--sigma": "float", "--uniform": "float", "--seed": "int",
                "--padding": "float"},
     "aliases": [("-o", "sphere.obj")], "outputs": ("g.npz",)},
    {"argv": ["batch", "jobs.jsonl", "--no-cache"], "values": {"--workers": "int"},
     "aliases": [], "outputs": ("out/",)},
    {"argv": ["bench", "cornell.obj", "--size", "8x8", "--repeat", "1", "--sample", "10"],
     "values": {"--size": "size", "--repeat": "count", "--sample": "count", "--offset": "float",
                "--settings": "text", "--csv": "out"},
     "aliases": [("--csv", "cornell.obj")], "outputs": ("b.csv",)},
    {"argv": ["cache"], "values": {}, "aliases": []},
)


# -- the API's cases ----------------------------------------------------------------------------

RAY_OPS = ("trace", "occluded", "count", "intersections")
POINT_OPS = ("contains", "closest_points", "distance", "signed_distance", "winding_number", "occupancy")


def hostile_array(rng, rows=16, cols=3):
    """(array-like, what, kind): kind "ok" (numbers of the right shape), "nonfinite",
    "shape", "type" or "huge" (2^36 rows, virtual)."""
    r = rng.random()
    good = np.random.default_rng(int(rng.integers(1 << 30))).uniform(-1.5, 1.5, (rows, cols))
    if r < 0.25:
        a = good.copy()
        a.flat[int(rng.integers(a.size))] = pick(rng, NONFINITE)
        return a, "a NaN/inf component", "nonfinite"
    if r < 0.35:
        a = good.copy()
        a.flat[int(rng.integers(a.size))] = pick(rng, (1e308, -1e308, 1e39, 3.5e38, 1e300, 5e-324))
        return a, "a huge or tiny component", "ok"
    if r < 0.5:
        shape = pick(rng, ((rows, 2), (rows, 4), (rows,), (rows, 3, 1), (0, 2), (2, 0), ()))
        return np.zeros(shape), f"shape {shape}", "shape"
    if r < 0.65:
        dtype = pick(rng, ("float32", "float16", "int8", "uint64", "bool", "complex128", "object",
                           "U3", "datetime64[s]", "longdouble"))
        try:
            a = good.astype(dtype)
        except (TypeError, ValueError):
            a = good.astype(object)
            dtype = "object"
        kind = "ok" if dtype in ("float32", "float16", "int8", "uint64", "longdouble") else "type"
        return a, f"dtype {dtype}", kind
    if r < 0.75:
        v = pick(rng, ("points", None, 3.0, [[1, 2, "x"]], [[1, 2, 3], [4, 5]], {"a": 1},
                       [[None, 1, 2]], b"abc", [[1, 2, 3]] * 2, [["1", "2", "3"]]))
        return v, f"value {short(v)}", "ok" if v == [[1, 2, 3]] * 2 else "type"
    if r < 0.85:
        return Huge((2**36, cols)), "2^36 rows (virtual)", "huge"
    if r < 0.92:
        a = np.asfortranarray(good) if rng.random() < 0.5 else good[::-1]
        a.setflags(write=False)
        return a, "strided read-only", "ok"
    n = int(pick(rng, (0, 1, 7, 1000)))
    return good[:n] if n <= rows else np.random.default_rng(1).uniform(-1.5, 1.5, (n, cols)), f"{n} rows", "ok"


def api_case(rng):
    """One case of the Python API."""
    kind = rng.integers(10)
    if kind <= 2:                                   # ray queries
        op = pick(rng, RAY_OPS)
        o, ow, ok = hostile_array(rng) if rng.random() < 0.5 else (np.zeros(3) + [0, 0.5, 0.2], "(3,) origin", "ok")
        d, dw, dk = hostile_array(rng)
        n = len(d) if isinstance(d, np.ndarray) and d.ndim == 2 else None
        kwargs = {}
        refuse = False
        if rng.random() < 0.4:
            key = pick(rng, ("t_min", "t_max") + (("max_hits",) if op == "intersections" else ())
                       + (("precision",) if op in ("trace", "intersections") else ()))
            v = pick(rng, (math.nan, -1.0, math.inf, -math.inf, 0.0, 1e39, "1", None, True, 1.5, 0,
                           -2, np.float32(1), np.full(16, 0.5), np.full(3, 0.5), "double", "half"))
            kwargs[key] = v
            if key == "max_hits":
                refuse = not (isinstance(v, (int, np.integer)) and not isinstance(v, bool) and v >= 1) and v is not None
            elif key == "precision":
                refuse = not (isinstance(v, str) and v in ("single", "double"))
            else:
                refuse = isinstance(v, float) and (v != v or (key == "t_min" and v < 0)) \
                    or (key == "t_min" and isinstance(v, (int, float)) and v < 0) \
                    or (isinstance(v, np.ndarray) and len(v) != n) or isinstance(v, (str, bool)) or v is None
        refuse |= "shape" in (ok, dk) and not (ow.startswith("shape (0") or dw.startswith("shape (0"))
        refuse |= "type" in (ok, dk) or "huge" in (ok, dk)
        return Case("api", f"{op}: origins {ow}, directions {dw}", {}, op=op, args=(o, d),
                    kwargs=kwargs, refuse=refuse)
    if kind <= 5:                                   # point queries
        op = pick(rng, POINT_OPS)
        p, pw, pk = hostile_array(rng)
        kwargs = {}
        refuse = pk in ("nonfinite", "type", "huge") or (pk == "shape" and not pw.startswith("shape (0"))
        if rng.random() < 0.4:
            keys = {"closest_points": ("max_distance", "precision"), "distance": ("max_distance",),
                    "signed_distance": ("max_distance", "sign"), "winding_number": ("beta",),
                    "occupancy": ("sign",), "contains": ()}[op]
            if keys:
                key = pick(rng, keys)
                if key == "sign":
                    v = pick(rng, ("winding", "parity", "WINDING", "", None, 1))
                    refuse |= v not in ("winding", "parity")
                elif key == "precision":
                    v = pick(rng, ("single", "double", "float", None))
                    refuse |= v not in ("single", "double")
                else:
                    v = pick(rng, (math.nan, -1.0, math.inf, 0.0, 0.5, 1e308, "1", None, True, -math.inf))
                    low = 1.0 if key == "beta" else 0.0
                    refuse |= not (isinstance(v, float) and v == v and v >= low)
                kwargs[key] = v
        return Case("api", f"{op}: points {pw}", {}, op=op, args=(p,), kwargs=kwargs,
                    refuse=refuse)
    if kind == 6:                                   # cameras
        op = pick(rng, ("camera", "look_at", "from_intrinsics", "panorama", "frame"))
        v, vk = hostile_number(rng) if rng.random() < 0.7 else hostile_other(rng)
        if isinstance(v, Raw):
            v = math.inf
        field = pick(rng, CAMERA_FIELDS[op])
        refuse = vk == "nonfinite" or vk in ("type", "text")
        return Case("api", f"{op}: {field} = {short(v)}", {}, op=op, args=(field, v), refuse=refuse)
    if kind == 7:                                   # lidar specs
        m = mutate_json(LIDARS[pick(rng, sorted(LIDARS))], rng)
        try:
            spec = loads(m.data)
        except (ValueError, RecursionError):
            spec = m.data.decode("utf-8", "replace")
            m.refuse = True
        return Case("api", f"Lidar.from_dict: {m.what}", {}, op="lidar_dict", args=(spec,),
                    refuse=m.refuse)
    if kind == 9 and rng.random() < 0.5:            # renders and scans
        if rng.random() < 0.5:
            aovs = pick(rng, (("depth",), "depth,id", "all", "nope", "", None, 3, ["depth", 3], ("DEPTH",),
                              ["depth"] * 100, "depth,,id", ("object", "valid"), b"depth"))
            size = pick(rng, ((16, 12), (16, 12), (1, 1), (65536, 65536), (65536, 1)))
            refuse = not (isinstance(aovs, str) and aovs and "nope" not in aovs
                          or isinstance(aovs, (tuple, list)) and all(a in ("depth", "DEPTH") for a in aovs)
                          or aovs == ("object", "valid") and False) or size == (65536, 65536)
            return Case("api", f"render {size} aovs={short(aovs)}", {}, op="render", args=(size, aovs),
                        refuse=refuse)
        pose = np.loadtxt(io.BytesIO(SENSOR_POSE))
        what = "pose ok"
        refuse = False
        r = rng.random()
        if r < 0.5:
            i, j = int(rng.integers(4)), int(rng.integers(4))
            v, vk = hostile_number(rng)
            v = math.inf if isinstance(v, Raw) else float(v)
            pose[i, j] = v
            what = f"pose[{i},{j}] = {v}"
            refuse = not math.isfinite(v) or (i < 3 and j < 3 and abs(v - np.loadtxt(io.BytesIO(SENSOR_POSE))[i, j]) > 1e-5) \
                or (i == 3 and v != (1.0 if j == 3 else 0.0))
        elif r < 0.6:
            pose = pick(rng, (np.eye(3), np.eye(4)[:3], np.zeros((4, 4)), "pose", None, np.eye(4).tolist()))
            what = f"pose {short(pose)}"
            refuse = not (isinstance(pose, list) or isinstance(pose, np.ndarray) and pose.shape == (4, 4)
                          and pose[3, 3] == 1)
        spec = dict(LIDARS["os.json"])
        if rng.random() < 0.3:
            spec = {"channels": 1024, "fov_up": 20, "fov_down": -20, "columns": 65536, "max_range": 100}
            what += ", 1024 x 65536 beams"
            refuse = True                   # 67M beams: more memory than the worker may have
        return Case("api", f"scan: {what}", {}, op="scan", args=(spec, pose), refuse=refuse)
    if kind == 8:                                   # meshes and builds
        op = pick(rng, ("mesh", "build"))
        v, vw, vk = hostile_array(rng, 8, 3)
        f = np.array([[0, 1, 2], [2, 3, 4], [5, 6, 7]])
        fw = "faces"
        if rng.random() < 0.5:
            f = pick(rng, (np.array([[0, 1, 99]]), np.array([[-1, 0, 1]]), np.array([[0, 1, 2.5]]),
                           np.array([[0, 1]]), np.zeros((0, 3), int), np.array([[2**40, 0, 1]]),
                           np.array([["a", "b", "c"]]), [[0, 1, 2]], None, np.array([[0, 1, 2]], dtype=np.uint64)))
            fw = f"faces {short(f)}"
        kwargs = {}
        if op == "build" and rng.random() < 0.5:
            key = pick(rng, ("K_T", "K_I", "empty_bonus", "max_depth", "leaf_size", "threads", "scale", "origin"))
            kwargs[key] = pick(rng, (math.nan, -1, 0, 1e308, "20", None, True, 2**40, 1.5, [0, 0, 0],
                                     [math.nan, 0, 0], 3.0))
        return Case("api", f"{op}: vertices {vw}, {fw}", {}, op=op, args=(v, f), kwargs=kwargs,
                    refuse=vk in ("type", "huge"))
    op = pick(rng, ("check_grid", "sdf_grid", "sdf_samples", "tracer"))   # grids, Tracer options
    if op == "tracer":
        key = pick(rng, ("stack_size", "local_size", "batch_size", "groups", "packet", "device", "refine"))
        v = pick(rng, (0, -1, 65, 3, 2**31, 1.5, "8", None, True, math.nan, "nonsense", 7))
        return Case("api", f"Tracer({key}={short(v)})", {}, op="tracer", kwargs={key: v})
    if op == "sdf_samples":
        key = pick(rng, ("count", "sigma", "uniform", "padding", "seed", "sign"))
        v = pick(rng, (0, -1, 10**12, 2**40, 1.5, math.nan, math.inf, -0.5, 2.0, "x", None, 10))
        refuse = v is not None and not isinstance(v, (int, float)) or (isinstance(v, float) and v != v)
        return Case("api", f"sdf_samples({key}={short(v)})", {}, op=op, kwargs={key: v},
                    refuse=refuse)
    res = pick(rng, (0, 1, 2, 3, 4097, 4096, 2**20, -5, 2.5, "8", None, True, 10**30))
    pad = pick(rng, (0.1, 0.0, -0.5, math.nan, math.inf, 1e308, "0.1", None))
    refuse = not (isinstance(res, int) and not isinstance(res, bool) and 2 <= res <= 4096) or \
        not (isinstance(pad, float) and math.isfinite(pad) and pad >= 0) or res >= 2048
    if op == "sdf_grid" and not refuse and res > 16:
        res = 16
    return Case("api", f"{op}(resolution={short(res)}, padding={short(pad)})", {}, op=op,
                args=(res, pad), refuse=refuse)


CAMERA_FIELDS = {
    "camera": ("width", "height", "fx", "fy", "cx", "cy", "skew", "t", "R", "model", "distortion"),
    "look_at": ("eye", "target", "up", "fov_deg", "width", "height"),
    "from_intrinsics": ("fx", "cx", "t", "width", "model", "distortion"),
    "panorama": ("width", "height", "longitude", "latitude", "t"),
    "frame": ("lo", "hi", "fov_deg", "width", "direction", "up"),
}


# -- the contract, CLI -----------------------------------------------------------------------------

WARNING_LINE = re.compile(r"^\S.*:\d+: \w*Warning: ", re.M)


def check_cli(case, rc, sig, timed_out, stdout, stderr, before, after):
    """The contract's breaches of one CLI run (a list of sentences; empty: it holds)."""
    bad = []
    err = stderr.decode("utf-8", "replace")
    lines = [ln for ln in err.split("\n") if ln.strip()]      # a terminal's lines, not Unicode's
    if timed_out:
        bad.append(f"no answer after {TIMEOUT:.0f} s of CPU or {HARD_TIMEOUT:.0f} s (a hang)")
    elif sig:
        bad.append(f"killed by signal {sig} ({signal.Signals(sig).name})")
    elif rc not in (0, 1, 2):
        bad.append(f"exit code {rc}")
    if "Traceback" in err:
        bad.append("a traceback on stderr")
    if WARNING_LINE.search(err) or "RuntimeWarning" in err:
        bad.append("a Python warning on stderr")
    if rc == 1 and not timed_out:
        errors = [ln for ln in lines if ln.startswith("kdray: error: ")]
        if not lines or not lines[-1].startswith("kdray: error: ") or len(errors) != 1:
            bad.append("exit 1 without exactly one last line `kdray: error: ...`")
        elif any(not ln.startswith("kdray: ") for ln in lines):
            bad.append("stderr lines that are not kdray's (a message of several lines?)")
    if rc == 2 and not (lines and lines[-1].startswith("Error: ")):
        bad.append("exit 2 without click's `Error: ...` line")
    if rc == 0 and case.refuse and not timed_out:
        bad.append("exit 0 where the docs promise a refusal")
    failed = rc != 0 or timed_out or sig
    outputs = tuple(case.outputs)
    for name, digest in before.items():
        mine = any(name == o or (o.endswith("/") and name.startswith(o)) for o in outputs)
        if after.get(name) != digest and (failed or not mine):
            bad.append(f"{name} {'changed' if name in after else 'vanished'}"
                       + (" on a failure" if failed else " (not an output)"))
    left = [n for n in after if re.search(r"(^|/)\.[^/]+\.tmp$", n) and n not in outputs]
    if left:
        bad.append(f"a temporary file left: {left[0]}")
    return bad


def folder_hashes(root):
    """relative name -> BLAKE2b of its bytes (a link: of its target's name) for every file."""
    out = {}
    for dirpath, dirnames, filenames in os.walk(root):
        for n in filenames + [d for d in dirnames if os.path.islink(os.path.join(dirpath, d))]:
            p = os.path.join(dirpath, n)
            rel = os.path.relpath(p, root)
            try:
                if os.path.islink(p):
                    out[rel] = "link:" + os.readlink(p)
                else:
                    h = hashlib.blake2b(digest_size=16)
                    with open(p, "rb") as f:
                        for chunk in iter(lambda: f.read(1 << 20), b""):
                            h.update(chunk)
                    out[rel] = h.hexdigest()
            except OSError as e:
                out[rel] = f"unreadable: {e}"
    return out


def write_files(root, files):
    for name, data in files.items():
        p = Path(root, name)
        if name.endswith("/"):
            p.mkdir(parents=True, exist_ok=True)
            continue
        p.parent.mkdir(parents=True, exist_ok=True)
        if isinstance(data, Link) and data.hard:
            os.link(Path(root, data.target), p)
        elif isinstance(data, Link):
            os.symlink(data.target, p)
        else:
            p.write_bytes(data)


def _limits():
    """preexec_fn of a CLI case: a session of its own, bounded memory, no core files."""
    os.setsid()
    resource.setrlimit(resource.RLIMIT_AS, (MEMORY_LIMIT, MEMORY_LIMIT))
    resource.setrlimit(resource.RLIMIT_CORE, (0, 0))


class CliServer:
    """Runs CLI cases: forked from a server that has done kdray's imports (default), or
    each a fresh `kdray` process (spawn=True)."""

    def __init__(self, spawn=False):
        self.spawn = spawn
        self.proc = None

    def start(self):
        if self.spawn or self.proc is not None:
            return
        self.proc = subprocess.Popen(
            [sys.executable, "-c", f"import sys; sys.path.insert(0, {str(HERE)!r}); import fuzz; fuzz.cli_server()"],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, cwd=ROOT)
        line = self.proc.stdout.readline()
        if line.strip() != b"ready":
            raise RuntimeError(f"the fuzz CLI server did not start: {line!r}")

    def close(self):
        if self.proc is not None:
            self.proc.stdin.close()
            self.proc.wait(timeout=30)
            self.proc = None

    def run(self, argv, cwd, io_dir, env):
        """(rc, signal, timed_out, stdout, stderr) of `kdray argv` in cwd."""
        out, err = Path(io_dir, "stdout"), Path(io_dir, "stderr")
        if self.spawn:
            with open(out, "wb") as fo, open(err, "wb") as fe:
                p = subprocess.Popen([str(KDRAY)] + argv, cwd=cwd, stdin=subprocess.DEVNULL,
                                     stdout=fo, stderr=fe, env={**os.environ, **env},
                                     preexec_fn=_limits)
                started, timed_out = time.monotonic(), False
                while True:
                    try:
                        rc = p.wait(timeout=TIMEOUT)
                        break
                    except subprocess.TimeoutExpired:
                        if (time.monotonic() - started > HARD_TIMEOUT
                                or cpu_seconds(p.pid) > TIMEOUT):
                            os.killpg(p.pid, signal.SIGKILL)
                            rc = p.wait()
                            timed_out = True
                            break
            sig = -rc if rc < 0 else 0
        else:
            self.start()
            msg = json.dumps({"argv": argv, "cwd": str(cwd), "out": str(out), "err": str(err),
                              "env": env, "timeout": TIMEOUT, "memory": MEMORY_LIMIT})
            self.proc.stdin.write(msg.encode("utf-8", "surrogatepass") + b"\n")
            self.proc.stdin.flush()
            reply = json.loads(self.proc.stdout.readline())
            rc, sig, timed_out = reply["rc"], reply["signal"], reply["timed_out"]
        return rc, sig, timed_out, out.read_bytes(), err.read_bytes()


def cli_server():
    """The fork server: import what kdray's commands import, then run each case (a JSON
    line on stdin) in a forked child, set up as _limits sets up a spawned one."""
    import click  # noqa: F401
    import kdray
    import kdray.cli
    from kdray import (camera, camera_files, dataset, files, images, lidar, load, render,  # noqa: F401
                       sdf, trace, tree, cache, bench, cull)
    import trimesh.exchange.load  # noqa: F401
    try:
        import OpenImageIO  # noqa: F401
    except ImportError:
        pass
    proto_in = os.fdopen(os.dup(0), "rb")
    proto_out = os.fdopen(os.dup(1), "wb")
    devnull = os.open(os.devnull, os.O_RDWR)
    os.dup2(devnull, 0)
    os.dup2(devnull, 1)
    proto_out.write(b"ready\n")
    proto_out.flush()
    for line in proto_in:
        case = json.loads(line)
        pid = os.fork()
        if pid == 0:
            code = 1
            try:
                os.setsid()
                resource.setrlimit(resource.RLIMIT_AS, (case["memory"], case["memory"]))
                resource.setrlimit(resource.RLIMIT_CORE, (0, 0))
                os.chdir(case["cwd"])
                fo = os.open(case["out"], os.O_WRONLY | os.O_CREAT | os.O_TRUNC)
                fe = os.open(case["err"], os.O_WRONLY | os.O_CREAT | os.O_TRUNC)
                os.dup2(fo, 1)
                os.dup2(fe, 2)
                os.environ.update(case["env"])
                sys.argv = ["kdray"] + case["argv"]
                code = _run_main(kdray.cli.main)
            finally:
                os._exit(code)
        started = time.monotonic()
        timed_out = False
        delay = 0.0005
        while True:
            done, status = os.waitpid(pid, os.WNOHANG)
            if done:
                break
            waited = time.monotonic() - started
            if waited > case["timeout"] and (waited > HARD_TIMEOUT
                                             or cpu_seconds(pid) > case["timeout"]):
                os.killpg(pid, signal.SIGKILL)
                _, status = os.waitpid(pid, 0)
                timed_out = True
                break
            time.sleep(delay)
            delay = min(delay * 2, 0.02)
        rc = os.waitstatus_to_exitcode(status)
        reply = {"rc": rc, "signal": -rc if rc < 0 else 0, "timed_out": timed_out}
        proto_out.write(json.dumps(reply).encode() + b"\n")
        proto_out.flush()


def cpu_seconds(pid):
    """CPU seconds process `pid` (its threads, and children it has waited for) has used
    (Linux /proc); inf where that cannot be read, so that a timeout then goes by the
    clock."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            fields = f.read().rpartition(")")[2].split()
        return sum(int(x) for x in fields[11:15]) / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return math.inf


def _run_main(main):
    """What the interpreter does with a console script: its exit code, a traceback for an
    exception that escapes."""
    code = 0
    try:
        main()
    except SystemExit as e:
        if e.code is None:
            code = 0
        elif isinstance(e.code, int):
            code = e.code
        else:
            print(e.code, file=sys.stderr)
            code = 1
    except BaseException:
        traceback.print_exc()
        code = 1
    for f in (sys.stdout, sys.stderr):
        try:
            f.flush()
        except Exception:
            pass
    return code


# -- the contract, API -----------------------------------------------------------------------------

class ApiWorker:
    """The API cases' process: Tracers made once; restarted after a hang or a crash. Its
    stderr (kdray's log, a crash's traceback) goes to the file `log`."""

    def __init__(self, log=None):
        self.proc = None
        self.log = log

    def start(self):
        if self.proc is None:
            self.proc = subprocess.Popen(
                [sys.executable, "-c", f"import sys; sys.path.insert(0, {str(HERE)!r}); import fuzz; fuzz.api_worker()"],
                stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=self.log, cwd=ROOT)
            if self._read(120) != "ready":
                raise RuntimeError("the fuzz API worker did not start")

    def close(self):
        if self.proc is not None:
            self.proc.stdin.close()
            self.proc.wait(timeout=30)
            self.proc = None

    def _read(self, timeout):
        fd = self.proc.stdout
        ready, _, _ = select.select([fd], [], [], timeout)
        if not ready:
            return None
        head = fd.read(8)
        if len(head) < 8:
            return None
        return pickle.loads(fd.read(int.from_bytes(head, "little")))

    def run(self, case, folder):
        """The contract's breaches of one API case, its files in `folder`."""
        self.start()
        blob = pickle.dumps((case, str(folder)))
        self.proc.stdin.write(len(blob).to_bytes(8, "little") + blob)
        self.proc.stdin.flush()
        started, cpu0 = time.monotonic(), cpu_seconds(self.proc.pid)
        reply = self._read(TIMEOUT)
        while reply is None and self.proc.poll() is None:      # slow by the clock only?
            waited = time.monotonic() - started
            if waited > HARD_TIMEOUT or cpu_seconds(self.proc.pid) - cpu0 > TIMEOUT:
                break
            reply = self._read(min(TIMEOUT, HARD_TIMEOUT - waited))
        if reply is None:
            rc = self.proc.poll()
            if rc is None:
                self.proc.kill()
                self.proc.wait()
                what = f"no answer after {TIMEOUT:.0f} s of CPU or {HARD_TIMEOUT:.0f} s (a hang)"
            else:
                what = f"the worker died (exit {rc}{', ' + signal.Signals(-rc).name if rc < 0 else ''})"
            self.proc = None
            return [what]
        return reply


def api_worker():
    """Runs API cases sent by ApiWorker: pickled (case, folder) frames on stdin, a pickled
    list of breaches back on stdout."""
    import kdray
    from kdray import sdf
    proto_in = os.fdopen(os.dup(0), "rb")
    proto_out = os.fdopen(os.dup(1), "wb")
    devnull = os.open(os.devnull, os.O_RDWR)
    os.dup2(devnull, 0)
    os.dup2(devnull, 1)
    cornell = kdray.load(SCENES / "cornell.obj")
    sphere = kdray.load(SCENES / "sphere.obj")
    ctx = {"kdray": kdray, "sdf": sdf,
           "tracer": kdray.Tracer(kdray.build(cornell.vertices, cornell.faces)),
           "ball": kdray.Tracer(kdray.build(sphere.vertices, sphere.faces))}
    for t in (ctx["tracer"], ctx["ball"]):          # the programs compiled before the limit
        t.trace(np.zeros((4, 3)), np.ones((4, 3)))
        t.contains(np.zeros((4, 3)))
        t.distance(np.zeros((4, 3)))
    ctx["tracer"].render(kdray.Camera.look_at((0, 0.5, 1.85), (0, 0.5, 0), width=8, height=6))
    vm = _vm_bytes()
    if vm:
        resource.setrlimit(resource.RLIMIT_AS, (vm + MEMORY_LIMIT, vm + MEMORY_LIMIT))

    def send(obj):
        blob = pickle.dumps(obj)
        proto_out.write(len(blob).to_bytes(8, "little") + blob)
        proto_out.flush()

    send("ready")
    while True:
        head = proto_in.read(8)
        if len(head) < 8:
            return
        case, folder = pickle.loads(proto_in.read(int.from_bytes(head, "little")))
        os.chdir(folder)
        try:
            send(check_api(case, ctx))
        finally:
            os.chdir(ROOT)


def _vm_bytes():
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmSize:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        return None


def check_api(case, ctx):
    """Run one API case here; the contract's breaches."""
    from kdray.errors import KdrayError
    from kdray.points import OpenMeshWarning
    args = tuple(a.array() if isinstance(a, Huge) else a for a in case.args)
    bad = []
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            result = API_OPS[case.op](ctx, *args, **case.kwargs)
        except KdrayError as e:
            if "\n" in str(e).strip():
                bad.append(f"a message of several lines: {str(e)[:200]!r}")
            result = None
        except TypeError as e:
            if not case.type_error_ok:
                bad.append(f"TypeError where a KdrayError is due: {one_line(e)}")
            result = None
        except RecursionError:
            bad.append("RecursionError (nesting not bounded)")
            result = None
        except MemoryError as e:
            bad.append(f"{type(e).__name__} (memory not checked first): {one_line(e)}")
            result = None
        except Exception as e:
            tb = traceback.extract_tb(e.__traceback__)[-1]
            bad.append(f"{type(e).__name__}: {one_line(e)} (at {Path(tb.filename).name}:{tb.lineno})")
            result = None
        else:
            if case.refuse:
                bad.append("accepted where the docs promise a refusal")
            try:
                bad += RESULT_CHECKS.get(case.op, lambda r, c: [])(result, case)
            except Exception as e:
                bad.append(f"its answer cannot be used: {type(e).__name__}: {one_line(e)}")
    for w in caught:
        if not issubclass(w.category, OpenMeshWarning):
            bad.append(f"a warning: {w.category.__name__}: {one_line(w.message)} "
                       f"({Path(w.filename).name}:{w.lineno})")
    return bad


def one_line(e):
    lines = [ln for ln in str(e).splitlines() if ln.strip()]
    return (lines[0] if lines else "")[:200]


def _camera_api(ctx, field, value):
    from kdray import Camera
    K = [[30.0, 0, 16], [0, 30, 12], [0, 0, 1]]
    pose = [[1.0, 0, 0, 0], [0, -1, 0, 0.5], [0, 0, -1, 1.85], [0, 0, 0, 1]]
    kw = {"width": 32, "height": 24, "model": "pinhole", "distortion": ()}
    if field in ("fx", "fy", "cx", "cy", "skew"):
        i, j = {"fx": (0, 0), "fy": (1, 1), "cx": (0, 2), "cy": (1, 2), "skew": (0, 1)}[field]
        K[i][j] = value
    elif field == "t":
        pose[0][3] = pose[1][3] = pose[2][3] = value
    elif field == "R":
        pose[0][0] = value
    elif field == "distortion":
        kw["model"] = "opencv"
        kw["distortion"] = (value, 0.0, 0.0, 0.0)
    else:
        kw[field] = value
    return Camera(kw["width"], kw["height"], K, pose, model=kw["model"], distortion=kw["distortion"])


def _look_at(ctx, field, value):
    from kdray import Camera
    kw = {"eye": (0, 0.5, 1.85), "target": (0, 0.5, 0), "up": (0, 1, 0), "fov_deg": 40,
          "width": 32, "height": 24}
    kw[field] = (value, 0.5, 1.85) if field in ("eye", "target", "up") else value
    return Camera.look_at(**kw)


def _from_intrinsics(ctx, field, value):
    from kdray import Camera
    K = [[30.0, 0, 16], [0, 30, 12], [0, 0, 1]]
    pose = [[1.0, 0, 0, 0], [0, -1, 0, 0.5], [0, 0, -1, 1.85], [0, 0, 0, 1]]
    kw = {"width": 32, "height": 24, "model": "pinhole", "distortion": ()}
    if field == "fx":
        K[0][0] = value
    elif field == "cx":
        K[0][2] = value
    elif field == "t":
        pose[0][3] = value
    elif field == "distortion":
        kw["model"], kw["distortion"] = "fisheye", (0.0, value, 0.0, 0.0)
    else:
        kw[field] = value
    return Camera.from_intrinsics(K, pose, kw["width"], kw["height"], model=kw["model"],
                                  distortion=kw["distortion"])


def _panorama(ctx, field, value):
    from kdray import Camera
    kw = {"cam_to_world": np.eye(4), "width": 32, "height": 16}
    if field == "t":
        pose = np.eye(4).tolist()
        pose[1][3] = value
        kw["cam_to_world"] = pose
    elif field in ("longitude", "latitude"):
        kw[field] = (value, 1.0)
    else:
        kw[field] = value
    return Camera.panorama(**kw)


def _frame(ctx, field, value):
    from kdray import Camera
    kw = {"lo": (0, 0, 0), "hi": (1, 1, 1), "fov_deg": 45, "width": 32, "direction": (-0.5, -0.4, -0.75),
          "up": (0, 1, 0)}
    kw[field] = (value, 0, 0) if field in ("lo", "hi", "direction", "up") else value
    lo, hi = kw.pop("lo"), kw.pop("hi")
    return Camera.frame(lo, hi, height=24, **kw)


def _check_camera(cam, case):
    bad = []
    if cam.width * cam.height <= 1 << 16:
        o, d, valid = cam.rays(valid=True)
        if not (np.isfinite(o[valid]).all() and np.isfinite(d[valid]).all()):
            bad.append("an accepted camera gives rays that are not finite")
        if valid.any() and not (np.abs(d[valid]).max(axis=1) > 0).all():
            bad.append("an accepted camera gives zero directions")
    return bad


def _check_lidar(lidar, case):
    bad = []
    if lidar.beams * lidar.columns <= 1 << 16:
        d = lidar.directions()
        if not np.isfinite(d).all():
            bad.append("an accepted lidar gives directions that are not finite")
    return bad


def _check_finite(name, allow_inf=True):
    def check(result, case):
        a = np.asarray(getattr(result, name) if name else result)
        if a.dtype.kind == "f" and np.isnan(a).any():
            return [f"NaN in the answer ({name or case.op})"]
        if not allow_inf and a.dtype.kind == "f" and not np.isfinite(a).all():
            return [f"an infinite value in the answer ({name or case.op})"]
        return []
    return check


def _check_mesh(mesh, case):
    used = np.unique(mesh.faces)
    if len(mesh.faces) == 0 or used.min() < 0 or used.max() >= len(mesh.vertices):
        return ["an accepted mesh with faces out of range"]
    if not np.isfinite(mesh.vertices[used]).all():
        return ["an accepted mesh with used vertices that are not finite"]
    return []


def _load(ctx, path):
    mesh = ctx["kdray"].load(path)
    if len(mesh.faces) <= 200_000:
        ctx["kdray"].build(mesh.vertices, mesh.faces)
    return mesh


def _tree_load(ctx, path):
    tree = ctx["kdray"].KdTree.load(path)
    tree.validate(coverage_samples=None)            # TreeError here: the loader let it in
    return tree


def _read_jobs(ctx, path):
    from kdray.dataset import read_jobs
    return read_jobs(path)


def _tracer(ctx, **kw):
    from kdray import Tracer
    t = ctx["tracer"]
    return Tracer(t.tree, **kw)


def _sdf_samples(ctx, **kw):
    args = {"count": 10, "sigma": None, "uniform": 0.1, "padding": 0.1, "sign": "winding", "seed": 0}
    args.update(kw)
    if isinstance(args["count"], int) and args["count"] > 100_000 and args["count"] < 2**30:
        args["count"] = 100_000
    return ctx["sdf"].sdf_samples(ctx["ball"], **args)


def _ray(op):
    def run(ctx, o, d, **kw):
        tracer = ctx["tracer"] if op != "count" else ctx["ball"]
        return getattr(tracer, op)(o, d, **kw)
    return run


def _point(op):
    def run(ctx, p, **kw):
        return getattr(ctx["ball"], op)(p, **kw)
    return run


def _render(ctx, size, aovs):
    from kdray import Camera
    cam = Camera.look_at((0, 0.5, 1.85), (0, 0.5, 0), width=size[0], height=size[1])
    return ctx["tracer"].render(cam, aovs=aovs)


def _scan(ctx, spec, pose):
    lidar = ctx["kdray"].Lidar.from_dict(spec)
    return ctx["tracer"].scan(lidar, pose)


def _lidar_json(ctx, path):
    lidar = ctx["kdray"].Lidar.from_json(path)
    if lidar.beams * lidar.columns <= 1 << 16:
        lidar.rays(np.loadtxt(io.BytesIO(SENSOR_POSE)))
    return lidar


API_OPS = {
    "load": _load,
    "tree_load": _tree_load,
    "camera_json": lambda ctx, path: ctx["kdray"].Camera.from_json(path),
    "read_cameras": lambda ctx, path: __import__("kdray.camera_files", fromlist=["x"]).read_cameras(path),
    "lidar_json": _lidar_json,
    "pose_file": lambda ctx, path: __import__("kdray.camera", fromlist=["x"]).pose_from_file(path),
    "read_jobs": _read_jobs,
    "camera": _camera_api, "look_at": _look_at, "from_intrinsics": _from_intrinsics,
    "panorama": _panorama, "frame": _frame,
    "lidar_dict": lambda ctx, spec: ctx["kdray"].Lidar.from_dict(spec),
    "mesh": lambda ctx, v, f: ctx["kdray"].Mesh.from_arrays(v, f),
    "build": lambda ctx, v, f, **kw: ctx["kdray"].build(v, f, **kw),
    "check_grid": lambda ctx, r, p: ctx["sdf"].check_grid(r, p),
    "sdf_grid": lambda ctx, r, p: ctx["sdf"].sdf_grid(ctx["ball"], r, p),
    "sdf_samples": _sdf_samples,
    "tracer": _tracer, "render": _render, "scan": _scan,
    **{op: _ray(op) for op in RAY_OPS},
    **{op: _point(op) for op in POINT_OPS},
}

RESULT_CHECKS = {
    "camera_json": _check_camera, "camera": _check_camera, "look_at": _check_camera,
    "from_intrinsics": _check_camera, "panorama": _check_camera, "frame": _check_camera,
    "read_cameras": lambda views, case: [b for v in views for b in _check_camera(v.camera, case)],
    "lidar_json": _check_lidar, "lidar_dict": _check_lidar,
    "load": _check_mesh, "mesh": _check_mesh,
    "pose_file": lambda p, case: [] if np.isfinite(p).all() and p.shape == (4, 4) else
    ["an accepted pose that is not a finite 4 x 4 matrix"],
    "trace": _check_finite("t"), "intersections": _check_finite("t"),
    "closest_points": _check_finite("distance"), "distance": _check_finite(None),
    "signed_distance": _check_finite(None), "winding_number": _check_finite(None, False),
    "sdf_grid": _check_finite("values"),
    "render": lambda images, case: [f"NaN in {k}" for k, v in images.items()
                                    if k in ("depth", "distance", "normal", "bary") and np.isnan(v).any()],
    "scan": lambda images, case: ["NaN in range"] if np.isnan(images["range"]).any() else [],
}


# -- the run --------------------------------------------------------------------------------------

@dataclasses.dataclass
class Failure:
    case: Case
    problems: list
    stderr: str = ""


@dataclasses.dataclass
class Report:
    counts: dict          # surface -> {"cli": [run, passed], "api": [run, passed]}
    failures: list
    seconds: float

    @property
    def ok(self):
        return not self.failures

    def table(self):
        rows = ["| surface | CLI cases | passed | API cases | passed | seconds |",
                "|---|---:|---:|---:|---:|---:|"]
        tot = [0, 0, 0, 0, 0]
        for s, c in self.counts.items():
            vals = c["cli"] + c["api"] + [c.get("seconds", 0)]
            tot = [a + b for a, b in zip(tot, vals)]
            rows.append(f"| {s} | {vals[0]:,} | {vals[1]:,} | {vals[2]:,} | {vals[3]:,} | {vals[4]:.0f} |")
        rows.append(f"| all | {tot[0]:,} | {tot[1]:,} | {tot[2]:,} | {tot[3]:,} | {tot[4]:.0f} |")
        return "\n".join(rows)

    def summary(self, most=20):
        lines = [self.table(), "", f"{sum(sum(c['cli'][:1] + c['api'][:1]) for c in self.counts.values()):,} "
                 f"cases in {self.seconds:.0f} s, {len(self.failures)} failed"]
        for f in self.failures[:most]:
            lines.append(f"- [{f.case.surface}] {f.case.what}: {'; '.join(f.problems)}\n    {f.case.describe()[:300]}"
                         + (f"\n    stderr: {f.stderr.strip()[-300:]!r}" if f.stderr.strip() else ""))
        if len(self.failures) > most:
            lines.append(f"... and {len(self.failures) - most} more")
        return "\n".join(lines)


def fuzz(cases_per_surface, seed=0, surfaces=SURFACES, spawn=False, save=None, progress=None,
         examples=None, cli_scale=1.0):
    """Run `cases_per_surface` (an int, or a dict surface -> int) seeded cases of each
    surface, the file surfaces' CLI_SHARE times cli_scale through the CLI; a Report."""
    examples = examples or Examples()
    counts = {s: {"cli": [0, 0], "api": [0, 0]} for s in surfaces}
    failures = []
    started = time.monotonic()
    scratch = Path(tempfile.mkdtemp(prefix="kdray-fuzz-"))
    worker_log = open(scratch / "api-worker.log", "wb")
    server, worker = CliServer(spawn), ApiWorker(worker_log)
    try:
        for k, surface in enumerate(surfaces):
            n = cases_per_surface[surface] if isinstance(cases_per_surface, dict) else cases_per_surface
            gen = Generator(examples, (seed, k))
            t0 = time.monotonic()
            for i, case in enumerate(gen.cases(surface, n, cli_scale)):
                folder, io_dir = scratch / "case", scratch / "io"
                for p in (folder, io_dir):
                    shutil.rmtree(p, ignore_errors=True)
                    p.mkdir()
                write_files(folder, case.files)
                stderr = ""
                if case.cli:
                    before = folder_hashes(folder)
                    env = {"KDRAY_CACHE_DIR": str(io_dir / "cache")}
                    rc, sig, timed_out, out, err = server.run(case.argv, folder, io_dir, env)
                    problems = check_cli(case, rc, sig, timed_out, out, err, before, folder_hashes(folder))
                    stderr = err.decode("utf-8", "replace")
                else:
                    problems = worker.run(case, folder)
                tally = counts[surface]["cli" if case.cli else "api"]
                tally[0] += 1
                if problems:
                    failures.append(Failure(case, problems, stderr))
                    if save:
                        _save(Path(save) / f"{surface}-{i:05d}", case, problems, stderr)
                else:
                    tally[1] += 1
                if progress:
                    progress(surface, i + 1, n, problems)
            counts[surface]["seconds"] = time.monotonic() - t0
    finally:
        server.close()
        worker.close()
        worker_log.close()
        shutil.rmtree(scratch, ignore_errors=True)
    return Report(counts, failures, time.monotonic() - started)


def _save(folder, case, problems, stderr):
    """A failure's reproducer: its files, the command (or call) and what broke."""
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir(parents=True)
    write_files(folder, case.files)
    (folder / "README.txt").write_text(
        f"{case.surface}: {case.what}\n{case.describe()}\n\n" + "\n".join(problems)
        + (f"\n\nstderr:\n{stderr}" if stderr else "") + "\n", errors="replace")
    if not case.cli:
        with open(folder / "case.pickle", "wb") as f:
            pickle.dump(case, f)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", type=int, default=1000, help="cases in all (split over the surfaces)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--surface", action="append", choices=SURFACES, help="only these surfaces")
    ap.add_argument("--spawn", action="store_true", help="each CLI case a fresh `kdray` process")
    ap.add_argument("--cli-scale", type=float, default=1.0,
                    help="scale the file surfaces' share of CLI cases (CLI_SHARE)")
    ap.add_argument("--save", help="a folder for each failure's reproducer")
    ap.add_argument("-v", "--verbose", action="store_true", help="print each failure as it comes")
    args = ap.parse_args(argv)
    surfaces = tuple(args.surface or SURFACES)
    per = split_cases(args.cases, surfaces)

    def progress(surface, i, n, problems):
        if problems and args.verbose:
            print(f"FAIL [{surface} {i}] {'; '.join(problems)}", file=sys.stderr, flush=True)
        if i == n:
            print(f"{surface}: {n} cases done", file=sys.stderr, flush=True)

    report = fuzz(per, args.seed, surfaces, args.spawn, args.save, progress, cli_scale=args.cli_scale)
    print(f"python tests/fuzz.py --cases {args.cases} --seed {args.seed}"
          + (f" --cli-scale {args.cli_scale:g}" if args.cli_scale != 1 else "")
          + (f" {' '.join('--surface ' + s for s in args.surface)}" if args.surface else "")
          + (" --spawn" if args.spawn else ""))
    print(report.summary(most=200 if args.verbose else 30))
    return 0 if report.ok else 1


WEIGHTS = {"mesh": 10, "tree": 10, "camera": 12, "cameras": 10, "lidar": 10, "pose": 8,
           "batch": 8, "points": 4, "argv": 8, "api": 20}
"""How a run's cases are shared among the surfaces."""


def split_cases(total, surfaces=SURFACES):
    w = sum(WEIGHTS[s] for s in surfaces)
    per = {s: max(1, total * WEIGHTS[s] // w) for s in surfaces}
    per[surfaces[-1]] += total - sum(per.values())
    return per


if __name__ == "__main__":
    sys.path.insert(0, str(HERE))
    import fuzz as _self                       # pickled cases name fuzz.Case, not __main__.Case
    sys.exit(_self.main())
