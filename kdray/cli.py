"""The `kdray` command: a thin shell over the Python API.

Errors: library code raises KdrayError subclasses; here they become one line on
stderr and exit code 1 (click's usage errors exit 2). `--debug` shows tracebacks.
"""
import contextlib
import io
import logging
import os
import sys
import time
import warnings

import click
import numpy as np

from .errors import DeviceError, KdrayError, MeshError, OutputError, TreeError, one_line
from .files import check_output

log = logging.getLogger("kdray")


class FilePath(click.Path):
    """click.Path that refuses an empty path (a usage error, exit 2): "" names no file,
    and an option given so must not pass for one not given."""

    def convert(self, value, param, ctx):
        if isinstance(value, str) and value == "":
            self.fail("an empty path names no file", param, ctx)
        return super().convert(value, param, ctx)


def _floats(n):
    """A click callback parsing 'a,b,c' into a tuple of n floats."""
    def parse(ctx, param, value):
        if value is None:
            return None
        try:
            out = tuple(float(x) for x in value.split(","))
        except ValueError:
            raise click.BadParameter(f"expected {n} comma-separated numbers, got {value!r}")
        if len(out) != n:
            raise click.BadParameter(f"expected {n} comma-separated numbers, got {len(out)}")
        return out
    return parse


def _size(ctx, param, value):
    try:
        w, h = (int(x) for x in value.lower().split("x"))
    except ValueError:
        raise click.BadParameter(f"expected WIDTHxHEIGHT, e.g. 640x480, got {value!r}")
    if w < 1 or h < 1:
        raise click.BadParameter(f"width and height must be at least 1, got {w}x{h}")
    return w, h


device_option = click.option(
    "--device", default=None,
    help="OpenCL device, PYOPENCL_CTX syntax (0:0, intel, pocl; see `kdray devices`).")
"""The --device option every command that traces takes."""

tree_option = click.option(
    "--tree", "tree_file", type=FilePath(dir_okay=False),
    help="Use this dumped tree instead of building one.")
"""The --tree option of the query commands (contains, cast, points, sdf)."""


def build_options(f):
    """The builder's parameters as options (defaults documented in kdray.tree.BuildParams)."""
    from .tree import BuildParams
    d = BuildParams()
    opts = [
        click.option("--k-t", "K_T", type=float, default=d.K_T, show_default=True,
                     help="K_T: SAH cost of one traversal step; 0 = 400, rising to 600 "
                          "from 2^20 triangles (kdray.tree.auto_K_T)."),
        click.option("--k-i", "K_I", type=float, default=d.K_I, show_default=True,
                     help="K_I: SAH cost of one ray/triangle test."),
        click.option("--empty-bonus", type=float, default=d.empty_bonus, show_default=True,
                     help="lambda: SAH cost factor for splits with an empty side (1 = off)."),
        click.option("--max-depth", type=int, default=d.max_depth, show_default=True,
                     help="Deepest leaf; 0 = round(8 + 1.3 log2 n), at most 64."),
        click.option("--leaf-size", type=int, default=d.leaf_size, show_default=True,
                     help="Nodes with at most this many triangles become leaves."),
    ]
    for opt in reversed(opts):
        f = opt(f)
    return f


def dataset_options(f):
    """The options of runs of many views (kdray render --cameras, kdray batch)."""
    opts = [
        click.option("--workers", type=click.IntRange(min=1), default=None,
                     help="Run on a local Dask cluster of N worker processes "
                          "[default: in this process]; needs kdray[dask]."),
        click.option("--scheduler", default=None,
                     help="Run on an existing Dask cluster: its scheduler's address "
                          "(tcp://host:8786, or a scheduler file's path)."),
        click.option("--no-cache", is_flag=True,
                     help="Build every tree; do not read or fill the tree cache "
                          "(KDRAY_CACHE_DIR, default ~/.cache/kdray/trees)."),
        click.option("--overwrite", is_flag=True,
                     help="Render every view, also those whose files exist "
                          "[default: only the missing ones]."),
    ]
    for opt in reversed(opts):
        f = opt(f)
    return f


SDF_PROGRESS_POINTS = 1 << 22
"""`kdray sdf` shows its progress (as Steps does: on a terminal, without -q) for grids
of at least this many points."""


def _build_kwargs(kw):
    return {k: kw.pop(k) for k in ("K_T", "K_I", "empty_bonus", "max_depth", "leaf_size")}


def _process_age():
    """Seconds since this process started (Linux, 10 ms resolution), or None."""
    try:
        with open("/proc/self/stat") as f:
            fields = f.read().rpartition(")")[2].split()
        started = int(fields[19]) / os.sysconf("SC_CLK_TCK")   # field 22: ticks after boot
        return max(time.clock_gettime(time.CLOCK_BOOTTIME) - started, 0.0)
    except (OSError, ValueError, IndexError, AttributeError):
        return None


class Steps:
    """Times the steps of a command; shows them on stderr when it is a terminal
    (and -q was not given), stays quiet otherwise. `-v` logs the timings, after the
    start-up: the time from the process's start to the command (interpreter, imports)."""

    def __init__(self):
        self.seconds = {}
        self.start_up = _process_age()
        self.live = sys.stderr.isatty() and log.getEffectiveLevel() <= logging.WARNING

    @contextlib.contextmanager
    def __call__(self, what):
        if self.live:
            click.echo(f"kdray: {what}...", err=True, nl=False)
        t0 = time.perf_counter()
        try:
            yield
        finally:
            dt = self.seconds[what] = time.perf_counter() - t0
            if self.live:
                click.echo(f"\rkdray: {what} ({dt:.2f} s)", err=True)

    def log(self):
        start = [] if self.start_up is None else [f"start-up {self.start_up:.3f} s"]
        log.info("%s", ", ".join(start + [f"{k} {v:.3f} s" for k, v in self.seconds.items()]))


def _build_mesh(mesh, path, params, builder=None, *args):
    """builder(vertices, faces, *args, **params) (default kdray.builder.build) on a loaded
    mesh; mesh errors name the file."""
    if builder is None:
        from .builder import build as builder
    _say_if_builder_compiles()
    try:
        return builder(mesh.vertices, mesh.faces, *args, **params)
    except MeshError as e:
        raise MeshError(f"{path}: {e}") from None


