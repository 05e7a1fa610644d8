/* kernels/hit_rows.cl: `intersections`' hits gathered into their rows (kdray/rays.py,
 * _gathered): ray i's hits, found in slots first[i] .. first[i] + count - 1 of the
 * first pass's slots (queries.cl, list_first: each work-item's hits one after another,
 * in no order of rays), copied to rows offsets[i] .. offsets[i + 1] - 1 of the
 * compressed rows, t, u and v, and triangle, as they are.
 *
 * One ray a work-item, not in SIMD lanes (vec_type_hint): most rays have no hit or
 * one, and a group's lanes would make gathers of scattered slots. On the host the same
 * copy was an index array over the hits and three numpy takes on one thread, about
 * twice the time.
 *
 * A ray's run may reach past the slots written (a ray with more hits than its slots,
 * whose whole list the host puts in place afterwards): such slots are read as the last
 * one, n_slots - 1 (numpy's take with mode "clip"), never past the buffers.
 *
 * Options (-D): FIRST_T (uint or long): the type of `first`.
 */
#include "inline.h"

__kernel __attribute__((vec_type_hint(float4)))
void hit_rows(__global const FIRST_T *first, uint first_at, __global const long *offsets,
              uint offsets_at, uint n, ulong n_slots, __global const float *t,
              __global const float *uv, __global const uint *prim, __global float *t_out,
              __global float *uv_out, __global uint *prim_out)
{
    uint i = (uint)get_global_id(0);
    if (i >= n)
        return;
    long a = offsets[offsets_at + i], b = offsets[offsets_at + i + 1u];
    ulong s = (ulong)first[first_at + i];
    for (long k = a; k < b; k++, s++) {
        ulong from = s < n_slots ? s : n_slots - 1u;
        t_out[k] = t[from];
        uv_out[2 * k] = uv[2 * from];
        uv_out[2 * k + 1] = uv[2 * from + 1];
        prim_out[k] = prim[from];
    }
}
