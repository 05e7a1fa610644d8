/* kernels/packet.cl: packets of KD_PACKET rays (8 or 16) traversed together, a lane
 * each of the vector types floatP, intP, uintP (lanes.h) (Wald, Slusallek, Benthin &
 * Wagner 2001, "Interactive Rendering with Coherent Ray Tracing": the packet visits
 * the union of its rays' nodes, each ray masked to its own).
 *
 * Why: CPU runtimes run a work-item's data-dependent loop scalar, one eighth or one
 * sixteenth of a core's vector width (BENCHMARKS.md); the same loop on vector lanes
 * runs at full width: 8 lanes fill an AVX2 register, 16 an AVX-512 one. Coherent rays
 * (a block of 4 x 2 or 4 x 4 pixels) share most nodes, so a packet costs little more
 * than a ray.
 *
 * Each lane makes exactly the decisions the scalar traversal (traverse.cl) makes for
 * its ray: the same t_split, slack, child ranges and early exit, and its triangle
 * tests are the scalar test's arithmetic on vectors (same operations, same order,
 * FP_CONTRACT OFF). Since a hit depends only on the ray and the triangle (the order
 * (t, index), triangle.cl), a lane's result equals the scalar kernel's bit for bit.
 *
 * A lane leaves the packet and is traced again by the scalar kernel when it cannot
 * follow the packet's order: at a node where it needs both children and its near child
 * is not the packet's (origins on different sides of the plane; a lane needing one
 * child goes along whatever the order), when it lies in a split plane (t_split NaN: the
 * scalar kernel's passes handle it), or when the packet's stack is full.
 *
 * A packet whose origins lie far apart (kd_alone) is not traversed as a packet at all:
 * each of its rays is traced alone, as the lanes that leave are. In packet programs
 * the scalar kernel tests a leaf KD_PACKET triangles at a time (kd_ray_leaf).
 *
 * The packet's stack is a plain one of PACKET_STACK_SIZE entries (node, ranges, lanes):
 * the Tracer makes it the tree's depth + 1, so it is never full on a valid tree.
 */
#ifndef KDRAY_PACKET_CL
#define KDRAY_PACKET_CL

#pragma OPENCL FP_CONTRACT OFF
#include "layout.h"
#include "triangle.cl"
#include "traverse.cl"

/* the packet's width: PACKET (-D PACKET=8 or 16) */
#define KD_PACKET PACKET
#include "lanes.h"

#ifndef PACKET_STACK_SIZE
#define PACKET_STACK_SIZE 64
#endif

#ifdef STATS
/* per lane: x = interior nodes, y = leaves, z = triangle tests (as traverse.cl) */
typedef struct { uintP x, y, z; } KdPacketStats;
#define KD_PSTAT(field, mask) ((*pstats).field += as_uintP(mask) & (uintP)(1u))
#define KD_PSTATS_PARAM , KdPacketStats *pstats
#define KD_PSTATS_ARG , pstats
#else
#define KD_PSTAT(field, mask)
#define KD_PSTATS_PARAM
#define KD_PSTATS_ARG
#endif

/* A leaf's triangles culled for a whole packet of one origin before its lanes test
 * them (kd_block_culls): with double precision, which keeps the edge functions' signs
 * exact; not on PoCL, where neither its speed nor its frames' size (kdray/work_sizes.py,
 * POCL_ITEM_BYTES) have been measured with it (PoCL 3.0 does not run on the AVX-512
 * CPUs it was written on). */
#if defined(cl_khr_fp64) && !defined(KD_PLAIN_VECTOR_OPS)
#define KD_CULL
#define KD_CULLS(r) ((r)->cull)
#else
#define KD_CULLS(r) false
#endif

typedef struct {
    floatP okx, oky, okz;                /* origin components along each lane's kx, ky, kz */
    floatP Sx, Sy, Sz;                   /* shear constants (RayShear) per lane */
    intP kx, ky, kz;                     /* shear axes per lane */
    bool uniform;                        /* every lane has the same axes ... */
    uint ukx, uky, ukz;                  /* ... these */
    floatP o[3], d[3];                   /* origin and direction per axis, for the planes */
    floatP d_inv[3];                     /* 1 / d per axis, when by_inverse */
    bool by_inverse;                     /* planes' t by multiplying with d_inv (KD_INVERSE_MIN) */
    floatP t_min, t_max;                 /* the rays' range: t_min < t < t_max */
    bool shared_o;                       /* every lane that is on has origin uo (a camera's eye) */
    float uo[3];
#ifdef KD_CULL
    bool cull;                           /* shared_o and uniform: kd_block_culls applies */
    float Sx_lo, Sx_hi, Sy_lo, Sy_hi;    /* the range of Sx and Sy over the lanes that are on */
#endif
} KdPacket;

/* A vector and its lanes (OpenCL C allows reading a union member other than the one
 * written last); cheaper on PoCL than vloadn/vstoren on private arrays. */
typedef union { floatP v; float s[KD_PACKET]; } KdFP;
typedef union { intP v; int s[KD_PACKET]; } KdIP;
typedef union { uintP v; uint s[KD_PACKET]; } KdUP;

typedef struct {
    floatP t;                            /* nearest t so far; t_max while none */
    floatP V, W, det;                    /* of the nearest hit: u = V / det, v = W / det */
    uintP tri;                           /* its triangle index, KD_NO_HIT while none */
} KdPacketHit;

/* Where the KD_PACKET (ray, triangle) pairs of a test come from, for the rare lanes decided
 * again in double: the packet's rays r and one triangle (its numbers from p, kd_tri_base),
 * or, where r is 0, one ray (shear s, origin o) and KD_PACKET triangles (q: 9 vectors,
 * v0 x y z, v1 x y z, v2 x y z). */
typedef struct {
    const KdPacket *r;
    __global const float *p;
    const RayShear *s;
    float3 o;
    const KdFP *q;
} KdPairs;

/* Lane l's shear and origin. */
KD_INLINE
void kd_lane_shear(const KdPacket *r, uint l, RayShear *s, float3 *o)
{
    KdIP kx, ky, kz;
    KdFP Sx, Sy, Sz, ox, oy, oz;
    kx.v = r->kx; ky.v = r->ky; kz.v = r->kz;
    Sx.v = r->Sx; Sy.v = r->Sy; Sz.v = r->Sz;
    ox.v = r->o[0]; oy.v = r->o[1]; oz.v = r->o[2];
    s->kx = (uint)kx.s[l]; s->ky = (uint)ky.s[l]; s->kz = (uint)kz.s[l];
    s->Sx = Sx.s[l]; s->Sy = Sy.s[l]; s->Sz = Sz.s[l];
    *o = (float3)(ox.s[l], oy.s[l], oz.s[l]);
}

#ifdef cl_khr_fp64
/* kd_t_double of lane l's (ray, triangle) pair: the lane's ray against src's one
 * triangle (src->r not 0), or src's one ray against the lane's triangle. */
