"""The SAH k-d tree builder (Wald & Havran 2006, O(n log n), with perfect splits).

    import kdray.builder
    tree = kdray.builder.build(vertices, faces)        # -> kdray.tree.KdTree
    tree.validate()

Pipeline (one module each): `prepare` (mesh arrays -> float32 triangles relative to
an origin, degenerate ones left out), `events` (one sort of the root's events),
`sah` (the sweep that picks a plane), `classify` + `clip` (splitting the sorted
events between the children, re-clipping straddlers), `subdivide` (the depth-first
loop with an explicit stack; subtrees below the top levels are built on threads);
`scratch` keeps the events' array for the next build, `threads` the threads. Beside
them, `bvh`: the binary BVH under a Tracer's wide nodes (kdray/wide.py), built from a
tree's triangles when rays that share no path first need it.

The build is a pure function: no I/O, and its one global, the kept array, never
changes a result; the same input gives identical arrays, whatever the number of
threads. The numba kernels are cached on disk
(`__pycache__`); the first call in a fresh checkout compiles them (about 20 s on 2
cores). numba checks a cached function against its own file only: after editing one of these modules, delete
`kdray/builder/__pycache__/*.nb[ic]` so that the functions calling it are rebuilt too.
"""
import logging
import math
import numbers
import os

import numpy as np

from .. import layout
from ..errors import MeshError, ParameterError
from ..tree import MAX_COORDINATE, BuildParams, KdTree
from ..validate import check_bool
# modules, not their functions, under the modules' names: kdray.builder.prepare is
# the module (a function of the same name would shadow it)
from . import prepare, scratch, subdivide
from .threads import kept_pool
from .events import sorted_root_events
from .subdivide import build_nodes

__all__ = ["build", "check_params", "compiled", "compile_all", "COMPILING"]

log = logging.getLogger(__name__)


def check_params(K_T=BuildParams.K_T, K_I=BuildParams.K_I, empty_bonus=BuildParams.empty_bonus,
                 max_depth=BuildParams.max_depth, leaf_size=BuildParams.leaf_size):
    """BuildParams of these values, checked; ParameterError for one of the wrong type or
    out of range. Types are kept, never converted: K_T, K_I and empty_bonus are real
    numbers (int, float or numpy's; not bool, not a string such as "20"), max_depth and
    leaf_size integers (not 3.0)."""
    params = BuildParams(K_T=_real(K_T, "K_T"), K_I=_real(K_I, "K_I"),
                         empty_bonus=_real(empty_bonus, "empty_bonus"),
                         max_depth=_whole(max_depth, "max_depth"),
                         leaf_size=_whole(leaf_size, "leaf_size"))
    if not (math.isfinite(params.K_T) and params.K_T >= 0):
        raise ParameterError(f"K_T must be a positive number (or 0: automatic), got {K_T}")
    if not (math.isfinite(params.K_I) and params.K_I > 0):
        raise ParameterError(f"K_I must be a positive number, got {K_I}")
    if not 0 < params.empty_bonus <= 1:
        raise ParameterError(f"empty_bonus must be in (0, 1], got {empty_bonus}")
    if params.max_depth < 0:
        raise ParameterError(f"max_depth must be >= 0 (0 = automatic), got {max_depth}")
    if not 0 <= params.leaf_size <= 0xFFFFFFFF:         # a count of triangles (uint32 ids)
        raise ParameterError(f"leaf_size must be from 0 to 4294967295 (a triangle count), "
                             f"got {leaf_size}")
    return params


def _real(value, name):
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ParameterError(f"{name} must be a number, got {value!r}")
    try:
        return float(value)
    except OverflowError:                   # an int beyond float64's range
        raise ParameterError(f"{name} must be finite, got an integer of "
                             f"{len(str(abs(value)))} digits") from None


def _whole(value, name):
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise ParameterError(f"{name} must be a whole number (an integer), got {value!r}")
    return int(value)


