/* kernels/queries.cl: ray queries beyond the nearest hit (kdray/rays.py).
 *
 *   occluded_rays  is there any hit with t_min < t < t_max (stops at the first)
 *   count_rays     how many triangles the ray hits: with `crossing`, how many times
 *                  it crosses the surface (triangle.cl, kd_tie: a shared edge or
 *                  vertex counts once); else every triangle hit, for list_rays' sizes
 *   list_rays      every hit, into the ray's own slots, sorted by (t, input id)
 *   nearest_rays   the nearest hit, as trace_rays finds it (render.cl), for rays with
 *                  a t range each (trace_rays takes one for all)
 *
 * One walk (kd_walk) serves them all: it visits every leaf the ray's range reaches,
 * near child first, and hands each to kd_query_leaf, which does what the query does
 * with a hit and says when the walk may stop. Unlike the nearest hit's traversal
 * (traverse.cl), a walk needs every leaf (bar the any-hit's early stop), so it keeps a
 * full stack and never restarts, and a ray that lies in a split plane visits both
 * children over the same range in one walk (order does not matter here).
 *
 * A triangle in several leaves has a copy in each (layout.h), and a ray that reaches
 * two of them finds the same hit twice (the test depends on the ray and the triangle
 * only): a hit counts once per input id. count_rays keeps the ids it has counted in
 * KD_SEEN private slots; a ray with more distinct hits counts every hit found, its
 * count then marked KD_COUNT_RAW (an upper bound, which list_rays, deduplicating in
 * its own slots, makes exact). The walk's node decisions are traverse.cl's (the same
 * slack), so it visits every leaf the nearest hit's traversal may.
 *
 * Options (-D): STACK_SIZE (at least the tree's depth + 1), LOCAL_SIZE, RUN (rays a
 * work-item takes, consecutive), REFINE (list_rays' t, u, v recomputed in double,
 * triangle.cl, kd_refine_hit, from the caller's rays in double). Rays are float32, relative to the tree's origin in its
 * units; t_min, t_max per ray (t_step 1) or one pair for all (t_step 0), in the same
 * units. Outputs are in those units too: the host scales t.
 */
#pragma OPENCL FP_CONTRACT OFF
#include "layout.h"
#include "triangle.cl"
#include "traverse.cl"
#ifdef PACKET
/* packet programs test a lone ray's leaf KD_PACKET triangles at a time (packet.cl,
 * kd_ray_leaf: kd_intersect_leaf's hit bit for bit), which the nearest and any-hit
 * queries use: they keep one best hit a leaf; count and list need every hit */
#include "packet.cl"
#endif

#ifndef LOCAL_SIZE
#define LOCAL_SIZE 8
#endif
#ifndef RUN
#define RUN 1
#endif

/* One ray a work-item, its walk a data-dependent loop: vec_type_hint of a vector type
 * tells Intel's CPU runtime not to run a group's work-items in SIMD lanes, which it
 * does for groups as wide as its vector unit, about 5 times slower for these kernels
 * (a float4 hint, as render.cl's floatP hint for packets). Others ignore it. */
#define KD_NO_LANES __attribute__((vec_type_hint(float4)))

#define KD_SEEN 32u                     /* input ids count_rays keeps, per ray */
#define KD_COUNT_RAW 0x80000000u         /* count_rays: the count is every hit found */
#define KD_WALK_FAULT 0x40000000u        /* the walk met a corrupt tree (never otherwise) */

#define KD_ANY 0u
#define KD_COUNT 1u
#define KD_LIST 2u
#define KD_NEAREST 3u

/* What a query keeps of one ray while it walks. */
typedef struct {
    bool crossing;                       /* the count's rule (intersect_triangle) */
    bool fault;                          /* the walk's stack or leaf bound was exceeded */
    bool in_plane;                       /* nearest: a node's plane held the ray */
    Hit hit;                             /* nearest: the best hit so far */
    uint n;                              /* distinct hits (any: 1 once hit) */
    uint raw;                            /* count: hits found, copies included */
    uint seen[KD_SEEN];                  /* count: the input ids counted */
    /* list: the ray's slots, cap of them, n used, sorted by (t, input id) */
    __global float *t;
    __global float *uv;
    __global uint *tri;                  /* the device's triangle copy (layout.h) */
    uint cap;
} KdQuery;