KD_INLINE
double kd_pair_t_double(const KdPairs *src, uint l, double *bound)
{
    if (src->r) {
        RayShear s;
        float3 o;
        kd_lane_shear(src->r, l, &s, &o);
        return kd_t_double(&s, o, kd_base_vertex(src->p, 0), kd_base_vertex(src->p, 1),
                           kd_base_vertex(src->p, 2), bound);
    }
    const KdFP *q = src->q;
    float3 p0 = (float3)(q[0].s[l], q[1].s[l], q[2].s[l]);
    float3 p1 = (float3)(q[3].s[l], q[4].s[l], q[5].s[l]);
    float3 p2 = (float3)(q[6].s[l], q[7].s[l], q[8].s[l]);
    return kd_t_double(src->s, src->o, p0, p1, p2, bound);
}
#endif

/* The test of triangle.cl on KD_PACKET (ray, triangle) pairs, one per lane, for the lanes in
 * `act`: the vertices P along each lane's shear axes (kx, ky, kz), the ray's origin
 * along them and its shear constants, its range (t_min, t_max) and best hit so far
 * (best_t, best_tri), the triangle's index triP (tri_ids: input ids, for ties).
 * Returns the lanes that hit before their best, with t, V, W and det (u = V / det,
 * v = W / det). */
KD_INLINE  /* a call would pass its vectors through memory */
intP kd_test_pairs(floatP P0x, floatP P0y, floatP P0z, floatP P1x, floatP P1y, floatP P1z,
                   floatP P2x, floatP P2y, floatP P2z,
                   floatP okx, floatP oky, floatP okz, floatP Sx, floatP Sy, floatP Sz,
                   floatP t_min, floatP t_max, floatP best_t, uintP best_tri, uintP triP,
                   __global const uint *tri_ids, intP act, const KdPairs *src,
                   floatP *t_out, floatP *V_out, floatP *W_out, floatP *det_out)
{
    /* Vertices relative to the ray origins, sheared (intersect_triangle's steps) */
    floatP Az = P0z - okz, Bz = P1z - okz, Cz = P2z - okz;
    floatP Ax = (P0x - okx) - Sx * Az;
    floatP Ay = (P0y - oky) - Sy * Az;
    floatP Bx = (P1x - okx) - Sx * Bz;
    floatP By = (P1y - oky) - Sy * Bz;
    floatP Cx = (P2x - okx) - Sx * Cz;
    floatP Cy = (P2y - oky) - Sy * Cz;

    floatP U = Cx * By - Cy * Bx;
    floatP V = Ax * Cy - Ay * Cx;
    floatP W = Bx * Ay - By * Ax;
#ifdef cl_khr_fp64
    intP zero = act & ((U == 0.0f) | (V == 0.0f) | (W == 0.0f));
    if (kd_anyP(zero)) {
        /* lane by lane (double vector to float vector conversions crash PoCL's LLVM) */
        KdFP ax, ay, bx, by, cx, cy, u, v, w;
        KdIP z;
        ax.v = Ax; ay.v = Ay; bx.v = Bx; by.v = By; cx.v = Cx; cy.v = Cy;
        u.v = U; v.v = V; w.v = W; z.v = zero;
        for (uint l = 0; l < KD_PACKET; l++) {
            if (z.s[l]) {
                u.s[l] = kd_signed_float((double)cx.s[l] * (double)by.s[l] - (double)cy.s[l] * (double)bx.s[l]);
                v.s[l] = kd_signed_float((double)ax.s[l] * (double)cy.s[l] - (double)ay.s[l] * (double)cx.s[l]);
                w.s[l] = kd_signed_float((double)bx.s[l] * (double)ay.s[l] - (double)by.s[l] * (double)ax.s[l]);
            }
        }
        U = u.v;
        V = v.v;
        W = w.v;
    }
#endif
    intP cand = act & (((U >= 0.0f) & (V >= 0.0f) & (W >= 0.0f))
                       | ((U <= 0.0f) & (V <= 0.0f) & (W <= 0.0f)));
    if (!kd_anyP(cand))
        return cand;
    floatP det = U + V + W;
    floatP T = U * (Sz * Az) + V * (Sz * Bz) + W * (Sz * Cz);
    floatP det_abs = kd_absP(det);
    floatP t = T / det;
    cand &= (det != 0.0f);
#if defined(REFINE) && defined(cl_khr_fp64)
    /* t of a far-reaching triangle from double before it is compared (intersect_triangle) */
    intP in_double = cand & !(kd_absP(Sz) * kd_maxP(kd_absP(Az), kd_maxP(kd_absP(Bz), kd_absP(Cz)))
                              <= KD_FAR_REACH * kd_absP(t));
    /* the bound on t's rounding error (triangle.cl): a far-reaching triangle whose t
     * and bound lie below t_min misses without double (intersect_triangle says why) */
    KD_T_ERROR_BOUND(floatP, kd_absP, kd_maxP, KD_GAMMA, Sz, det_abs, delta_t)
    intP below = in_double & (t + delta_t < t_min);
    cand &= ~below;
    in_double &= ~below;
    if (kd_anyP(in_double)) {
        KdIP in_l, ok_l;
        KdFP t_l;
        in_l.v = in_double; t_l.v = t;
        ok_l.v = (intP)(-1);
        for (uint l = 0; l < KD_PACKET; l++) {
            if (!in_l.s[l])
                continue;
            double bound;
            double t_d = kd_pair_t_double(src, l, &bound);
            if (t_d > bound)
                t_l.s[l] = (float)t_d;
            else
                ok_l.s[l] = 0;
        }
        t = t_l.v;
        cand &= ok_l.v;
    }
#endif
    cand &= (t > t_min) & (t < t_max);
    intP tie = cand & (t == best_t);     /* rare: compare input ids (kd_before) */
    cand &= t < best_t;
    if (kd_anyP(tie)) {
        KdIP tie_l, win;
        KdUP a, b;
        tie_l.v = tie; a.v = triP; b.v = best_tri;
        win.v = (intP)(0);
        for (uint l = 0; l < KD_PACKET; l++)
            if (tie_l.s[l] && tri_ids[a.s[l]] < tri_ids[b.s[l]])
                win.s[l] = -1;
        cand |= win.v;
    }
    if (!kd_anyP(cand))
        return cand;

#if defined(REFINE) && defined(cl_khr_fp64)
    intP doubt = cand & ~in_double & !(t > delta_t);
#else
    /* The bound on t's rounding error (triangle.cl) */
    KD_T_ERROR_BOUND(floatP, kd_absP, kd_maxP, KD_GAMMA, Sz, det_abs, delta_t)
    intP doubt = cand & !(t > delta_t);
#endif
    if (kd_anyP(doubt)) {
        KdIP doubt_l, ok_l;
        doubt_l.v = doubt;
        ok_l.v = (intP)(0);
#ifdef cl_khr_fp64
        for (uint l = 0; l < KD_PACKET; l++) {
            double bound;
            if (doubt_l.s[l] && kd_pair_t_double(src, l, &bound) > bound)
                ok_l.s[l] = -1;
        }
#endif
        cand &= ~doubt | ok_l.v;
    }
    *t_out = t;
    *V_out = V;
    *W_out = W;
    *det_out = det;
    return cand;
}