def _scene_tree(step, scene, tree_file, params, double=False):
    """The tree of a command's SCENE, each part timed by `step` (Steps): loaded from
    tree_file when given, else built from the mesh with params, with its objects; with
    `double`, with the mesh's float64 triangles (--precision double)."""
    from .tree import KdTree
    if tree_file:
        with step("loading the tree"):
            tree = KdTree.load(tree_file)
        return _with_double(step, tree, scene, tree_file) if double else tree
    from .load import load
    with step("loading"):
        mesh = load(scene)
    with step(f"building the tree of {len(mesh.faces):,} triangles"):
        params = dict(params, keep_double=True) if double else params
        return _build_mesh(mesh, scene, params).with_objects(mesh.objects, mesh.object_names)


def _scene_tracer(scene, tree_file, params, device, double=False):
    """(step, tracer): a command's new Steps and a Tracer of its SCENE's tree
    (`_scene_tree`) on `device`, each part timed."""
    from .trace import Tracer
    step = Steps()
    tree = _scene_tree(step, scene, tree_file, params, double=double)
    with step("setting up the device"):
        return step, Tracer(tree, device=device)


def _with_double(step, tree, scene, tree_file):
    """`tree`, read from tree_file, with the float64 triangles of SCENE, its mesh
    (TreeError when SCENE is not that mesh)."""
    from .load import load
    with step("loading the float64 triangles"):
        mesh = load(scene)
        try:
            return tree.with_double(mesh.vertices, mesh.faces)
        except TreeError as e:
            raise TreeError(f"{scene} is not the mesh of {tree_file}: {e}") from None


def _say_if_builder_compiles():
    """A warning on stderr when the builder's compiled code is not on disk yet, and then
    all of it compiled (numba; `builder.compile_all`, as `kdray batch` does): about half
    a minute that would otherwise pass in silence. All of it: a build alone compiles only
    the functions it calls, and the warning then came again at every command until a
    trace of rays that share no path had compiled the wide nodes' BVH."""
    from . import builder
    if not builder.compiled():
        log.warning(builder.COMPILING)
        builder.compile_all()


def _log_left_out(tree, tracer, n_culled, from_file, outputs):
    """-v: what the render left out: triangles, kernel outputs, stack entries."""
    from .layout import KERNEL_OUTPUTS
    from .trace import default_stack_size
    n_input, n_kept = tree.n_input_tris, len(tree.tri_ids)
    if from_file:
        log.info("the tree holds %d of %d input triangles (the others are degenerate, or were "
                 "left out when it was built)", n_kept, n_input)
    else:
        culled = n_culled or 0
        log.info("triangles left out as degenerate: %d of %d", n_input - n_kept - culled, n_input)
        if n_culled is not None:
            log.info("triangles left out by --cull (outside the view): %d of %d; %d in the tree",
                     culled, n_input, n_kept)
    skipped = [name for name in KERNEL_OUTPUTS if name not in outputs]
    log.info("kernel outputs: %s; not computed: %s", ", ".join(outputs), ", ".join(skipped) or "none")
    log.info("stack size: %d entries (tree depth %d; default %d)", tracer.stack_size, tree.depth,
             default_stack_size(tree))
    log.info("tree on the device: %.1f MiB (%d nodes, %d triangle copies)",
             tracer.device_bytes / 2**20, len(tree.nodes), len(tree.leaf_tris))
    if tree.triangles64 is not None:
        log.info("float64 triangles on the host (--precision double): %.1f MiB",
                 tree.triangles64.nbytes / 2**20)
    log.info("hits refined in double: %s", "yes" if tracer.refine else
             "no (the device has no double precision)")
    if tracer.packet > 1:
        log.info("packets of %d rays per work-item, packet stack %d entries", tracer.packet,
                 tracer.packet_stack_size)


def _print_objects(tree, most=20):
    """The tree's objects: their number, and the names of the first `most`."""
    none = "" if tree.object_names else " (no object table: every triangle is object 0)"
    click.echo(f"{'objects':<19}{tree.n_objects}{none}")
    for i, name in enumerate(tree.object_names[:most]):
        click.echo(f"{f'  object {i}':<19}{name}")
    if len(tree.object_names) > most:
        click.echo(f"{'':<19}... and {len(tree.object_names) - most} more")


def _print_stats(stats, seconds=None):
    width = max(len(k) for k in stats)
    for k, v in stats.items():
        click.echo(f"{k:<{width}}  {v:.4g}" if isinstance(v, float) else f"{k:<{width}}  {v}")
    if seconds is not None:
        click.echo(f"{'build_seconds':<{width}}  {seconds:.3f}")


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.option("-v", "--verbose", count=True, help="More log output on stderr (-vv for debug).")
@click.option("-q", "--quiet", is_flag=True, help="Only errors on stderr.")
@click.option("--debug", is_flag=True, help="Show a traceback on errors.")
def cli(verbose, quiet, debug):
    """kdray: exact depth, normal, barycentric and triangle-id images of meshes."""
    level = logging.ERROR if quiet else (logging.WARNING, logging.INFO, logging.DEBUG)[min(verbose, 2)]
    logging.basicConfig(level=level, format="kdray: %(message)s", stream=sys.stderr)


@cli.command()
@click.argument("scene", type=FilePath(dir_okay=False))
@click.option("--dump", type=FilePath(), help="Write the tree to this file.")
@build_options
def build(scene, dump, **kw):
    """Build the SAH k-d tree of SCENE; print its statistics and the build time."""
    from .load import load
    params = _build_kwargs(kw)
    if dump:
        check_output(dump, inputs=(scene,), what="--dump")
    step = Steps()
    with step("loading"):
        mesh = load(scene)
    with step(f"building the tree of {len(mesh.faces):,} triangles"):
        tree = _build_mesh(mesh, scene, params).with_objects(mesh.objects, mesh.object_names)
    if dump:
        with step("writing the tree"):
            _save_tree(tree, dump)
    step.log()
    _print_stats(tree.stats(), step.seconds[f"building the tree of {len(mesh.faces):,} triangles"])


@cli.command()
@click.argument("tree_file", metavar="TREE.bin", type=FilePath(dir_okay=False))
@click.option("--check", is_flag=True, help="Also run the full structural validation.")
def info(tree_file, check):
    """Print a tree file's header and statistics (the loader always checks the format)."""
    from .tree import KdTree
    tree = KdTree.load(tree_file)
    p = tree.params
    click.echo(f"file               {tree_file}")
    click.echo(f"origin             {' '.join(repr(float(x)) for x in tree.origin)}")
    click.echo(f"scale              {tree.scale!r}")
    click.echo(f"bounds (relative)  {tree.bounds[0].tolist()} .. {tree.bounds[1].tolist()}")
    click.echo(f"params             K_T={p.K_T} K_I={p.K_I} empty_bonus={p.empty_bonus} "
               f"max_depth={p.max_depth} leaf_size={p.leaf_size}")
    _print_stats(tree.stats())
    _print_objects(tree)
    if check:
        try:
            tree.validate()
        except TreeError as e:          # name the file, as the loader's errors do
            raise TreeError(f"{tree_file}: {e}") from None
        click.echo("check              ok")