def _dispatchers():
    """The builder's numba functions (CPUDispatcher objects) of every module."""
    from numba.core.registry import CPUDispatcher
    from . import bvh, classify, clip, events, sah
    mods = (bvh, classify, clip, events, prepare, sah, subdivide)
    # functions inlined into their callers are never compiled on their own
    return [f for m in mods for f in vars(m).values()
            if isinstance(f, CPUDispatcher) and f.targetoptions.get("inline") != "always"]


COMPILING = ("compiling the tree builder (once per install, about half a minute; "
             "`kdray setup` does it ahead)")
"""What to tell a user who waits while `compile_all`, or a first build, compiles."""


def compiled():
    """True when every numba function of the builder has compiled code in its on-disk
    cache (so that a build starts at once), False when the first build of this
    install would compile them (about half a minute on 2 cores)."""
    try:
        return all(os.path.exists(f._cache._cache_file._index_path) for f in _dispatchers())
    except AttributeError:           # another numba's cache internals: assume compiled
        return True


def compile_all():
    """Compile every numba function of the builder into its on-disk cache, so that
    `compiled` holds (it checks each one): one build of a single triangle (the
    one-thread path), one of `events.SPLIT_TRIS` on two threads (the threaded path,
    with z's root events made in two jobs as on two CPUs: that job's call from Python
    is compiled apart, and was left to a first build of 30,000 triangles or more on
    such machines), and `events.event_counts`,
    which no build calls (`sorted_root_events` counts with it for a caller that passes
    no `flat`); left out, every command that builds would warn that it compiles. Also
    the wide nodes' BVH (`bvh`, kdray/wide.py), which a Tracer's first trace of rays
    that share no path builds."""
    from . import events
    from ..wide import wide_nodes
    rng = np.random.default_rng(0)
    one = build([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])
    events.event_counts(one.triangles)
    n = events.SPLIT_TRIS
    soup = rng.random((n, 1, 3)) + 0.01 * rng.random((n, 3, 3))
    wide_nodes(build(soup.reshape(-1, 3), np.arange(3 * n).reshape(-1, 3), threads=2), 16, 0)


MAX_THREADS = 1024
"""Most threads a build may be asked for (`threads`): each is a thread of the process."""


MAX_NODES = layout.MAX_NODES
"""Nodes a tree may hold: an interior node's child index is 30 bits (layout.py)."""

MAX_LEAF_REFS = 1 << 32
"""Leaf references a tree may hold: a leaf's offset into them is 32 bits (layout.py)."""


def check_size(n_nodes, n_refs, n_tris):
    """ParameterError where a finished build has more nodes than the tree format's
    child indices hold (MAX_NODES, 30 bits) or more leaf references than its
    leaf offsets (MAX_LEAF_REFS): the builder stores them in those bits, so such a tree
    would point at the wrong nodes and leaves (parameters that split far more than the
    defaults, K_T=15 or K_T=1 on meshes of about 10^8 triangles)."""
    if n_nodes >= MAX_NODES or n_refs >= MAX_LEAF_REFS:
        raise ParameterError(
            f"the tree of {n_tris:,} triangles came out with {n_nodes:,} nodes and "
            f"{n_refs:,} leaf references, more than the tree format holds (2^30 nodes, "
            f"2^32 references): build it with a larger K_T or K_I, or a smaller max_depth")


