/* bench/wide_nodes.cl: an experiment, not part of kdray's kernels (bench/wide_nodes.py
 * builds and runs it). Nearest hits through wide nodes collapsed from the k-d tree:
 * each node holds up to W_N children (the k-d subtree's nodes 3 levels down for 8, 4
 * for 16; empty leaves left out), each with the box of its triangles clipped to its
 * cell. A ray tests all W_N boxes in one vector step, pushes the children it meets
 * nearest last, and skips an entry whose box it enters beyond its best hit. W_R rays
 * a work-item take their steps in turns, so that their chains of loads overlap.
 *
 * The hits are trace's bit for bit: hits do not depend on the tree (the nearest in
 * (t, input id) order), every leaf is tested with kd_ray_leaf (the same arithmetic),
 * and a box is only missed where no triangle in it can be hit: each box is widened by
 * W_PAD of the ray's reach (the largest coordinate of the scene plus of the origin,
 * which bounds |v - o| of every vertex), more than the triangle test's and the slab
 * test's roundings (packet.cl's reasoning for KD_T_SLACK, at 2^-16 instead of 2^-20);
 * a NaN slab (a ray parallel to a face, in its widened plane) is ignored by fmin and
 * fmax, which only widens what is kept. */
#pragma OPENCL FP_CONTRACT OFF
#include "layout.h"
#include "triangle.cl"
#include "traverse.cl"
#include "packet.cl"

#ifndef W_N
#define W_N 8
#endif
#if W_N == 16
typedef float16 floatW;
typedef int16 intW;
typedef uint16 uintW;
#define as_intW as_int16
#define as_uintW as_uint16
#define vloadW vload16
#else
typedef float8 floatW;
typedef int8 intW;
typedef uint8 uintW;
#define as_intW as_int8
#define as_uintW as_uint8
#define vloadW vload8
#endif
#ifdef W_ORDER
/* W_ORDER (8 children only): after the children's rows, 8 words, one an octant of the
 * ray's direction (bit 0: x negative, 1: y, 2: z): the children's slots in the order a
 * ray of that octant meets their cells (3 bits a slot, the nearest in the lowest bits).
 * The cells are disjoint k-d cells, so this order is front to back for every ray of
 * the octant: pushing the hit children in it needs no compare. */
#define W_WORDS (8u * W_N + 8u)
#else
#define W_WORDS (8u * W_N)
#endif
#define W_LEAF 0x80000000u
#define W_EMPTY 0xFFFFFFFFu
#define W_PAD 0x1p-16f
#ifndef W_STACK
#define W_STACK 96
#endif

#ifndef W_R
#define W_R 1
#endif

/* a ray's stack of entries: the node or leaf (child, meta) and where the ray enters it */
typedef struct {
    uint meta[W_STACK], child[W_STACK];
    float t[W_STACK];
} WStack;

typedef struct {
    float3 o;
    RayShear shear;
    floatW ox, oy, oz, ix, iy, iz, pad;
    Hit hit;
    uint top, n_nodes, n_leaves;
    bool has_cur;                        /* W_DIRECT: the entry to take next, off the stack */
    uint cur_meta, cur_child;
#ifdef W_ORDER
    uint oct, nx, fx, ny, fy, nz, fz;   /* the octant; the rows of the near, far planes */
    floatW cnx, cny, cnz, cfx, cfy, cfz; /* near, far planes' pad outwards, minus o */
#endif
    WStack *st;                          /* apart, so that the rest can stay in registers */
} WRay;

KD_INLINE
void w_start(WRay *r, WStack *st, float3 o, float3 d, float reach)
{
    r->st = st;
    r->o = o;
    r->shear = ray_shear(d);
    float3 inv = (float3)(1.0f) / d;
    r->hit.t = INFINITY; r->hit.u = 0.0f; r->hit.v = 0.0f; r->hit.tri = KD_NO_HIT;
    r->st->meta[0] = 0u; r->st->child[0] = 0u; r->st->t[0] = 0.0f; r->top = 1;
    r->n_nodes = 0u; r->n_leaves = 0u;
    r->has_cur = false; r->cur_meta = 0u; r->cur_child = 0u;
    r->ox = (floatW)(o.x); r->oy = (floatW)(o.y); r->oz = (floatW)(o.z);
    r->ix = (floatW)(inv.x); r->iy = (floatW)(inv.y); r->iz = (floatW)(inv.z);
    float a = fmax(fmax(fabs(o.x), fabs(o.y)), fabs(o.z));
    r->pad = (floatW)((a + reach) * W_PAD + 0x1p-120f);
#ifdef W_ORDER
    /* the near plane of a slab is its min for a ray going up the axis, its max going
     * down (inv's sign: -0 gives -inf, going down); each plane moved out by the pad,
     * and the origin taken off with it: the rounding of (pad - o) and of (plane + c)
     * is at most 2^-23 of (|o| + reach), far below the pad's 2^-16 of it, so each box
     * stays widened by more than the tests' roundings */
    float px = inv.x < 0.0f ? 1.0f : -1.0f, py = inv.y < 0.0f ? 1.0f : -1.0f;
    float pz = inv.z < 0.0f ? 1.0f : -1.0f;
    r->oct = (inv.x < 0.0f ? 1u : 0u) | (inv.y < 0.0f ? 2u : 0u) | (inv.z < 0.0f ? 4u : 0u);
    r->nx = inv.x < 0.0f ? 3u : 0u; r->fx = 3u - r->nx;
    r->ny = inv.y < 0.0f ? 4u : 1u; r->fy = 5u - r->ny;
    r->nz = inv.z < 0.0f ? 5u : 2u; r->fz = 7u - r->nz;
    r->cnx = r->pad * px - r->ox; r->cny = r->pad * py - r->oy; r->cnz = r->pad * pz - r->oz;
    r->cfx = -r->pad * px - r->ox; r->cfy = -r->pad * py - r->oy;
    r->cfz = -r->pad * pz - r->oz;
#endif
}

