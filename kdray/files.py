"""Writing files so that nothing half-written is ever left: a temporary file beside the
target, flushed to disk, then renamed over it. An error or Ctrl-C leaves the old file
(if any) as it was and removes the temporary one."""
import os
import secrets
from pathlib import Path

from .errors import OutputError


def atomic_write(path, write):
    """Call write(tmp_path) for a fresh temporary file beside `path`, flush it to disk,
    then rename it over `path`. OSError -> OutputError naming `path`."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.{secrets.token_hex(4)}.tmp")
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
