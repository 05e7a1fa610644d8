/* kernels/world_rays.h: the rays a kernel reads, as trace_rays (render.cl) and the ray
 * queries (queries.cl) take them.
 *
 * The rays' input type: float, origins relative to the tree's origin in its units
 * (the host converted them), or with RAYS_WORLD the caller's rays in world
 * coordinates, origins of type ORIGIN_T and directions of DIRECTION_T (float or
 * double: -D options), converted here as the host would: (float)(((double)o -
 * origin) / scale), (float)d, each one rounding to nearest (the scale is a power of
 * two). The tree's origin is a kernel argument (KD_ORIGIN_PARAMS), not a -D option,
 * so that one program serves every tree of scale 1. Directions are not scaled: t is found in the
 * tree's units, t / scale, and SCALE turns it back when stored.
 *
 * Options (-D): RAYS_WORLD with ORIGIN_T and DIRECTION_T; SCALE and SCALE_INV (a
 * float and a double literal) where the tree's scale is not 1. */
#ifndef KDRAY_WORLD_RAYS_H
#define KDRAY_WORLD_RAYS_H

#ifndef KD_SCALE_INV
#ifdef SCALE
#define KD_SCALE_INV (SCALE_INV)
#else
#define KD_SCALE_INV 1.0
#endif
#endif

#ifdef RAYS_WORLD
#define KD_ORIGIN_T ORIGIN_T
#define KD_DIRECTION_T DIRECTION_T
#define KD_ORIGIN_PARAMS , double origin_x, double origin_y, double origin_z
#define KD_ORIGIN_PASS , origin_x, origin_y, origin_z
#define KD_RAY_ORIGIN(p, i) kd_ray_origin(p, i, (double3)(origin_x, origin_y, origin_z))
KD_INLINE
float3 kd_ray_origin(__global const ORIGIN_T *p, size_t i, double3 origin)
{
    p += 3 * i;
    double x = (double)p[0] - origin.x, y = (double)p[1] - origin.y, z = (double)p[2] - origin.z;
#ifdef SCALE
    return (float3)((float)(x * KD_SCALE_INV), (float)(y * KD_SCALE_INV), (float)(z * KD_SCALE_INV));
#else
    return (float3)((float)x, (float)y, (float)z);
#endif
}
KD_INLINE
float3 kd_ray_direction(__global const DIRECTION_T *p, size_t i)
{
    p += 3 * i;
    return (float3)((float)p[0], (float)p[1], (float)p[2]);
}
#else
#define KD_ORIGIN_T float
#define KD_DIRECTION_T float
#define KD_ORIGIN_PARAMS
#define KD_ORIGIN_PASS
#define KD_RAY_ORIGIN(p, i) kd_load3(p, i)
KD_INLINE float3 kd_ray_direction(__global const float *p, size_t i) { return kd_load3(p, i); }
#endif

#endif