/* count: one more hit of input id `id`, counted unless counted already. */
KD_INLINE
void kd_count_hit(KdQuery *q, uint id)
{
    q->raw++;
    if (q->n > KD_SEEN)                  /* past the slots: every hit counts (raw) */
        return;
    for (uint j = 0; j < q->n; j++)
        if (q->seen[j] == id)
            return;
    if (q->n < KD_SEEN)
        q->seen[q->n] = id;
    q->n++;                              /* KD_SEEN + 1: overflowed */
}

/* list: the hit (t, u, v) of copy `tri` into the ray's slots, kept sorted by (t, input
 * id), unless its triangle is there already; with every slot taken (max_hits) it
 * replaces the last one if it comes before it. A copy dropped so is never taken
 * later: the last slot only moves nearer. */
KD_INLINE
void kd_list_hit(KdQuery *q, uint tri, float t, float u, float v, __global const uint *tri_ids)
{
    uint id = tri_ids[tri];
    for (uint j = 0; j < q->n; j++)
        if (tri_ids[q->tri[j]] == id)
            return;
    uint j = q->n;
    if (j == q->cap) {
        if (j == 0u || !kd_before(t, tri, q->t[j - 1u], q->tri[j - 1u], tri_ids))
            return;
        j--;
    } else {
        q->n++;
    }
    for (; j > 0u && kd_before(t, tri, q->t[j - 1u], q->tri[j - 1u], tri_ids); j--) {
        q->t[j] = q->t[j - 1u];
        q->uv[2u * j] = q->uv[2u * j - 2u];
        q->uv[2u * j + 1u] = q->uv[2u * j - 1u];
        q->tri[j] = q->tri[j - 1u];
    }
    q->t[j] = t;
    q->uv[2u * j] = u;
    q->uv[2u * j + 1u] = v;
    q->tri[j] = tri;
}

#ifdef PACKET
/* The count's crossing rule a run of KD_PACKET triangles at a time: the lanes whose
 * triangle the ray may cross. intersect_triangle's sheared edge functions U, V, W,
 * computed alike lane by lane (the same operations in the same order), have the sign
 * of their exact values wherever KD_EDGE_SURE holds; a triangle with one surely
 * positive and one surely negative is crossed under no rule, and every other lane
 * (NaN included) is left to intersect_triangle, which decides it exactly. So the
 * lanes kept hold every crossing, and the count is the scalar loop's. */
KD_INLINE
intP kd_crossing_lanes(const RayShear *s, float3 o, const KdFP *q, intP valid)
{
    uint kx = s->kx, ky = s->ky, kz = s->kz;
    float ox = kd_comp(o, kx), oy = kd_comp(o, ky), oz = kd_comp(o, kz);
    floatP Sx = (floatP)(s->Sx), Sy = (floatP)(s->Sy);
    floatP Az = q[kz].v - oz, Bz = q[3 + kz].v - oz, Cz = q[6 + kz].v - oz;
    floatP Ax = (q[kx].v - ox) - Sx * Az, Ay = (q[ky].v - oy) - Sy * Az;
    floatP Bx = (q[3 + kx].v - ox) - Sx * Bz, By = (q[3 + ky].v - oy) - Sy * Bz;
    floatP Cx = (q[6 + kx].v - ox) - Sx * Cz, Cy = (q[6 + ky].v - oy) - Sy * Cz;
    floatP u1 = Cx * By, u2 = Cy * Bx, v1 = Ax * Cy, v2 = Ay * Cx, w1 = Bx * Ay, w2 = By * Ax;
    floatP U = u1 - u2, V = v1 - v2, W = w1 - w2;
    floatP tiny = (floatP)(0x1p-126f);
    intP sure_u = kd_absP(U) > 0x1p-22f * (kd_absP(u1) + kd_absP(u2)) + tiny;
    intP sure_v = kd_absP(V) > 0x1p-22f * (kd_absP(v1) + kd_absP(v2)) + tiny;
    intP sure_w = kd_absP(W) > 0x1p-22f * (kd_absP(w1) + kd_absP(w2)) + tiny;
    floatP zero = (floatP)(0.0f);
    intP pos = (sure_u & (U > zero)) | (sure_v & (V > zero)) | (sure_w & (W > zero));
    intP neg = (sure_u & (U < zero)) | (sure_v & (V < zero)) | (sure_w & (W < zero));
    return valid & ~(pos & neg);
}
#endif

