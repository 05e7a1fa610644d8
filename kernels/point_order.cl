/* kernels/point_order.cl: points put in spatial order on the device (kdray/point_order.py),
 * so that the queries of near points run one after another on the same nodes and
 * triangles in the caches.
 *
 *   point_keys     each point's 15-bit key: the Morton code of its cell in a 32^3 grid
 *                  over a box (bit 3 b + k: bit b of the cell's index on axis k), with
 *                  the cells' top bits (12 + k) replaced by the point's side of the
 *                  box's middle where asked (`by_sides`): kdray.points.spatial_order's
 *                  keys, the same numbers
 *   contains_rays  the rays of `contains` taken in an order: slot j's ray is point
 *                  order[j], its origin relative to the tree's origin in its units
 *                  rounded to float once (kdray.ray_input.rays32's arithmetic) and its
 *                  direction the one of the point's octant (kdray.rays.contains_directions)
 *
 * Why on the device: on the host the keys, the sides, the gather of the points into
 * their order and their rounding were four passes over the points on one thread and
 * half of a `contains` of 2^20 random points; here they are two passes on every core.
 * The order changes no answer, only the time; the rays are the host's bit for bit
 * (tests/test_point_order.py).
 *
 * Needs cl_khr_fp64: the points are float64 (kdray/point_order.py keeps the host's way
 * on a device without it).
 */
#pragma OPENCL FP_CONTRACT OFF
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
#include "inline.h"

/* bits 0..4 of c spread to bits 0, 3, 6, 9, 12 (kdray.points.MORTON_SPREAD) */
KD_INLINE
uint kd_spread5(uint c)
{
    return (c & 1u) | ((c & 2u) << 2) | ((c & 4u) << 4) | ((c & 8u) << 6) | ((c & 16u) << 8);
}

/* The cell (0..31) of coordinate x on an axis from lo with scale cells a unit, as
 * spatial_order computes it: in float, clamped to the grid (NaN: cell 0). */
KD_INLINE
uint kd_cell32(double x, float lo, float scale)
{
    float c = ((float)x - lo) * scale;
    return c >= 31.0f ? 31u : (c > 0.0f ? (uint)c : 0u);
}

/* The side of the middle c of point p on each axis (bit k: p's coordinate k >= c's),
 * in double, as kdray.rays._sides computes it. */
KD_INLINE
uint kd_sides(double px, double py, double pz, double cx, double cy, double cz)
{
    return (px >= cx ? 1u : 0u) | (py >= cy ? 2u : 0u) | (pz >= cz ? 4u : 0u);
}

/* keys[k] for points k = 0 .. n - 1 (rows of 3 from element offset of `points`) over
 * the grid from lo with scale cells a unit on each axis; by_sides: the top bits are
 * the point's sides of the middle (cx, cy, cz). Where rel and sides are not NULL
 * (`contains`), also the point relative to the tree's origin in its units, rounded
 * to float once ((p - origin) / scale: kdray.ray_input.rays32's numbers), and its
 * sides (kd_sides), for contains_rays to take in order. */
__kernel void point_keys(__global const double *points, uint offset, uint n,
                         float lo_x, float lo_y, float lo_z, float scale_x, float scale_y,
                         float scale_z, uint by_sides, double cx, double cy, double cz,
                         double origin_x, double origin_y, double origin_z, double scale,
                         __global ushort *keys, __global float *rel, __global uchar *sides)
{
    uint k = (uint)get_global_id(0);
    if (k >= n)
        return;
    __global const double *p = points + offset + 3 * (size_t)k;
    double px = p[0], py = p[1], pz = p[2];
    uint side = kd_sides(px, py, pz, cx, cy, cz);
    uint key = kd_spread5(kd_cell32(px, lo_x, scale_x))
               | kd_spread5(kd_cell32(py, lo_y, scale_y)) << 1
               | kd_spread5(kd_cell32(pz, lo_z, scale_z)) << 2;
    if (by_sides)
        key = (key & 0x0FFFu) | side << 12;
    keys[k] = (ushort)key;
    if (rel) {
        rel[3 * (size_t)k] = (float)((px - origin_x) / scale);
        rel[3 * (size_t)k + 1] = (float)((py - origin_y) / scale);
        rel[3 * (size_t)k + 2] = (float)((pz - origin_z) / scale);
    }
    if (sides)
        sides[k] = (uchar)side;
}

/* Slot j = 0 .. n - 1 of the rays of `contains` taken in an order: point order[j]
 * (from element order_offset of `order`) as point_keys left it, its origin rel's row
 * into o[j] and the direction of its sides, directions[3 s .. 3 s + 2], into d[j].
 * One point a work-item, not in SIMD lanes: scattered reads of rows of 3, which
 * Intel's CPU runtime otherwise makes gathers of 16 at a time, 1.5 times slower. */
__kernel __attribute__((vec_type_hint(float4)))
void contains_rays(__global const float *rel, __global const uchar *sides,
                   __global const uint *order, uint order_offset, uint n,
                   __global const float *directions, __global float *o, __global float *d)
{
    uint j = (uint)get_global_id(0);
    if (j >= n)
        return;
    size_t i = order[order_offset + j], at = 3 * (size_t)j;
    o[at] = rel[3 * i];
    o[at + 1] = rel[3 * i + 1];
    o[at + 2] = rel[3 * i + 2];
    uint s = sides[i];
    d[at] = directions[3 * s];
    d[at + 1] = directions[3 * s + 1];
    d[at + 2] = directions[3 * s + 2];
}
