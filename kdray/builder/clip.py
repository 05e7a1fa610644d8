"""Perfect splits: the boxes of a triangle clipped to the two children of a node.

`clip_split` clips the triangle to the node's box (Sutherland-Hodgman, float64), cuts
the polygon by the split plane and returns each side's box rounded outward to
float32, so that event positions (and with them split planes) are float32 values and
each box is conservative: it holds every point of the triangle inside that child.

To stay conservative under float64 rounding, each plane is pushed out by a tolerance
(`2**-40` of the triangle's largest coordinate, far above float64 error and far below
one float32 step), the box is widened by the same amount before rounding, then
clamped to the node's box and to the triangle's own (exact) box: a triangle lying in
a plane x = c keeps a flat box there, and one that only touches the node box from
outside becomes a flat box on the node's face.

Numba-compiled (`cache=True`; the first call compiles).
"""
import numpy as np
from numba import njit

from .jit import BORROW

_REL_TOL = 2.0 ** -40
_MAX_VERTS = 16          # a triangle clipped by 6 planes has at most 9 vertices


@njit(cache=True)
def polygon_scratch():
    """Scratch buffers for `clip_split`: (3, 16, 3) float64 (two polygons; the third row unused)."""
    return np.empty((3, _MAX_VERTS, 3), dtype=np.float64)


@njit(cache=True)
def round_down(x):
    """Largest float32 <= x (x float64). Steps on the bits: np.nextafter is slow in numba."""
    f = np.float32(x)
    if f > x:
        b = f.view(np.int32)
        if b == 0:
            b = np.int32(-2147483647)                      # +0.0 -> -(smallest subnormal)
        elif b > 0:
            b -= np.int32(1)
        else:
            b += np.int32(1)                               # negative: away from zero
        f = np.int32(b).view(np.float32)
    return f


@njit(cache=True)
def round_up(x):
    """Smallest float32 >= x (x float64)."""
    f = np.float32(x)
    if f < x:
        b = f.view(np.int32)
        if b >= 0:
            b += np.int32(1)                               # positive or +0.0: away from zero
        else:
            b -= np.int32(1)                               # negative: towards zero
        f = np.int32(b).view(np.float32)
    return f


@njit(cache=True, **BORROW)
def clip_polygon(tri, t, box, poly):
    """Sutherland-Hodgman of triangle t against the six planes of `box`, each pushed
    out by the triangle's tolerance.

    Returns (count, index, tol): the polygon is poly[index, :count]; count 0 when
    nothing of the triangle lies in the box.
    """
    mag = 0.0
    crossed = 0                                            # bit per plane to clip against
    for k in range(3):
        lo = min(tri[t, 0, k], tri[t, 1, k], tri[t, 2, k])
        hi = max(tri[t, 0, k], tri[t, 1, k], tri[t, 2, k])
        if hi < box[0, k] or lo > box[1, k]:
            return 0, 0, 0.0                               # boxes disjoint
        if lo < box[0, k]:
            crossed |= 1 << (2 * k)
        if hi > box[1, k]:
            crossed |= 2 << (2 * k)
        mag = max(mag, abs(lo), abs(hi))
    tol = mag * _REL_TOL
    for i in range(3):
        for c in range(3):
            poly[0, i, c] = tri[t, i, c]
    n = 3
    src = 0
    if crossed == 0:
        return n, src, tol                                 # inside: the triangle itself
    for plane_index in range(6):
        if not (crossed >> plane_index) & 1:
            continue
        k = plane_index >> 1
        if plane_index & 1 == 0:
            plane = box[0, k] - tol
            sgn = 1.0
        else:
            plane = box[1, k] + tol
            sgn = -1.0
        dst = 1 - src
        nn = 0
        da = sgn * (poly[src, 0, k] - plane)
        for i in range(n):
            j = i + 1 if i + 1 < n else 0
            db = sgn * (poly[src, j, k] - plane)
            if da >= 0.0:
                poly[dst, nn, 0] = poly[src, i, 0]
                poly[dst, nn, 1] = poly[src, i, 1]
                poly[dst, nn, 2] = poly[src, i, 2]
                nn += 1
            if (da >= 0.0) != (db >= 0.0):
                s = da / (da - db)
                poly[dst, nn, 0] = poly[src, i, 0] + s * (poly[src, j, 0] - poly[src, i, 0])
                poly[dst, nn, 1] = poly[src, i, 1] + s * (poly[src, j, 1] - poly[src, i, 1])
                poly[dst, nn, 2] = poly[src, i, 2] + s * (poly[src, j, 2] - poly[src, i, 2])
                poly[dst, nn, k] = plane
                nn += 1
            da = db
        n = nn
        src = dst
        if n == 0:
            return 0, 0, tol
    return n, src, tol


