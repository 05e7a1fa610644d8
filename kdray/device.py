"""Choosing an OpenCL device and building kdray's programs.

    context, device = create_context("0:1")      # PYOPENCL_CTX syntax; None = prefer a GPU
    program = build_program(context, "render.cl", {"STACK_SIZE": 24, "OUT_UV": None})
    for line in list_devices(): print(line)

Programs are plain OpenCL C in the repository's `kernels/` folder, built with real
`#include`s (`-I kernels/`) and `-D` options. Nothing here keeps module-level OpenCL
state: a `Tracer` owns its context and queue and caches the programs it builds.
pyopencl is imported inside the functions, so the rest of kdray imports without it.

Build options never relax IEEE arithmetic (no fast or finite-only math): the
traversal relies on IEEE infinities, NaN and signed zeros. Where the device offers it,
-cl-fp32-correctly-rounded-divide-sqrt makes single-precision division exact, so a
device gives the same t, u, v as any other that rounds correctly.

Compiled programs are cached on disk by the OpenCL driver, not here: PoCL keeps them
in POCL_CACHE_DIR (default ~/.cache/pocl/kcache; POCL_KERNEL_CACHE=0 turns it off),
keyed by the preprocessed source (the `#include`d files too) and the options, with
the code it compiles at a kernel's first launch beside them; NVIDIA's driver keeps
its own; pyopencl's binary cache serves the drivers that have none. Some drivers'
caches hash the top-level source and options but not the `#include`d files, so every
build passes `-DKDRAY_KERNELS=<hash of every file in kernels/>`: a cache keyed by the
options can never serve a program built from other kernels.
"""
import hashlib
import logging
import os
from pathlib import Path

from .errors import DeviceError, KernelBuildError

log = logging.getLogger(__name__)

KERNEL_DIR = Path(__file__).resolve().parent / "kernels"
"""The OpenCL sources: the top-level `kernels/` folder, linked into the package as
`kdray/kernels` so that a wheel (package data) carries it too."""

_NO_PLATFORM = ("no OpenCL platform found: `pip install pocl-binary-distribution` for a "
                "CPU device, or install your GPU's OpenCL driver")


def _cl():
    try:
        import pyopencl
    except ImportError as e:  # pragma: no cover - pyopencl is a dependency
        raise DeviceError(f"pyopencl is not installed ({e}): `pip install pyopencl "
                          f"pocl-binary-distribution`") from None
    return pyopencl


def _platforms():
    cl = _cl()
    try:
        platforms = cl.get_platforms()
    except cl.Error:
        platforms = []
    if not platforms:
        raise DeviceError(_NO_PLATFORM)
    return platforms


def _devices(platform):
    cl = _cl()
    try:
        return platform.get_devices()
    except cl.Error:
        return []


def _pick(items, key, what, names):
    """One of `items` by index ("1") or by a case-insensitive substring of its name."""
    key = key.strip()
    if key.isdigit():
        i = int(key)
        if i >= len(items):
            raise DeviceError(f"no OpenCL {what} {i} (there are {len(items)}: "
                              f"{'; '.join(names) or 'none'})")
        return items[i]
    for item, name in zip(items, names):
        if key.lower() in name.lower():
            return item
    raise DeviceError(f"no OpenCL {what} matches {key!r} (there are: {'; '.join(names) or 'none'})")


def choose_device(spec=None):
    """The OpenCL device for `spec`.

    spec : None, or a PYOPENCL_CTX-style string "PLATFORM[:DEVICE]", each part an index
        or a case-insensitive substring of the name ("0", "0:1", "nvidia", "portable:0").
        None reads the PYOPENCL_CTX environment variable; unset or "" prefers a GPU
        and falls back to any device (PoCL's CPU device).
        Never prompts.
    Raises DeviceError when no platform or no matching device exists.
    """
    cl = _cl()
    platforms = _platforms()
    if spec is None:
        spec = os.environ.get("PYOPENCL_CTX")
    if spec is None or str(spec).strip() == "":
        devices = [d for p in platforms for d in _devices(p)]
        if not devices:
            raise DeviceError(_NO_PLATFORM)
        gpus = [d for d in devices if d.type & cl.device_type.GPU]
        return (gpus or devices)[0]
    plat_key, _, dev_key = str(spec).partition(":")
    platform = _pick(platforms, plat_key, "platform", [p.name for p in platforms])
    devices = _devices(platform)
    if not devices:
        raise DeviceError(f"OpenCL platform {platform.name!r} has no devices")
    if dev_key.strip() == "":
        return devices[0]
    return _pick(devices, dev_key, "device", [d.name for d in devices])


def create_context(spec=None):
    """(context, device) for `spec` (see `choose_device`)."""
    cl = _cl()
    device = choose_device(spec)
    try:
        context = cl.Context([device])
    except cl.Error as e:
        raise DeviceError(f"cannot create an OpenCL context on {device.name!r}: {e}") from None
    log.info("OpenCL device: %s (%s)", device.name.strip(), device.platform.name.strip())
    return context, device