/* Component k of p for each lane (k per lane: 0, 1, 2). */
KD_INLINE
floatP kd_pickP(float3 p, intP k)
{
    return kd_selectP(kd_selectP((floatP)(p.x), (floatP)(p.y), k == 1), (floatP)(p.z), k == 2);
}

/* The vertices of one triangle (its numbers from p = kd_tri_base(tris, tri)) along
 * each lane's shear axes: P[3 i + c] is vertex i's coordinate kx, ky, kz (c = 0, 1, 2). */
KD_INLINE
void kd_lane_vertices(const KdPacket *r, __global const float *p, floatP *P)
{
    if (r->uniform) {
        /* the packet's axes index the vertices' coordinates: loaded, not selected */
        __global const float *px = p + KD_TRI_BLOCK * r->ukx, *py = p + KD_TRI_BLOCK * r->uky,
                             *pz = p + KD_TRI_BLOCK * r->ukz;
        for (uint i = 0; i < 3u; i++) {
            P[3u * i] = (floatP)(px[3u * i * KD_TRI_BLOCK]);
            P[3u * i + 1u] = (floatP)(py[3u * i * KD_TRI_BLOCK]);
            P[3u * i + 2u] = (floatP)(pz[3u * i * KD_TRI_BLOCK]);
        }
    } else {
        for (uint i = 0; i < 3u; i++) {
            float3 v = kd_base_vertex(p, i);
            P[3u * i] = kd_pickP(v, r->kx);
            P[3u * i + 1u] = kd_pickP(v, r->ky);
            P[3u * i + 2u] = kd_pickP(v, r->kz);
        }
    }
}

/* Every lane in `act` against triangle `tri` (its numbers from p = kd_tri_base(tris,
 * tri): v0 x y z, v1 x y z, v2 x y z, KD_TRI_BLOCK apart); lanes where it hits before
 * their best hit take it. */
KD_INLINE
void kd_packet_intersect(const KdPacket *r, __global const float *p, uint tri,
                         __global const uint *tri_ids, intP act, KdPacketHit *h)
{
    floatP P[9];
    kd_lane_vertices(r, p, P);
    floatP P0x = P[0], P0y = P[1], P0z = P[2], P1x = P[3], P1y = P[4], P1z = P[5];
    floatP P2x = P[6], P2y = P[7], P2z = P[8];
    KdPairs src;
    src.r = r; src.p = p;
    uintP triP = (uintP)(tri);
    floatP t, V, W, det;
    intP cand = kd_test_pairs(P0x, P0y, P0z, P1x, P1y, P1z, P2x, P2y, P2z,
                              r->okx, r->oky, r->okz, r->Sx, r->Sy, r->Sz, r->t_min, r->t_max,
                              h->t, h->tri, triP, tri_ids, act, &src, &t, &V, &W, &det);
    if (!kd_anyP(cand))
        return;
    h->t = kd_selectP(h->t, t, cand);
    h->V = kd_selectP(h->V, V, cand);
    h->W = kd_selectP(h->W, W, cand);
    h->det = kd_selectP(h->det, det, cand);
    h->tri = kd_selectPu(h->tri, triP, cand);
}

/* Triangles first .. first + KD_PACKET - 1 (a leaf's run from `first`, layout.h) into
 * the lanes of q: 9 vectors, v0 x y z, v1 x y z, v2 x y z. `first` is a multiple of
 * KD_PACKET (device_triangles starts leaves there), so the run lies in one block: a
 * vector load of each of its 9 rows. Lanes past the leaf's end hold its padding
 * (zero triangles; the callers mask them off). On PoCL, which calls vload out of line
 * (ops.h), number by number. */
KD_INLINE
void kd_gather_tris(__global const float *tris, uint first, KdFP *q)
{
    __global const float *p = kd_tri_base(tris, first);
#pragma unroll
    for (uint c = 0; c < 9; c++) {
#ifdef KD_PLAIN_VECTOR_OPS
#pragma unroll
        for (uint j = 0; j < KD_PACKET; j++)
            q[c].s[j] = p[c * KD_TRI_BLOCK + j];
#else
        q[c].v = vloadP(0, p + c * KD_TRI_BLOCK);
#endif
    }
}

/* One ray (shear s, origin o, range t_min < t < t_max, best hit so far best_t,
 * best_tri) against up to KD_PACKET triangles at once, the lanes of q in `valid`
 * (indices triP): the pairs and arithmetic of kd_packet_intersect with rays and
 * triangles swapped. Returns the lanes whose triangle is hit before the best, with
 * each lane's t, V, W, det (u = V / det, v = W / det): every hit of the block when
 * the best is (t_max, KD_NO_HIT) (queries.cl). */
KD_INLINE
intP kd_ray_block_all(const RayShear *s, float3 o, float t_min, float t_max, float best_t,
                      uint best_tri, const KdFP *q, uintP triP, intP valid,
                      __global const uint *tri_ids, floatP *t, floatP *V, floatP *W,
                      floatP *det)
{
    uint ax = s->kx, ay = s->ky, az = s->kz;
    KdPairs src;
    src.r = 0; src.s = s; src.o = o; src.q = q;
    return kd_test_pairs(q[ax].v, q[ay].v, q[az].v, q[3 + ax].v, q[3 + ay].v, q[3 + az].v,
                         q[6 + ax].v, q[6 + ay].v, q[6 + az].v,
                         (floatP)(kd_comp(o, ax)), (floatP)(kd_comp(o, ay)),
                         (floatP)(kd_comp(o, az)),
                         (floatP)(s->Sx), (floatP)(s->Sy), (floatP)(s->Sz),
                         (floatP)(t_min), (floatP)(t_max), (floatP)(best_t),
                         (uintP)(best_tri), triP, tri_ids, valid, &src, t, V, W, det);
}

/* kd_ray_block_all's first candidate in the order (t, index): whether there is one,
 * then its t, V, W, det and index. */
KD_INLINE
bool kd_ray_block(const RayShear *s, float3 o, float t_min, float t_max, float best_t,
                  uint best_tri, const KdFP *q, uintP triP, intP valid,
                  __global const uint *tri_ids, float *t_out, float *V_out, float *W_out,
                  float *det_out, uint *tri_out)
{
    floatP t, V, W, det;
    intP cand = kd_ray_block_all(s, o, t_min, t_max, best_t, best_tri, q, triP, valid,
                                 tri_ids, &t, &V, &W, &det);
    if (!kd_anyP(cand))
        return false;
    /* the first candidate in the order (t, index); each one is before the best */
    KdFP tl, Vl, Wl, dl;
    KdUP il;
    tl.v = t; Vl.v = V; Wl.v = W; dl.v = det; il.v = triP;
    /* the candidates' lanes only, in ascending order (most blocks have one) */
    uint lanes = kd_bitsP(cand);
    uint best = kd_take_lane(&lanes);
    while (lanes) {
        uint j = kd_take_lane(&lanes);
        if (kd_before(tl.s[j], il.s[j], tl.s[best], il.s[best], tri_ids))
            best = j;
    }
    *t_out = tl.s[best];
    *V_out = Vl.s[best];
    *W_out = Wl.s[best];
    *det_out = dl.s[best];
    *tri_out = il.s[best];
    return true;
}

