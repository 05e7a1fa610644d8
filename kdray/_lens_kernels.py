"""The per-pixel inversions of kdray.lens's opencv and fisheye models, in numba: a
safeguarded Newton iteration per pixel, float64 (compiled on first use, cached on disk
in kdray/__pycache__). Each takes the pixels [start, end) of a row-major image `width` wide, makes their
normalized points K^-1 (i + 0.5, j + 0.5, 1) itself, writes the directions turned by R
(world axes) and releases the GIL, so that kdray.lens runs parts of an image on threads.

Each pixel's distorted radius rd is inverted on the radial part first: Newton's method
kept inside a bisection bracket [0, reach] (the radial map is increasing up to limit
>= reach, and passes every pixel's radius at reach: kdray.lens._monotonic_limit), until
the error is `stop` times the tolerance or the iterate stops moving; then, for opencv
with a tangential part, Newton's method on the full 2D model from that point (which
may leave the bracket: a pixel beyond g(limit) may still have its point inside limit,
so only a radial model refuses those at once), each step halved until it brings the
distortion nearer, and once more from the pixel's own point where the first did not
end in a solution. The result is checked: distortion within tol (1 + rd) of the
pixel's point, radius below `limit`, and a positive Jacobian.
"""
import math

from numba import njit


@njit(cache=True)
def _radial(r, k1, k2, k3, k4, k5, k6):
    """(g(r) = r num / den, g'(r), den) of OpenCV's rational radial distortion."""
    s = r * r
    num = 1.0 + s * (k1 + s * (k2 + s * k3))
    den = 1.0 + s * (k4 + s * (k5 + s * k6))
    dnum = 2.0 * r * (k1 + s * (2.0 * k2 + 3.0 * s * k3))
    dden = 2.0 * r * (k4 + s * (2.0 * k5 + 3.0 * s * k6))
    return r * num / den, (num + r * dnum) / den - r * num * dden / (den * den), den


@njit(cache=True)
def _bracketed_newton(r, f, df, lo, hi):
    """One step for f(r) = 0, f increasing on [lo, hi]: the bracket narrowed by r's
    sign, and Newton's step, or the bracket's midpoint where that leaves it.
    Returns (next r, lo, hi)."""
    if f < 0.0:
        lo = r
    else:
        hi = r
    # (df is 0 at a fold, where a tangential pixel's radial start may end)
    step = r - f / df if df > 0.0 else hi
    if not (lo < step < hi):
        step = 0.5 * (lo + hi)
    return step, lo, hi


@njit(cache=True)
def _distort(x, y, k1, k2, p1, p2, k3, k4, k5, k6):
    """OpenCV's distortion of (x, y) and its Jacobian: xd, yd, j00, j01, j10, j11."""
    r2 = x * x + y * y
    num = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    den = 1.0 + r2 * (k4 + r2 * (k5 + r2 * k6))
    radial = num / den
    dnum = k1 + r2 * (2.0 * k2 + 3.0 * r2 * k3)
    dden = k4 + r2 * (2.0 * k5 + 3.0 * r2 * k6)
    drad = (dnum * den - num * dden) / (den * den)
    xy = x * y
    xd = x * radial + 2.0 * p1 * xy + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * xy
    j00 = radial + 2.0 * x * x * drad + 2.0 * p1 * y + 6.0 * p2 * x
    j01 = 2.0 * xy * drad + 2.0 * p1 * x + 2.0 * p2 * y
    j11 = radial + 2.0 * y * y * drad + 6.0 * p1 * y + 2.0 * p2 * x
    return xd, yd, j00, j01, j01, j11


@njit(cache=True)
def _newton_2d(xi, yi, ai, bi, bound, k, max_iterations):
    """(x, y) whose distortion (k: k1 k2 p1 p2 k3 k4 k5 k6) is within `bound` of the
    pixel's point (ai, bi): Newton's method on the 2D model from (xi, yi), each step
    halved (up to 30 times) until it brings the distortion nearer, where the whole
    step would not (it is taken whole where no halving does)."""
    k1, k2, p1, p2, k3, k4, k5, k6 = k[0], k[1], k[2], k[3], k[4], k[5], k[6], k[7]
    for _ in range(max_iterations):
        xd, yd, j00, j01, j10, j11 = _distort(xi, yi, k1, k2, p1, p2, k3, k4, k5, k6)
        fx, fy = xd - ai, yd - bi
        error = math.sqrt(fx * fx + fy * fy)
        if not (error > bound):
            break
        det = j00 * j11 - j01 * j10
        if det == 0.0:
            break           # a fold: refused by _solved (its Jacobian is not positive)
        dx = (j11 * fx - j01 * fy) / det
        dy = (j00 * fy - j10 * fx) / det
        t = 1.0
        for _ in range(30):
            xn, yn = xi - t * dx, yi - t * dy
            xd, yd, _, _, _, _ = _distort(xn, yn, k1, k2, p1, p2, k3, k4, k5, k6)
            if math.sqrt((xd - ai) ** 2 + (yd - bi) ** 2) < error:
                break
            t *= 0.5
        else:
            xn, yn = xi - dx, yi - dy
        if abs(xn - xi) + abs(yn - yi) <= 1e-16 * (abs(xi) + abs(yi)):
            return xn, yn   # moving by roundings: as near as float64 gets
        xi, yi = xn, yn
    return xi, yi