@cli.command()
def devices():
    """List the OpenCL platforms and devices, each probed (works or fails, and why), and
    the default; exit code 1 when no device works."""
    from .device import device_table
    table = device_table()
    for line in table.lines():
        click.echo(line)
    if table.default is None:
        raise DeviceError(table.error)


@cli.command()
@click.argument("scene", type=FilePath(dir_okay=False))
@click.option("-o", "--output", type=FilePath(), default=None,
              help="EXR file to write [default: SCENE's name with .exr, here]; with --cameras "
                   "the folder of the views' files [default: SCENE's name, here].")
@click.option("--size", default="640x480", show_default=True, callback=_size, help="Image WIDTHxHEIGHT.")
@click.option("--eye", callback=_floats(3), help="Camera position X,Y,Z (look-at camera).")
@click.option("--target", callback=_floats(3), help="Point looked at X,Y,Z.")
@click.option("--up", callback=_floats(3), default="0,1,0", show_default=True, help="Up direction X,Y,Z.")
@click.option("--fov", type=float, default=45.0, show_default=True, help="Vertical field of view, degrees.")
@click.option("--intrinsics", callback=_floats(4), help="FX,FY,CX,CY in pixels (with --pose).")
@click.option("--pose", type=FilePath(dir_okay=False),
              help="4x4 camera-to-world matrix file (OpenCV axes), with --intrinsics.")
@click.option("--camera", "camera_file", type=FilePath(dir_okay=False), help="A JSON camera file.")
@click.option("--aov", default="depth,normal,bary,id", show_default=True,
              help="Comma-separated outputs: depth, distance, normal, bary, id, position, "
                   "object (or all).")
@click.option("--preview", type=click.Path(), is_flag=False, flag_value="",
              help="Also write an 8-bit PNG for people (with --cameras, or with no value: "
                   "beside each EXR).")
@click.option("--cameras", "cameras_file", type=FilePath(),
              help="Render every view of a camera file (nerfstudio transforms.json, a COLMAP "
                   "text model, a JSON list of cameras) to -o DIR/<name>.exr.")
@dataset_options
@click.option("--tree", "tree_file", type=FilePath(dir_okay=False),
              help="Render from this dumped tree instead of building one.")
@device_option
@click.option("--cull", is_flag=True,
              help="Build the tree of only the triangles the camera can see (same images).")
@click.option("--precision", type=click.Choice(["single", "double"]), default="single",
              show_default=True,
              help="double: depth, distance, position and bary computed in float64 from the "
                   "mesh's float64 triangles (the EXR stores them rounded to float32).")
@build_options
def render(scene, output, size, eye, target, up, fov, intrinsics, pose, camera_file, aov,
           preview, cameras_file, workers, scheduler, no_cache, overwrite, tree_file, device,
           cull, precision, **kw):
    """Render SCENE's depth, normal, barycentric and id images to an EXR file (with
    --cameras: one EXR file per view, in the folder -o DIR)."""
    from .images import check_camera_header, write_exr, write_preview
    from .render import kernel_outputs, parse_aovs
    from .trace import Tracer
    from .tree import KdTree
    params = _build_kwargs(kw)
    aovs = parse_aovs(aov)
    width, height = size
    if cameras_file:
        given = {"--camera": camera_file, "--eye": eye, "--target": target,
                 "--intrinsics": intrinsics, "--pose": pose, "--tree": tree_file, "--cull": cull,
                 "--preview FILE": preview}           # --preview alone: a PNG a view
        # the views' own sizes and fields of view: these would be ignored
        ctx = click.get_current_context()
        for name in ("size", "fov", "up"):
            given[f"--{name}"] = (ctx.get_parameter_source(name)
                                  is not click.core.ParameterSource.DEFAULT)
        clash = [k for k, v in given.items() if v]
        if clash:
            raise click.UsageError(f"--cameras cannot be combined with {', '.join(clash)}")
        from .dataset import Job, check_params
        job = Job(scene=scene, cameras=cameras_file,
                  output=output or os.path.splitext(os.path.basename(scene))[0],
                  aovs=aovs, preview=preview is not None, precision=precision,
                  params=check_params(params))
        from .camera_files import read_cameras
        read_cameras(job.cameras)            # a bad camera file: one line, nothing written
        if not os.path.exists(scene):        # nor a folder made for a scene not there
            raise KdrayError(f"{scene}: no such file")
        _run_jobs([job], workers, scheduler, device, no_cache, overwrite)
        return
    for clash in ("workers", "scheduler", "no_cache", "overwrite"):
        if locals()[clash]:
            raise click.UsageError(f"--{clash.replace('_', '-')} goes with --cameras")
    if output is None:
        output = os.path.splitext(os.path.basename(scene))[0] + ".exr"
    if preview == "":
        preview = os.path.splitext(output)[0] + ".png"
    inputs = (scene, tree_file, camera_file, pose)
    check_output(output, inputs, what="-o")
    if preview:
        check_output(preview, inputs, others=(output,), what="--preview")
    if cull and tree_file:
        raise click.UsageError("--cull applies when building the tree; it cannot be combined with --tree")
    step = Steps()
    n_culled = None
    if precision == "double":
        params["keep_double"] = True
    if tree_file:
        with step("loading the tree"):
            tree = KdTree.load(tree_file)
        if precision == "double":
            tree = _with_double(step, tree, scene, tree_file)
        camera = _camera(lambda: _tree_box(tree), width, height, eye, target, up, fov,
                         intrinsics, pose, camera_file)
    else:
        from .load import load
        with step("loading"):
            mesh = load(scene)
        if cull:
            from .cull import build_for_camera, scene_box
            camera = _camera(lambda: _build_mesh(mesh, scene, {}, scene_box), width, height, eye,
                             target, up, fov, intrinsics, pose, camera_file)
            with step(f"building the tree of the visible part of {len(mesh.faces):,} triangles"):
                tree, n_culled = _build_mesh(mesh, scene, params, build_for_camera, camera)
            tree = tree.with_objects(mesh.objects, mesh.object_names)
        else:
            with step(f"building the tree of {len(mesh.faces):,} triangles"):
                tree = _build_mesh(mesh, scene, params).with_objects(mesh.objects,
                                                                     mesh.object_names)
            camera = _camera(lambda: _tree_box(tree), width, height, eye, target, up, fov,
                             intrinsics, pose, camera_file)
    check_camera_header(camera, output)         # the EXR can hold it: asked before the work
    with step("setting up the device"):
        tracer = Tracer(tree, device=device)
    outputs = kernel_outputs(aovs)
    with step("compiling the kernels"):
        tracer.compile(aovs, precision=precision)
    width, height = int(camera.width), int(camera.height)   # a camera file has its own size
    with step(f"tracing {width}x{height} rays"):
        images = tracer.render(camera, aovs=aovs, precision=precision)
    _log_left_out(tree, tracer, n_culled, from_file=bool(tree_file), outputs=outputs)
    with step("writing"):
        write_exr(output, images, camera=camera, object_names=tree.object_names)
        if preview:
            write_preview(preview, images)
    step.log()
    if "id" in images or "object" in images:
        hit = np.count_nonzero(images.get("id", images.get("object")) != 0xFFFFFFFF)
    elif "depth" in images or "distance" in images:
        hit = np.count_nonzero(np.isfinite(images.get("depth", images.get("distance"))))
    else:
        hit = None
    click.echo(f"wrote {output} ({width}x{height}, {', '.join(aovs)}"
               + (f", {hit} of {width * height} pixels hit" if hit is not None else "") + ")")