/* A single ray's leaf (traverse.cl's kd_intersect_leaf in packet programs): its
 * triangles KD_PACKET at a time against the ray (kd_ray_block), each block's first hit
 * before the best kept, so the hit is kd_intersect_leaf's bit for bit. */
KD_INLINE
void kd_ray_leaf(KdNode leaf, __global const float *tris, __global const uint *tri_ids,
                 const RayShear *shear, float3 o, float t_min, float t_max,
                 Hit *hit KD_STATS_PARAM)
{
    uint count = kd_n_prims(leaf);
    uint first = kd_leaf_offset(leaf);
    for (uint i0 = 0; i0 < count; i0 += KD_PACKET) {
        uint m = count - i0 < KD_PACKET ? count - i0 : KD_PACKET;
        KdFP q[9];
        kd_gather_tris(tris, first + i0, q);
#ifdef STATS
        (*stats).z += m;
#endif
        float t, V, W, det;
        uint tri;
        if (kd_ray_block(shear, o, t_min, t_max, hit->t, hit->tri, q,
                         (uintP)(first + i0) + KD_LANE_INDEX_U, KD_LANE_INDEX < (intP)((int)m),
                         tri_ids, &t, &V, &W, &det, &tri)) {
            hit->t = t;
            hit->u = V / det;
            hit->v = W / det;
            hit->tri = tri;
#ifdef ANY_HIT
            return;                       /* any hit: the leaf's other runs are not needed */
#endif
        }
    }
}

#ifndef KD_LANE_RATIO
#define KD_LANE_RATIO 0.5f
#endif
/* KD_LANE_RATIO for packets that cull (r->cull): their packet tests cost less */
#ifndef KD_CULL_LANE_RATIO
#define KD_CULL_LANE_RATIO 0.25f
#endif

#ifdef KD_CULL
/* Which of the KD_PACKET triangles in q (9 vectors, v0 x y z, v1 x y z, v2 x y z; as
 * kd_gather_tris) no lane of packet r (r->cull: one origin, one set of shear axes)
 * can hit, decided for all lanes at once by four tests of each triangle's vertices:
 * whether every lane's sheared x (Ax, Bx, Cx of kd_test_pairs) is > 0, every one < 0,
 * every sheared y > 0, or every one < 0.
 *
 * Why it is exact (a lane's test of a culled triangle finds no candidate):
 * - A lane's sheared x of a vertex is (P.x - o.x) - S * (P.z - o.z), S its Sx; the
 *   differences are the same in every lane. Rounding is monotone, so for z > 0 the
 *   least over the lanes is at the largest S and the greatest at the smallest S (the
 *   other way round for z < 0; for z = 0 it is the same in all). The test computes
 *   just those, with the lanes' operations: what holds for them holds for every lane.
 * - When a lane's three vertices lie strictly on one side of a line through its ray
 *   (x = 0 or y = 0 in sheared space), their exact edge functions are all 0 (det 0)
 *   or of both strict signs (they are sines of angle differences that sum to 0). The
 *   float edge functions have those signs or are 0 (monotone rounding), and 0 is
 *   recomputed in double with its exact sign kept (kd_signed_float). So the lane's
 *   signs differ, or det is 0, and the triangle is not a candidate. */
KD_INLINE
intP kd_block_culls(const KdPacket *r, const KdFP *q)
{
    floatP ox = (floatP)(r->uo[r->ukx]), oy = (floatP)(r->uo[r->uky]), oz = (floatP)(r->uo[r->ukz]);
    intP x_above = (intP)(-1), x_below = (intP)(-1), y_above = (intP)(-1), y_below = (intP)(-1);
#pragma unroll
    for (uint v = 0; v < 3; v++) {
        floatP ax = q[3 * v + r->ukx].v - ox;
        floatP ay = q[3 * v + r->uky].v - oy;
        floatP az = q[3 * v + r->ukz].v - oz;
        intP pos = az > 0.0f;
        /* the least x over the lanes: at the largest S where z > 0 */
        floatP sx_least = kd_selectP((floatP)(r->Sx_lo), (floatP)(r->Sx_hi), pos);
        floatP sx_most = kd_selectP((floatP)(r->Sx_hi), (floatP)(r->Sx_lo), pos);
        floatP sy_least = kd_selectP((floatP)(r->Sy_lo), (floatP)(r->Sy_hi), pos);
        floatP sy_most = kd_selectP((floatP)(r->Sy_hi), (floatP)(r->Sy_lo), pos);
        x_above &= ax - sx_least * az > 0.0f;
        x_below &= ax - sx_most * az < 0.0f;
        y_above &= ay - sy_least * az > 0.0f;
        y_below &= ay - sy_most * az < 0.0f;
    }
    return x_above | x_below | y_above | y_below;
}

/* kd_block_culls' constants for packet r, whose lanes `on` (first: the first of them)
 * have origin r->uo and axes r->ukx, r->uky, r->ukz when r->cull. */
KD_INLINE
void kd_cull_setup(KdPacket *r, intP on, uint first)
{
    r->cull = r->shared_o && r->uniform;
    if (!r->cull)
        return;
    /* the lanes that are off take the first lane's shear */
    KdFP Sx, Sy;
    Sx.v = r->Sx;
    Sy.v = r->Sy;
    kd_rangeP(kd_selectP((floatP)(Sx.s[first]), r->Sx, on), &r->Sx_lo, &r->Sx_hi);
    kd_rangeP(kd_selectP((floatP)(Sy.s[first]), r->Sy, on), &r->Sy_lo, &r->Sy_hi);
}

#endif

/* Leaf: every lane in `act` tests the leaf's triangles. Where few lanes reach a leaf
 * (most leaves, once triangles are smaller than a packet's footprint) the leaf is
 * tested ray by ray against P = KD_PACKET triangles at a time: a * ceil(n / P) tests
 * of P lanes instead of n, for a lanes and n triangles; KD_LANE_RATIO accounts for
 * gathering the triangles. Else a packet of one origin and shear (r->cull) takes the
 * triangles KD_PACKET at a time, leaves out those no lane can hit (kd_block_culls) and
 * tests the others with all its lanes; its few candidates cost less than the
 * ray-by-ray tests down to KD_CULL_LANE_RATIO (BENCHMARKS.md, "Kernel parameters"). The pairs and
 * their arithmetic are the same every way. */
