"""A Tracer shared by threads, and Tracers made by with_tree: each call's answers are
the ones it gets alone (docs/interface.md, "Threads").

The races are made to happen every time, not by chance: pyopencl's calls that open
them (the batch counter's reset, a kernel's launch) are wrapped with a short sleep, in
which the other thread runs. Without the Tracer's lock, the second of two traces
started from the counter the first left (its first batches never traced), and a
launch ran on the other call's arguments (its outputs never written)."""
import concurrent.futures
import threading
import time

import numpy as np

import kdray
from helpers import random_rays, real_mesh_arrays


def _tracer(name, **build):
    v, f = real_mesh_arrays(name)
    return kdray.Tracer(kdray.build(v, f, **build))


def _points(tree, n, seed):
    lo, hi = tree.world_box()
    return lo + np.random.default_rng(seed).random((n, 3)) * (hi - lo) * 1.2 - 0.1 * (hi - lo)


def _together(calls):
    """Run each of `calls` (functions of no argument) on its own thread, released at
    once; their results in order."""
    start = threading.Barrier(len(calls), timeout=60)

    def run(call):
        start.wait()
        return call()
    with concurrent.futures.ThreadPoolExecutor(len(calls)) as pool:
        futures = [pool.submit(run, call) for call in calls]
        return [f.result(timeout=240) for f in futures]


def _slowed(monkeypatch, module, name):
    """module.name made to sleep 5 ms after it returns (or before, for a launch)."""
    real = getattr(module, name)

    def slow(*args, **kwargs):
        if name == "enqueue_nd_range_kernel":
            time.sleep(0.005)
            return real(*args, **kwargs)
        out = real(*args, **kwargs)
        time.sleep(0.005)
        return out
    monkeypatch.setattr(module, name, slow)


def test_traces_and_renders_on_threads_share_the_batch_counter(monkeypatch):
    import pyopencl
    tracer = _tracer("teapot.obj")
    tracer._poison_outputs = True                 # rows no kernel wrote are garbage
    rays = [random_rays(tracer.tree, n, seed) for n, seed in ((333, 1), (12345, 2))]
    want = [tracer.trace(o, d) for o, d in rays]
    cam = kdray.Camera.frame(*tracer.tree.world_box(), width=96, height=64)
    image = tracer.render(cam, aovs="id,depth")
    _slowed(monkeypatch, pyopencl, "enqueue_fill_buffer")
    for _ in range(2):
        got = _together([lambda r=r: tracer.trace(*r) for r in rays])
        for g, w in zip(got, want):
            assert np.array_equal(g.prim, w.prim) and np.array_equal(g.t, w.t)
        for images in _together([lambda: tracer.render(cam, aovs="id,depth")] * 2):
            assert all(np.array_equal(images[k], image[k]) for k in image)


def test_queries_on_threads_launch_with_their_own_arguments(monkeypatch):
    import pyopencl._cl
    tracer = _tracer("teapot.obj")
    tracer._poison_outputs = True
    rays = [random_rays(tracer.tree, n, seed) for n, seed in ((1000, 3), (777, 4))]
    points = [_points(tracer.tree, n, seed) for n, seed in ((1000, 5), (777, 6))]
    counts = [tracer.count(o, d) for o, d in rays]
    closest = [tracer.closest_points(p) for p in points]
    listed = [tracer.intersections(o, d) for o, d in rays]
    _slowed(monkeypatch, pyopencl._cl, "enqueue_nd_range_kernel")
    for _ in range(2):
        got = _together([lambda r=r: tracer.count(*r) for r in rays])
        assert all(np.array_equal(g, w) for g, w in zip(got, counts))
        got = _together([lambda p=p: tracer.closest_points(p) for p in points])
        assert all(np.array_equal(g.prim, w.prim) and np.array_equal(g.distance, w.distance)
                   for g, w in zip(got, closest))
        got = _together([lambda r=r: tracer.intersections(*r) for r in rays]
                        + [lambda p=p: tracer.contains(p) for p in points])
        for g, w in zip(got[:2], listed):
            assert np.array_equal(g.offsets, w.offsets) and np.array_equal(g.prim, w.prim)
        assert all(np.array_equal(g, tracer.contains(p)) for g, p in zip(got[2:], points))


