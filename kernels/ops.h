/* kernels/ops.h: plain-operator versions of the OpenCL builtins used in hot loops.
 *
 * PoCL as shipped by pocl-binary-distribution calls builtins such as fabs, fmax,
 * clamp, isnan, select, any and vload as out-of-line functions, with vector arguments
 * passed through memory; in the traversal loops that cost more than the arithmetic
 * (BENCHMARKS.md). These versions are bit for bit the
 * same as the builtins for the values kdray gives them: masks are comparison results
 * (each lane all ones or all zeros), and kd_max/kd_min see no NaN (their callers rule
 * it out first) except where noted.
 */
#ifndef KDRAY_OPS_H
#define KDRAY_OPS_H

#include "inline.h"

KD_INLINE float kd_abs(float x) { return as_float(as_uint(x) & 0x7FFFFFFFu); }
KD_INLINE float kd_max(float a, float b) { return a > b ? a : b; }
KD_INLINE float kd_min(float a, float b) { return a < b ? a : b; }
/* min(max(x, lo), hi) */
KD_INLINE float kd_clamp(float x, float lo, float hi) { return kd_min(kd_max(x, lo), hi); }
KD_INLINE bool kd_isnan(float x) { return x != x; }
/* no component is infinite or NaN (x - x is 0 only for finite x) */
KD_INLINE
bool kd_finite3(float3 v) { return v.x - v.x == 0.0f && v.y - v.y == 0.0f && v.z - v.z == 0.0f; }

/* A direction no ray takes: 0, or so short that the inverse of its largest component
 * overflows (every component below about 2^-128 in magnitude). Such a ray misses, as a
 * zero one does: its shear (1 / d[kz]) is infinite, and a wide walk's slab tests, NaN
 * on every axis (wide.cl, kd_wide_inverse), would take the empty slots of its nodes
 * for met (a crash). Where the largest component's inverse is finite, its slab keeps
 * the walk right (a zero component's inverse is +-inf, not NaN). */
KD_INLINE
bool kd_no_direction(float3 d)
{
    float m = kd_max(kd_abs(d.x), kd_max(kd_abs(d.y), kd_abs(d.z)));
    return !(1.0f / m < INFINITY);
}

KD_INLINE
float3 kd_cross(float3 a, float3 b)
{
    return (float3)(a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x);
}

/* v / |v| for v != 0, scaled by its largest component first so that tiny and huge
 * vectors neither underflow nor overflow (as normalize() does) */
KD_INLINE
float3 kd_normalize(float3 v)
{
    float m = kd_max(kd_abs(v.x), kd_max(kd_abs(v.y), kd_abs(v.z)));
    v = v / m;
    return v / sqrt(v.x * v.x + v.y * v.y + v.z * v.z);
}

/* Element i of an array of 3-float rows (vload3(i, p)) */
KD_INLINE
float3 kd_load3(__global const float *p, size_t i)
{
    p += 3 * i;
    return (float3)(p[0], p[1], p[2]);
}

#endif