KD_INLINE
void kd_packet_leaf(KdNode leaf, __global const float *tris, __global const uint *tri_ids,
                    const KdPacket *r, intP act, KdPacketHit *h KD_PSTATS_PARAM)
{
    uint count = kd_n_prims(leaf);
    if (count == 0u)
        return;
    uint first = kd_leaf_offset(leaf);
    uint a = kd_countP(act);
    float ratio = KD_CULLS(r) ? KD_CULL_LANE_RATIO : KD_LANE_RATIO;
    if ((float)(a * ((count + KD_PACKET - 1) / KD_PACKET)) < ratio * (float)count) {
        /* each lane's ray, range and best hit taken out of the vectors once, carried
         * over the leaf's blocks, and put back once */
        KdIP act_l;
        KdFP t_min_l, t_max_l, ht, hV, hW, hd;
        KdUP htri;
        act_l.v = act;
        t_min_l.v = r->t_min; t_max_l.v = r->t_max;
        ht.v = h->t; htri.v = h->tri;
        uint lane[KD_PACKET];
        RayShear shear[KD_PACKET];
        float3 o[KD_PACKET];
        float best_t[KD_PACKET], best_V[KD_PACKET], best_W[KD_PACKET], best_det[KD_PACKET];
        uint best_tri[KD_PACKET];
        bool found[KD_PACKET];
        uint n_on = 0;
        for (uint l = 0; l < KD_PACKET; l++) {
            if (!act_l.s[l])
                continue;
            lane[n_on] = l;
            kd_lane_shear(r, l, &shear[n_on], &o[n_on]);
            best_t[n_on] = ht.s[l];
            best_tri[n_on] = htri.s[l];
            found[n_on] = false;
            n_on++;
        }
        for (uint i0 = 0; i0 < count; i0 += KD_PACKET) {
            uint m = count - i0 < KD_PACKET ? count - i0 : KD_PACKET;
            KdFP q[9];
            kd_gather_tris(tris, first + i0, q);
            /* lane j is triangle first + i0 + j */
            uintP triP = (uintP)(first + i0) + KD_LANE_INDEX_U;
            intP valid = KD_LANE_INDEX < (intP)((int)m);
            for (uint k = 0; k < n_on; k++) {
                uint l = lane[k];
#ifdef ANY_HIT
                if (found[k])
                    continue;                /* any hit: its first is enough */
#endif
#ifdef STATS
                KdUP z;
                z.v = (*pstats).z;
                z.s[l] += m;
                (*pstats).z = z.v;
#endif
                float t, V, W, det;
                uint tri;
                if (kd_ray_block(&shear[k], o[k], t_min_l.s[l], t_max_l.s[l], best_t[k],
                                 best_tri[k], q, triP, valid, tri_ids, &t, &V, &W, &det, &tri)) {
                    best_t[k] = t; best_V[k] = V; best_W[k] = W; best_det[k] = det;
                    best_tri[k] = tri;
                    found[k] = true;
                }
            }
        }
        hV.v = h->V; hW.v = h->W; hd.v = h->det;
        for (uint k = 0; k < n_on; k++) {
            if (!found[k])
                continue;
            uint l = lane[k];
            ht.s[l] = best_t[k]; hV.s[l] = best_V[k]; hW.s[l] = best_W[k];
            hd.s[l] = best_det[k]; htri.s[l] = best_tri[k];
        }
        h->t = ht.v; h->V = hV.v; h->W = hW.v; h->det = hd.v; h->tri = htri.v;
        return;
    }
#ifdef KD_CULL
    if (r->cull) {
        /* KD_PACKET triangles at a time: those no lane can hit left out at once
         * (kd_block_culls), the others tested by every lane */
        for (uint i0 = 0; i0 < count; i0 += KD_PACKET) {
            uint m = count - i0 < KD_PACKET ? count - i0 : KD_PACKET;
            KdFP q[9];
            kd_gather_tris(tris, first + i0, q);
#ifdef STATS
            /* culled or not, as the scalar kernel counts them */
            (*pstats).z += (as_uintP(act) & (uintP)(1u)) * m;
#endif
            uint keep = kd_bitsP((KD_LANE_INDEX < (intP)((int)m)) & ~kd_block_culls(r, q));
            while (keep != 0u) {
                uint j = kd_take_lane(&keep);
                uint tri = first + i0 + j;
                kd_packet_intersect(r, kd_tri_base(tris, tri), tri, tri_ids, act, h);
#ifdef ANY_HIT
                /* any hit: a lane with one is done, the leaf once every lane is */
                act &= as_intP(h->tri == (uintP)(KD_NO_HIT));
                if (!kd_anyP(act))
                    return;
#endif
            }
        }
        return;
    }
#endif
    for (uint i = 0; i < count; i++) {
        uint tri = first + i;
        KD_PSTAT(z, act);
        kd_packet_intersect(r, kd_tri_base(tris, tri), tri, tri_ids, act, h);
#ifdef ANY_HIT
        act &= as_intP(h->tri == (uintP)(KD_NO_HIT));
        if (!kd_anyP(act))
            return;
#endif
    }
}

/* One inner node's step for the packet's lanes in `act` (its plane: axis, split; the
 * slack bounds of the lanes' ranges: t_lo, t_hi): the children each lane needs, by
 * traverse.cl's rules, in the packet's one order. `leave`: the lanes that cannot
 * follow the packet here (a ray in the plane, t_split NaN, or one needing both
 * children in the other order), in neither need. */
typedef struct {
    floatP t_split;
    intP need_first, need_second;        /* first: the near child in the packet's order */
    intP leave;
    bool below_first;                    /* the packet's order */
} KdPacketStep;

KD_INLINE
KdPacketStep kd_packet_step(const KdPacket *r, uint axis, float split, intP act, floatP t_lo,
                            floatP t_hi)
{
    KdPacketStep s;
    floatP o_k = r->o[axis];
    floatP d_k = r->d[axis];
    floatP t_split = r->by_inverse ? (split - o_k) * r->d_inv[axis] : (split - o_k) / d_k;
    s.t_split = t_split;

    /* The children each lane needs (traverse.cl) */
    intP near_only = (t_split > t_hi) | (t_split <= 0.0f);
    intP far_only = ~near_only & (t_split < t_lo);
    if (r->shared_o && r->uo[axis] != split) {
        /* One origin off the plane: every lane's near child is the same, and
         * t_split is never NaN (split - o is not zero, d finite). The general
         * case below then makes exactly these decisions, with no lane leaving. */
        s.below_first = r->uo[axis] < split;
        s.leave = (intP)(0);
        s.need_first = act & ~far_only;
        s.need_second = act & ~near_only;
        return s;
    }
    /* Each lane's own near child */
    intP below_first_l = (o_k < split) | ((o_k == split) & (d_k <= 0.0f));
    intP both = act & ~near_only & ~far_only;
    /* The packet's order is that of the lanes needing both children; a lane
     * in the plane (t_split NaN), or needing both in the other order, leaves */
    intP leave = act & (t_split != t_split);
    s.below_first = kd_anyP(both & ~leave & below_first_l)
                    || !kd_anyP(both & ~leave) && kd_anyP(act & ~leave & below_first_l);
    leave |= both & (s.below_first ? ~below_first_l : below_first_l);
    s.leave = leave;
    act &= ~leave;
    /* A lane with the packet's order needs first (its near child) unless
     * far_only and second unless near_only; one with the other order needs
     * a single child: first if that is its far one */
    intP same = s.below_first ? below_first_l : ~below_first_l;
    s.need_first = act & kd_selectPi(far_only, ~far_only, same);
    s.need_second = act & kd_selectPi(near_only, ~near_only, same);
    return s;
}

/* Front-to-back traversal of the packet's lanes in `act` over [t_enter, t_exit] per
 * lane. Lanes that must be traced by the scalar kernel instead are or-ed into
 * *fallback (and their hit is left as it is). */
