"""ray_grid.grid_width: the width of the row-major image that (N, 3) rays are, found
from a sample of them, or 0 when they are not one."""
import numpy as np
import pytest

from kdray import Camera
from kdray.ray_grid import MIN_WIDTH, grid_width, rows_coherent

BOX = (np.zeros(3), np.ones(3))


@pytest.mark.parametrize("w, h", [(1024, 768), (640, 480), (64, 7), (17, 100), (96, 64)])
def test_camera_rays_in_rows(w, h):
    o, d = Camera.frame(*BOX, w, h).rays()
    assert grid_width(o, d) == w
    assert grid_width(o[0], d.astype(np.float32)) == w


def test_too_few_rows_or_too_narrow():
    o, d = Camera.frame(*BOX, 100, 80).rays()
    band = d.reshape(80, 100, 3)[40:43].reshape(-1, 3)
    assert grid_width(o[0], band) == 0                  # 3 rows < 4
    assert grid_width(o[0], band, min_rows=2) == 100
    o, d = Camera.frame(*BOX, 4096, 1).rays()
    assert grid_width(o, d) == 0
    # narrower than MIN_WIDTH: two rows together are a grid, at worst
    o, d = Camera.frame(*BOX, 9, 40).rays()
    assert grid_width(o, d) in (0, 18)
    assert grid_width(np.zeros(3), np.ones((MIN_WIDTH * 4 - 1, 3))) == 0


def test_layouts():
    o, d = Camera.frame(*BOX, 320, 240).rays()
    image = d.reshape(240, 320, 3)
    # images one after the other (the second upside down); column-major order
    assert grid_width(o[0], np.concatenate([d, d[::-1]])) == 320
    assert grid_width(o[0], np.concatenate([d, d, d])) == 320
    assert grid_width(o[0], image.transpose(1, 0, 2).reshape(-1, 3)) == 240
    # pixels with no ray (NaN), as a fisheye's corners, and zero directions
    holes = d.copy()
    y, x = np.mgrid[0:240, 0:320]
    holes[((x - 160) ** 2 + (y - 120) ** 2 > 120 ** 2).ravel()] = np.nan
    holes[::7] = 0.0
    assert grid_width(o[0], holes) == 320
    # an orthographic camera: one direction, a grid of origins
    origins = np.stack([x, y, np.zeros_like(x)], axis=-1).reshape(-1, 3) * 0.01
    assert grid_width(origins, np.broadcast_to([0.0, 0.0, 1.0], origins.shape)) == 320
    # origins that scatter break the grid, whatever the directions
    scattered = np.random.default_rng(1).normal(size=d.shape)
    assert grid_width(scattered, d) == 0


def test_not_an_image():
    rng = np.random.default_rng(0)
    n = 1 << 16
    assert grid_width(rng.normal(size=(n, 3)), rng.normal(size=(n, 3))) == 0
    assert grid_width(np.zeros(3), rng.normal(size=(n, 3))) == 0
    # all rays alike, none usable, a prime count (no divisor to be a width)
    assert grid_width(np.zeros(3), np.broadcast_to([0.0, 0.0, 1.0], (n, 3))) == 0
    assert grid_width(np.zeros(3), np.full((n, 3), np.nan)) == 0
    assert grid_width(np.zeros(3), np.zeros((n, 3))) == 0
    o, d = Camera.frame(*BOX, 256, 256).rays()
    assert grid_width(o, d[:65521]) == 0
    # an image's rays in random order: not rows
    assert grid_width(o, d[rng.permutation(len(d))]) == 0


def test_rows_coherent_tells_images_from_rays_in_no_order():
    """The quick check before a width kept for a count is used: every image that
    grid_width finds passes it (one origin or per-ray origins, float32, holes, an
    orthographic grid of origins); random rays, an image's rays shuffled and too few
    rays fail it."""
    rng = np.random.default_rng(2)
    for w, h in [(1024, 768), (64, 7), (17, 100), (9, 40)]:
        o, d = Camera.frame(*BOX, w, h).rays()
        assert rows_coherent(o, d) and rows_coherent(o[0], d.astype(np.float32)), (w, h)
        assert not rows_coherent(o, d[rng.permutation(len(d))]), (w, h)
    o, d = Camera.frame(*BOX, 320, 240).rays()
    holes = d.copy()
    holes[::7] = np.nan
    assert rows_coherent(o[0], holes)
    y, x = np.mgrid[0:240, 0:320]
    origins = np.stack([x, y, np.zeros_like(x)], axis=-1).reshape(-1, 3) * 0.01
    assert rows_coherent(origins, np.broadcast_to([0.0, 0.0, 1.0], origins.shape))
    n = 1 << 16
    assert not rows_coherent(rng.normal(size=(n, 3)), rng.normal(size=(n, 3)))
    assert not rows_coherent(np.zeros(3), rng.normal(size=(n, 3)))
    assert not rows_coherent(np.zeros(3), np.broadcast_to([0.0, 0.0, 1.0], (n, 3)))
    assert not rows_coherent(o, d[:31])
