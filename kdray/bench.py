"""`kdray bench`: error against run time for kdray's settings on the user's scenes.

    rows = run(["scene.obj"], size=(512, 512), repeat=5, sample=10000, settings=None)
    text = header((512, 512), 5, 10000) + "\n" + format_table(rows)   # what the CLI prints
    write_csv(rows, "bench.csv")

For each scene: the automatic framing camera (`Camera.frame`) gives W x H primary rays,
the same rays for every setting. A setting is

    kdray[:KEY=VALUE[:KEY=VALUE...]]   kdray's tree and kernel; keys are the build
                                        parameters K_T, K_I, empty_bonus, max_depth,
                                        leaf_size and the kernel's stack, local, batch,
                                        refine (0: t, u, v as the float test gives them)

or, from Python, any object with a `name` and a `hits(mesh, o, d, repeat)` method
returning (build s, trace s, t, prim (-1 on a miss), normal or None): another ray
caster on the same rays (bench/bench_error.py compares Open3D and embreex this way).

Per (scene, setting): build seconds (one build, the first with those build
parameters in the process, timed once; bench/bench_build.py times warm builds in
turns); trace seconds (median of `repeat` warm runs, numpy rays in, numpy hits out,
kernels already compiled); Mrays/s; and, on `sample` random
rays against a float64 reference (`reference.traverse` with the input's float64
triangles, the tree choosing only candidates): hit/miss disagreements, rays naming
another triangle, relative depth error (p99, max; rays both hit) and normal angle error
in degrees (p99, max; rays naming the same triangle). The reference normal is the unit
float64 (v1 - v0) x (v2 - v0) of the reference's triangle; a method that gives no
normals is given that of the triangle it names.

`offset` moves scene and camera by (D, D, D): precision far from the origin.

Only the package's own dependencies are used.
"""
import contextlib
import csv
import dataclasses
import math
import os
import time

import numpy as np

from .errors import MeshError, ParameterError

BUILD_KEYS = {"K_T": float, "K_I": float, "empty_bonus": float, "max_depth": int, "leaf_size": int}
KERNEL_KEYS = {"stack": int, "local": int, "batch": int, "refine": int}

DEFAULT_SETTINGS = ("kdray", "kdray:refine=0", "kdray:K_T=15", "kdray:empty_bonus=1", "kdray:stack=1")

COLUMNS = ("scene", "tris", "setting", "build_s", "trace_s", "mrays_s", "disagree",
           "prim_diff", "depth_p99", "depth_max", "normal_p99_deg", "normal_max_deg")

_HEADERS = {"scene": "scene", "tris": "tris", "setting": "setting", "build_s": "build s",
            "trace_s": "trace s", "mrays_s": "Mrays/s", "disagree": "disagree",
            "prim_diff": "prim!=", "depth_p99": "depth p99", "depth_max": "depth max",
            "normal_p99_deg": "normal p99 deg", "normal_max_deg": "normal max deg"}


@dataclasses.dataclass(frozen=True)
class Setting:
    """One kdray configuration: build parameters and kernel options."""
    name: str
    build: tuple = ()             # sorted (key, value) build parameters
    kernel: tuple = ()            # sorted (key, value) kernel options


def parse_settings(text):
    """'kdray,kdray:K_T=20' -> [Setting]; raises ParameterError naming the bad one."""
    names = [s.strip() for s in text.split(",")] if isinstance(text, str) else list(text)
    names = [s for s in names if s]
    if not names:
        raise ParameterError("--settings names no setting")
    return [parse_setting(s) for s in names]


def parse_setting(name):
    """'kdray:K_T=20:stack=8' -> Setting; raises ParameterError naming the bad part."""
    head, *parts = name.split(":")
    if head in ("open3d", "embreex"):
        raise ParameterError(f"setting {name!r}: other ray casters are compared by "
                             f"bench/bench_error.py in kdray's repository")
    if head != "kdray":
        raise ParameterError(f"unknown setting {name!r}: expected kdray[:KEY=VALUE...]")
    build, kernel = {}, {}
    for part in parts:
        key, eq, value = part.partition("=")
        if not eq or (key not in BUILD_KEYS and key not in KERNEL_KEYS):
            raise ParameterError(f"setting {name!r}: {part!r} is not KEY=VALUE with KEY one of "
                                 f"{', '.join(list(BUILD_KEYS) + list(KERNEL_KEYS))}")
        kind = BUILD_KEYS.get(key) or KERNEL_KEYS[key]
        try:
            val = kind(value)
        except ValueError:
            raise ParameterError(f"setting {name!r}: {key} must be {'an integer' if kind is int else 'a number'}, "
                                 f"got {value!r}") from None
        if key == "refine" and val not in (0, 1):
            raise ParameterError(f"setting {name!r}: refine must be 0 or 1, got {value!r}")
        (build if key in BUILD_KEYS else kernel)[key] = val
    return Setting(name, tuple(sorted(build.items())), tuple(sorted(kernel.items())))


