"""`kdray bench`: error against run time, kdray's settings beside Open3D and embreex.

    rows, notes = run(scenes, size=(512, 512), repeat=5, sample=10000, settings=None)
    table = format_table(rows)
    write_csv(rows, "bench.csv")
    plot(rows, "bench.png")

For each scene: the automatic framing camera (`Camera.frame`) gives W x H primary rays,
the same rays for every setting. A setting is

    kdray[:KEY=VALUE[:KEY=VALUE...]]   kdray's tree and kernel; keys are the build
                                        parameters K_T, K_I, empty_bonus, max_depth,
                                        leaf_size and the kernel's stack, local, batch
    open3d                             Open3D's RaycastingScene (numpy rays to numpy)
    embreex                            trimesh's embreex front end (numpy to numpy)

Per (scene, setting): build seconds; trace seconds (median of `repeat` warm runs, numpy
rays in, numpy hits out, kernels already compiled); Mrays/s; and, on `sample` random
rays against a float64 reference (`reference.traverse` with the input's float64
triangles, the tree choosing only candidates): hit/miss disagreements, rays naming
another triangle, relative depth error (p99, max; rays both hit) and normal angle error
in degrees (p99, max; rays naming the same triangle). The reference normal is the unit
float64 (v1 - v0) x (v2 - v0) of the reference's triangle.

`offset` moves scene and camera by D along (1, 1, 1): Open3D and embreex then get
float32 world coordinates, as their users would give them.

Open3D, embreex and matplotlib are optional and imported only when used.
"""
import contextlib
import csv
import dataclasses
import math
import os
import time

import numpy as np

from .errors import MeshError, OutputError, ParameterError

BUILD_KEYS = {"K_T": float, "K_I": float, "empty_bonus": float, "max_depth": int, "leaf_size": int}
KERNEL_KEYS = {"stack": int, "local": int, "batch": int}

DEFAULT_SETTINGS = ("kdray", "kdray:K_T=15", "kdray:empty_bonus=1", "kdray:stack=1",
                    "open3d", "embreex")
"""Open3D and embreex are left out of the default list (with a note) when not installed."""

COLUMNS = ("scene", "tris", "setting", "build_s", "trace_s", "mrays_s", "disagree",
           "prim_diff", "depth_p99", "depth_max", "normal_p99_deg", "normal_max_deg")

_HEADERS = {"scene": "scene", "tris": "tris", "setting": "setting", "build_s": "build s",
            "trace_s": "trace s", "mrays_s": "Mrays/s", "disagree": "disagree",
            "prim_diff": "prim!=", "depth_p99": "depth p99", "depth_max": "depth max",
            "normal_p99_deg": "normal p99 deg", "normal_max_deg": "normal max deg"}


def default_scenes(root=None):
    """The shipped cornell and sphere scenes and, in a clone of the repository, the
    tests' gzipped Stanford bunny (tests/data/meshes)."""
    root = root or os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    scenes = [os.path.join(root, "scenes", "cornell.obj"), os.path.join(root, "scenes", "sphere.obj")]
    bunny = os.path.join(root, "tests", "data", "meshes", "stanford-bunny.obj.gz")
    if os.path.exists(bunny):
        scenes.append(os.path.normpath(bunny))
    return scenes


@dataclasses.dataclass(frozen=True)
class Setting:
    name: str
    kind: str                     # "kdray", "open3d" or "embreex"
    build: tuple = ()             # sorted (key, value) build parameters
    kernel: tuple = ()            # sorted (key, value) kernel options


def parse_settings(text):
    """'kdray,kdray:K_T=20,open3d' -> [Setting]; raises ParameterError naming the bad one."""
    names = [s.strip() for s in text.split(",")] if isinstance(text, str) else list(text)
    names = [s for s in names if s]
    if not names:
        raise ParameterError("--settings names no setting")
    return [parse_setting(s) for s in names]


def parse_setting(name):
    head, *parts = name.split(":")
    if head in ("open3d", "embreex"):
        if parts:
            raise ParameterError(f"setting {name!r}: {head} takes no options")
        return Setting(name, head)
    if head != "kdray":
        raise ParameterError(f"unknown setting {name!r}: expected kdray[:KEY=VALUE...], open3d "
                             f"or embreex")
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
        (build if key in BUILD_KEYS else kernel)[key] = val
    return Setting(name, "kdray", tuple(sorted(build.items())), tuple(sorted(kernel.items())))


def _importable(module):
    try:
        __import__(module)
        return True
    except Exception:
        return False


def timed(fn, repeat):
    """Median wall time of `repeat` calls after one warm-up call; returns (seconds, result)."""
    result = fn()
    times = []
    for _ in range(max(1, repeat)):
        t0 = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times)), result


ROUND_ROBIN_PAUSE = 0.1
"""Seconds between two timed calls of `round_robin`: a library's worker threads can
keep the cores busy for a while after its call returns (Open3D's, Embree's TBB
workers: a kdray bunny build started right after an Open3D build took 1.05-1.07x as
long as one started after another kdray build or 0.2 s of quiet, and 1.03x after
5 ms; Open3D's build was the same after either), so that whichever call comes next
would pay for them."""