@cli.command()
@click.argument("scene", type=FilePath(dir_okay=False))
@click.option("--lidar", "lidar_file", required=True, type=FilePath(dir_okay=False),
              help="The lidar's JSON spec: elevations or channels/fov_up/fov_down, columns, "
                   "max_range (docs/sensors.md).")
@click.option("--pose", required=True, type=FilePath(dir_okay=False),
              help="4x4 sensor-to-world matrix file (text or .npy), sensor axes x forward, "
                   "y left, z up (ROS REP 103).")
@click.option("-o", "--output", type=FilePath(), default=None,
              help="EXR range image to write: range, id, object [default: SCENE's name with "
                   ".exr, here].")
@click.option("--points", type=FilePath(),
              help="Also write the hit points as a binary PLY (x y z ring column range id "
                   "object).")
@click.option("--tree", "tree_file", type=FilePath(dir_okay=False),
              help="Scan this dumped tree instead of building one.")
@device_option
@build_options
def scan(scene, lidar_file, pose, output, points, tree_file, device, **kw):
    """Scan SCENE with a lidar: a range image (rows = beams, columns = azimuth steps)
    to an EXR file, and optionally its hit points to a PLY file."""
    from .camera import pose_from_file
    from .images import write_exr
    from .lidar import Lidar, write_points_ply
    params = _build_kwargs(kw)
    if output is None:
        output = os.path.splitext(os.path.basename(scene))[0] + ".exr"
    inputs = (scene, tree_file, lidar_file, pose)
    check_output(output, inputs, what="-o")
    if points:
        check_output(points, inputs, others=(output,), what="--points")
    lidar = Lidar.from_json(lidar_file)          # a bad spec or pose: one line, nothing read
    lidar.check_memory()                         # before the tree is built
    sensor_to_world = pose_from_file(pose)
    step, tracer = _scene_tracer(scene, tree_file, params, device)
    beams, columns = lidar.shape
    with step(f"scanning {beams}x{columns} beams"):
        images = tracer.scan(lidar, sensor_to_world)
    with step("writing"):
        write_exr(output, {k: images[k] for k in ("range", "id", "object")},
                  object_names=tracer.tree.object_names, lidar=lidar,
                  sensor_to_world=sensor_to_world)
        if points:
            write_points_ply(points, images)
    step.log()
    hit = int(np.count_nonzero(images["id"] != 0xFFFFFFFF))
    click.echo(f"wrote {output}" + (f" and {points}" if points else "")
               + f" ({beams} beams x {columns} columns, {hit} of {beams * columns} beams hit)")


def _write_npz(step, output, arrays):
    """Write arrays (name -> numpy array) to the .npz file `output`, whole or not at all
    (kdray.files.atomic_write), timed by `step` (Steps)."""
    from .files import atomic_write

    def save(tmp):
        with open(tmp, "wb") as f:
            np.savez(f, **arrays)

    with step("writing"):
        atomic_write(output, save)


def _read_table(path, what):
    """The numbers of a .npy file, or of a text file (rows of numbers): a 2-D array,
    float64 from text; KdrayError naming `what` for a file that cannot be read."""
    from .validate import check_not_device, read_npy
    if str(path).lower().endswith(".npy"):          # as .NPY too
        return read_npy(path, f"{what} file {path}", KdrayError)
    check_not_device(path, f"{what} file {path}", KdrayError)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error")          # "input contained no data": refused
            return np.loadtxt(path, dtype=np.float64, ndmin=2)
    except (OSError, ValueError, UserWarning) as e:
        raise KdrayError(f"{path}: cannot read {what} ({one_line(e)})") from None


def _read_points(path):
    """(N, 3) points of a .npy file, or of a text file (X Y Z a line): KdrayError
    otherwise."""
    points = _read_table(path, "points")
    if points.dtype.kind not in "fiu" or points.ndim != 2 or points.shape[1] != 3:
        raise KdrayError(f"{path}: points must be an (N, 3) array of numbers, got "
                         f"{points.dtype} {points.shape}")
    return points


RAY_ARRAYS = ("origins", "directions", "t_min", "t_max", "prim")
"""The arrays of a .npz rays file (`kdray cast`): origins (N, 3) or (3,), directions
(N, 3), and optionally t_min and t_max, (N,) or one number, and prim, (N,) or one
integer: the input triangle each origin lies on, which its ray leaves (the origins are
moved off it: kdray.offset_origins)."""