def timed(fn, repeat):
    """Median wall time of `repeat` calls after one warm-up call; returns (seconds, result)."""
    result = fn()
    times = []
    for _ in range(max(1, repeat)):
        t0 = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times)), result


def unit_normals(triangles):
    """(n, 3) float64 unit (v1 - v0) x (v2 - v0) of (n, 3, 3) triangles."""
    tri = np.asarray(triangles, dtype=np.float64)
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    length = np.linalg.norm(n, axis=1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        return n / length


def angle_deg(a, b):
    """Angles in degrees between rows of a and b (atan2 form: exact for tiny angles)."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    return np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b), axis=1), np.einsum("ij,ij->i", a, b)))


def errors(t, prim, normal, ref_t, ref_prim, ref_normal):
    """Error metrics of one method's sampled hits against the reference.

    t : (n,) ray parameters (+inf on a miss); prim : (n,) int64, -1 on a miss;
    normal : (n, 3) or None (then computed from the reference's float64 triangles
    where the triangles agree, i.e. no normal error of its own).
    """
    t = np.asarray(t, dtype=np.float64)
    prim = np.asarray(prim, dtype=np.int64)
    hit, ref_hit = prim >= 0, ref_prim >= 0
    both = hit & ref_hit
    rel = np.abs(t[both] - ref_t[both]) / ref_t[both]
    same = both & (prim == ref_prim)
    if normal is None:
        ang = np.zeros(0)
    else:
        ang = angle_deg(np.asarray(normal)[same], ref_normal[same])

    def pct(x, q):
        return float(np.percentile(x, q)) if len(x) else float("nan")
    return {"disagree": int(np.count_nonzero(hit != ref_hit)),
            "prim_diff": int(np.count_nonzero(both & (prim != ref_prim))),
            "depth_p99": pct(rel, 99), "depth_max": float(rel.max()) if len(rel) else float("nan"),
            "normal_p99_deg": pct(ang, 99), "normal_max_deg": float(ang.max()) if len(ang) else float("nan")}


# -- kdray's method: (build seconds, trace seconds, t, prim, normal) on all rays -------------

def _kdray(setting, mesh, trees, o, d, repeat, device):
    from .builder import build
    from .layout import MISS
    from .trace import Tracer
    key = setting.build
    if key not in trees:
        t0 = time.perf_counter()
        trees[key] = (build(mesh.vertices, mesh.faces, **dict(key)), time.perf_counter() - t0)
    tree, build_s = trees[key]
    k = dict(setting.kernel)
    tracer = Tracer(tree, device=device, stack_size=k.get("stack"), local_size=k.get("local"),
                    batch_size=k.get("batch"), refine=bool(k.get("refine", 1)))
    s, hits = timed(lambda: tracer.trace(o, d), repeat)
    prim = np.where(hits.prim == MISS, -1, hits.prim.astype(np.int64))
    return build_s, s, hits.t, prim, hits.normal


# -- the benchmark ----------------------------------------------------------------------------

def _settings(settings):
    """[Setting or another method]: names are parsed, objects kept as given."""
    if settings is None:
        return parse_settings(DEFAULT_SETTINGS)
    if isinstance(settings, str):
        return parse_settings(settings)
    out = [parse_setting(s) if isinstance(s, str) else s for s in settings]
    if not out:
        raise ParameterError("--settings names no setting")
    return out


def run(scenes, size=(512, 512), repeat=5, sample=10000, settings=None, device=None,
        offset=0.0, step=None, seed=0):
    """Benchmark `settings` on the mesh files `scenes`; returns rows, dicts keyed by
    COLUMNS, one per (scene, setting) in that order.

    settings : None (DEFAULT_SETTINGS), comma-separated names, or a list of names,
        Setting objects and other methods (objects with `name` and `hits`, see the
        module's docstring).
    step : a context-manager factory called with a description of each step
        (progress display), or None.
    """
    from .builder import build
    from .camera import Camera
    from .load import load
    from .mesh import Mesh
    from . import reference

    step = step or (lambda what: contextlib.nullcontext())
    settings = _settings(settings)
    scenes = list(scenes or ())
    if not scenes:
        raise ParameterError("no scene given: name one or more mesh files (OBJ, PLY, STL, ...)")
    for path in scenes:
        if not os.path.isfile(path):
            raise MeshError(f"{path}: no such file")
    if repeat < 1:
        raise ParameterError(f"--repeat must be at least 1, got {repeat}")
    if sample < 1:
        raise ParameterError(f"--sample must be at least 1, got {sample}")
    if not math.isfinite(offset):
        raise ParameterError(f"--offset must be a finite number, got {offset}")
    width, height = size
    n_rays = width * height
    build(np.eye(3), np.array([[0, 1, 2]]))                       # compile the builder first
    rows = []
    for path in scenes:
        name = scene_name(path)
        with step(f"{name}: loading"):
            mesh = load(path)
            if offset:
                mesh = Mesh.from_arrays(mesh.vertices + offset, mesh.faces, name=mesh.name)
        lo, hi = mesh.bounds
        camera = Camera.frame(lo, hi, width, height)
        o, d = camera.rays()
        # a scene's sample depends on it and the options only, not on the scenes before
        rng = np.random.default_rng(seed)
        idx = np.sort(rng.choice(n_rays, size=min(sample, n_rays), replace=False))
        trees = {}
        with step(f"{name}: float64 reference on {len(idx):,} rays"):
            t0 = time.perf_counter()
            trees[()] = (build(mesh.vertices, mesh.faces), time.perf_counter() - t0)
            ref = reference.traverse(trees[()][0], o[idx], d[idx], triangles64=mesh.triangles)
        ref_normal = np.zeros((len(idx), 3))
        ref_normal[ref.hit] = unit_normals(mesh.triangles[ref.prim[ref.hit]])
        tri_normal = None
        for s in settings:
            with step(f"{name}: {s.name}"):
                if isinstance(s, Setting):
                    b, t_s, t, prim, normal = _kdray(s, mesh, trees, o, d, repeat, device)
                else:
                    b, t_s, t, prim, normal = s.hits(mesh, o, d, repeat)
            t, prim = np.asarray(t)[idx], np.asarray(prim)[idx]
            if normal is None:                 # the float64 normal of the triangle named
                if tri_normal is None:
                    tri_normal = unit_normals(mesh.triangles)
                normal = np.zeros((len(idx), 3))
                normal[prim >= 0] = tri_normal[prim[prim >= 0]]
            else:
                normal = np.asarray(normal)[idx]
            err = errors(t, prim, normal, ref.t, ref.prim, ref_normal)
            rows.append({"scene": name, "tris": len(mesh.faces), "setting": s.name, "build_s": b,
                         "trace_s": t_s, "mrays_s": n_rays / t_s / 1e6, **err})
    return rows


def scene_name(path):
    """The table's name of a scene file: its base name without extensions
    (.obj, and .obj.gz)."""
    name = os.path.basename(os.fspath(path))
    if name.endswith(".gz"):
        name = name[:-3]
    return os.path.splitext(name)[0]


def header(size, repeat, sample, offset=0.0):
    """The line above the table: what was measured ('# ...')."""
    width, height = size
    return (f"# {width}x{height} primary rays, median of {repeat} warm runs; errors on "
            f"{min(sample, width * height)} random rays against the float64 reference"
            + (f"; scene moved by ({offset:g}, {offset:g}, {offset:g})" if offset else ""))

# -- output -----------------------------------------------------------------------------------

def _cell(key, value):
    if key in ("build_s",):
        return f"{value:.3f}"
    if key == "trace_s":
        return f"{value:.4f}"
    if key == "mrays_s":
        return f"{value:.2f}"
    if key.startswith("depth"):
        return f"{value:.2e}"
    if key.startswith("normal"):
        return f"{value:.2e}"
    return str(value)


def format_table(rows):
    """Rows as a plain table with aligned columns (text left, numbers right)."""
    cells = [[_HEADERS[k] for k in COLUMNS]] + [[_cell(k, r[k]) for k in COLUMNS] for r in rows]
    widths = [max(len(c[i]) for c in cells) for i in range(len(COLUMNS))]
    left = {"scene", "setting"}
    lines = []
    for c in cells:
        lines.append("  ".join(v.ljust(w) if k in left else v.rjust(w)
                               for k, v, w in zip(COLUMNS, c, widths)).rstrip())
    return "\n".join(lines)


def write_csv(rows, path):
    """The table's rows as a CSV file, atomically (kdray.files: a failed write leaves
    no half-written file and keeps the one there)."""
    from .files import atomic_write

    def write(tmp):
        with open(tmp, "w", newline="", encoding="utf-8") as f:
            w = csv.DictWriter(f, fieldnames=COLUMNS)
            w.writeheader()
            for r in rows:
                # every digit of a float (numpy's too, which repr would name)
                w.writerow({k: (repr(float(v)) if isinstance(v, (float, np.floating))
                                else int(v) if isinstance(v, np.integer) else v)
                            for k, v in r.items()})

    atomic_write(path, write)