def build(vertices, faces, *, K_T=BuildParams.K_T, K_I=BuildParams.K_I,
          empty_bonus=BuildParams.empty_bonus, max_depth=BuildParams.max_depth,
          leaf_size=BuildParams.leaf_size, origin=None, threads=None, scale=None,
          keep_double=False):
    """Build a KdTree over a triangle mesh.

    vertices : (n, 3) float-like (read as float64);  faces : (m, 3) int.
    K_T, K_I : SAH costs of a traversal step and of a triangle test (W&H Table 1);
        K_T 0 = automatic (`kdray.tree.auto_K_T`: 400, 600 from a million triangles);
    empty_bonus : lambda in (0, 1], the cost factor of a split with an empty side;
    max_depth : deepest leaf, 0 = round(8 + 1.3 log2 n) capped at 64 (pbrt);
    leaf_size : nodes with at most this many triangles become leaves;
    origin : None (centre of the box of the vertices the faces use) or (3,) float64:
        the point the float32 triangles are stored relative to. A tree over part of a
        mesh built with the whole mesh's origin stores the same float32 triangles;
    threads : None (the CPUs this process may run on) or the number of threads that
        build subtrees; the tree is the same for any number;
    scale : None (1 for scenes 2^-28 .. 2^28 across, else the power of two nearest
        the size: kdray.builder.prepare.scale_for) or a power of two: the unit of the
        stored triangles (KdTree.scale). Like origin, for a tree over part of a mesh
        (MeshError where the two leave a stored coordinate beyond 2^28:
        kdray.tree.MAX_COORDINATE);
    keep_double : also keep the input's float64 triangles (KdTree.triangles64, 72
        bytes a triangle) for Tracer.trace and render with precision="double".

    Triangles with a non-finite coordinate or a zero float32 cross product are left
    out (`tri_ids` maps kept triangles to input rows). Raises MeshError for bad arrays
    or when no triangle is left; ParameterError (a ValueError) for parameters out of range.
    """
    params = check_params(K_T, K_I, empty_bonus, max_depth, leaf_size)
    keep_double = check_bool(keep_double, "keep_double", ParameterError)

    if threads is None:
        threads = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    if (isinstance(threads, bool) or not isinstance(threads, (int, np.integer))
            or not 1 <= threads <= MAX_THREADS):
        raise ParameterError(f"threads must be None or an integer from 1 to {MAX_THREADS}, "
                             f"got {threads!r}")

    threads = int(threads)
    try:
        small = len(faces) < subdivide.MIN_PARALLEL_TRIS
    except TypeError:                           # not a sequence: prepare says what is wrong
        small = True
    if small:
        threads = 1                             # one thread, no pool
    pool = kept_pool(threads)
    mesh = prepare.prepare(vertices, faces, origin, pool=pool, threads=threads,
                           scale=scale)
    far = float(np.abs(mesh.bounds).max())
    if far > MAX_COORDINATE:            # only with an origin or a scale given
        raise MeshError(f"the triangles lie {far:.3g} from the origin in units of the scale "
                        f"{mesh.scale:.3g}; at most {MAX_COORDINATE:.3g} (2^28), where "
                        f"the kernels' products of coordinates stay within float32")
    params = params.resolved(len(mesh.triangles))
    # The events are the builder's two event stacks, with room to grow (about 1.5
    # times the root's events each; `subdivide.split_keys`).
    # Their array is kept for the next build when it is small enough (`scratch`).
    nodes, leaf_tris, depth = build_nodes(
        mesh.triangles, *sorted_root_events(mesh.triangles, room=12 * len(mesh.triangles) + 256,
                                           threads=threads, pool=pool, empty=scratch.take,
                                           flat=mesh.flat),
        mesh.bounds.astype(np.float64),
        params.K_T, params.K_I, params.empty_bonus, params.max_depth, params.leaf_size,
        threads=threads, pool=pool, reuse=True)
    log.debug("built %d nodes, %d leaf references over %d triangles (%d input)",
              len(nodes), len(leaf_tris), len(mesh.triangles), mesh.n_input_tris)
    check_size(len(nodes), len(leaf_tris), len(mesh.triangles))
    tree = KdTree(nodes=nodes, leaf_tris=leaf_tris, triangles=mesh.triangles,
                  tri_ids=mesh.tri_ids, origin=mesh.origin, bounds=mesh.bounds,
                  n_input_tris=mesh.n_input_tris, depth=int(depth), params=params,
                  scale=mesh.scale)
    return tree.with_double(vertices, faces, built=True) if keep_double else tree