KD_INLINE
void kd_packet_traverse(__global const KdNode *nodes, uint max_leaves,
                        __global const float *tris, __global const uint *tri_ids,
                        const KdPacket *r, intP act, floatP t_enter, floatP t_exit,
                        KdPacketHit *h, intP *fallback KD_PSTATS_PARAM)
{
    uint stack_node[PACKET_STACK_SIZE];
    floatP stack_t_min[PACKET_STACK_SIZE];
    floatP stack_t_max[PACKET_STACK_SIZE];
    intP stack_act[PACKET_STACK_SIZE];
    uint count = 0;
    intP live = act;                     /* lanes still looking for their hit */
    uint leaves = 0;

    uint node = 0;
    floatP t_min_cur = t_enter;
    floatP t_max_cur = t_exit;

    /* the slack bounds of traverse.cl's tests, kept with the range they widen */
    floatP t_lo = t_min_cur * (1.0f - KD_T_SLACK);
    floatP t_hi = t_max_cur * (1.0f + KD_T_SLACK);

    for (;;) {
        KdNode n = nodes[node];
        while (!kd_is_leaf(n) && kd_anyP(act)) {
            KD_PSTAT(x, act);
            uint axis = kd_split_axis(n);
            float split = kd_split(n);
            uint below = node + 1u;
            uint above = kd_above_child(n);
            /* both children, loaded while the division runs: the next step's node is
             * then at hand, and an empty first child can be passed by (below) */
            KdNode n_below = nodes[below];
            KdNode n_above = nodes[above];
            KdPacketStep st = kd_packet_step(r, axis, split, act, t_lo, t_hi);
            if (kd_anyP(st.leave)) {
                *fallback |= st.leave;
                live &= ~st.leave;
                act &= ~st.leave;
                if (!kd_anyP(act))
                    break;
            }
            bool below_first = st.below_first;
            intP need_first = st.need_first, need_second = st.need_second;
            floatP t_split = st.t_split;
            /* the lanes needing both (need_first & need_second: only lanes of the
             * packet's order can need both) */
            intP both = need_first & need_second;
            uint first = below_first ? below : above;
            uint second = below_first ? above : below;
            floatP t_mid = kd_clampP(t_split, t_min_cur, t_max_cur);
            if (!kd_anyP(need_second)) {
                node = first;
            } else if (!kd_anyP(need_first)) {
                node = second;
            } else if (kd_is_empty_leaf(below_first ? n_below : n_above)) {
                /* The first child is an empty leaf: visiting it would only end the
                 * lanes whose hit is final before its exit (the leaf step below) and
                 * pop the second child. Both are done here, with no push. */
                if (++leaves > max_leaves)
                    return;
                KD_PSTAT(y, need_first);
                floatP t_exit_first = kd_selectP(t_max_cur, t_mid, both);
                live &= ~(need_first & (h->t < t_exit_first * (1.0f - KD_T_SLACK)));
                node = second;
                t_min_cur = kd_selectP(t_min_cur, t_mid, both);
                t_lo = t_min_cur * (1.0f - KD_T_SLACK);
                act = need_second & live;
                if (!kd_anyP(act))
                    break;
            } else {
                if (count == PACKET_STACK_SIZE) {
                    /* not on a valid tree (depth < PACKET_STACK_SIZE): the scalar kernel copes */
                    *fallback |= live;
                    return;
                }
                stack_node[count] = second;
                stack_t_min[count] = kd_selectP(t_min_cur, t_mid, both);
                stack_t_max[count] = t_max_cur;
                stack_act[count] = need_second;
                count++;
                node = first;
                t_max_cur = kd_selectP(t_max_cur, t_mid, both);
                t_hi = t_max_cur * (1.0f + KD_T_SLACK);
                act = need_first;
            }
            n = node == below ? n_below : n_above;
        }

        if (kd_anyP(act)) {
            if (++leaves > max_leaves)
                return;
            KD_PSTAT(y, act);
            kd_packet_leaf(n, tris, tri_ids, r, act, h KD_PSTATS_ARG);
            /* lanes whose hit is final are done (traverse.cl, kd_hit_done) */
#ifdef ANY_HIT
            live &= ~(act & (h->tri != (uintP)(KD_NO_HIT)));
#else
            live &= ~(act & (h->t < t_max_cur * (1.0f - KD_T_SLACK)));
#endif
        }

        /* Pop the next entry with a live lane */
        act = (intP)(0);
        while (count > 0 && !kd_anyP(act)) {
            count--;
            node = stack_node[count];
            t_min_cur = stack_t_min[count];
            t_max_cur = stack_t_max[count];
            act = stack_act[count] & live;
        }
        t_lo = t_min_cur * (1.0f - KD_T_SLACK);
        t_hi = t_max_cur * (1.0f + KD_T_SLACK);
        if (!kd_anyP(act))
            return;
    }
}

/* One axis of trace_ray's box clip (kd_slab) for every lane: t0, t1 narrowed where d
 * is not zero; returns the lanes still inside. */
KD_INLINE
intP kd_slabP(floatP o, floatP d, float lo, float hi, floatP *t0, floatP *t1)
{
    intP flat = d == 0.0f;
    floatP ta = (lo - o) / d;
    floatP tb = (hi - o) / d;
    *t0 = kd_selectP(kd_maxP(*t0, kd_minP(ta, tb)), *t0, flat);
    *t1 = kd_selectP(kd_minP(*t1, kd_maxP(ta, tb)), *t1, flat);
    return ~flat | ((o >= lo) & (o <= hi));
}

/* Component k (per lane: 0, 1, 2) of the vector (x, y, z) per lane. */
KD_INLINE
floatP kd_compP(floatP x, floatP y, floatP z, intP k)
{
    return kd_selectP(kd_selectP(x, y, k == 1), z, k == 2);
}

/* Whether a lane's direction component d keeps its packet from finding planes' t as
 * (split - o) * (1 / d), a multiplication in the node loop in place of the division,
 * whose latency the loop waits on. Where every lane's components are 0 or between
 * KD_INVERSE_MIN and 1 / KD_INVERSE_MIN in magnitude, 1 / d is a normal float, its
 * extra rounding within KD_T_SLACK (traverse.cl), or +-inf for +-0, where the
 * division's t is the same +-inf (NaN for 0 / 0 as for 0 * inf). Else the packet
 * divides: 1 / d overflows to +-inf below 2^-128, where (split - o) / d is finite
 * and a crossing far along the ray would be lost (tests/test_runtimes.py), and is
 * subnormal, with fewer bits, above 2^126. */
#define KD_INVERSE_MIN 2.3509887e-38f         /* 2^-125 */
KD_INLINE
intP kd_inverse_far(floatP d)
{
    floatP a = kd_absP(d);
    return (d != 0.0f) & ~((a >= KD_INVERSE_MIN) & (a <= 1.0f / KD_INVERSE_MIN));
}

/* The rest of packet r for traversal: ray_shear's axes and constants for every lane,
 * whether the lanes in `on` share the axes of lane `first` (the first on), and the
 * rays' origins, directions and ranges (each lane's). */