@njit(cache=True, **BORROW)
def _store(tri, t, lo, hi, box_lo, box_hi, tol, out, k):
    """One axis of a clipped box: widen [lo, hi] by tol, round outward to float32,
    clamp to [box_lo, box_hi] and to the triangle's own extent; False if empty."""
    lo32 = max(round_down(lo - tol), np.float32(box_lo),
               min(tri[t, 0, k], tri[t, 1, k], tri[t, 2, k]))
    hi32 = min(round_up(hi + tol), np.float32(box_hi),
               max(tri[t, 0, k], tri[t, 1, k], tri[t, 2, k]))
    out[0, k] = lo32
    out[1, k] = hi32
    return lo32 <= hi32


@njit(cache=True, **BORROW)
def clip_split(tri, t, box, axis, pos, poly, out_left, out_right):
    """Boxes of triangle t clipped to the children of `box` split at `pos` on `axis`.

    tri : (m, 3, 3) float32;  box : (2, 3) float64 holding float32 values (min, max);
    pos : float32 strictly inside the box;  poly : scratch from `polygon_scratch()`;
    out_left, out_right : (2, 3) float32, written.
    Returns (left_ok, right_ok): False where nothing of the triangle lies in that child.

    The triangle is clipped to the node's box once; each side's box is then the box
    of the polygon's vertices on that side and of its edges' crossings of the plane
    (the plane is pushed towards the other side by tol, on each side).
    """
    n, src, tol = clip_polygon(tri, t, box, poly)
    if n == 0:
        return False, False
    plane_l = pos + tol                  # the left side keeps x <= plane_l
    plane_r = pos - tol                  # the right side keeps x >= plane_r
    # Box accumulators: left (l*) and right (r*) lo and hi, in registers.
    llo0 = llo1 = llo2 = rlo0 = rlo1 = rlo2 = np.inf
    lhi0 = lhi1 = lhi2 = rhi0 = rhi1 = rhi2 = -np.inf
    for i in range(n):
        j = i + 1 if i + 1 < n else 0
        a0 = poly[src, i, 0]
        a1 = poly[src, i, 1]
        a2 = poly[src, i, 2]
        xa = poly[src, i, axis]
        xb = poly[src, j, axis]
        if xa <= plane_l:
            llo0, llo1, llo2 = min(llo0, a0), min(llo1, a1), min(llo2, a2)
            lhi0, lhi1, lhi2 = max(lhi0, a0), max(lhi1, a1), max(lhi2, a2)
        if xa >= plane_r:
            rlo0, rlo1, rlo2 = min(rlo0, a0), min(rlo1, a1), min(rlo2, a2)
            rhi0, rhi1, rhi2 = max(rhi0, a0), max(rhi1, a1), max(rhi2, a2)
        # A crossing of either plane lies on both sides (plane_r <= x <= plane_l).
        for side in range(2):
            plane = plane_l if side == 0 else plane_r
            if (xa < plane) != (xb < plane):
                s = (plane - xa) / (xb - xa)
                y0 = a0 + s * (poly[src, j, 0] - a0)
                y1 = a1 + s * (poly[src, j, 1] - a1)
                y2 = a2 + s * (poly[src, j, 2] - a2)
                if axis == 0:
                    y0 = plane
                elif axis == 1:
                    y1 = plane
                else:
                    y2 = plane
                llo0, llo1, llo2 = min(llo0, y0), min(llo1, y1), min(llo2, y2)
                lhi0, lhi1, lhi2 = max(lhi0, y0), max(lhi1, y1), max(lhi2, y2)
                rlo0, rlo1, rlo2 = min(rlo0, y0), min(rlo1, y1), min(rlo2, y2)
                rhi0, rhi1, rhi2 = max(rhi0, y0), max(rhi1, y1), max(rhi2, y2)
    left_ok = llo0 <= lhi0
    right_ok = rlo0 <= rhi0
    for k in range(3):
        b_lo = box[0, k]
        b_hi = box[1, k]
        l_lo = llo0 if k == 0 else (llo1 if k == 1 else llo2)
        l_hi = lhi0 if k == 0 else (lhi1 if k == 1 else lhi2)
        r_lo = rlo0 if k == 0 else (rlo1 if k == 1 else rlo2)
        r_hi = rhi0 if k == 0 else (rhi1 if k == 1 else rhi2)
        if left_ok:
            left_ok = _store(tri, t, l_lo, l_hi, b_lo, pos if k == axis else b_hi, tol, out_left, k)
        if right_ok:
            right_ok = _store(tri, t, r_lo, r_hi, pos if k == axis else b_lo, b_hi, tol, out_right, k)
    return left_ok, right_ok
