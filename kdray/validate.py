"""Checks that several input surfaces share, so that the command line and the Python
API refuse the same values with the same one-line messages.

    data = read_json(path, f"camera file {path}", CameraError)   # a JSON file, checked
    data = parse_json(text, f"{path}, line 3", DatasetError)      # the same, of a string
    array = read_npy(path, f"pose file {path}", CameraError)     # a .npy file of numbers
    check_float32(values, "K", CameraError)                      # values the kernels hold

Every JSON input of kdray (camera files and lists, lidar specs, jobs files, the JSON
in tree files and EXR headers) is read here: JSON that Python's parser cannot take
(nesting 1,000 deep: RecursionError; integers of over 4,300 digits: ValueError) or
that kdray cannot use (nesting deeper than JSON_MAX_DEPTH, an integer no float64
holds, a key given twice in one object) is a one-line error of the caller's class
naming the source and the limit.
Floats beyond float64's range (1e999) are read as inf, as NaN and Infinity are: the
caller's checks then refuse them naming the field ("cx must be finite").
"""
import io
import json
import math
import numbers
import os
import stat
import warnings

import numpy as np

from .errors import one_line

JSON_MAX_DEPTH = 32
"""Deepest nesting of arrays and objects in a JSON input. kdray's deepest is 4 (a
4x4 matrix in a frame in a list of frames in an object); Python's parser fails with
RecursionError near 1,000, and code that walks a nested list recurses too."""

JSON_MAX_DIGITS = 309
"""Most digits of a JSON integer: float64 holds at most 1.8e308 (309 digits). Every
number kdray reads is used as a float64 (sizes and counts are far smaller), so a
longer integer is refused here, before Python's parser (4,300 digits at most) or
float() (OverflowError) would fail on it."""

FLOAT32_MAX = float(np.finfo(np.float32).max)
"""Largest float32, about 3.4e38: the kernels compute in float32, and EXR headers hold
cameras' matrices as float32 (docs/exr.md)."""


class _Refused(Exception):
    """A JSON number kdray cannot use (not a ValueError: json would not wrap it)."""


def _parse_int(text):
    digits = len(text.lstrip("-"))
    if digits > JSON_MAX_DIGITS:
        raise _Refused(f"an integer of {digits} digits is beyond float64's range (at most "
                       f"{JSON_MAX_DIGITS} digits, 1.8e308)")
    value = int(text)
    try:
        float(value)
    except OverflowError:
        raise _Refused(f"the integer {text[:12]}... is beyond float64's range "
                       f"(at most 1.8e308)") from None
    return value


def _unique_keys(pairs):
    """An object's dict, refusing a key given twice (Python's parser keeps the last one
    silently; which one another reader keeps is its own choice: RFC 8259, 4)."""
    data = dict(pairs)
    if len(data) < len(pairs):
        seen = set()
        key = next(k for k, _ in pairs if k in seen or seen.add(k))
        raise _Refused(f"the key {json.dumps(key)[:60]} is given twice in one object")
    return data


def _depth_beyond(data, limit):
    """True when `data` (parsed JSON) nests arrays and objects more than `limit` deep;
    an explicit stack, no recursion."""
    stack = [(data, 1)]
    while stack:
        value, depth = stack.pop()
        items = value.values() if isinstance(value, dict) else value
        if depth > limit:
            return True
        stack.extend((v, depth + 1) for v in items if isinstance(v, (list, dict)))
    return False


def parse_json(text, source, error):
    """The value of JSON `text`, read by the rules of the module docstring; `error`
    (a KdrayError class) "<source> is not valid JSON: ..." or "<source>: ..." for text
    that breaks them."""
    try:
        data = json.loads(text, parse_int=_parse_int, object_pairs_hook=_unique_keys)
    except _Refused as e:
        raise error(f"{source}: {e}") from None
    except RecursionError:
        raise error(f"{source}: JSON nested more than {JSON_MAX_DEPTH} deep "
                    f"(JSON_MAX_DEPTH)") from None
    except ValueError as e:                    # JSONDecodeError
        raise error(f"{source} is not valid JSON: {one_line(e)}") from None
    if isinstance(data, (list, dict)) and _depth_beyond(data, JSON_MAX_DEPTH):
        raise error(f"{source}: JSON nested more than {JSON_MAX_DEPTH} deep (JSON_MAX_DEPTH)")
    return data


def check_not_device(path, source, error):
    """`error` "<source> is a device, not a file" for a character or block device
    (/dev/zero, /dev/urandom: a read to the end would never end). Files and pipes
    (is_pipe) pass; a path that cannot be looked at passes too (its reader says why)."""
    try:
        mode = os.stat(path).st_mode
    except (OSError, ValueError, TypeError):
        return
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        raise error(f"{source} is a device, not a file.")


def is_pipe(path):
    """Whether path is a pipe (a FIFO, or /dev/stdin from one): read as a stream, once,
    where a file is mapped or sought in."""
    try:
        return stat.S_ISFIFO(os.stat(path).st_mode)
    except (OSError, ValueError, TypeError):
        return False


def read_pipe(path):
    """The bytes a pipe gives until it ends."""
    with open(path, "rb") as f:
        return f.read()