def round_robin(fns, repeat, pause=ROUND_ROBIN_PAUSE):
    """Time several calls side by side: one warm-up call each, then `repeat` rounds
    that call each once (the order reversed every other round), so that drift in the
    machine's speed (seen here: +-20 % over minutes) hits them alike. Every call
    starts `pause` seconds after the one before (ROUND_ROBIN_PAUSE), untimed.

    fns : {name: zero-argument callable}. Returns (wall, cpu, results): {name: (repeat,)
    float64 wall seconds}, the same for this process's CPU seconds (all threads), and
    {name: the last call's result}; compare two of them by the median of their
    per-round ratios (`median_ratio`).
    """
    results = {}
    for name, fn in fns.items():
        time.sleep(pause)
        results[name] = fn()
    wall = {name: [] for name in fns}
    cpu = {name: [] for name in fns}
    names = list(fns)
    for r in range(max(1, repeat)):
        for name in (names if r % 2 == 0 else names[::-1]):
            time.sleep(pause)
            t0, c0 = time.perf_counter(), time.process_time()
            results[name] = fns[name]()
            wall[name].append(time.perf_counter() - t0)
            cpu[name].append(time.process_time() - c0)
    return ({name: np.array(s) for name, s in wall.items()},
            {name: np.array(s) for name, s in cpu.items()}, results)


def median_ratio(slower, faster):
    """Median over rounds of slower / faster seconds (`round_robin`): > 1 means the
    second is faster by that factor."""
    return float(np.median(np.asarray(slower) / np.asarray(faster)))


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


# -- the methods: each returns (build seconds, trace seconds, t, prim, normal) on all rays -----

def _kdray(setting, mesh, trees, o, d, repeat, device):
    from .builder import build
    from .layout import MISS
    from .trace import Tracer
    params = dict(setting.build)
    key = setting.build
    if key not in trees:
        t0 = time.perf_counter()
        trees[key] = (build(mesh.vertices, mesh.faces, **params), time.perf_counter() - t0)
    tree, build_s = trees[key]
    k = dict(setting.kernel)
    tracer = Tracer(tree, device=device, stack_size=k.get("stack"), local_size=k.get("local"),
                    batch_size=k.get("batch"))
    s, hits = timed(lambda: tracer.trace(o, d), repeat)
    prim = np.where(hits.prim == MISS, -1, hits.prim.astype(np.int64))
    return build_s, s, hits.t, prim, hits.normal


def open3d_scene(mesh):
    """Open3D's RaycastingScene of a mesh in float32 world coordinates, its BVH built
    (Open3D builds lazily, at the first cast). Returns (scene, build seconds)."""
    import open3d as o3d
    t0 = time.perf_counter()
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(mesh.vertices.astype(np.float32)),
                        o3d.core.Tensor(mesh.faces.astype(np.uint32)))
    scene.cast_rays(o3d.core.Tensor(np.zeros((1, 6), np.float32)))
    return scene, time.perf_counter() - t0


def open3d_cast(scene, o, d):
    """numpy rays -> Open3D -> numpy (t, prim with -1 on a miss, normal)."""
    import open3d as o3d
    r = scene.cast_rays(o3d.core.Tensor(np.concatenate([o, d], axis=1).astype(np.float32)))
    t = r["t_hit"].numpy()
    prim = np.where(np.isfinite(t), r["primitive_ids"].numpy().astype(np.int64), -1)
    return t, prim, r["primitive_normals"].numpy()


def open3d_hits(mesh, o, d, repeat):
    """Open3D's RaycastingScene, numpy rays to numpy hits (float32 world coordinates).
    Returns (build s, median trace s, t, prim (-1 on a miss), normal)."""
    scene, build_s = open3d_scene(mesh)
    s, (t, prim, normal) = timed(lambda: open3d_cast(scene, o, d), repeat)
    return build_s, s, t, prim, normal


def embreex_hits(mesh, o, d, repeat):
    """trimesh's embreex front end, numpy to numpy (hit points refined in float64 by
    trimesh). Returns (build s, median trace s, t, prim (-1 on a miss), None)."""
    import trimesh
    from trimesh.ray.ray_pyembree import RayMeshIntersector
    t0 = time.perf_counter()
    tm = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)
    rmi = RayMeshIntersector(tm)
    rmi.intersects_first(o[:1], d[:1])
    build_s = time.perf_counter() - t0

    def run():
        tri, ray, loc = rmi.intersects_id(o, d, multiple_hits=False, return_locations=True)
        t = np.full(len(o), np.inf)
        prim = np.full(len(o), -1, dtype=np.int64)
        t[ray] = np.einsum("ij,ij->i", loc - o[ray], d[ray]) / np.einsum("ij,ij->i", d[ray], d[ray])
        prim[ray] = tri
        return t, prim
    s, (t, prim) = timed(run, repeat)
    return build_s, s, t, prim, None


# -- the benchmark ----------------------------------------------------------------------------