/* Test a leaf's triangles for `query`; true when the walk may stop: any, at a hit;
 * nearest, when its best hit is final at the leaf's exit t_exit (traverse.cl,
 * kd_hit_final), unless the walk has met a node whose plane holds the ray: its
 * second child is then walked over the same range, and may hold a nearer hit. */
KD_INLINE
bool kd_query_leaf(uint query, KdNode leaf, __global const float *tris,
                   __global const uint *tri_ids, const RayShear *shear, float3 o, float t_min,
                   float t_max, float t_exit, KdQuery *q)
{
    if (query == KD_NEAREST) {
        KD_RAY_LEAF(leaf, tris, tri_ids, shear, o, t_min, t_max, &q->hit);
        return !q->in_plane && kd_hit_final(q->hit.t, t_exit);
    }
    uint count = kd_n_prims(leaf);
    uint first = kd_leaf_offset(leaf);
#ifdef PACKET
    if (query == KD_ANY) {
        /* the leaf's nearest hit, a vector of triangles at a time: any is one */
        KD_RAY_LEAF(leaf, tris, tri_ids, shear, o, t_min, t_max, &q->hit);
        q->n = q->hit.tri != KD_NO_HIT;
        return q->n != 0u;
    }
    if (!(query == KD_COUNT && q->crossing)) {
        /* every hit of the nearest hit's rule: the block test's lanes (kd_ray_block_all
         * with no best hit yet), each as kd_query_leaf's loop below takes it */
        for (uint i0 = 0; i0 < count; i0 += KD_PACKET) {
            KdFP qv[9];
            kd_gather_tris(tris, first + i0, qv);
            uint m = count - i0 < KD_PACKET ? count - i0 : KD_PACKET;
            KdIP c;
            KdFP t, V, W, det;
            c.v = kd_ray_block_all(shear, o, t_min, t_max, t_max, KD_NO_HIT, qv,
                                   (uintP)(first + i0) + KD_LANE_INDEX_U,
                                   KD_LANE_INDEX < (intP)((int)m), tri_ids, &t.v, &V.v,
                                   &W.v, &det.v);
            if (!kd_anyP(c.v))
                continue;
            for (uint j = 0; j < m; j++) {
                if (!c.s[j])
                    continue;
                uint tri = first + i0 + j;
                if (query == KD_COUNT)
                    kd_count_hit(q, tri_ids[tri]);
                else
                    kd_list_hit(q, tri, t.s[j], V.s[j] / det.s[j], W.s[j] / det.s[j], tri_ids);
            }
        }
        return false;
    }
    /* the count's crossing rule: the lanes that may be crossed, each then decided by
     * intersect_triangle as the loop below decides it */
    for (uint i0 = 0; i0 < count; i0 += KD_PACKET) {
        KdFP qv[9];
        kd_gather_tris(tris, first + i0, qv);
        uint m = count - i0 < KD_PACKET ? count - i0 : KD_PACKET;
        KdIP c;
        c.v = kd_crossing_lanes(shear, o, qv, KD_LANE_INDEX < (intP)((int)m));
        if (!kd_anyP(c.v))
            continue;
        for (uint j = 0; j < m; j++) {
            uint tri = first + i0 + j;
            float t, u, v;
            if (c.s[j] && intersect_triangle(shear, o, kd_vertex(tris, tri, 0),
                                             kd_vertex(tris, tri, 1), kd_vertex(tris, tri, 2),
                                             tri, t_min, t_max, t_max, KD_NO_HIT, tri_ids, true,
                                             &t, &u, &v))
                kd_count_hit(q, tri_ids[tri]);
        }
    }
    return false;
#endif
    for (uint i = 0; i < count; i++) {
        uint tri = first + i;
        float t, u, v;
        if (!intersect_triangle(shear, o, kd_vertex(tris, tri, 0), kd_vertex(tris, tri, 1),
                                kd_vertex(tris, tri, 2), tri, t_min, t_max, t_max, KD_NO_HIT,
                                tri_ids, query == KD_COUNT && q->crossing, &t, &u, &v))
            continue;
        if (query == KD_ANY) {
            q->n = 1u;
            return true;
        }
        if (query == KD_COUNT)
            kd_count_hit(q, tri_ids[tri]);
        else
            kd_list_hit(q, tri, t, u, v, tri_ids);
    }
    return false;
}