def describe(device):
    """One line naming a device: 'NAME (PLATFORM, OpenCL x.y, N compute units)'."""
    return (f"{device.name.strip()} ({device.platform.name.strip()}, "
            f"{device.version.strip()}, {device.max_compute_units} compute units)")


def list_devices():
    """Lines describing every platform and device, with the --device string of each."""
    cl = _cl()
    lines = []
    for i, platform in enumerate(_platforms()):
        lines.append(f"platform {i}: {platform.name.strip()} ({platform.version.strip()})")
        for j, device in enumerate(_devices(platform)):
            kind = cl.device_type.to_string(device.type)
            lines.append(f"  --device {i}:{j}  {kind:<4} {describe(device)}")
    default = choose_device(None)
    lines.append(f"default: {describe(default)}")
    return lines


def is_cpu(device):
    cl = _cl()
    return bool(device.type & cl.device_type.CPU)


def has_fp64(device):
    return "cl_khr_fp64" in device.extensions.split()


def kernels_hash(folder=None):
    """The first 16 hex digits of the SHA-256 of every file in `folder` (default
    KERNEL_DIR): names and contents, in name order. Raises DeviceError when the folder
    cannot be read."""
    folder = Path(KERNEL_DIR if folder is None else folder)
    digest = hashlib.sha256()
    try:
        for path in sorted(folder.iterdir()):
            if path.is_file():
                data = path.read_bytes()
                digest.update(f"{path.name}\0{len(data)}\0".encode())
                digest.update(data)
    except OSError as e:
        raise DeviceError(f"kernel folder {folder} cannot be read ({e.strerror or e}); "
                          f"kdray's kernels/ folder must sit beside the kdray package") from None
    return digest.hexdigest()[:16]


def build_options(device, defines):
    """-I, -D and precision options for `device`, with -DKDRAY_KERNELS=kernels_hash().

    defines : dict name -> value, or None for a bare `-D NAME`.
    """
    cl = _cl()
    options = ["-I", str(KERNEL_DIR), f"-DKDRAY_KERNELS={kernels_hash()}"]
    for name, value in sorted(defines.items()):
        options.append(f"-D{name}" if value is None else f"-D{name}={value}")
    try:
        exact_div = bool(device.single_fp_config & cl.device_fp_config.CORRECTLY_ROUNDED_DIVIDE_SQRT)
    except cl.Error:
        exact_div = False
    if exact_div:
        options.append("-cl-fp32-correctly-rounded-divide-sqrt")
    return options


def build_program(context, source_name, defines=None):
    """Build `kernels/<source_name>` for the context's devices.

    Raises KernelBuildError (with the compiler's log in `.log`) when it does not build.
    """
    cl = _cl()
    path = KERNEL_DIR / source_name
    try:
        source = path.read_text(encoding="utf-8")
    except OSError as e:
        raise DeviceError(f"kernel source {path} cannot be read ({e.strerror or e}); "
                          f"kdray's kernels/ folder must sit beside the kdray package") from None
    device = context.devices[0]
    options = build_options(device, defines or {})
    program = cl.Program(context, source)
    try:
        import warnings
        with warnings.catch_warnings():
            # PoCL and some drivers print harmless notes; the log is kept on errors.
            warnings.simplefilter("ignore", cl.CompilerWarning)
            program = program.build(options=options)
    except cl.Error as e:
        build_log = ""
        try:
            build_log = program.get_build_info(device, cl.program_build_info.LOG)
        except Exception:
            pass
        if not build_log:
            build_log = str(e)
        first = next((ln.strip() for ln in build_log.splitlines() if "error" in ln.lower()),
                     build_log.strip().splitlines()[0] if build_log.strip() else str(e))
        raise KernelBuildError(
            f"OpenCL program {source_name} failed to build on {device.name.strip()} "
            f"(options: {' '.join(options)}): {first}", log=build_log) from None
    # A corrupt entry in the driver's cache builds "successfully" into a program without
    # kernels (seen with PoCL 3.0: creating a kernel then fails, and the process aborts
    # when it exits); say what to remove instead.
    if "__kernel" in source and program.get_info(cl.program_info.NUM_KERNELS) == 0:
        raise KernelBuildError(
            f"OpenCL program {source_name} built on {device.name.strip()} without its kernels: "
            f"the driver's compiler cache is probably corrupt; remove it ({_driver_cache(device)}) "
            f"and run again")
    return program


def _driver_cache(device):
    """Where the device's driver keeps compiled programs, in words."""
    if "portable computing language" in device.platform.name.lower():
        xdg = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
        return os.environ.get("POCL_CACHE_DIR") or os.path.join(xdg, "pocl", "kcache")
    return "see the OpenCL driver's documentation"