def resolve_settings(settings):
    """(settings, notes): the default list drops Open3D/embreex when not installed; an
    explicitly named one that is missing is an error."""
    notes = []
    if settings is None:
        out = []
        for s in parse_settings(DEFAULT_SETTINGS):
            if s.kind != "kdray" and not _importable(s.kind):
                notes.append(f"{s.kind} is not installed: left out (pip install -e '.[bench]')")
                continue
            out.append(s)
        return out, notes
    out = parse_settings(settings)
    for s in out:
        if s.kind != "kdray" and not _importable(s.kind):
            raise ParameterError(f"setting {s.name!r}: {s.kind} is not installed "
                                 f"(pip install -e '.[bench]')")
    return out, notes


def run(scenes=None, size=(512, 512), repeat=5, sample=10000, settings=None, device=None,
        offset=0.0, step=None, seed=0):
    """Benchmark `settings` on `scenes`; returns (rows, notes): rows are dicts keyed by
    COLUMNS, notes are sentences about what was left out."""
    from .builder import build
    from .camera import Camera
    from .load import load
    from .mesh import Mesh
    from . import reference

    step = step or (lambda what: contextlib.nullcontext())
    settings, notes = resolve_settings(settings)
    scenes = list(scenes) if scenes else default_scenes()
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
    rng = np.random.default_rng(seed)
    build(np.eye(3), np.array([[0, 1, 2]]))                       # compile the builder first
    rows = []
    for path in scenes:
        name = os.path.splitext(os.path.basename(path))[0]
        with step(f"{name}: loading"):
            mesh = load(path)
            if offset:
                mesh = Mesh.from_arrays(mesh.vertices + offset, mesh.faces, name=mesh.name)
        lo, hi = mesh.bounds
        camera = Camera.frame(lo, hi, width, height)
        o, d = camera.rays()
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
                if s.kind == "kdray":
                    b, t_s, t, prim, normal = _kdray(s, mesh, trees, o, d, repeat, device)
                elif s.kind == "open3d":
                    b, t_s, t, prim, normal = open3d_hits(mesh, o, d, repeat)
                else:
                    b, t_s, t, prim, normal = embreex_hits(mesh, o, d, repeat)
            t, prim = np.asarray(t)[idx], np.asarray(prim)[idx]
            if normal is None:                 # embreex: the float64 normal of its triangle
                if tri_normal is None:
                    tri_normal = unit_normals(mesh.triangles)
                normal = np.zeros((len(idx), 3))
                normal[prim >= 0] = tri_normal[prim[prim >= 0]]
            else:
                normal = np.asarray(normal)[idx]
            err = errors(t, prim, normal, ref.t, ref.prim, ref_normal)
            rows.append({"scene": name, "tris": len(mesh.faces), "setting": s.name, "build_s": b,
                         "trace_s": t_s, "mrays_s": n_rays / t_s / 1e6, **err})
    return rows, notes


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
    try:
        with open(path, "w", newline="", encoding="utf-8") as f:
            w = csv.DictWriter(f, fieldnames=COLUMNS)
            w.writeheader()
            for r in rows:
                w.writerow({k: (repr(v) if isinstance(v, float) else v) for k, v in r.items()})
    except OSError as e:
        raise OutputError(f"{path}: cannot write the CSV file ({e.strerror or e})") from None


def plot(rows, path, x="mrays_s"):
    """Depth error p99 (log) against Mrays/s (or trace_s): one colour per scene, one
    marker per setting. Returns None, or a note when matplotlib is not installed."""
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return f"matplotlib is not installed: {path} not written (pip install -e '.[bench]')"
    scenes = list(dict.fromkeys(r["scene"] for r in rows))
    settings = list(dict.fromkeys(r["setting"] for r in rows))
    markers = "os^vD<>pP*Xh"
    colours = plt.get_cmap("tab10")
    floor = 1e-17                                 # log axis: an exact 0 is drawn here
    fig, ax = plt.subplots(figsize=(8, 5.5))
    for r in rows:
        y = r["depth_p99"]
        if not math.isfinite(y):
            continue
        ax.scatter(r[x], max(y, floor), color=colours(scenes.index(r["scene"]) % 10),
                   marker=markers[settings.index(r["setting"]) % len(markers)], s=50)
    ax.set_yscale("log")
    ax.set_xlabel("Mrays/s (numpy rays to numpy hits)" if x == "mrays_s" else "trace seconds")
    ax.set_ylabel("relative depth error, 99th percentile")
    ax.set_title("kdray bench: error against speed")
    ax.grid(True, which="both", alpha=0.3)
    from matplotlib.lines import Line2D
    handles = [Line2D([], [], color=colours(i % 10), marker="o", ls="", label=s) for i, s in enumerate(scenes)]
    handles += [Line2D([], [], color="grey", marker=markers[i % len(markers)], ls="", label=s)
                for i, s in enumerate(settings)]
    ax.legend(handles=handles, fontsize=8, loc="best")
    fig.tight_layout()
    try:
        fig.savefig(path, dpi=120)
    except OSError as e:
        raise OutputError(f"{path}: cannot write the plot ({e.strerror or e})") from None
    finally:
        plt.close(fig)
    return None
