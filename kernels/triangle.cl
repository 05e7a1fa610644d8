/* kernels/triangle.cl: the watertight ray/triangle test of Woop, Benthin & Wald 2013,
 * "Watertight Ray/Triangle Intersection" (JCGT 2(1)); the shape of pbrt-v4's
 * IntersectTriangle.
 *
 * The ray is sheared so that it runs along +z from the origin; the triangle's
 * vertices, taken relative to the ray origin and sheared the same way, are tested
 * with 2D edge functions U, V, W. A point on an edge shared by two triangles gives
 * the same edge value (up to sign) in both, so no ray leaks between them. Needs
 * FP_CONTRACT OFF: a fused multiply-add would round the two triangles' shared edge
 * function differently.
 *
 * Hit convention: P = (1 - u - v) v0 + u v1 + v v2, u = V / det, v = W / det,
 * t = T / det in units of |direction|; a hit needs t_min < t < t_max, t larger than
 * the bound on its own rounding error (so t = 0 never counts, even rounded), and
 * (t, tri) before the best hit so far in the order "smaller t, then lower input id of
 * the triangle" (kd_before). Whether a triangle is hit therefore depends on the ray and the
 * triangle alone, and the nearest hit does not depend on the order triangles are
 * tested in: a packet, a scalar traversal and a tree over fewer triangles agree.
 */
#ifndef KDRAY_TRIANGLE_CL
#define KDRAY_TRIANGLE_CL

#pragma OPENCL FP_CONTRACT OFF
#include "ops.h"
#ifdef cl_khr_fp64
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
#endif

/* With REFINE: how far along the ray, in multiples of its t, a triangle's vertices
 * may reach for the float test's t to decide a hit (farther, t is recomputed in
 * double). T sums products of the scaled z of the vertices: their rounding errors,
 * relative to t, grow with that reach (the leading term of t's error bound is
 * 3 gamma(3) max_z); at 32 the bound is about 2^-16 of t. */
#define KD_FAR_REACH 32.0f

/* gamma(n) = n u / (1 - n u), u = 2^-24: the bound on n float32 roundings (pbrt). */
#define KD_GAMMA(n) ((float)(n) * 0x1p-24f / (1.0f - (float)(n) * 0x1p-24f))

/* Component k (0, 1, 2) of v, without indexing a private array. */
KD_INLINE float kd_comp(float3 v, uint k) { return k == 0u ? v.x : (k == 1u ? v.y : v.z); }

/* Per-ray constants of the shear. */
typedef struct {
    uint kx, ky, kz;                     /* kz: largest |d| component; kx, ky: the others */
    float Sx, Sy, Sz;                    /* d[kx] / d[kz], d[ky] / d[kz], 1 / d[kz] */
} RayShear;

KD_INLINE
RayShear ray_shear(float3 d)
{
    RayShear s;
    /* kz = argmax |d| (first of equals), kx and ky cyclic after it */
    float3 a = fabs(d);
    s.kz = (a.x >= a.y) ? ((a.x >= a.z) ? 0u : 2u) : ((a.y >= a.z) ? 1u : 2u);
    s.kx = (s.kz == 2u) ? 0u : s.kz + 1u;
    s.ky = (s.kx == 2u) ? 0u : s.kx + 1u;
    float dz = kd_comp(d, s.kz);
    /* Swap kx and ky to keep the triangle's winding when the ray runs along -kz */
    if (dz < 0.0f) {
        uint k = s.kx;
        s.kx = s.ky;
        s.ky = k;
    }
    s.Sx = kd_comp(d, s.kx) / dz;
    s.Sy = kd_comp(d, s.ky) / dz;
    s.Sz = 1.0f / dz;
    return s;
}

/* The bound on t's rounding error (pbrt-v4, after Woop et al.; the reasoning is at
 * its use in intersect_triangle), written once for float, double and a packet's
 * floatP: declares `delta_t` of type T from the sheared coordinates Ax .. Cz and edge
 * functions U, V, W in scope, the shear's Sz and |det|. ABS, MAX and GAMMA are the
 * type's absolute value, maximum and gamma(n); the operations and their order are the
 * same for all. */