def _read_rays(path):
    """{"origins", "directions"[, "t_min", "t_max"]: arrays} of a rays file: a .npz
    file of RAY_ARRAYS, or an (N, 6) .npy or text file (origin x y z, direction x y z a
    row, as Open3D's rays). KdrayError for anything else; the shapes are checked here,
    the values (finite, nonzero directions, ranges) by the queries."""
    from .validate import is_pipe, read_pipe
    if str(path).lower().endswith(".npz"):
        try:
            # a zip is read by seeking: a pipe's bytes are read first
            source = io.BytesIO(read_pipe(path)) if is_pipe(path) else path
            with np.load(source, allow_pickle=False) as f:
                arrays = {k: np.asarray(f[k]) for k in f.files}
        except FileNotFoundError:
            raise KdrayError(f"rays file {path} does not exist") from None
        except Exception as e:          # np.load on hostile bytes: any of a dozen classes
            raise KdrayError(f"{path}: cannot read rays ({one_line(e) or type(e).__name__})") \
                from None
        extra = sorted(set(arrays) - set(RAY_ARRAYS))
        missing = [k for k in RAY_ARRAYS[:2] if k not in arrays]
        if extra or missing:
            raise KdrayError(f"{path}: a rays .npz file holds origins, directions and "
                             f"optionally t_min, t_max and prim; "
                             + (f"{', '.join(missing)} missing" if missing
                                else f"{', '.join(extra)} unknown"))
        for k, a in arrays.items():
            if a.dtype.kind not in "fiu":
                raise KdrayError(f"{path}: {k} must hold numbers, got {a.dtype}")
        d, o = arrays["directions"], arrays["origins"]
        if d.ndim != 2 or d.shape[1] != 3 or o.shape not in ((3,), d.shape):
            raise KdrayError(f"{path}: directions must be (N, 3) and origins (N, 3) or (3,), "
                             f"got {d.shape} and {o.shape}")
        for k in RAY_ARRAYS[2:]:
            if k in arrays and arrays[k].shape not in ((), (len(d),)):
                raise KdrayError(f"{path}: {k} must be one number or ({len(d)},), got "
                                 f"{arrays[k].shape}")
        if "prim" in arrays and arrays["prim"].dtype.kind not in "iu":
            raise KdrayError(f"{path}: prim must hold integers (input triangle ids), got "
                             f"{arrays['prim'].dtype}")
        return arrays
    rays = _read_table(path, "rays")
    if rays.dtype.kind not in "fiu" or rays.ndim != 2 or rays.shape[1] != 6:
        raise KdrayError(f"{path}: rays must be an (N, 6) array of numbers (origin, "
                         f"direction), got {rays.dtype} {rays.shape}")
    return {"origins": rays[:, :3], "directions": rays[:, 3:]}


@cli.command()
@click.argument("scene", type=FilePath(dir_okay=False))
@click.option("--points", "points_file", required=True, type=FilePath(dir_okay=False),
              help="The points: an (N, 3) .npy file, or text, X Y Z a line.")
@click.option("-o", "--output", required=True, type=FilePath(),
              help="The answers to write: an (N,) .npy file, bool (inside) or int32 "
                   "(--count).")
@click.option("--count", "direction", callback=_floats(3), default=None,
              help="Write each point's surface crossings along the direction X,Y,Z "
                   "instead of inside or not.")
@tree_option
@device_option
@build_options
def contains(scene, points_file, output, direction, tree_file, device, **kw):
    """Which points lie inside SCENE, a closed mesh (the parity of one ray's exact
    crossing count: docs/conventions.md), or with --count how many times a ray from
    each point crosses the surface."""
    from .files import atomic_write
    params = _build_kwargs(kw)
    check_output(output, inputs=(scene, tree_file, points_file), what="-o")
    from .points import check_points
    points = check_points(_read_points(points_file))[0]      # finite, with --count too
    if direction is not None:
        if not (np.isfinite(direction).all() and np.any(direction)):
            raise KdrayError(f"--count needs a finite, nonzero direction, got {direction}")
        # a crossing count does not depend on the direction's length: made unit, one
        # beyond float32's range (1e-46 or 1e39 long) is traced as any other
        direction = np.asarray(direction, dtype=np.float64)
        direction = direction / np.abs(direction).max()
        direction = direction / np.linalg.norm(direction)
    step, tracer = _scene_tracer(scene, tree_file, params, device)
    if direction is None:
        with step(f"testing {len(points):,} points"):
            answers = tracer.contains(points)
        summary = f"{int(answers.sum())} of {len(points)} points inside"
    else:
        with step(f"counting the crossings of {len(points):,} rays"):
            answers = tracer.count(points, np.broadcast_to(np.asarray(direction), points.shape))
        summary = f"{int((answers > 0).sum())} of {len(points)} rays cross the surface"
    def save(tmp):
        with open(tmp, "wb") as f:
            np.save(f, answers)

    with step("writing"):
        atomic_write(output, save)
    step.log()
    click.echo(f"wrote {output} ({summary})")


@cli.command()
@click.argument("scene", type=FilePath(dir_okay=False))
@click.option("--rays", "rays_file", required=True, type=FilePath(dir_okay=False),
              help="The rays: an (N, 6) .npy or text file (origin, direction a row), or a "
                   ".npz file of origins, directions and optionally t_min and t_max.")
@click.option("-o", "--output", required=True, type=FilePath(),
              help="The .npz file to write (its arrays depend on --query).")
@click.option("--query", type=click.Choice(["nearest", "any", "count", "all"]),
              default="nearest", show_default=True,
              help="nearest: each ray's nearest hit; any: whether it hits anything; count: "
                   "its exact surface crossings; all: every hit, sorted by t.")
@click.option("--max-hits", type=int, default=None,
              help="--query all: keep each ray's K nearest hits.")
@click.option("--t-min", type=float, default=None,
              help="Hits count from here on, in units of each ray's |direction|  [default: 0].")
@click.option("--t-max", type=float, default=None,
              help="... and up to here  [default: inf].")
@click.option("--precision", type=click.Choice(["single", "double"]), default="single",
              show_default=True,
              help="double: the hits that count with the mesh's float64 triangles, and "
                   "(nearest, all) their t, u and v in float64.")