/* one entry of the ray's stack: a leaf tested, or a node's hit children pushed */
KD_INLINE
void w_step(WRay *r, __global const float *wide, __global const float *tris,
            __global const uint *tri_ids)
{
    const float t_min = 0.0f, t_max = INFINITY;
    uint top = r->top, meta, child;
    if (r->has_cur) {
        meta = r->cur_meta;
        child = r->cur_child;
        r->has_cur = false;
    } else {
        top = --r->top;
        meta = r->st->meta[top];
        child = r->st->child[top];
        if (r->st->t[top] > r->hit.t)
            return;
    }
    if (meta & W_LEAF) {
        KdNode leaf;
        leaf.flags = ((meta & ~W_LEAF) << 2) | KD_LEAF;
        leaf.data = child;
        r->n_leaves++;
        kd_ray_leaf(leaf, tris, tri_ids, &r->shear, r->o, t_min, t_max, &r->hit);
        return;
    }
    r->n_nodes++;
    __global const float *w = wide + (size_t)child * W_WORDS;
#ifdef W_ORDER
    {
        /* entry: near plane + cn, exit: far plane + cf, times 1 / d. An empty slot (min
         * +inf, max -inf) enters at +inf whatever the direction. */
        /* maxima and minima as selects with the slab's value first: a NaN slab (a
         * ray parallel to a face, in its widened plane) loses the compare and leaves
         * the other, as fmax and fmin ignore NaN, in one vmaxps or vminps each */
        floatW tn = (floatW)(t_min), tf = (floatW)(r->hit.t), s;
        s = (vloadW(r->nz, w) + r->cnz) * r->iz; tn = s > tn ? s : tn;
        s = (vloadW(r->ny, w) + r->cny) * r->iy; tn = s > tn ? s : tn;
        s = (vloadW(r->nx, w) + r->cnx) * r->ix; tn = s > tn ? s : tn;
        s = (vloadW(r->fz, w) + r->cfz) * r->iz; tf = s < tf ? s : tf;
        s = (vloadW(r->fy, w) + r->cfy) * r->iy; tf = s < tf ? s : tf;
        s = (vloadW(r->fx, w) + r->cfx) * r->ix; tf = s < tf ? s : tf;
        __global const uint *cw = (__global const uint *)(w + 6 * W_N);
        union { floatW v; float s[W_N]; } tv;
        union { intW v; int s[W_N]; } okv;
        tv.v = tn;
        okv.v = tn <= tf;
        uint seq = cw[2 * W_N + r->oct];
        /* the farthest first, so that the nearest is on top; every slot written, the
         * top moved only for those hit */
#pragma unroll
        for (int k = W_N - 1; k >= 0; k--) {
            uint j = (seq >> (3 * k)) & 7u;
            r->st->t[top] = tv.s[j];
            r->st->meta[top] = cw[W_N + j];
            r->st->child[top] = cw[j];
            top += (uint)(okv.s[j]) & 1u;
        }
        r->top = top;
        return;
    }
#endif
    floatW lx = vloadW(0, w) - r->ox, ly = vloadW(1, w) - r->oy, lz = vloadW(2, w) - r->oz;
    floatW hx = vloadW(3, w) - r->ox, hy = vloadW(4, w) - r->oy, hz = vloadW(5, w) - r->oz;
    floatW pad = r->pad;
    floatW ax = (lx - pad) * r->ix, bx = (hx + pad) * r->ix;
    floatW ay = (ly - pad) * r->iy, by = (hy + pad) * r->iy;
    floatW az = (lz - pad) * r->iz, bz = (hz + pad) * r->iz;
    floatW tn = fmax(fmax(fmin(ax, bx), fmin(ay, by)), fmax(fmin(az, bz), (floatW)(t_min)));
    floatW tf = fmin(fmin(fmax(ax, bx), fmax(ay, by)), fmin(fmax(az, bz), (floatW)(r->hit.t)));
    __global const uint *cm = (__global const uint *)(w + 6 * W_N);
#if W_N == 16
    intW valid = as_intW(vload16(1, cm)) != (intW)(-1);
    uintW wbits = (uintW)(1u, 2u, 4u, 8u, 16u, 32u, 64u, 128u, 256u, 512u, 1024u, 2048u,
                          4096u, 8192u, 16384u, 32768u);
#else
    intW valid = as_intW(vload8(1, cm)) != (intW)(-1);
    uintW wbits = (uintW)(1u, 2u, 4u, 8u, 16u, 32u, 64u, 128u);
#endif
    intW ok = (tn <= tf) & valid;
    uintW b = as_uintW(ok) & wbits;
#if W_N == 16
    uint8 b8 = b.lo | b.hi;
#else
    uint8 b8 = b;
#endif
    uint4 b4 = b8.lo | b8.hi;
    uint2 b2 = b4.lo | b4.hi;
    uint bits = b2.x | b2.y;
    union { floatW v; float s[W_N]; } tnl;
    tnl.v = tn;
#ifdef W_DIRECT
    /* the nearest child next, off the stack; the others pushed, nearest last */
    if (!bits)
        return;
    uint near = 31u - clz(bits & (0u - bits));
    uint rest = bits & (bits - 1u);
    if (rest) {
        uint far = 31u - clz(rest & (0u - rest));
        if (!(rest & (rest - 1u))) {             /* two: push the farther */
            if (tnl.s[far] < tnl.s[near]) {
                uint x = near; near = far; far = x;
            }
            r->st->t[top] = tnl.s[far]; r->st->meta[top] = cm[W_N + far];
            r->st->child[top] = cm[far];
            r->top = top + 1u;
            r->has_cur = true; r->cur_meta = cm[W_N + near]; r->cur_child = cm[near];
            return;
        }
    } else {
        r->has_cur = true; r->cur_meta = cm[W_N + near]; r->cur_child = cm[near];
        return;
    }
#endif
    uint base = top;
    while (bits) {
        uint j = 31u - clz(bits & (0u - bits));
        bits &= bits - 1u;
        float t = tnl.s[j];
        uint i = top++;
        while (i > base && r->st->t[i - 1] < t) {
            r->st->t[i] = r->st->t[i - 1]; r->st->meta[i] = r->st->meta[i - 1];
            r->st->child[i] = r->st->child[i - 1];
            i--;
        }
        r->st->t[i] = t; r->st->meta[i] = cm[W_N + j]; r->st->child[i] = cm[j];
    }
    r->top = top;
#ifdef W_DIRECT
    /* three or more: the nearest, on top, taken next */
    top = --r->top;
    r->has_cur = true; r->cur_meta = r->st->meta[top]; r->cur_child = r->st->child[top];
#endif
}