#define KD_T_ERROR_BOUND(T, ABS, MAX, GAMMA, Sz, det_abs, delta_t)                          \
    T delta_t;                                                                             \
    {                                                                                      \
        T max_zu = MAX(ABS(Az), MAX(ABS(Bz), ABS(Cz)));                                    \
        T max_z = ABS(Sz) * max_zu;                                                        \
        T max_x = MAX(ABS(Ax), MAX(ABS(Bx), ABS(Cx)));                                     \
        T max_y = MAX(ABS(Ay), MAX(ABS(By), ABS(Cy)));                                     \
        T max_e = MAX(ABS(U), MAX(ABS(V), ABS(W)));                                        \
        T delta_z = GAMMA(3) * max_z;                                                      \
        T delta_x = GAMMA(5) * (max_x + max_zu);                                           \
        T delta_y = GAMMA(5) * (max_y + max_zu);                                           \
        T delta_e = (T)(2) * (GAMMA(2) * max_x * max_y + delta_y * max_x + delta_x * max_y); \
        delta_t = (T)(3) * (GAMMA(3) * max_e * max_z + delta_e * max_z + delta_z * max_e)   \
                  / (det_abs);                                                             \
    }

#ifdef cl_khr_fp64
/* x rounded to float with its sign kept: a nonzero x too small for a float gives
 * +-FLT_MIN, not 0. An edge function recomputed in double (intersect_triangle) keeps
 * its exact sign so, and a triangle whose three vertices lie strictly on one side of
 * a line through the ray is never hit (packet.cl, kd_block_culls, relies on it). */
KD_INLINE
float kd_signed_float(double x)
{
    float f = (float)x;
    return f == 0.0f && x != 0.0 ? (x > 0.0 ? FLT_MIN : -FLT_MIN) : f;
}

#define KD_GAMMA_D(n) ((double)(n) * 0x1p-53 / (1.0 - (double)(n) * 0x1p-53))

KD_INLINE double kd_comp_d(double3 v, uint k) { return k == 0u ? v.x : (k == 1u ? v.y : v.z); }

/* The test's t recomputed in double from the same float inputs (the ray's shear
 * constants taken as exact); *bound: the same error bound in double's unit roundoff
 * (t > *bound: t is certainly positive). */
KD_INLINE
double kd_t_double(const RayShear *s, float3 o, float3 p0, float3 p1, float3 p2, double *bound)
{
    double3 od = convert_double3(o);
    double3 A = convert_double3(p0) - od;
    double3 B = convert_double3(p1) - od;
    double3 C = convert_double3(p2) - od;
    double Sx = s->Sx, Sy = s->Sy, Sz = s->Sz;
    double Az = kd_comp_d(A, s->kz), Bz = kd_comp_d(B, s->kz), Cz = kd_comp_d(C, s->kz);
    double Ax = kd_comp_d(A, s->kx) - Sx * Az, Ay = kd_comp_d(A, s->ky) - Sy * Az;
    double Bx = kd_comp_d(B, s->kx) - Sx * Bz, By = kd_comp_d(B, s->ky) - Sy * Bz;
    double Cx = kd_comp_d(C, s->kx) - Sx * Cz, Cy = kd_comp_d(C, s->ky) - Sy * Cz;
    double U = Cx * By - Cy * Bx, V = Ax * Cy - Ay * Cx, W = Bx * Ay - By * Ax;
    double det = U + V + W;
    if (det == 0.0) {
        *bound = INFINITY;
        return 0.0;
    }
    double t = (U * (Sz * Az) + V * (Sz * Bz) + W * (Sz * Cz)) / det;
    KD_T_ERROR_BOUND(double, fabs, fmax, KD_GAMMA_D, Sz, fabs(det), delta_t)
    *bound = delta_t;
    return t;
}

/* kd_t_double's t exceeds its bound: the test's t is certainly positive. */
KD_INLINE
bool kd_t_certified_double(const RayShear *s, float3 o, float3 p0, float3 p1, float3 p2)
{
    double bound;
    double t = kd_t_double(s, o, p0, p1, p2, &bound);
    return t > bound;
}
#endif

#if defined(REFINE) && defined(cl_khr_fp64)
/* x is neither infinite nor NaN (isfinite(), which PoCL calls out of line: ops.h) */
KD_INLINE bool kd_finite_d(double x) { return x - x == 0.0; }

/* (a . b) in kd_refine_hit's order, for any floating type */
#define KD_DOT(ax, ay, az, bx, by, bz) (((ax) * (bx) + (ay) * (by)) + (az) * (bz))

/* kd_refine_hit's arithmetic, written once for double and a packet's doubleP (the
 * same operations in the same order: bit for bit the same): declares tt, uu, vv of
 * type T from the ray (ox .. dz) and the vertices (p0x .. p2z), all of type T and
 * all converted exactly from float or double. */