@tree_option
@device_option
@build_options
def cast(scene, rays_file, output, query, max_hits, t_min, t_max, precision, tree_file, device,
         **kw):
    """Cast the rays of a file at SCENE: their nearest hits, whether they hit anything,
    their exact crossing counts or all their hits (docs/interface.md, "kdray cast")."""
    params = _build_kwargs(kw)
    check_output(output, inputs=(scene, tree_file, rays_file), what="-o")
    if max_hits is not None and query != "all":
        raise click.UsageError("--max-hits goes with --query all")
    rays = _read_rays(rays_file)
    ranges = {}
    for name, value in (("t_min", t_min), ("t_max", t_max)):
        if value is not None and name in rays:
            raise click.UsageError(f"--{name.replace('_', '-')} and the rays file's {name} "
                                   f"cannot both be given")
        if name in rays or value is not None:
            ranges[name] = rays.get(name, value)
    o, d = rays["origins"], rays["directions"]
    n = len(d)
    if "t_min" in rays or "t_max" in rays:
        from .query_rays import check_ranges
        try:
            check_ranges(ranges.get("t_min", 0.0), ranges.get("t_max", np.inf), n)
        except KdrayError as e:         # the file's values: say which file
            raise KdrayError(f"{rays_file}: {e}") from None
    step, tracer = _scene_tracer(scene, tree_file, params, device, double=precision == "double")
    if "prim" in rays:                  # rays that leave the triangles their origins lie on
        from .spawn import offset_origins
        try:
            o = offset_origins(tracer.tree, np.broadcast_to(o, d.shape), np.broadcast_to(
                rays["prim"], (n,)), d)
        except KdrayError as e:         # the file's values: say which file
            raise KdrayError(f"{rays_file}: {e}") from None
    with step(f"casting {n:,} rays ({query})"):
        if query == "nearest":
            hits = tracer.trace(o, d, precision=precision, **ranges)
            arrays = {"t": hits.t, "prim": hits.prim, "u": hits.u, "v": hits.v,
                      "normal": hits.normal, "object": hits.object}
            summary = f"{int(np.count_nonzero(hits.hit)):,} hit"
        elif query == "any":
            arrays = {"occluded": tracer.occluded(o, d, precision=precision, **ranges)}
            summary = f"{int(np.count_nonzero(arrays['occluded'])):,} hit"
        elif query == "count":
            arrays = {"count": tracer.count(o, d, precision=precision, **ranges)}
            summary = f"{int(np.count_nonzero(arrays['count'])):,} cross the surface"
        else:
            hits = tracer.intersections(o, d, max_hits=max_hits, precision=precision, **ranges)
            arrays = {"offsets": hits.offsets, "ray": hits.ray, "t": hits.t, "prim": hits.prim,
                      "u": hits.u, "v": hits.v, "object": hits.object}
            summary = f"{len(hits.t):,} hits"

    _write_npz(step, output, arrays)
    step.log()
    click.echo(f"wrote {output} ({n:,} rays, {summary})")


def _warn_parity(scene, tree, sign):
    """With sign "parity", one log line when SCENE's tree has open edges (the point
    queries' OpenMeshWarning, which the commands then ignore, as a log line)."""
    from .points import open_edges
    if sign != "parity":
        return
    edges = open_edges(tree)
    if edges:
        log.warning("%s has %d open edges: --sign parity is undefined where a point's "
                    "ray leaves through a hole (--sign winding is meant for such meshes)",
                    scene, edges)


POINT_QUERIES = ("closest", "distance", "signed", "winding", "occupancy")
"""`kdray points`' queries: Tracer.closest_points, distance, signed_distance,
winding_number and occupancy."""


@cli.command()
@click.argument("scene", type=FilePath(dir_okay=False))
@click.option("--points", "points_file", required=True, type=FilePath(dir_okay=False),
              help="The points: an (N, 3) .npy file, or text, X Y Z a line.")
@click.option("-o", "--output", required=True, type=FilePath(),
              help="The .npz file to write (its arrays depend on --query).")
@click.option("--query", type=click.Choice(POINT_QUERIES), default="signed", show_default=True,
              help="closest: the nearest surface point, its distance, triangle and "
                   "barycentrics; distance; signed: the distance, negative inside; winding: "
                   "the generalized winding number; occupancy: inside or not.")
@click.option("--sign", type=click.Choice(["winding", "parity"]), default=None,
              help="signed and occupancy: inside by the generalized winding number (meshes "
                   "with holes too) or by the parity of an exact crossing count (closed "
                   "meshes)  [default: winding].")
@click.option("--max-distance", type=float, default=None,
              help="closest, distance and signed: look no farther (world units); beyond, "
                   "a miss (inf)  [default: inf].")
@click.option("--precision", type=click.Choice(["single", "double"]), default="single",
              show_default=True,
              help="double: closest, distance and signed measure against the mesh's "
                   "float64 triangles, and signed, winding and occupancy take their "
                   "side of them near the surface.")
@tree_option
@device_option
@build_options
def points(scene, points_file, output, query, sign, max_distance, precision, tree_file, device,
           **kw):
    """The point queries at the points of a file: nearest surface points, distances,
    signed distances, winding numbers or occupancy (docs/interface.md, "kdray points")."""
    from .points import INSIDE_ABOVE, OpenMeshWarning
    params = _build_kwargs(kw)
    check_output(output, inputs=(scene, tree_file, points_file), what="-o")
    measures = query in ("closest", "distance", "signed")
    for name, given, fits in (("--sign", sign is not None, query in ("signed", "occupancy")),
                              ("--max-distance", max_distance is not None, measures)):
        if given and not fits:
            raise click.UsageError(f"{name} does not go with --query {query}")
    sign = sign or "winding"
    limit = {} if max_distance is None else {"max_distance": max_distance}
    at = _read_points(points_file)
    n = len(at)
    step, tracer = _scene_tracer(scene, tree_file, params, device, double=precision == "double")
    _warn_parity(scene, tracer.tree, sign if query in ("signed", "occupancy") else None)
    with step(f"{query} of {n:,} points"), warnings.catch_warnings():
        warnings.simplefilter("ignore", OpenMeshWarning)     # _warn_parity's
        if query == "closest":
            c = tracer.closest_points(at, precision=precision, **limit)
            arrays = {"point": c.point, "distance": c.distance, "prim": c.prim, "u": c.u,
                      "v": c.v, "object": c.object}
            summary = f"{int(np.count_nonzero(c.hit)):,} found"
        elif query == "distance":
            arrays = {"distance": tracer.distance(at, precision=precision, **limit)}
            summary = f"{int(np.count_nonzero(np.isfinite(arrays['distance']))):,} found"
        elif query == "signed":
            d = tracer.signed_distance(at, sign, precision=precision, **limit)
            arrays = {"signed_distance": d}
            summary = f"{int(np.count_nonzero(d < 0)):,} inside"
        elif query == "winding":
            arrays = {"winding_number": tracer.winding_number(at, precision=precision)}
            summary = f"{int(np.count_nonzero(arrays['winding_number'] > INSIDE_ABOVE)):,} inside"
        else:
            arrays = {"occupancy": tracer.occupancy(at, sign, precision)}
            summary = f"{int(np.count_nonzero(arrays['occupancy'])):,} inside"
    _write_npz(step, output, arrays)
    step.log()
    click.echo(f"wrote {output} ({n:,} points, {summary})")


@cli.command()
@click.argument("scene", type=FilePath(dir_okay=False))
@click.option("-o", "--output", required=True, type=FilePath(),
              help="The .npz file to write: a grid (sdf or occupancy, origin, spacing, "
                   "sign), or with --samples the points and their sdf.")