/* Walk every leaf of the ray o + t d's range [t_min, t_max] within the scene box
 * (bmin, bmax), near child first, each leaf once, handing each to kd_query_leaf. */
KD_INLINE
void kd_walk(uint query, __global const KdNode *nodes, uint n_nodes, __global const float *tris,
             __global const uint *tri_ids, float3 bmin, float3 bmax, float3 o, float3 d,
             float t_min, float t_max, KdQuery *q)
{
    if (!(kd_finite3(o) && kd_finite3(d)) || (d.x == 0.0f && d.y == 0.0f && d.z == 0.0f))
        return;
    float t_enter = t_min;
    float t_exit = t_max;
    if (!(kd_slab(o.x, d.x, bmin.x, bmax.x, &t_enter, &t_exit)
          && kd_slab(o.y, d.y, bmin.y, bmax.y, &t_enter, &t_exit)
          && kd_slab(o.z, d.z, bmin.z, bmax.z, &t_enter, &t_exit)))
        return;
    if (!(t_enter <= t_exit))
        return;

    RayShear shear = ray_shear(d);
    uint stack_node[STACK_SIZE];
    float stack_t_min[STACK_SIZE];
    float stack_t_max[STACK_SIZE];
    uint count = 0;
    uint node = 0;
    float t0 = t_enter;
    float t1 = t_exit;
    uint leaves = 0;
    for (;;) {
        KdNode n = nodes[node];
        while (!kd_is_leaf(n)) {
            uint first, second;
            bool below_first;
            float t_mid;
            uint step = kd_node_step(n, node, o, d, t0, t1, &first, &second, &below_first,
                                     &t_mid);
            if (step == KD_STEP_FIRST || step == KD_STEP_SECOND) {
                node = step == KD_STEP_FIRST ? first : second;
            } else {
                /* both children: the second later, over [t_mid, t1] or, in the plane,
                 * over the same range */
                if (count == STACK_SIZE) {   /* deeper than the tree's depth: corrupt */
                    q->fault = true;
                    return;
                }
                if (step == KD_STEP_IN_PLANE) {
                    t_mid = t1;
                    q->in_plane = true;
                }
                stack_node[count] = second;
                stack_t_min[count] = step == KD_STEP_IN_PLANE ? t0 : t_mid;
                stack_t_max[count] = t1;
                count++;
                node = first;
                t1 = t_mid;
            }
            n = nodes[node];
        }
        if (++leaves > n_nodes) {            /* more leaves than nodes: corrupt */
            q->fault = true;
            return;
        }
        if (kd_query_leaf(query, n, tris, tri_ids, &shear, o, t_min, t_max, t1, q))
            return;
        if (count == 0u)
            return;
        count--;
        node = stack_node[count];
        t0 = stack_t_min[count];
        t1 = stack_t_max[count];
    }
}

/* A query's state before its walk: nothing found (a nearest hit of t_max), the
 * count's rule when `crossing`. */
KD_INLINE
void kd_query_start(KdQuery *q, bool crossing, float t_max)
{
    q->crossing = crossing;
    q->fault = false;
    q->in_plane = false;
    q->n = 0u;
    q->raw = 0u;
    q->hit.t = t_max;
    q->hit.u = 0.0f;
    q->hit.v = 0.0f;
    q->hit.tri = KD_NO_HIT;
}