#define KD_REFINE_PLANE(T, ox, oy, oz, dx, dy, dz, p0x, p0y, p0z, p1x, p1y, p1z,          \
                        p2x, p2y, p2z, tt, uu, vv)                                       \
    T tt, uu, vv;                                                                        \
    {                                                                                    \
        T ax = (p0x) - (ox), ay = (p0y) - (oy), az = (p0z) - (oz);                       \
        T e1x = (p1x) - (p0x), e1y = (p1y) - (p0y), e1z = (p1z) - (p0z);                 \
        T e2x = (p2x) - (p0x), e2y = (p2y) - (p0y), e2z = (p2z) - (p0z);                 \
        T nx = e1y * e2z - e1z * e2y, ny = e1z * e2x - e1x * e2z;                        \
        T nz = e1x * e2y - e1y * e2x;                                                    \
        tt = KD_DOT(nx, ny, nz, ax, ay, az) / KD_DOT(nx, ny, nz, (dx), (dy), (dz));      \
        /* the hit point relative to p0 */                                               \
        T hx = tt * (dx) - ax, hy = tt * (dy) - ay, hz = tt * (dz) - az;                 \
        T nn = KD_DOT(nx, ny, nz, nx, ny, nz);                                           \
        uu = KD_DOT(hy * e2z - hz * e2y, hz * e2x - hx * e2z, hx * e2y - hy * e2x,       \
                    nx, ny, nz) / nn;                                                    \
        vv = KD_DOT(e1y * hz - e1z * hy, e1z * hx - e1x * hz, e1x * hy - e1y * hx,       \
                    nx, ny, nz) / nn;                                                    \
    }

/* The refined values tt, uu, vv (double) taken into *t, *u, *v when they are usable:
 * t inside (t_min, t_max) and u, v finite (see kd_refine_hit). */
KD_INLINE
void kd_take_refined(double tt, double uu, double vv, float t_min, float t_max, float *t,
                     float *u, float *v)
{
    float tf = (float)tt;
    if (!(tf > t_min && tf < t_max && kd_finite_d(uu) && kd_finite_d(vv)))
        return;
    /* within the triangle up to rounding: clamped to its closure */
    float uf = kd_clamp((float)uu, 0.0f, 1.0f);
    float vf = kd_clamp((float)vv, 0.0f, 1.0f - uf);
    *t = tf;
    *u = uf;
    *v = vf;
}

/* The found hit's t, u, v recomputed in double from the ray (o, d: the float ray
 * traced, or the caller's double ray it was rounded from) and the triangle's float
 * vertices (all relative to the tree's origin): t from the triangle's plane, u and v
 * as the barycentrics of the point o + t d in it. The watertight test's edge functions
 * are float products of coordinates relative to the ray's origin; when the triangle
 * is much larger than t (a ground plane under a small object, a wall beside the eye)
 * they cancel, and t and u, v lose as many float roundings as the ratio. In double
 * the same cancellation costs as many double roundings: far below one of float's.
 * Which triangle is hit is not changed; the test's values stay when the plane's are
 * not finite (a ray in the plane) or t falls outside (t_min, t_max). */
KD_INLINE
void kd_refine_hit(double3 o, double3 d, float3 p0, float3 p1, float3 p2, float t_min,
                   float t_max, float *t, float *u, float *v)
{
    KD_REFINE_PLANE(double, o.x, o.y, o.z, d.x, d.y, d.z,
                    (double)p0.x, (double)p0.y, (double)p0.z, (double)p1.x, (double)p1.y,
                    (double)p1.z, (double)p2.x, (double)p2.y, (double)p2.z, tt, uu, vv)
    kd_take_refined(tt, uu, vv, t_min, t_max, t, u, v);
}
#endif

/* (t, tri) comes before (t_best, tri_best): nearer, or as near with a lower input id
 * (tri_ids: the device's triangle order is the tree's leaf order, not the input's). */
KD_INLINE
bool kd_before(float t, uint tri, float t_best, uint tri_best, __global const uint *tri_ids)
{
    return t < t_best || (t == t_best && tri_ids[tri] < tri_ids[tri_best]);
}

/* The sign an edge function e = F(P, Q) = Qx Py - Qy Px takes when the ray is moved by
 * an infinitesimal step delta = (1, 0) and then a smaller one (0, 1) in the sheared
 * plane (e itself where it is not 0): the derivatives of F along them are Qy - Py and
 * Px - Qx. Two triangles that share the edge see it reversed, F(Q, P) = -F(P, Q) bit
 * for bit and so are these, so a ray through the edge enters exactly one of them; at a
 * vertex the moved ray lies inside exactly one triangle of a fan that covers the
 * vertex once (the rasterizer's top-left rule, written as a perturbation). Only signs
 * matter: the values stay the test's. */
