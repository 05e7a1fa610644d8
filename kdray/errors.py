"""Errors raised by kdray. Library code raises these; only `kdray.cli` turns them
into one-line messages."""


class KdrayError(Exception):
    """Base class of every error kdray raises on purpose. Its message is one line: a
    newline or carriage return it quotes (a file name may hold one) is written as
    \\n or \\r."""

    def __init__(self, *args):
        if args and isinstance(args[0], str):
            args = (args[0].replace("\r", "\\r").replace("\n", "\\n"), *args[1:])
        super().__init__(*args)


class MeshError(KdrayError):
    """A mesh file or mesh arrays that cannot be used (missing, unreadable, no triangles)."""


class TreeFileError(KdrayError):
    """A tree file that is truncated, corrupt, of another version or out of range."""


class TreeError(KdrayError):
    """A tree whose arrays break a structural invariant (see `KdTree.validate`)."""


class DeviceError(KdrayError):
    """No OpenCL platform or device, or a device too small for the work."""


class KernelBuildError(DeviceError):
    """An OpenCL program failed to build; `log` holds the compiler's build log."""

    def __init__(self, message, log=""):
        super().__init__(message)
        self.log = log


class CameraError(KdrayError):
    """A camera that cannot be built (bad field of view, eye equal to target, ...)."""


class OutputError(KdrayError):
    """An image or tree file that cannot be written."""


class DatasetError(KdrayError):
    """A jobs file that cannot be used, or a dataset run some of whose jobs failed."""


class ParameterError(KdrayError, ValueError):
    """An option or argument out of its range (a build parameter, a work size)."""


def one_line(text):
    """The first non-blank line of `text` (str or an exception), stripped, for messages
    that must be one line; "unknown error" when there is none."""
    lines = [ln.strip() for ln in str(text).splitlines() if ln.strip()]
    return lines[0] if lines else "unknown error"