@click.option("--resolution", type=int, default=None,
              help="Grid samples a side (the grid is N x N x N)  [default: 128].")
@click.option("--padding", type=float, default=0.1, show_default=True,
              help="Room around the scene's box, a fraction of its largest side, each side.")
@click.option("--sign", type=click.Choice(["winding", "parity"]), default="winding",
              show_default=True,
              help="Inside by the generalized winding number (meshes with holes too) or "
                   "by the parity of an exact crossing count (closed meshes).")
@click.option("--occupancy", is_flag=True,
              help="Write a uint8 grid, 1 inside, instead of signed distances.")
@click.option("--samples", type=int, default=None,
              help="Instead of a grid, N points as DeepSDF samples them: on the surface "
                   "moved by Gaussian noise, and --uniform of them uniform in the box.")
@click.option("--sigma", type=float, default=None,
              help="--samples: the noise's deviation, world units [default: 1/200 of the "
                   "box's diagonal].")
@click.option("--uniform", type=float, default=None,
              help="--samples: the fraction of points uniform in the padded box  "
                   "[default: 0.1].")
@click.option("--seed", type=int, default=None,
              help="--samples: the random seed (the same seed, the same samples)  "
                   "[default: 0].")
@tree_option
@device_option
@build_options
def sdf(scene, output, resolution, padding, sign, occupancy, samples, sigma, uniform, seed,
        tree_file, device, **kw):
    """Signed distances of SCENE (negative inside) on a grid, or at points sampled near
    its surface (docs/conventions.md, "Point queries")."""
    from . import sdf as _sdf
    from .points import OpenMeshWarning
    from .trace import Tracer
    params = _build_kwargs(kw)
    check_output(output, inputs=(scene, tree_file), what="-o")
    if samples is None:
        for name, value in (("--sigma", sigma), ("--uniform", uniform), ("--seed", seed)):
            if value is not None:
                raise click.UsageError(f"{name} goes with --samples")
        resolution = 128 if resolution is None else resolution
        _sdf.check_grid(resolution, padding, occupancy)     # bad values: before any work
    elif occupancy or resolution is not None:
        raise click.UsageError(f"{'--occupancy' if occupancy else '--resolution'} makes a "
                               f"grid; it cannot be combined with --samples")
    else:
        uniform, seed = 0.1 if uniform is None else uniform, 0 if seed is None else seed
        _sdf.check_samples(samples, sigma, uniform, padding, sign, seed)   # before any work
    step = Steps()
    tree = _scene_tree(step, scene, tree_file, params)
    _warn_parity(scene, tree, sign)
    with step("setting up the device"):
        tracer = Tracer(tree, device=device)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OpenMeshWarning)     # _warn_parity's
        if samples is None:
            what = "occupancy" if occupancy else "signed distances"
            shown = [0]

            def progress(done, total):
                if not step.live or total < SDF_PROGRESS_POINTS:
                    return
                if done == total or done - shown[0] >= total // 20:
                    shown[0] = done
                    click.echo(f"\r{what}: {100 * done // total}% of {total:,} points",
                               err=True, nl=done == total)

            with step(f"{what} of a {resolution}^3 grid ({sign})"):
                grid = _sdf.sdf_grid(tracer, resolution, padding, sign, occupancy, progress)
            arrays = {"occupancy" if occupancy else "sdf": grid.values, "origin": grid.origin,
                      "spacing": np.float64(grid.spacing), "sign": np.str_(sign)}
            inside = int(np.count_nonzero(grid.values if occupancy else grid.values < 0))
            summary = f"{resolution}^3 grid, {inside:,} points inside"
        else:
            with step(f"signed distances of {samples:,} samples ({sign})"):
                p, d = _sdf.sdf_samples(tracer, samples, sigma, uniform, padding, sign, seed)
            arrays = {"points": p, "sdf": d, "sign": np.str_(sign)}
            summary = f"{samples:,} samples, {int(np.count_nonzero(d < 0)):,} inside"

    _write_npz(step, output, arrays)
    step.log()
    click.echo(f"wrote {output} ({summary})")


@cli.command()
@click.argument("scenes", metavar="SCENE...", nargs=-1, type=FilePath(dir_okay=False))
@click.option("--size", default="512x512", show_default=True, callback=_size, help="Rays: WIDTHxHEIGHT pixels.")
@click.option("--repeat", type=int, default=5, show_default=True, help="Warm runs timed (median).")
@click.option("--sample", type=int, default=10000, show_default=True,
              help="Random rays checked against the float64 reference.")
@click.option("--settings", default=None,
              help="Comma-separated: kdray[:KEY=VALUE...] (K_T, K_I, empty_bonus, max_depth, "
                   "leaf_size, stack, local, batch, refine=0|1). "
                   "[default: kdray,kdray:refine=0,kdray:K_T=15,kdray:empty_bonus=1,kdray:stack=1]")
@click.option("--csv", "csv_file", type=FilePath(), help="Also write the table as CSV.")
@device_option
@click.option("--offset", type=float, default=0.0, show_default=True,
              help="Move scene and camera by (D, D, D) (precision far from the origin).")
def bench(scenes, size, repeat, sample, settings, csv_file, device, offset):
    """Error against run time of kdray's settings on the same rays of each SCENE.

    Each SCENE is a mesh file; every setting traces the framing camera's rays and is
    checked against the float64 reference. The comparison with Open3D and embreex is
    the script bench/bench_error.py of kdray's source repository (not installed)."""
    from . import bench as _bench
    if not scenes:
        raise click.UsageError("name one or more mesh files to benchmark: kdray bench SCENE...")
    if csv_file is not None:
        check_output(csv_file, inputs=scenes, what="--csv")
    step = Steps()
    rows = _bench.run(scenes, size=size, repeat=repeat, sample=sample, settings=settings,
                      device=device, offset=offset, step=step)
    click.echo(_bench.header(size, repeat, sample, offset))
    click.echo(_bench.format_table(rows))
    if csv_file is not None:
        _bench.write_csv(rows, csv_file)