/* A work-item's rays: RUN consecutive ones from get_global_id(0) * RUN. */
#define KD_FOR_ITEM_RAYS(k)                                                                \
    uint first_ray = (uint)get_global_id(0) * RUN;                                         \
    uint end_ray = min(first_ray + (uint)RUN, n_rays);                                     \
    for (uint k = first_ray; k < end_ray; k++)

#define KD_QUERY_ARGS                                                                      \
    __global const KdNode *nodes, __global const float *tris, __global const uint *tri_ids, \
    __global const float *bounds, uint n_nodes, __global const float *origins,             \
    __global const float *directions, uint o_step, __global const float *t_mins,          \
    __global const float *t_maxs, uint t_step, uint n_rays

#define KD_WALK_RAY(query, k, q)                                                           \
    kd_walk(query, nodes, n_nodes, tris, tri_ids, vload3(0, bounds), vload3(1, bounds),   \
            kd_load3(origins, (size_t)(k) * o_step), kd_load3(directions, k),             \
            t_mins[(k) * t_step], t_maxs[(k) * t_step], q)

/* out[k]: 1 when ray k hits anything with t_min < t < t_max, else 0; 2 on a fault. */
__kernel __attribute__((reqd_work_group_size(LOCAL_SIZE, 1, 1))) KD_NO_LANES
void occluded_rays(KD_QUERY_ARGS, __global uchar *out)
{
    KD_FOR_ITEM_RAYS(k) {
        KdQuery q;
        kd_query_start(&q, false, t_maxs[k * t_step]);
        KD_WALK_RAY(KD_ANY, k, &q);
        out[k] = q.fault ? (uchar)2 : (uchar)q.n;
    }
}

/* out[k]: the number of distinct triangles ray k hits (crossing: under the count's
 * rule), or every hit found | KD_COUNT_RAW when they were more than KD_SEEN, or
 * KD_WALK_FAULT. */
__kernel __attribute__((reqd_work_group_size(LOCAL_SIZE, 1, 1))) KD_NO_LANES
void count_rays(KD_QUERY_ARGS, uint crossing, __global uint *out)
{
    KD_FOR_ITEM_RAYS(k) {
        KdQuery q;
        kd_query_start(&q, crossing != 0u, t_maxs[k * t_step]);
        KD_WALK_RAY(KD_COUNT, k, &q);
        out[k] = q.fault ? KD_WALK_FAULT : (q.n > KD_SEEN ? q.raw | KD_COUNT_RAW : q.n);
    }
}

/* Ray k's hits into slots offsets[k] .. offsets[k] + caps[k] - 1 (hit_t, hit_uv two
 * floats a slot, hit_id the input id), its count into out_n[k] (KD_WALK_FAULT on a
 * fault): with caps[k] at least its distinct hits, every hit, else the caps[k] first
 * in (t, input id) order. Sorted by (t, input id), as refined with REFINE. */
#if defined(REFINE) && defined(cl_khr_fp64)
/* the caller's rays in double, relative to the tree's origin in its units (origins
 * o_step apart, as `origins`), which the hits are refined from, as trace_rays refines
 * its hit from them (render.cl, kd_exact_ray) */
#define KD_EXACT_RAY_ARGS , __global const double *exact_o, __global const double *exact_d
#else
#define KD_EXACT_RAY_ARGS
#endif