KD_INLINE
float kd_tie(float e, float qy_py, float px_qx)
{
    return e != 0.0f ? e : (qy_py != 0.0f ? qy_py : px_qx);
}

/* The float edge function e = fl(fl(p) - fl(q)) of the products p and q has the sign
 * of p - q: its error is under 2^-24 (|p| + |q|) + 2^-24 |e| (two products and a
 * difference, each rounded once), so an e larger than 2^-22 (|p| + |q|) (and than the
 * smallest normal float, for products that underflowed) cannot have the wrong sign. */
#define KD_EDGE_SURE(e, p, q) \
    (kd_abs(e) > 0x1p-22f * (kd_abs(p) + kd_abs(q)) + 0x1p-126f)

/* The triangle (p0, p1, p2) in the ray's sheared frame (ray_shear, o its origin):
 * declares Az, Bz, Cz (unscaled z: scaled later, only for candidate hits) and Ax, Ay,
 * Bx, By, Cx, Cy (sheared), floats, written once for intersect_triangle and those that
 * must see the triangle exactly as it does (queries.cl, kd_facing). */
#define KD_SHEAR_VERTICES(s, o, p0, p1, p2)                                                \
    float3 A = (p0) - (o);                                                                 \
    float3 B = (p1) - (o);                                                                 \
    float3 C = (p2) - (o);                                                                 \
    float Az = kd_comp(A, (s)->kz), Bz = kd_comp(B, (s)->kz), Cz = kd_comp(C, (s)->kz);    \
    float Ax = kd_comp(A, (s)->kx) - (s)->Sx * Az;                                         \
    float Ay = kd_comp(A, (s)->ky) - (s)->Sy * Az;                                         \
    float Bx = kd_comp(B, (s)->kx) - (s)->Sx * Bz;                                         \
    float By = kd_comp(B, (s)->ky) - (s)->Sy * Bz;                                         \
    float Cx = kd_comp(C, (s)->kx) - (s)->Sx * Cz;                                         \
    float Cy = kd_comp(C, (s)->ky) - (s)->Sy * Cz;

/* Intersect the ray (o, shear) with triangle `tri` (p0, p1, p2), all relative to the
 * tree's origin. On a hit with t_min < t < t_max that comes before (t_best,
 * tri_best), write t, u, v and return true.
 * crossing: the count's rule (queries.cl): the edge functions' signs are exact (from
 * double where the device has it) and one that is exactly 0 takes kd_tie's sign, so a
 * point of an edge or a vertex shared by consistently oriented triangles is hit in
 * exactly one of them; else a point on an edge is hit in every triangle that has it
 * (the nearest hit's rule: no ray leaks between triangles). */