def test_with_tree_on_threads(monkeypatch):
    """Tracers of with_tree share their queue and kernels: one lock for them all."""
    import pyopencl._cl
    first = _tracer("teapot.obj")
    other = first.with_tree(_tracer("spot.obj").tree)
    assert other._lock is first._lock
    r1, r2 = random_rays(first.tree, 2000, 7), random_rays(other.tree, 1500, 8)
    want = first.trace(*r1).prim, other.trace(*r2).prim
    _slowed(monkeypatch, pyopencl._cl, "enqueue_nd_range_kernel")
    got = _together([lambda: first.trace(*r1).prim, lambda: other.trace(*r2).prim])
    assert np.array_equal(got[0], want[0]) and np.array_equal(got[1], want[1])


def test_with_tree_keeps_the_point_queries_of_each_tree_apart():
    """with_tree's Tracer answers point queries about its own tree, and the first one
    about its own: the point queries' data (winding moments, float64 triangles, the
    mesh's edges) is a tree's, not shared by copying the Tracer (the new Tracer gave
    the first tree's winding numbers, and the first then read the new tree's float64
    triangles with its own ids: a crash)."""
    spot = _tracer("spot.obj", keep_double=True)
    first = _tracer("teapot.obj", keep_double=True)
    p_spot, p_first = _points(spot.tree, 700, 1), _points(first.tree, 700, 2)
    want = {"winding": spot.winding_number(p_spot), "inside": spot.occupancy(p_spot),
            "closest": spot.closest_points(p_spot, precision="double").prim}
    mine = {"winding": first.winding_number(p_first), "inside": first.occupancy(p_first),
            "closest": first.closest_points(p_first, precision="double").prim}
    other = first.with_tree(spot.tree)
    got = {"winding": other.winding_number(p_spot), "inside": other.occupancy(p_spot),
           "closest": other.closest_points(p_spot, precision="double").prim}
    assert all(np.array_equal(got[k], want[k]) for k in want)
    again = {"winding": first.winding_number(p_first), "inside": first.occupancy(p_first),
             "closest": first.closest_points(p_first, precision="double").prim}
    assert all(np.array_equal(again[k], mine[k]) for k in mine)


def test_threads_make_a_trees_point_query_data_once(monkeypatch):
    """Two threads' first point queries on one Tracer make its winding moments and
    float64 triangles once (points._made, under the Tracer's lock): each was made by
    every thread that found it missing, the slower one's kept."""
    from kdray import points as kpoints
    made = {"winding": 0, "tris64": 0}
    moments = kpoints.winding_moments

    def slow_moments(*args):
        made["winding"] += 1
        time.sleep(0.3)                         # the other thread finds them missing
        return moments(*args)
    monkeypatch.setattr(kpoints, "winding_moments", slow_moments)
    tracer = _tracer("spot.obj", keep_double=True)
    buffer = tracer._tree_buffer

    def counted_buffer(array):
        if array.dtype == np.float64:
            made["tris64"] += 1
            time.sleep(0.3)
        return buffer(array)
    monkeypatch.setattr(tracer, "_tree_buffer", counted_buffer)
    p = _points(tracer.tree, 500, 3)
    got = _together([lambda: tracer.winding_number(p), lambda: tracer.winding_number(p),
                     lambda: tracer.closest_points(p, precision="double").prim,
                     lambda: tracer.closest_points(p, precision="double").prim])
    assert made == {"winding": 1, "tris64": 1}
    assert np.array_equal(got[0], got[1]) and np.array_equal(got[2], got[3])
