"""Writing files so that nothing half-written is ever left: a temporary file beside the
target, flushed to disk, then renamed over it. An error or Ctrl-C leaves the old file
(if any) as it was and removes the temporary one.

    check_output(path, inputs=(scene, tree_file), others=(preview,))   # before any work
    atomic_write(path, lambda tmp: ...)

`check_output` is the one place where an output path is checked, for every command and
the dataset runs: what it refuses is refused before anything is read or computed.
"""
import os
import secrets
import stat
from pathlib import Path

from .errors import OutputError

NAME_MAX_BYTES = 255
"""Longest file name (bytes, UTF-8) on common file systems (ext4, XFS, APFS, NTFS)."""

TEMPORARY_EXTRA_BYTES = len(".") + len(".01234567.tmp")
"""Bytes the temporary name `.NAME.<8 hex>.tmp` adds to NAME: the longest name written
for an output is its temporary's, so name checks count these too."""


def temporary_path(path):
    """A fresh temporary path beside `path`: `.NAME.<8 hex digits>.tmp`."""
    path = Path(path)
    return path.with_name(f".{path.name}.{secrets.token_hex(4)}.tmp")


def name_problem(name):
    """Why a file name (str) cannot be written beside its temporary, or None: a name
    whose temporary would pass NAME_MAX_BYTES."""
    size = len(name.encode("utf-8", "surrogateescape")) + TEMPORARY_EXTRA_BYTES
    if size > NAME_MAX_BYTES:
        return (f"its temporary file's name (.NAME.<8 hex>.tmp) would be {size} bytes, more "
                f"than the {NAME_MAX_BYTES} a file name may have")
    return None


def same_file(a, b):
    """Whether paths `a` and `b` name one file, existing or not: os.path.samefile when
    both exist (hard links too), else the same path once symlinks, '.' and '..' are
    resolved (os.path.realpath)."""
    if not a or not b:
        return False
    a, b = os.fspath(a), os.fspath(b)
    try:
        if os.path.exists(a) and os.path.exists(b):
            return os.path.samefile(a, b)
    except (OSError, ValueError):
        pass
    return os.path.normcase(os.path.realpath(a)) == os.path.normcase(os.path.realpath(b))


def check_output(path, inputs=(), others=(), what="output"):
    """OutputError, before any work, for an output file `path` that cannot be written
    whole: a NUL byte, a folder (`.`, `dir/`, an existing folder), a name too long for
    its temporary file (name_problem), a device, a pipe or a socket (a file renamed
    over its name would replace it), a folder that does not exist or cannot be
    written, or the same file as one of `inputs` (it would be overwritten) or of
    `others` (other outputs of the same run: one would replace the other). None
    entries of inputs and others are skipped."""
    text = os.fspath(path)
    if "\0" in text:
        raise OutputError(f"{what} {text!r}: a path cannot hold a NUL byte")
    name = os.path.basename(text)
    if not name or name in (".", "..") or text.endswith(os.sep) or os.path.isdir(text):
        raise OutputError(f"{what} {text}: is a folder; give a file name")
    problem = name_problem(name)
    if problem:
        raise OutputError(f"{what} {text}: {problem}")
    if _not_a_file(text):
        raise OutputError(f"{what} {text}: is a device, a pipe or a socket, not a file; "
                          "kdray writes files whole")
    folder = os.path.dirname(os.path.abspath(text))
    if not os.path.isdir(folder):
        raise OutputError(f"{what} {text}: the folder {folder} does not exist")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise OutputError(f"{what} {text}: the folder {folder} is not writable")
    for source in inputs:
        if same_file(source, text):
            raise OutputError(f"{what} {text}: the output would overwrite the input {source}")
    for other in others:
        if same_file(other, text):
            raise OutputError(f"{what} {text}: the same file as the output {other}; "
                              "one would replace the other")


def _not_a_file(text):
    """Whether path `text` exists and is not a regular file (a device, a pipe, a socket,
    a folder): a file written whole and renamed over its name would replace it."""
    try:
        return not stat.S_ISREG(os.stat(text).st_mode)
    except (OSError, ValueError):
        return False


def atomic_write(path, write):
    """Call write(tmp_path) for a fresh temporary file beside `path`, flush it to disk,
    then rename it over `path`. OSError -> OutputError naming `path`; OutputError
    before anything is written where `path` is a device, a pipe or a socket (the rename
    would replace it: /dev/null made a plain file, by a root user's Python call)."""
    text = os.fspath(path)
    if "\0" in text or os.path.basename(text.rstrip(os.sep)) in ("", ".", ".."):
        raise OutputError(f"cannot write {text!r}: not a file name.")
    if _not_a_file(text):
        raise OutputError(f"cannot write {text}: it is a device, a pipe, a socket or a "
                          "folder, not a file; kdray writes files whole")
    path = Path(path)
    tmp = temporary_path(path)
    try:
        # Created here (mode 0o666 less the umask) so the result has normal permissions.
        os.close(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
        write(tmp)
        fd = os.open(tmp, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
        os.replace(tmp, path)
    except OSError as exc:
        _remove(tmp)
        raise OutputError(f"cannot write {path}: {exc.strerror or exc}.") from None
    except BaseException:
        _remove(tmp)
        raise


def atomic_write_bytes(path, data):
    """atomic_write of a bytes object."""
    atomic_write(path, lambda tmp: Path(tmp).write_bytes(data))


def _remove(path):
    try:
        os.unlink(path)
    except OSError:
        pass