__kernel __attribute__((vec_type_hint(floatW)))
void wide_trace(__global const float *wide, __global const float *tris,
                __global const uint *tri_ids, __global const float *bounds,
                __global const float *o_in, __global const float *d_in, uint n,
                __global float *out_t, __global uint *out_tri)
{
    /* the scene's largest coordinate: |v - o| <= reach + |o| for every vertex v */
    float reach = fmax(fmax(fmax(fabs(bounds[0]), fabs(bounds[1])), fabs(bounds[2])),
                       fmax(fmax(fabs(bounds[3]), fabs(bounds[4])), fabs(bounds[5])));
    uint k0 = get_global_id(0) * W_R;
    if (k0 >= n)
        return;
#if W_R == 2
    /* two rays in structs of their own (no array indexed at run time): their state can
     * stay in registers between turns */
    WRay a, b;
    WStack sa, sb;
    w_start(&a, &sa, vload3(k0, o_in), vload3(k0, d_in), reach);
    uint kb = k0 + 1u < n ? k0 + 1u : k0;
    w_start(&b, &sb, vload3(kb, o_in), vload3(kb, d_in), reach);
    bool la = true, lb = true;
    while (la | lb) {
        if (la) {
            w_step(&a, wide, tris, tri_ids);
            la = a.top || a.has_cur;
        }
        if (lb) {
            w_step(&b, wide, tris, tri_ids);
            lb = b.top || b.has_cur;
        }
    }
    WRay r[2];
    r[0] = a;
    r[1] = b;
#else
    WRay r[W_R];
    WStack s[W_R];
    uint live = 0u;
    for (uint i = 0; i < W_R; i++) {
        uint k = k0 + i < n ? k0 + i : k0;
        w_start(&r[i], &s[i], vload3(k, o_in), vload3(k, d_in), reach);
        live |= 1u << i;
    }
    while (live) {
        for (uint i = 0; i < W_R; i++) {
            if (r[i].top || r[i].has_cur) {
                w_step(&r[i], wide, tris, tri_ids);
                if (!r[i].top && !r[i].has_cur)
                    live &= ~(1u << i);
            }
        }
    }
#endif
    for (uint i = 0; i < W_R && k0 + i < n; i++) {
#ifdef W_COUNT
        out_t[k0 + i] = (float)r[i].n_nodes + 1000.0f * (float)r[i].n_leaves;
#else
        out_t[k0 + i] = r[i].hit.t;
#endif
        out_tri[k0 + i] = r[i].hit.tri == KD_NO_HIT ? KD_NO_HIT : tri_ids[r[i].hit.tri];
    }
}