KD_INLINE
bool intersect_triangle(const RayShear *s, float3 o, float3 p0, float3 p1, float3 p2, uint tri,
                        float t_min, float t_max, float t_best, uint tri_best,
                        __global const uint *tri_ids, bool crossing, float *t_out,
                        float *u_out, float *v_out)
{
    KD_SHEAR_VERTICES(s, o, p0, p1, p2)

    /* Scaled barycentric coordinates (edge functions) */
    float U = Cx * By - Cy * Bx;
    float V = Ax * Cy - Ay * Cx;
    float W = Bx * Ay - By * Ax;

    /* Ue, Ve, We: the edge functions the count's rule decides by */
#ifdef cl_khr_fp64
    /* On an edge, recompute in double: the products of floats are exact there, so
     * the sign of each edge function is exact (and kept: kd_signed_float). The count's
     * rule takes every sign exact, so that two triangles never see their shared edge
     * with two signs: a float edge function's where it exceeds its rounding bound
     * (KD_EDGE_SURE), else all three from double. */
    bool unsure = crossing && !(KD_EDGE_SURE(U, Cx * By, Cy * Bx)
                                && KD_EDGE_SURE(V, Ax * Cy, Ay * Cx)
                                && KD_EDGE_SURE(W, Bx * Ay, By * Ax));
    bool zero = U == 0.0f || V == 0.0f || W == 0.0f;
    float Ue = U, Ve = V, We = W;
    if (unsure || zero) {
        Ue = kd_signed_float((double)Cx * (double)By - (double)Cy * (double)Bx);
        Ve = kd_signed_float((double)Ax * (double)Cy - (double)Ay * (double)Cx);
        We = kd_signed_float((double)Bx * (double)Ay - (double)By * (double)Ax);
        if (zero) {                       /* both rules' values on an edge */
            U = Ue;
            V = Ve;
            W = We;
        }
    }
#else
    float Ue = U, Ve = V, We = W;
#endif

    if (crossing) {
        /* Miss unless the moved ray is strictly inside (kd_tie): U = F(B, C),
         * V = F(C, A), W = F(A, B) */
        float Us = kd_tie(Ue, Cy - By, Bx - Cx);
        float Vs = kd_tie(Ve, Ay - Cy, Cx - Ax);
        float Ws = kd_tie(We, By - Ay, Ax - Bx);
        if (!((Us > 0.0f && Vs > 0.0f && Ws > 0.0f) || (Us < 0.0f && Vs < 0.0f && Ws < 0.0f)))
            return false;
        /* t, u, v from the nearest hit's rule's edge functions where that rule hits the
         * triangle too: one t a triangle for both rules, so that a range's ends keep
         * or drop it alike (count <= intersections); else from the exact ones */
        if (!((U >= 0.0f && V >= 0.0f && W >= 0.0f) || (U <= 0.0f && V <= 0.0f && W <= 0.0f))) {
            U = Ue;
            V = Ve;
            W = We;
        }
    } else if (!((U >= 0.0f && V >= 0.0f && W >= 0.0f) || (U <= 0.0f && V <= 0.0f && W <= 0.0f))) {
        /* Miss when the edge functions differ in sign (written so that NaN misses) */
        return false;
    }
    float det = U + V + W;
    if (det == 0.0f)
        return false;

    /* Hit distance; compared after the division only, so that the decision is one
     * rounding of T / det whatever the best hit so far is */
    float T = U * (s->Sz * Az) + V * (s->Sz * Bz) + W * (s->Sz * Cz);
    float det_abs = kd_abs(det);
    float t = T / det;
#if defined(REFINE) && defined(cl_khr_fp64)
    /* With REFINE the t of a triangle that reaches much farther along the ray than t
     * (KD_FAR_REACH; its vertices' coordinates relative to the ray's origin cancel in
     * T) is taken from double before it is compared, so that it neither misses nor
     * wins for its rounding; double's bound decides whether it is positive. */
    bool in_double = !(kd_abs(s->Sz) * kd_max(kd_abs(Az), kd_max(kd_abs(Bz), kd_abs(Cz)))
                       <= KD_FAR_REACH * kd_abs(t));
    KD_T_ERROR_BOUND(float, kd_abs, kd_max, KD_GAMMA, s->Sz, det_abs, delta_t)
    /* ... unless t and its error bound lie below t_min: the exact t of the same inputs,
     * which double's t rounds, lies below it too, so double's t would miss (a
     * rounded sum is at least t_min when the exact one is: no false miss). A ray
     * leaving a surface meets its own triangle so, behind its origin. */
    if (in_double && t + delta_t < t_min)
        return false;
    if (in_double) {
        double bound;
        double t_d = kd_t_double(s, o, p0, p1, p2, &bound);
        if (!(t_d > bound))
            return false;
        t = (float)t_d;
    }
    if (!(t > t_min && t < t_max && kd_before(t, tri, t_best, tri_best, tri_ids)))
        return false;
    if (!in_double && !(t > delta_t)) {
#else
    if (!(t > t_min && t < t_max && kd_before(t, tri, t_best, tri_best, tri_ids)))
        return false;

    /* t must exceed a conservative bound on its own rounding error (pbrt-v4, after
     * Woop et al.), so a ray starting on a surface never hits that surface at a
     * rounded t just above 0. Magnitudes of the sheared coordinates bound the error
     * of each step: the shear (x, y, with |Sx|, |Sy| <= 1 times the unscaled z, in
     * units of length), the edge functions (e), then T (scaled z, in units of t).
     * pbrt adds the scaled z to x and y, which is only right for |d| near 1. */
    KD_T_ERROR_BOUND(float, kd_abs, kd_max, KD_GAMMA, s->Sz, det_abs, delta_t)
    if (!(t > delta_t)) {
#endif
        /* The bound is a worst case; grazing hits of thin triangles reach it while
         * their t is fine. Decide again in double, whose bound is 2^29 times smaller:
         * a ray that starts on the triangle still fails it. */
#ifdef cl_khr_fp64
        if (!kd_t_certified_double(s, o, p0, p1, p2))
            return false;
#else
        return false;
#endif
    }
    *t_out = t;
    *u_out = V / det;
    *v_out = W / det;
    return true;
}

#endif
