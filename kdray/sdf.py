"""Signed distance grids and samples of a mesh, as learning pipelines take them.

    grid = sdf_grid(tracer, 128, padding=0.1, sign="winding")   # Grid: .values (N, N, N)
    points, sdf = sdf_samples(tracer, 250_000, sigma=None, uniform=0.1, seed=0)

A grid's values are at origin + spacing * (i, j, k), values[i, j, k], over a cube
centred on the scene's box whose side is the box's largest side plus `padding` times
it on each side. Samples follow DeepSDF (Park et al. 2019): points on the surface
(uniform by area) moved by Gaussian noise of deviation sigma, and a fraction of
points uniform in the padded box, with their signed distances; the same seed gives
the same samples. Signed distances are negative inside (kdray.points).
"""
import dataclasses

import numpy as np

from . import points as _points
from .errors import KdrayError
from .host import check_host_memory
from .validate import FLOAT32_MAX, check_bool

MAX_RESOLUTION = 4096
"""The most samples a grid's side takes (4096^3 float32 values are 256 GiB)."""

SLAB_POINTS = 1 << 20
"""About the most grid points computed at once: a few slabs of the grid, 24 bytes a
point in flight besides the values."""


@dataclasses.dataclass(eq=False)
class Grid:
    """Values on a cubic grid: values[i, j, k] at origin + spacing * (i, j, k).

    values : (N, N, N) float32 signed distances (world units, negative inside), or
        uint8 occupancy (1 inside)
    origin : (3,) float64 world position of values[0, 0, 0];  spacing : float
    sign : how inside was decided, "winding" or "parity"
    """
    values: np.ndarray
    origin: np.ndarray
    spacing: float
    sign: str

    def points(self, i):
        """(N * N, 3) float64 world positions of the slab values[i] (rows j, then k)."""
        n = self.values.shape[0]
        j, k = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
        ijk = np.stack([np.full(j.size, i), j.ravel(), k.ravel()], axis=1)
        return self.origin + self.spacing * ijk