__kernel __attribute__((reqd_work_group_size(LOCAL_SIZE, 1, 1))) KD_NO_LANES
void list_rays(KD_QUERY_ARGS, uint crossing, __global const ulong *offsets,
               __global const uint *caps KD_EXACT_RAY_ARGS, __global float *hit_t,
               __global float *hit_uv, __global uint *hit_id, __global uint *out_n)
{
    KD_FOR_ITEM_RAYS(k) {
        KdQuery q;
        kd_query_start(&q, crossing != 0u, t_maxs[k * t_step]);
        ulong at = offsets[k];
        q.t = hit_t + at;
        q.uv = hit_uv + 2u * at;
        q.tri = hit_id + at;             /* copies while walking, input ids at the end */
        q.cap = caps[k];
        KD_WALK_RAY(KD_LIST, k, &q);
        if (q.fault) {
            out_n[k] = KD_WALK_FAULT;
            continue;
        }
#if defined(REFINE) && defined(cl_khr_fp64)
        /* each hit's t, u, v from double (kd_refine_hit), then in order again: the
         * refined t moves by its float rounding at most, so this is a few swaps */
        double3 o = vload3((size_t)k * o_step, exact_o);
        double3 d = vload3(k, exact_d);
        float t_min = t_mins[k * t_step], t_max = t_maxs[k * t_step];
        for (uint j = 0; j < q.n; j++) {
            uint tri = q.tri[j];
            float t = q.t[j], u = q.uv[2u * j], v = q.uv[2u * j + 1u];
            kd_refine_hit(o, d, kd_vertex(tris, tri, 0),
                          kd_vertex(tris, tri, 1), kd_vertex(tris, tri, 2), t_min, t_max,
                          &t, &u, &v);
            uint i = j;
            for (; i > 0u && kd_before(t, tri, q.t[i - 1u], q.tri[i - 1u], tri_ids); i--) {
                q.t[i] = q.t[i - 1u];
                q.uv[2u * i] = q.uv[2u * i - 2u];
                q.uv[2u * i + 1u] = q.uv[2u * i - 1u];
                q.tri[i] = q.tri[i - 1u];
            }
            q.t[i] = t;
            q.uv[2u * i] = u;
            q.uv[2u * i + 1u] = v;
            q.tri[i] = tri;
        }
#endif
        for (uint j = 0; j < q.n; j++)
            q.tri[j] = tri_ids[q.tri[j]];
        out_n[k] = q.n;
    }
}

/* Ray k's nearest hit with t_mins[k] < t < t_maxs[k], the one trace_rays finds
 * (render.cl; the hit depends on the ray and the triangles only, not on the walk):
 * out_t its t (+inf on a miss, NaN on a fault), and where not NULL out_uv (u, v; 0 on
 * a miss), out_normal (unit geometric normal, render.cl's store_hit; 0) and out_id
 * (input id; KD_NO_HIT). With REFINE its t, u, v are refined as trace_rays refines
 * them, from the caller's rays. */
__kernel __attribute__((reqd_work_group_size(LOCAL_SIZE, 1, 1))) KD_NO_LANES
void nearest_rays(KD_QUERY_ARGS KD_EXACT_RAY_ARGS, __global float *out_t,
                  __global float *out_uv, __global float *out_normal, __global uint *out_id)
{
    KD_FOR_ITEM_RAYS(k) {
        KdQuery q;
        float t_min = t_mins[k * t_step], t_max = t_maxs[k * t_step];
        kd_query_start(&q, false, t_max);
        KD_WALK_RAY(KD_NEAREST, k, &q);
        bool found = q.hit.tri != KD_NO_HIT && !q.fault;
        float3 p0 = (float3)(0.0f), p1 = (float3)(0.0f), p2 = (float3)(0.0f);
        if (found) {
            p0 = kd_vertex(tris, q.hit.tri, 0);
            p1 = kd_vertex(tris, q.hit.tri, 1);
            p2 = kd_vertex(tris, q.hit.tri, 2);
#if defined(REFINE) && defined(cl_khr_fp64)
            kd_refine_hit(vload3((size_t)k * o_step, exact_o), vload3(k, exact_d), p0, p1, p2,
                          t_min, t_max, &q.hit.t, &q.hit.u, &q.hit.v);
#endif
        }
        out_t[k] = q.fault ? NAN : (found ? q.hit.t : INFINITY);
        if (out_uv) {
            out_uv[2 * (size_t)k] = found ? q.hit.u : 0.0f;
            out_uv[2 * (size_t)k + 1] = found ? q.hit.v : 0.0f;
        }
        if (out_normal) {
            float3 normal = found ? kd_normalize(kd_cross(p1 - p0, p2 - p0)) : (float3)(0.0f);
            out_normal[3 * (size_t)k] = normal.x;
            out_normal[3 * (size_t)k + 1] = normal.y;
            out_normal[3 * (size_t)k + 2] = normal.z;
        }
        if (out_id)
            out_id[k] = found ? tri_ids[q.hit.tri] : KD_NO_HIT;
    }
}