def _run_jobs(jobs, workers, scheduler, device, no_cache, overwrite):
    """Run dataset jobs with a progress bar; print a line per job (each step's time);
    DatasetError (exit code 1) when any failed."""
    from .cache import TreeCache
    from .dataset import Progress, run
    from .errors import DatasetError
    if workers and scheduler:
        raise click.UsageError("--workers starts a local cluster, --scheduler uses another: give one")
    live = sys.stderr.isatty() and log.getEffectiveLevel() == logging.WARNING
    started = time.perf_counter()
    reports = run(jobs, workers=workers, scheduler=scheduler, device=device,
                  cache=None if no_cache else TreeCache(), overwrite=overwrite,
                  progress=Progress(0, live=live))
    seconds = time.perf_counter() - started
    rendered = sum(r.rendered for r in reports)
    for r in reports:
        if not r.ok:
            for error in r.errors:
                click.echo(f"kdray: {error}", err=True)
        click.echo(r.summary())
    failed = [r for r in reports if not r.ok]
    click.echo(f"wrote {rendered} views in {seconds:.1f} s"
               + (f" ({rendered / seconds:.1f} views/s)" if rendered and seconds > 0 else "")
               + f"; {sum(r.skipped for r in reports)} already there")
    if failed:
        names = ", ".join(r.job.scene.name for r in failed[:5]) + (", ..." if len(failed) > 5 else "")
        raise DatasetError(f"{len(failed)} of {len(reports)} job(s) failed: {names}")


@cli.command()
@click.argument("jobs_file", metavar="JOBS", type=FilePath(dir_okay=False))
@dataset_options
@device_option
def batch(jobs_file, workers, scheduler, no_cache, overwrite, device):
    """Render many scenes: JOBS holds one JSON object a line with scene, cameras,
    output (a folder) and optionally aovs, preview, precision and build (build
    parameters); paths relative to JOBS' folder. A job that fails is reported and the
    others go on; the exit code is 1 when any failed. docs/interface.md has the format."""
    from .dataset import read_jobs
    jobs = read_jobs(jobs_file)
    _run_jobs(jobs, workers, scheduler, device, no_cache, overwrite)


@cli.command()
@device_option
def setup(device):
    """Compile the tree builder (once per install), the kernels of a default render
    on the device (for trees up to 31 levels deep: meshes to millions of triangles)
    and the camera models' inversions, so that the first render does not wait for
    them."""
    from . import builder, lens
    from .device import choose_device
    from .trace import Tracer
    from .work_sizes import STACK_SIZES
    step = Steps()
    if device is not None:
        choose_device(device)           # a --device that does not work: before the builder
    if builder.compiled():
        click.echo("tree builder: compiled already")
    else:
        with step("compiling the tree builder (once per install, about half a minute)"):
            builder.compile_all()
        click.echo("tree builder: compiled")
    tree = builder.build([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])
    with step("compiling the kernels"):
        # the programs of trees of each stack size but the deepest (a depth above 31),
        # which the on-disk program cache then gives any tree of that size
        tracer = Tracer(tree, device=device).compile(stack_sizes=STACK_SIZES[:-1])
    click.echo(f"kernels: compiled for {tracer.device.name.strip()}")
    with step("compiling the camera models' inversions"):
        lens.compile_kernels()
    click.echo("camera models: compiled")
    step.log()


@cli.command()
@click.option("--clear", is_flag=True, help="Remove every cached tree.")
def cache(clear):
    """Show (or --clear) the tree cache of kdray batch and render --cameras:
    KDRAY_CACHE_DIR, else $XDG_CACHE_HOME/kdray/trees, else ~/.cache/kdray/trees."""
    from .cache import TreeCache
    trees = TreeCache()
    if trees.folder.exists() and not trees.folder.is_dir():
        raise OutputError(f"the tree cache {trees.folder} is a file, not a folder "
                          f"(KDRAY_CACHE_DIR names the cache's folder)")
    if clear:
        files, size = trees.clear()
        click.echo(f"removed {files} trees ({size / 2**20:.1f} MiB) from {trees.folder}")
    else:
        files, size = trees.usage()
        click.echo(f"{trees.folder}: {files} trees, {size / 2**20:.1f} MiB")


def _camera(box, width, height, eye, target, up, fov, intrinsics, pose, camera_file):
    """Choose the camera from the options: JSON file, intrinsics + pose, look-at, or
    framing the box that `box()` returns ((lo, hi) float64 world, asked only then)."""
    from .camera import Camera, pose_from_file
    if camera_file:
        if eye or target or intrinsics or pose:
            raise click.UsageError("--camera cannot be combined with --eye/--target/--intrinsics/--pose")
        return Camera.from_json(camera_file)
    if intrinsics or pose:
        if not (intrinsics and pose):
            raise click.UsageError("--intrinsics and --pose go together")
        if eye or target:
            raise click.UsageError("--eye/--target cannot be combined with --intrinsics/--pose")
        fx, fy, cx, cy = intrinsics
        K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1]], dtype=np.float64)
        return Camera.from_intrinsics(K, pose_from_file(pose), width, height)
    if eye or target:
        if not (eye and target):
            raise click.UsageError("--eye and --target go together")
        return Camera.look_at(eye, target, up, fov, width, height)
    lo, hi = box()
    return Camera.frame(lo, hi, width, height, fov_deg=fov)


def _tree_box(tree):
    """(lo, hi) (3,) float64 world box of a tree's triangles."""
    return tree.world_box()


def _save_tree(tree, path):
    try:
        tree.save(path)
    except OSError as e:
        raise OutputError(f"{path}: cannot write the tree file ({e.strerror or e})") from None


def main(argv=None):
    """Console entry point: run the click group, turning errors into one line."""
    argv = sys.argv[1:] if argv is None else list(argv)
    debug = "--debug" in argv
    try:
        cli.main(args=argv, prog_name="kdray", standalone_mode=False)
    except click.exceptions.Abort:
        # click turns a Ctrl-C inside a command into Abort (its KeyboardInterrupt the
        # context: the traceback --debug shows)
        if debug:
            import traceback
            traceback.print_exc()
        else:
            click.echo("kdray: interrupted", err=True)
        sys.exit(130)
    except click.ClickException as e:
        e.show()
        sys.exit(e.exit_code)
    except KeyboardInterrupt:
        if debug:
            raise
        click.echo("kdray: interrupted", err=True)
        sys.exit(130)
    except KdrayError as e:
        if debug:
            raise
        # one line whatever the message quotes (a file name may hold a newline)
        message = str(e).replace("\r", "\\r").replace("\n", "\\n")
        click.echo(f"kdray: error: {message}", err=True)
        sys.exit(1)
    except MemoryError:
        # a last guard: the host's memory is checked before large arrays
        # (kdray.host.check_host_memory), but not before every small one
        if debug:
            raise
        click.echo("kdray: error: out of memory (the host's memory or the process's "
                   "address-space limit ran out)", err=True)
        sys.exit(1)


if __name__ == "__main__":
    main()