def check_grid(resolution, padding, occupancy=False):
    """(resolution, padding) checked: KdrayError for a resolution that is not an integer
    from 2 to MAX_RESOLUTION, a padding that is negative or not finite, occupancy not
    True or False, or a grid that does not fit in the host's memory (saying how much it
    needs)."""
    occupancy = check_bool(occupancy, "occupancy", KdrayError)
    if isinstance(resolution, bool) or not isinstance(resolution, (int, np.integer)):
        raise KdrayError(f"resolution must be an integer, got {resolution!r}")
    if not 2 <= resolution <= MAX_RESOLUTION:
        raise KdrayError(f"resolution must be from 2 to {MAX_RESOLUTION}, got {resolution}")
    padding = _check_padding(padding)
    n = int(resolution)
    slab = max(1, SLAB_POINTS // (n * n))
    check_host_memory(n ** 3 * (1 if occupancy else 4) + slab * n * n * 64, f"a {n}^3 grid",
                      "ask for a lower resolution")
    return n, padding


def _check_padding(padding):
    """padding as a float; KdrayError unless a finite number >= 0."""
    if isinstance(padding, bool) or not isinstance(padding, (int, float, np.integer, np.floating)):
        raise KdrayError(f"padding must be a number, got {padding!r}")
    padding = float(padding)
    if not (np.isfinite(padding) and padding >= 0):
        raise KdrayError(f"padding must be a finite number >= 0, got {padding!r}")
    return padding


def grid_frame(tracer, resolution, padding, occupancy=False):
    """(origin (3,) float64, spacing) of an N^3 grid over the tracer's scene box padded
    by `padding` times its largest side on each side (`check_grid`'s checks first, for
    float32 distances or with `occupancy` uint8 flags)."""
    resolution, padding = check_grid(resolution, padding, occupancy)
    lo, hi = tracer.tree.world_box()
    with np.errstate(all="ignore"):         # a side beyond float32's range: refused below
        side = float((hi - lo).max()) * (1.0 + 2.0 * padding)
        origin = 0.5 * (lo + hi) - 0.5 * side
    if not side > 0:
        side = 1.0                          # a flat point of a scene: any cube holds it
        origin = 0.5 * (lo + hi) - 0.5 * side
    if not (side <= FLOAT32_MAX and np.all(np.abs(origin) <= FLOAT32_MAX)):
        raise KdrayError(f"padding {padding!r} makes a grid {side:.3g} across, beyond float32's "
                         f"range (the distances are float32)")
    spacing = side / (resolution - 1)
    return origin, spacing


def sdf_grid(tracer, resolution, padding=0.1, sign="winding", occupancy=False,
             progress=None):
    """A Grid of resolution^3 signed distances (float32) or, with occupancy, inside
    flags (uint8) of the tracer's mesh (`grid_frame` says where). sign: "winding" or
    "parity" (kdray.points.signed_distance). progress: None or a function called with
    (points done, points in all) after each slab. KdrayError when the grid does not fit
    in memory (saying how much it needs)."""
    _points._check_sign(sign)
    origin, spacing = grid_frame(tracer, resolution, padding, occupancy)
    n = int(resolution)
    slab = max(1, SLAB_POINTS // (n * n))
    grid = Grid(np.empty((n, n, n), dtype=np.uint8 if occupancy else np.float32), origin,
                spacing, sign)
    if sign == "parity":
        _points._warn_open(tracer)
    for i in range(0, n, slab):
        stop = min(n, i + slab)
        p = np.concatenate([grid.points(k) for k in range(i, stop)])
        if occupancy:
            values = _points.inside(tracer, p, sign)
        else:
            values = _points.signed(tracer, p, sign)
        grid.values[i:stop] = values.reshape(stop - i, n, n)
        if progress is not None:
            progress(stop * n * n, n ** 3)
    return grid


def check_samples(count, sigma=None, uniform=0.1, padding=0.1, sign="winding", seed=0):
    """(uniform, sigma, padding) as `sdf_samples` takes them (floats; sigma None
    stays None): KdrayError for a bad one, or samples that would not fit in the host's
    memory, before any work (the scene's own checks, a padded box beyond float32's
    range, come with it)."""
    if isinstance(count, bool) or not isinstance(count, (int, np.integer)) or count < 1:
        raise KdrayError(f"the sample count must be an integer >= 1, got {count!r}")
    if isinstance(uniform, bool) or not isinstance(uniform, (int, float, np.integer, np.floating)):
        raise KdrayError(f"uniform must be a fraction from 0 to 1, got {uniform!r}")
    uniform = float(uniform)
    if not 0.0 <= uniform <= 1.0:
        raise KdrayError(f"uniform must be a fraction from 0 to 1, got {uniform!r}")
    _points._check_sign(sign)
    padding = _check_padding(padding)
    if sigma is not None:
        if isinstance(sigma, bool) or not isinstance(sigma, (int, float, np.integer,
                                                             np.floating)):
            raise KdrayError(f"sigma must be a number, got {sigma!r}")
        sigma = float(sigma) + 0.0         # -0.0 is 0 (numpy's normal refuses it)
        if not (np.isfinite(sigma) and 0 <= sigma <= FLOAT32_MAX):
            raise KdrayError(f"sigma must be a number from 0 to {FLOAT32_MAX:.4g} "
                             f"(float32's range), got {sigma!r}")
    if seed is not None and (isinstance(seed, bool) or not isinstance(seed, (int, np.integer))
                             or seed < 0):
        raise KdrayError(f"seed must be an integer >= 0 (or None), got {seed!r}")
    check_host_memory(int(count) * 96, f"{count} samples", "ask for fewer")
    return uniform, sigma, padding


def sdf_samples(tracer, count, sigma=None, uniform=0.1, padding=0.1, sign="winding",
                seed=0):
    """(points (count, 3) float64 world, sdf (count,) float32) as DeepSDF samples them:
    round(count * uniform) points uniform in the scene box padded by `padding` times its
    largest side on each side (each axis's range widened so), the rest on the surface,
    uniform by area, moved by Gaussian noise of deviation sigma (world units; None:
    1/200 of the scene box's diagonal); their signed distances (negative inside,
    `sign`). The surface's points come first. The same seed gives the same samples."""
    uniform, sigma, padding = check_samples(count, sigma, uniform, padding, sign, seed)
    lo, hi = tracer.tree.world_box()
    with np.errstate(over="ignore"):
        reach = padding * float((hi - lo).max())
        box_lo, box_hi = lo - reach, hi + reach
    if not (np.all(np.abs(box_lo) <= FLOAT32_MAX) and np.all(np.abs(box_hi) <= FLOAT32_MAX)):
        raise KdrayError(f"padding {padding!r} makes a box beyond float32's range (the "
                         f"distances are float32)")
    if sigma is None:
        sigma = float(np.linalg.norm(hi - lo)) / 200.0
    rng = np.random.default_rng(seed)
    n_uniform = int(round(count * uniform))
    n_surface = int(count) - n_uniform
    tree = tracer.tree
    tris = tree.world(np.asarray(tree.triangles, dtype=np.float64))       # (m, 3, 3)
    area = 0.5 * np.linalg.norm(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]),
                                axis=1)
    which = rng.choice(len(tris), size=n_surface, p=area / area.sum())
    # uniform on a triangle: reflect (r1, r2) into the lower half of the unit square
    r = rng.random((n_surface, 2))
    flip = r.sum(axis=1) > 1.0
    r[flip] = 1.0 - r[flip]
    t = tris[which]
    surface = t[:, 0] + r[:, :1] * (t[:, 1] - t[:, 0]) + r[:, 1:] * (t[:, 2] - t[:, 0])
    surface += rng.normal(scale=sigma, size=surface.shape)
    box = box_lo + (box_hi - box_lo) * rng.random((n_uniform, 3))
    p = np.concatenate([surface, box])
    if sign == "parity":
        _points._warn_open(tracer)
    return p, _points.signed(tracer, p, sign)