KD_INLINE
void kd_packet_shear(KdPacket *r, intP on, uint first, floatP ox, floatP oy, floatP oz,
                     floatP dx, floatP dy, floatP dz, floatP t_min, floatP t_max)
{
    floatP ax = kd_absP(dx), ay = kd_absP(dy), az = kd_absP(dz);
    intP kz = kd_selectPi(kd_selectPi((intP)(2), (intP)(1), ay >= az),
                          kd_selectPi((intP)(2), (intP)(0), ax >= az), ax >= ay);
    intP kx = kd_selectPi(kz + 1, (intP)(0), kz == 2);
    intP ky = kd_selectPi(kx + 1, (intP)(0), kx == 2);
    floatP d_kz = kd_compP(dx, dy, dz, kz);
    intP flip = d_kz < 0.0f;              /* swap kx, ky: keeps the winding */
    intP k = kx;
    kx = kd_selectPi(kx, ky, flip);
    ky = kd_selectPi(ky, k, flip);
    r->kx = kx; r->ky = ky; r->kz = kz;
    r->Sx = kd_compP(dx, dy, dz, kx) / d_kz;
    r->Sy = kd_compP(dx, dy, dz, ky) / d_kz;
    r->Sz = 1.0f / d_kz;
    r->okx = kd_compP(ox, oy, oz, kx);
    r->oky = kd_compP(ox, oy, oz, ky);
    r->okz = kd_compP(ox, oy, oz, kz);
    r->o[0] = ox; r->o[1] = oy; r->o[2] = oz;
    r->d[0] = dx; r->d[1] = dy; r->d[2] = dz;
    r->d_inv[0] = 1.0f / dx; r->d_inv[1] = 1.0f / dy; r->d_inv[2] = 1.0f / dz;
    r->by_inverse = !kd_anyP(on & (kd_inverse_far(dx) | kd_inverse_far(dy) | kd_inverse_far(dz)));
    r->t_min = t_min;
    r->t_max = t_max;
    KdIP kx_l, ky_l, kz_l;
    kx_l.v = kx; ky_l.v = ky; kz_l.v = kz;
    r->ukx = (uint)kx_l.s[first]; r->uky = (uint)ky_l.s[first]; r->ukz = (uint)kz_l.s[first];
    r->uniform = !kd_anyP(on & ((kx != (int)r->ukx) | (ky != (int)r->uky) | (kz != (int)r->ukz)));
#ifdef KD_CULL
    kd_cull_setup(r, on, first);
#endif
}

/* The share of the scene box's longest side above which a packet's origins are too far
 * apart for it to be traversed as a packet (kd_alone). */
#ifndef KD_ALONE_SPREAD
#define KD_ALONE_SPREAD 0.25f
#endif

/* The span of a packet's direction components on some axis, in units of their largest
 * magnitude, above which its rays, even from one point, are traced each on its own
 * path (kd_alone): random directions of one length span about 2, a camera's 4 x 4
 * pixels or a lidar's neighbouring beams hundredths. */
#ifndef KD_ALONE_TURN
#define KD_ALONE_TURN 0.5f
#endif

/* Whether directions (x, y, z), one a lane, span more than KD_ALONE_TURN of their
 * largest magnitude on some axis. */
KD_INLINE
bool kd_turn_wide(floatP x, floatP y, floatP z)
{
    float lo_x, hi_x, lo_y, hi_y, lo_z, hi_z;
    kd_rangeP(x, &lo_x, &hi_x);
    kd_rangeP(y, &lo_y, &hi_y);
    kd_rangeP(z, &lo_z, &hi_z);
    float big = kd_max(kd_max(kd_max(-lo_x, hi_x), kd_max(-lo_y, hi_y)), kd_max(-lo_z, hi_z));
    float span = kd_max(hi_x - lo_x, kd_max(hi_y - lo_y, hi_z - lo_z));
    return span > KD_ALONE_TURN * big;
}

/* Whether the lanes in `on` (origins ox, oy, oz, directions dx, dy, dz; r: their
 * packet) are better traced each on its own path (trace_packet: wide.cl's walk; their
 * leaves KD_PACKET triangles at a time: kd_ray_leaf) than as a packet: their
 * origins span more than KD_ALONE_SPREAD of the scene box's longest side on some axis,
 * or their directions more than KD_ALONE_TURN, as they are and scaled each to a
 * largest component of 1 (rays that point alike with other lengths: a user's rays from
 * one point, taken in the order of their directions, kdray/ray_order.py). Rays that
 * far apart or that diverge share few nodes below the top of the tree, and the union
 * of their paths, each node a vector step, costs more than their own paths; rays from
 * one point or a small patch pointing alike (cameras, lidars, a projector's pixels)
 * share most nodes (BENCHMARKS.md, "Incoherent rays"). Either way every lane's hit is
 * the same. */
KD_INLINE
bool kd_alone(const KdPacket *r, intP on, bool camera, floatP ox, floatP oy, floatP oz,
              floatP dx, floatP dy, floatP dz, float3 bmin, float3 bmax)
{
    if (0.0f > KD_ALONE_SPREAD)
        return true;                        /* tests set it below 0 to trace all alone */
    /* lanes that are off take the first on lane's values (the first lane's when every
     * lane is on: no lane is off but at the end of the rays) */
    floatP x, y, z;
    if (!r->shared_o) {
        x = kd_selectP((floatP)(r->uo[0]), ox, on);
        y = kd_selectP((floatP)(r->uo[1]), oy, on);
        z = kd_selectP((floatP)(r->uo[2]), oz, on);
        float span = kd_max(kd_spanP(x), kd_max(kd_spanP(y), kd_spanP(z)));
        float3 side = bmax - bmin;
        if (span > KD_ALONE_SPREAD * kd_max(side.x, kd_max(side.y, side.z)))
            return true;
    }
    if (camera)
        return false;                       /* a camera's pixels point alike */
    /* lanes that are off take the first on lane's direction */
    KdFP a, b, c;
    a.v = dx; b.v = dy; c.v = dz;
    uint on_bits = kd_bitsP(on);
    uint l0 = kd_take_lane(&on_bits);
    x = kd_selectP((floatP)(a.s[l0]), dx, on);
    y = kd_selectP((floatP)(b.s[l0]), dy, on);
    z = kd_selectP((floatP)(c.s[l0]), dz, on);
    if (!kd_turn_wide(x, y, z))
        return false;
    /* scaled (a zero direction left as it is): only where they span too much as they
     * are, so that rays of one length (a camera's, a lidar's) pay nothing for it */
    floatP m = kd_maxP(kd_absP(x), kd_maxP(kd_absP(y), kd_absP(z)));
    m = kd_selectP((floatP)(1.0f), m, m > 0.0f);
    return kd_turn_wide(x / m, y / m, z / m);
}

#include "wide.cl"

/* Nearest hits of the rays o + t d (per lane, relative to the tree's origin) with
 * t_min < t < t_max (each lane's range), as trace_ray gives them, for the lanes in `on`; bmin, bmax: the
 * scene box; camera: the rays are a camera's pixels (render_camera), which point
 * alike (kd_alone). Writes t (t_max on a miss), u, v (0 on a miss) and tri (KD_NO_HIT
 * on a miss) per lane, and with STATS per-lane counts. */
