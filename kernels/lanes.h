/* kernels/lanes.h: the vector types of a packet of KD_PACKET rays (8 or 16 lanes) and
 * the operations packet.cl does on them.
 *
 * A packet's width is its rays' lanes in one vector register: 8 floats in an AVX2
 * register, 16 in an AVX-512 one. The Tracer picks the width from the device's native
 * float vector width (kdray/work_sizes.py, default_packet); the kernels are the same code
 * either way, so every lane makes the same decisions at either width.
 *
 * floatP, intP, uintP: KD_PACKET lanes of float, int (masks: each lane all ones or all
 * zeros) and uint. KD_LANE_INDEX (intP) and KD_LANE_INDEX_U (uintP): 0, 1, 2, ...
 *
 * The operations are plain operators, not builtins, for the reason ops.h gives; they
 * are bit for bit the builtins for the values kdray gives them.
 */
#ifndef KDRAY_LANES_H
#define KDRAY_LANES_H

#include "inline.h"

#ifndef KD_PACKET
#define KD_PACKET 8
#endif

#if KD_PACKET == 16
typedef float16 floatP;
typedef int16 intP;
typedef uint16 uintP;
#define as_floatP as_float16
#define as_intP as_int16
#define as_uintP as_uint16
#define convert_floatP convert_float16
#define vloadP vload16
#define KD_LANE_INDEX (int16)(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15)
#define KD_LANE_INDEX_U (uint16)(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15)
#elif KD_PACKET == 8
typedef float8 floatP;
typedef int8 intP;
typedef uint8 uintP;
#define as_floatP as_float8
#define as_intP as_int8
#define as_uintP as_uint8
#define convert_floatP convert_float8
#define vloadP vload8
#define KD_LANE_INDEX (int8)(0, 1, 2, 3, 4, 5, 6, 7)
#define KD_LANE_INDEX_U (uint8)(0, 1, 2, 3, 4, 5, 6, 7)
#else
#error "KD_PACKET must be 8 or 16"
#endif

/* doubleP: KD_PACKET lanes of double, where the device has doubles (the includer
 * enables cl_khr_fp64) */
#ifdef cl_khr_fp64
#if KD_PACKET == 16
typedef double16 doubleP;
#define convert_doubleP convert_double16
#else
typedef double8 doubleP;
#define convert_doubleP convert_double8
#endif
#endif

/* p[i] of each lane's index i, as one vector of type T (a vector literal of plain
 * loads: what the CPU runtimes compile best, PoCL's included) */
#if KD_PACKET == 16
#define KD_GATHER_AS(T, p, i)                                                            \
    (T)((p)[(i).s0], (p)[(i).s1], (p)[(i).s2], (p)[(i).s3], (p)[(i).s4], (p)[(i).s5],    \
        (p)[(i).s6], (p)[(i).s7], (p)[(i).s8], (p)[(i).s9], (p)[(i).sa], (p)[(i).sb],    \
        (p)[(i).sc], (p)[(i).sd], (p)[(i).se], (p)[(i).sf])
typedef ulong16 ulongP;
#define convert_uintP convert_uint16
#else
#define KD_GATHER_AS(T, p, i)                                                            \
    (T)((p)[(i).s0], (p)[(i).s1], (p)[(i).s2], (p)[(i).s3], (p)[(i).s4], (p)[(i).s5],    \
        (p)[(i).s6], (p)[(i).s7])
typedef ulong8 ulongP;
#define convert_uintP convert_uint8
#endif
#define KD_GATHER(p, i) KD_GATHER_AS(uintP, p, i)

/* The lanes whose bits are set in `bits` (lane l: bit l), as a mask. */
KD_INLINE
intP kd_maskP(uint bits)
{
    return -as_intP(((uintP)(bits) >> KD_LANE_INDEX_U) & (uintP)(1u));
}

KD_INLINE floatP kd_absP(floatP x) { return as_floatP(as_uintP(x) & (uintP)(0x7FFFFFFFu)); }
/* lanes of b where mask m is set, else of a (select(a, b, m)), as OpenCL's vector
 * ternary: Oclgrind 21.10 gets the same select written with & and | wrong, in the
 * packets' shear axes and barycentrics (tests/repros/oclgrind_vector_select.py) */
KD_INLINE floatP kd_selectP(floatP a, floatP b, intP m) { return m ? b : a; }
KD_INLINE intP kd_selectPi(intP a, intP b, intP m) { return m ? b : a; }
KD_INLINE uintP kd_selectPu(uintP a, uintP b, intP m) { return m ? b : a; }
KD_INLINE floatP kd_maxP(floatP a, floatP b) { return kd_selectP(b, a, a > b); }
KD_INLINE floatP kd_minP(floatP a, floatP b) { return kd_selectP(b, a, a < b); }
KD_INLINE floatP kd_clampP(floatP x, floatP lo, floatP hi) { return kd_minP(kd_maxP(x, lo), hi); }

/* The lanes of x or-ed together: halves or-ed down to one lane */
KD_INLINE
uint kd_orP(uintP x)
{
#if KD_PACKET == 16
    uint8 e = x.lo | x.hi;
#else
    uint8 e = x;
#endif
    uint4 a = e.lo | e.hi;
    uint2 c = a.lo | a.hi;
    return c.x | c.y;
}

/* some lane of mask m is set */
KD_INLINE
bool kd_anyP(intP m)
{
    return kd_orP(as_uintP(m)) != 0u;
}

/* Lane bits of mask m: bit l set where lane l is. */
KD_INLINE
uint kd_bitsP(intP m)
{
#if KD_PACKET == 16
    uintP w = (uintP)(1u, 2u, 4u, 8u, 16u, 32u, 64u, 128u, 256u, 512u, 1024u, 2048u, 4096u,
                      8192u, 16384u, 32768u);
#else
    uintP w = (uintP)(1u, 2u, 4u, 8u, 16u, 32u, 64u, 128u);
#endif
    return kd_orP(as_uintP(m) & w);
}

/* The lowest lane set in *bits (lane l: bit l, at least one set), cleared there. */
KD_INLINE
uint kd_take_lane(uint *bits)
{
    uint l = 31u - clz(*bits & (0u - *bits));
    *bits &= *bits - 1u;
    return l;
}

/* the number of lanes set in mask m */
KD_INLINE
uint kd_countP(intP m)
{
    uintP one = as_uintP(m) >> 31;
#if KD_PACKET == 16
    uint8 e = one.lo + one.hi;
#else
    uint8 e = one;
#endif
    uint4 a = e.lo + e.hi;
    uint2 c = a.lo + a.hi;
    return c.x + c.y;
}

/* the smallest and largest lane of x (no NaN): halves compared down to one lane */
KD_INLINE
void kd_rangeP(floatP x, float *lo_out, float *hi_out)
{
#if KD_PACKET == 16
    float8 hi = x.hi > x.lo ? x.hi : x.lo, lo = x.hi < x.lo ? x.hi : x.lo;
#else
    float8 hi = x, lo = x;
#endif
    float4 a = hi.hi > hi.lo ? hi.hi : hi.lo, b = lo.hi < lo.lo ? lo.hi : lo.lo;
    float2 c = a.hi > a.lo ? a.hi : a.lo, e = b.hi < b.lo ? b.hi : b.lo;
    *hi_out = c.y > c.x ? c.y : c.x;
    *lo_out = e.y < e.x ? e.y : e.x;
}

/* the largest lane of x less the smallest (no NaN) */
KD_INLINE
float kd_spanP(floatP x)
{
    float lo, hi;
    kd_rangeP(x, &lo, &hi);
    return hi - lo;
}

#endif