@njit(cache=True)
def _solved(xi, yi, ai, bi, tol, limit, k):
    """Whether (xi, yi) is the pixel's point's (ai, bi) inverse: its distortion within
    tol of it, its radius below limit, the Jacobian there positive."""
    xd, yd, j00, j01, j10, j11 = _distort(xi, yi, k[0], k[1], k[2], k[3], k[4], k[5], k[6], k[7])
    fx, fy = xd - ai, yd - bi
    return (math.sqrt(fx * fx + fy * fy) <= tol and math.sqrt(xi * xi + yi * yi) < limit
            and j00 * j11 - j01 * j10 > 0.0)


@njit(cache=True)
def _pixel_point(i, Kinv, width):
    """(a, b) = K^-1 (u, v, 1) of pixel i (row-major), u, v its centre."""
    u = (i % width) + 0.5
    v = (i // width) + 0.5
    return Kinv[0, 0] * u + Kinv[0, 1] * v + Kinv[0, 2], Kinv[1, 1] * v + Kinv[1, 2]


@njit(cache=True)
def _store(d, i, R, x, y, z):
    """d[i] = R (x, y, z), row by row."""
    for c in range(3):
        d[i, c] = x * R[c, 0] + y * R[c, 1] + z * R[c, 2]


@njit(cache=True, nogil=True)
def opencv_rays(Kinv, width, R, k, limit, g_limit, reach, tol, stop, max_iterations, d, valid,
                start, end):
    k1, k2, p1, p2, k3, k4, k5, k6 = k[0], k[1], k[2], k[3], k[4], k[5], k[6], k[7]
    tangential = p1 != 0.0 or p2 != 0.0
    scale = 1.0                       # r / rd of the pixel before: the next one's start
    for i in range(start, end):
        ai, bi = _pixel_point(i, Kinv, width)
        rd = math.sqrt(ai * ai + bi * bi)
        # a radial model has no point inside limit where rd >= g(limit); a tangential
        # part may still bring one there: tried, and checked at the end
        if not (rd < g_limit or (tangential and math.isfinite(rd))):
            d[i, 0] = d[i, 1] = d[i, 2] = math.nan
            valid[i] = False
            continue
        bound = stop * tol * (1.0 + rd)
        lo, hi = 0.0, reach
        r = rd * scale
        if not r < reach:             # start inside the bracket
            r = 0.5 * reach
        for _ in range(max_iterations):
            g, dg, _den = _radial(r, k1, k2, k3, k4, k5, k6)
            f = g - rd
            if abs(f) <= bound:
                break
            step, lo, hi = _bracketed_newton(r, f, dg, lo, hi)
            if step == r:
                break
            r = step
        s = r / rd if rd > 0.0 else 1.0
        if rd > 0.0:
            scale = s
        xi, yi = ai * s, bi * s
        if tangential:
            xi, yi = _newton_2d(xi, yi, ai, bi, bound, k, max_iterations)
        ok = _solved(xi, yi, ai, bi, tol * (1.0 + rd), limit, k)
        if tangential and not ok:
            # the radial start may lie by a pole of the rational part, from where the
            # 2D iteration does not come back: again from the pixel's own point
            xi, yi = _newton_2d(ai, bi, ai, bi, bound, k, max_iterations)
            ok = _solved(xi, yi, ai, bi, tol * (1.0 + rd), limit, k)
        valid[i] = ok
        if ok:
            _store(d, i, R, xi, yi, 1.0)
        else:
            d[i, 0] = d[i, 1] = d[i, 2] = math.nan


@njit(cache=True, nogil=True)
def fisheye_rays(Kinv, width, R, k, limit, f_limit, closed, tol, stop, max_iterations, d, valid,
                 start, end):
    k1, k2, k3, k4 = k[0], k[1], k[2], k[3]
    scale = 1.0                       # theta / rd of the pixel before: the next one's start
    for i in range(start, end):
        ai, bi = _pixel_point(i, Kinv, width)
        rd = math.sqrt(ai * ai + bi * bi)
        reach = rd <= f_limit if closed else rd < f_limit
        ok = False
        theta = 0.0
        if reach:
            bound = stop * tol * (1.0 + rd)
            lo, hi = 0.0, limit
            theta = rd * scale
            if not theta < limit:     # start inside the bracket
                theta = 0.5 * limit
            for _ in range(max_iterations):
                s = theta * theta
                f = theta * (1.0 + s * (k1 + s * (k2 + s * (k3 + s * k4)))) - rd
                if abs(f) <= bound:
                    break
                df = 1.0 + s * (3.0 * k1 + s * (5.0 * k2 + s * (7.0 * k3 + s * 9.0 * k4)))
                step, lo, hi = _bracketed_newton(theta, f, df, lo, hi)
                if step == theta:
                    break
                theta = step
            s = theta * theta
            f = theta * (1.0 + s * (k1 + s * (k2 + s * (k3 + s * k4)))) - rd
            ok = abs(f) <= tol * (1.0 + rd)
            if ok and rd > 0.0:
                scale = theta / rd
        valid[i] = ok
        if not ok:
            d[i, 0] = d[i, 1] = d[i, 2] = math.nan
            continue
        sin_over = math.sin(theta) / rd if rd > 0.0 else 1.0
        _store(d, i, R, ai * sin_over, bi * sin_over, math.cos(theta))
