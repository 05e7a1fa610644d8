/* kernels/ray_order.cl: the keys kdray/ray_order.py sorts rays in no order of their own
 * by, so that neighbouring rays enter the scene close together and head the same way.
 *
 *   ray_keys        each ray's 15-bit key: the octant of its direction (bit 12 + k:
 *                   component k negative) over the Morton code of the cell of a 16^3
 *                   grid over the scene's box where the ray enters it (bit 3 b + k: bit
 *                   b of the cell's index on axis k); or, for rays whose directions
 *                   follow their origins (toward a point light or along the sun's
 *                   direction from points on a mesh: kdray/ray_order.py's cell keys),
 *                   the Morton code of that cell in a 32^3 grid, with no octant
 *   direction_keys  for rays from one point (or a few close together): each ray's
 *                   16-bit key, the Morton code of its direction's cell in a 256 x 256
 *                   grid over the octahedral map of directions (bit 2 b: bit b of the
 *                   cell's column, bit 2 b + 1: of its row), so that rays taken in key
 *                   order point alike, as a camera's neighbouring pixels do
 *
 * The entry point is o + t d at the largest of 0 and the three near slab planes' t:
 * the origin itself for a ray that starts in the box, else where a ray from outside
 * comes in (rays from around a scene, a sensor's far off). A ray that misses the box,
 * or has an infinite or NaN entry, gets clamped cells: any key is a right one, since
 * no hit depends on the order, only the time.
 *
 * Options (-D): ORIGIN_T, DIRECTION_T (float or double): the rays' types, as the
 * kernels that then trace them read them. The box and the rays are in one frame (world
 * coordinates, or the tree's: the caller's choice); an origin is taken relative to
 * the box's low corner in its own type, then in float.
 */
#pragma OPENCL FP_CONTRACT OFF
#include "inline.h"

#if defined(cl_khr_fp64)
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
#endif

/* bits 0..4 of c spread to bits 0, 3, 6, 9, 12 */
KD_INLINE
uint kd_spread5(uint c)
{
    return (c & 1u) | ((c & 2u) << 2) | ((c & 4u) << 4) | ((c & 8u) << 6) | ((c & 16u) << 8);
}

/* The cell (0 .. last) of offset x along an axis whose cells are 1 / cells_per apart:
 * NaN and anything beyond the box go to the nearest end. */
KD_INLINE
uint kd_cell(float x, float cells_per, float last)
{
    float c = x * cells_per;
    return c >= last ? (uint)last : (c > 0.0f ? (uint)c : 0u);
}

/* keys[k] for rays k = 0 .. n - 1: origin k * o_step (o_step 0: one origin for all) and
 * direction k, from element o_offset and d_offset of their buffers (kdray/device_tree.py,
 * _input_buffer): the Morton code of the cell of a side^3 grid where the ray enters
 * the box, o + t d at the largest of 0 and the near slab planes' t (the origin for a
 * ray inside it), with octant 1 over the octant of its direction (kdray/ray_order.py:
 * side 16 with the octant, its ray_keys; 32 without, its cell_keys). lo: the box's low
 * corner, in the origins' type (a float32 corner of a scene 1e6 from 0 is off by
 * several of its cells); size: its extent along each axis. One ray a work-item (a
 * loop over rays in each took 2.5x as long on Intel's runtime). */
__kernel void ray_keys(__global const ORIGIN_T *origins, __global const DIRECTION_T *directions,
                       uint o_offset, uint d_offset, uint o_step, uint n,
                       ORIGIN_T lo_x, ORIGIN_T lo_y, ORIGIN_T lo_z, float size_x,
                       float size_y, float size_z, uint side, uint octant,
                       __global ushort *keys)
{
    origins += o_offset;
    directions += d_offset;
    float size[3] = {size_x, size_y, size_z};
    float cells = (float)side, last = (float)(side - 1u);
    float cells_per[3] = {cells / size_x, cells / size_y, cells / size_z};
    uint k = (uint)get_global_id(0);
    if (k < n) {
        size_t at = 3 * (size_t)k * o_step;
        float o[3] = {(float)(origins[at] - lo_x), (float)(origins[at + 1] - lo_y),
                      (float)(origins[at + 2] - lo_z)};
        float d[3] = {(float)directions[3 * (size_t)k], (float)directions[3 * (size_t)k + 1],
                      (float)directions[3 * (size_t)k + 2]};
        /* the entry: t past every near slab plane (the low one where d >= 0, else
         * the high one); fmax drops a NaN (d 0 on that axis) */
        float t = 0.0f;
        for (uint a = 0; a < 3u; a++)
            t = fmax(t, ((d[a] < 0.0f ? size[a] : 0.0f) - o[a]) / d[a]);
        uint key = 0u;
        for (uint a = 0; a < 3u; a++) {
            key |= kd_spread5(kd_cell(o[a] + t * d[a], cells_per[a], last)) << a;
            if (octant)
                key |= (d[a] < 0.0f ? 1u : 0u) << (12u + a);
        }
        keys[k] = (ushort)key;
    }
}

/* bits 0..7 of c spread to the even bits 0, 2, .., 14 */
KD_INLINE
uint kd_spread8(uint c)
{
    c = (c | (c << 4)) & 0x0F0Fu;
    c = (c | (c << 2)) & 0x3333u;
    return (c | (c << 1)) & 0x5555u;
}

/* The cell (0..255) of x in [-1, 1] on a side of 256 cells: NaN and anything beyond
 * go to the nearest end. */
KD_INLINE
uint kd_cell256(float x)
{
    float c = (x + 1.0f) * 128.0f;
    return c >= 255.0f ? 255u : (c > 0.0f ? (uint)c : 0u);
}

/* keys[k] for rays k = 0 .. n - 1: direction k from element d_offset of its buffer.
 * The octahedral map: d / (|x| + |y| + |z|) has (u, v) = (x, y) on the upper half
 * (z >= 0); the lower half is folded out over the square's corners, (u, v) = ((1 -
 * |y|) sign x, (1 - |x|) sign y). Neighbouring directions have neighbouring cells (but
 * across the fold), and the cells' sides lie on the planes x = 0 and y = 0, so a cell
 * holds one octant's directions but along the fold. A zero or non-finite direction
 * gets a clamped cell: any key is a right one. */
__kernel void direction_keys(__global const DIRECTION_T *directions, uint d_offset, uint n,
                             __global ushort *keys)
{
    directions += d_offset;
    uint k = (uint)get_global_id(0);
    if (k < n) {
        float x = (float)directions[3 * (size_t)k], y = (float)directions[3 * (size_t)k + 1],
              z = (float)directions[3 * (size_t)k + 2];
        float s = fabs(x) + fabs(y) + fabs(z);
        float u = x / s, v = y / s;
        if (z < 0.0f) {
            float fu = (1.0f - fabs(v)) * (u < 0.0f ? -1.0f : 1.0f);
            v = (1.0f - fabs(u)) * (v < 0.0f ? -1.0f : 1.0f);
            u = fu;
        }
        keys[k] = (ushort)(kd_spread8(kd_cell256(u)) | (kd_spread8(kd_cell256(v)) << 1));
    }
}