def npy_stream(data):
    """A seekable stream of the .npy bytes `data` whose header was checked against
    their size first (as np.load's memory map of a file checks it), so that a header
    that claims 10^12 rows is refused, not allocated: ValueError."""
    stream = io.BytesIO(data)
    version = np.lib.format.read_magic(stream)
    read_header = (np.lib.format.read_array_header_1_0 if version == (1, 0)
                   else np.lib.format.read_array_header_2_0)
    shape, _, dtype = read_header(stream)
    need = stream.tell() + math.prod(shape) * dtype.itemsize
    if need > len(data):
        raise ValueError(f"its header's {shape} {dtype} needs {need:,} bytes, it holds "
                         f"{len(data):,}")
    stream.seek(0)
    return stream


def read_text(path, source, error):
    """A UTF-8 text file's content; `error` "<source> does not exist" / "cannot be read"
    / "is a device" (check_not_device)."""
    check_not_device(path, source, error)
    try:
        with open(path, encoding="utf-8") as f:
            return f.read()
    except FileNotFoundError:
        raise error(f"{source} does not exist.") from None
    except (OSError, ValueError) as e:   # ValueError: not UTF-8, or a NUL in the path
        raise error(f"{source} cannot be read: {getattr(e, 'strerror', None) or e}.") from None


def read_json(path, source, error):
    """parse_json of a UTF-8 file's content (read_text's errors for a missing or
    unreadable one)."""
    return parse_json(read_text(path, source, error), source, error)


def check_float32(values, name, error):
    """`error` naming `name` when a value of `values` (array-like of float64) lies beyond
    float32's range (FLOAT32_MAX): values the kernels compute with in float32."""
    array = np.asarray(values, dtype=np.float64)
    big = np.abs(array) > FLOAT32_MAX
    if np.any(big):
        raise error(f"{name} holds {float(array[big].flat[0])!r}, beyond float32's range (at most "
                    f"{FLOAT32_MAX:.4g} in magnitude), which the kernels compute in.")


def check_class(value, cls, name):
    """TypeError (Python's, as for a call that does not fit: docs/interface.md,
    "Types are kept") when `value` is not a `cls`, naming what was given."""
    if not isinstance(value, cls):
        raise TypeError(f"{name} must be a kdray.{cls.__name__}, got {type(value).__name__}")


def real_number(value, name, error):
    """float(value) for a real number (an integer beyond float64's range: +-inf; a 0-d
    numpy array of one); `error` for bools, strings and anything else, which are
    refused, not converted."""
    if isinstance(value, np.ndarray) and value.ndim == 0 and value.dtype.kind in "fiu":
        value = value.item()
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise error(f"{name} must be a number, got {value!r:.80}")
    try:
        return float(value)
    except OverflowError:               # an int of 400 digits: as large as inf is
        return math.inf if value > 0 else -math.inf


def check_bool(value, name, error):
    """bool(value) for True or False (numpy's bool too); `error` for anything else
    ("no", 0, None), which is refused, not taken for its truth."""
    if not isinstance(value, (bool, np.bool_)):
        raise error(f"{name} must be True or False, got {value!r:.60}")
    return bool(value)


def whole_or_none(value, name, error):
    """None, or int(value) for an integer >= 1 (numpy's too); `error` for anything else
    (nan, "8", 1.5, True)."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise error(f"{name} must be None or an integer >= 1, got {value!r:.60}")
    return int(value)


def read_npy(path, source, error):
    """The numeric array of a .npy file, read by np.load without pickles; `error`
    "<source> does not exist" / "cannot be read: ..." / "must hold numbers" for a missing
    file, a corrupt or cut one (whatever np.load raises on it: ValueError, EOFError,
    SyntaxError from its header's parser, ...), or one of other values (strings, dates,
    complex numbers). The header is checked against the file's size before anything is
    allocated (np.load's memory map), so a header that claims 10^12 rows costs nothing."""
    check_not_device(path, source, error)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            if is_pipe(path):
                mapped = np.load(npy_stream(read_pipe(path)), allow_pickle=False)
            else:
                mapped = np.load(path, mmap_mode="r", allow_pickle=False)
            if not isinstance(mapped, np.ndarray):
                raise ValueError(f"not one array ({type(mapped).__name__})")
            if mapped.dtype.kind not in "fiu":
                raise error(f"{source} must hold numbers, got dtype {mapped.dtype}.")
            return np.array(mapped)
    except error:
        raise
    except FileNotFoundError:
        raise error(f"{source} does not exist.") from None
    except Exception as e:          # np.load on hostile bytes: any of a dozen classes
        why = getattr(e, 'strerror', None) or one_line(e) or type(e).__name__
        raise error(f"{source} cannot be read as a .npy file: {why.rstrip('.')}.") from None


def check_numbers(value, name, error, depth=4):
    """`error` naming `name` when a nested list or tuple `value` (up to `depth` levels:
    a camera's matrix, a vector) holds a bool, a string or None, which numpy would
    otherwise turn into a number ([[30, 0, True]] is float64). Arrays are left to their
    dtype's check."""
    stack = [(value, 0)]
    while stack:
        v, level = stack.pop()
        if isinstance(v, (list, tuple)) and level < depth:
            stack.extend((x, level + 1) for x in v)
        elif isinstance(v, (bool, np.bool_, str, bytes)) or v is None:
            raise error(f"{name} must hold numbers only, got {v!r:.40}.")