KD_INLINE
void trace_packet(__global const KdNode *nodes, uint n_nodes,
                  __global const float *tris, __global const uint *tri_ids KD_WIDE_PARAM,
                  float3 bmin, float3 bmax, intP on,
                  bool camera, floatP ox, floatP oy, floatP oz, floatP dx, floatP dy, floatP dz,
                  floatP t_min, floatP t_max,
                  floatP *t_out, floatP *u_out, floatP *v_out, uintP *tri_out
#ifdef STATS
                  , KdUP *stat_x, KdUP *stat_y, KdUP *stat_z, KdUP *stat_w
#endif
                  )
{
    /* trace_ray's checks and box clip, lane by lane in vectors */
    intP finite = (ox - ox == 0.0f) & (oy - oy == 0.0f) & (oz - oz == 0.0f)
                  & (dx - dx == 0.0f) & (dy - dy == 0.0f) & (dz - dz == 0.0f);
    /* (kd_no_direction, lane by lane) */
    on &= finite & ((floatP)(1.0f) / kd_maxP(kd_absP(dx), kd_maxP(kd_absP(dy), kd_absP(dz)))
                    < (floatP)(INFINITY));
    floatP t_enter = t_min, t_exit = t_max;
    on &= kd_slabP(ox, dx, bmin.x, bmax.x, &t_enter, &t_exit);
    on &= kd_slabP(oy, dy, bmin.y, bmax.y, &t_enter, &t_exit);
    on &= kd_slabP(oz, dz, bmin.z, bmax.z, &t_enter, &t_exit);
    t_enter = KD_BOX_ENTER(t_enter);
    t_exit = KD_BOX_EXIT(t_exit);
    on &= t_enter <= t_exit;
    if (!kd_anyP(on)) {
        /* every ray misses the scene's box (most packets of a camera framing the
         * scene): nothing to set up */
        *t_out = t_max;
        *u_out = (floatP)(0.0f);
        *v_out = (floatP)(0.0f);
        *tri_out = (uintP)(KD_NO_HIT);
#ifdef STATS
        stat_x->v = (uintP)(0u); stat_y->v = (uintP)(0u); stat_z->v = (uintP)(0u);
        stat_w->v = (uintP)(0u);
#endif
        return;
    }

    /* the first lane that is on; one origin: its origin, shared by every lane on */
    KdPacket r;
    KdIP on_l;
    on_l.v = on;
    uint first = 0;
    while (first < KD_PACKET - 1 && !on_l.s[first])
        first++;
    KdFP ox_l, oy_l, oz_l;
    ox_l.v = ox; oy_l.v = oy; oz_l.v = oz;
    r.uo[0] = ox_l.s[first]; r.uo[1] = oy_l.s[first]; r.uo[2] = oz_l.s[first];
    r.shared_o = !kd_anyP(on & ((ox != (floatP)(r.uo[0])) | (oy != (floatP)(r.uo[1]))
                                | (oz != (floatP)(r.uo[2]))));

    KdPacketHit h;
    h.t = t_max;
    h.V = (floatP)(0.0f);
    h.W = (floatP)(0.0f);
    h.det = (floatP)(1.0f);
    h.tri = (uintP)(KD_NO_HIT);
    KdIP fallback;
    fallback.v = (intP)(0);
#ifdef STATS
    KdPacketStats ps;
    ps.x = (uintP)(0u); ps.y = (uintP)(0u); ps.z = (uintP)(0u);
    KdPacketStats *pstats = &ps;
#endif
    if (kd_alone(&r, on, camera, ox, oy, oz, dx, dy, dz, bmin, bmax)) {
        fallback.v = on;                 /* traced ray by ray below: no packet set up */
    } else {
        kd_packet_shear(&r, on, first, ox, oy, oz, dx, dy, dz, t_min, t_max);
#ifdef KD_WIDE
        /* a packet whose directions share an octant walks the wide nodes (wide.cl),
         * others (a block across an axis of the view) the k-d tree */
        uint octant;
        if (kd_packet_octant(&r, on, first, &octant))
            kd_packet_wide_traverse(wide, tris, tri_ids, &r, on, octant,
                                    kd_wide_reach(bmin, bmax), &h);
        else
#endif
        kd_packet_traverse(nodes, 2u * n_nodes + 2u, tris, tri_ids, &r, on, t_enter, t_exit,
                           &h, &fallback.v KD_PSTATS_ARG);
    }

    KdFP t_l, u_l, v_l;
    KdUP tri_l;
    t_l.v = h.t;
    u_l.v = h.V / h.det;
    v_l.v = h.W / h.det;
    tri_l.v = h.tri;
#ifdef STATS
    stat_x->v = ps.x; stat_y->v = ps.y; stat_z->v = ps.z; stat_w->v = (uintP)(0u);
#endif
#ifdef KD_WIDE
    if (!camera && kd_anyP(fallback.v)) {
        /* lanes the packet handed over, or all of a packet traced alone: through the
         * wide nodes, two at a time, from the start (wide.cl) */
        kd_wide_trace(wide, tris, tri_ids, fallback.v, ox, oy, oz, dx, dy, dz, t_min, t_max,
                      bmin.x, bmin.y, bmin.z, bmax.x, bmax.y, bmax.z, &t_l, &u_l, &v_l,
                      &tri_l);
        fallback.v = (intP)(0);
    }
#endif
    if (kd_anyP(fallback.v)) {
        /* lanes the packet handed over where there are no wide nodes (a camera's, and
         * programs that count the work): the scalar kernel from the start */
        KdFP oxl, oyl, ozl, dxl, dyl, dzl, lo, hi;
        oxl.v = ox; oyl.v = oy; ozl.v = oz; dxl.v = dx; dyl.v = dy; dzl.v = dz;
        lo.v = t_min; hi.v = t_max;
        for (uint l = 0; l < KD_PACKET; l++) {
            if (!fallback.s[l])
                continue;
            Hit hit;
            float3 o = (float3)(oxl.s[l], oyl.s[l], ozl.s[l]);
            float3 d = (float3)(dxl.s[l], dyl.s[l], dzl.s[l]);
#ifdef STATS
            uint4 more = (uint4)(0u);
            trace_ray(nodes, n_nodes, tris, tri_ids, bmin, bmax, o, d, lo.s[l], hi.s[l], &hit,
                      &more);
            stat_x->s[l] += more.x; stat_y->s[l] += more.y;
            stat_z->s[l] += more.z; stat_w->s[l] += more.w;
#else
            trace_ray(nodes, n_nodes, tris, tri_ids, bmin, bmax, o, d, lo.s[l], hi.s[l], &hit);
#endif
            t_l.s[l] = hit.t;
            u_l.s[l] = hit.u;
            v_l.s[l] = hit.v;
            tri_l.s[l] = hit.tri;
        }
    }
    /* a miss: t_max, 0, 0 (as trace_ray) */
    intP miss = as_intP(tri_l.v == (uintP)(KD_NO_HIT));
    *t_out = kd_selectP(t_l.v, t_max, miss);
    *u_out = kd_selectP(u_l.v, (floatP)(0.0f), miss);
    *v_out = kd_selectP(v_l.v, (floatP)(0.0f), miss);
    *tri_out = tri_l.v;
}

#endif
