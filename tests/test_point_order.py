"""Points put in spatial order on the device (kdray.point_order, kernels/point_order.cl)
against the host's own numbers: kdray.points.spatial_order's order, ray_input.rays32's
rounding of the points and kdray.rays' directions by octant, number for number, and
`contains` answering the same either way."""
import numpy as np
import pytest

from helpers import grid_cube, real_mesh_arrays
from kdray import point_order
from kdray import rays as krays
from kdray.builder import build
from kdray.points import spatial_order
from kdray.ray_input import rays32
from kdray.trace import Tracer


@pytest.fixture(scope="module")
def teapot_arrays():
    return real_mesh_arrays("teapot.obj")


def awkward_points(tree, rng, n):
    """(n, 3) float64 points of the tree's box and around it: random ones, ones outside
    the box (clamped cells), ones exactly on the box's faces and its middle planes (the
    sides' ties), on grid lines of spatial_order's cells, and repeated ones."""
    lo, hi = tree.world_box()
    size = hi - lo
    mid = 0.5 * (lo + hi)
    p = lo + size * rng.uniform(-0.3, 1.3, (n, 3))
    k = n // 6
    on = rng.integers(0, 3, k)
    p[np.arange(k), on] = mid[on]                                  # on a middle plane
    p[k:2 * k] = np.where(rng.random((k, 3)) < 0.5, lo, hi)       # the box's corners
    cells = rng.integers(0, 33, (k, 3)) / 32.0
    p[2 * k:3 * k] = lo + size * cells                             # on the cells' sides
    p[3 * k:4 * k] = p[:k]                                         # repeated
    return p


@pytest.mark.parametrize("where", ["near", "far"])
def test_device_order_and_rays_are_the_hosts(runtime, teapot_arrays, where):
    """The device's keys sort the points as spatial_order does (with and without the
    sides of the middle), and contains_rays' rays are the host's rays32 of the points
    taken in that order, with the direction of each point's octant, bit for bit: a
    tree at the origin and one far from it at a large scale (the tracer's origin and
    scale not 0 and 1), points given from a page's start or not, counts that are not
    multiples of the work size."""
    v, f = teapot_arrays
    if where == "far":
        v = v * 2.0 ** 48 + np.array([3e15, -7e14, 1.5e15])     # beyond 2^40: scaled
    tree = build(v, f)
    tracer = Tracer(tree, device=runtime.spec)
    if not point_order.available(tracer):
        pytest.skip("no cl_khr_fp64: contains keeps the host's way")
    if where == "far":
        assert tracer._scale != 1.0 and np.abs(tracer._origin).max() > 0
    rng = np.random.default_rng(31)
    lo, hi = tree.world_box()
    centre = krays._middle(tracer)
    n = runtime.small(5003, 613)
    whole = awkward_points(tree, rng, n + 1)
    for p in (whole[:n], whole[1:]):        # from the array's start, and 24 bytes on
        assert np.array_equal(point_order.spatial_order(tracer, p, lo, hi),
                              spatial_order(p, lo, hi))
        sides = krays._sides(tracer, p)
        want = spatial_order(p, lo, hi, sides)
        assert np.array_equal(point_order.spatial_order(tracer, p, lo, hi, centre), want)
        order, o, d = point_order.contains_rays(tracer, p, centre, krays._OCTANT_DIRECTIONS)
        assert order.dtype == np.uint32 and np.array_equal(order, want)
        o32, d32 = rays32(p, krays.contains_directions(tracer, p), 1, tracer._origin,
                          tracer._scale)
        assert np.array_equal(o, o32[want]) and np.array_equal(d, d32[want])
    empty = np.zeros((0, 3))
    assert point_order.spatial_order(tracer, empty, lo, hi).shape == (0,)
    assert [a.shape for a in point_order.contains_rays(tracer, empty, centre,
                                                       krays._OCTANT_DIRECTIONS)] == \
        [(0,), (0, 3), (0, 3)]


def test_contains_answers_the_same_on_the_host(runtime, monkeypatch):
    """`contains` of points in spatial order (SORT_FROM or more) answers the same with
    its rays made on the device as on the host, on a closed grid cube whose vertices,
    edges and faces some points lie on."""
    v, f = grid_cube(2)
    tracer = Tracer(build(v, f), device=runtime.spec)
    rng = np.random.default_rng(32)
    n = krays.SORT_FROM + runtime.small(3001, 17)
    p = rng.uniform(-3, 3, (n, 3))
    p[: n // 4] = np.round(p[: n // 4])                  # on the cube's grid
    device = tracer.contains(p)
    monkeypatch.setattr(point_order, "available", lambda t: False)
    host = tracer.contains(p)
    assert np.array_equal(device, host)
    assert (device == (np.abs(p + 1e-6 * krays.contains_directions(tracer, p)) < 2)
            .all(axis=1)).all()
