/* kernels/queries.cl: ray queries beyond the nearest hit (kdray/rays.py).
 *
 *   count_rays     how many triangles the ray hits: with `crossing`, how many times
 *                  it crosses the surface (triangle.cl, kd_tie: a shared edge or
 *                  vertex counts once); else every triangle hit, for list_rays' sizes
 *   list_rays      every hit, into the ray's own slots, sorted by (t, input id); with
 *                  `crossing`, every crossing (the count's rule: what count_rays
 *                  counts, for the rays whose crossings it could not tell apart)
 *   list_first     (a program built with LIST_SLOTS) a first pass of list_rays with
 *                  at most LIST_SLOTS slots a ray, kept in private memory, the hits
 *                  written packed
 *
 * (Any hit and the nearest hit, with a t range a ray too, are trace_rays': render.cl,
 * with ANY_HIT for any.)
 *
 * One walk (kd_walk) serves them all: it visits every leaf the ray's range reaches,
 * near child first, and hands each to kd_query_leaf, which does what the query does
 * with a hit and says when the walk may stop. Packet programs walk a packet of rays
 * that share their paths as one (kd_packet_walk: a node step for all its lanes, a
 * leaf's triangles against all of them), and other rays through the tree's wide nodes
 * two at a time (kd_wide_walks, wide.cl), each visiting every leaf whose triangles'
 * box its range meets. Unlike the nearest hit's traversal (traverse.cl), a walk needs
 * every leaf (bar a k-nearest list's early stop), so it keeps a full stack and never
 * restarts, and a ray that lies in a split plane visits both
 * children over the same range in one walk (order does not matter here).
 *
 * A triangle in several leaves has a copy in each (layout.h), and a ray that reaches
 * two of them finds the same hit twice (the test depends on the ray and the triangle
 * only): a hit counts once per input id. count_rays keeps the KD_SEEN greatest hits
 * it has counted (t and input id) in private slots, where a copy finds its twin; a
 * ray whose hits come so far out of order that a copy's twin may have been dropped
 * (kd_count_hit) counts every hit found, its count then marked KD_COUNT_RAW (an upper
 * bound, which list_rays, deduplicating in its own slots, makes exact). A wide walk
 * meets each triangle once (the wide nodes hold each in one leaf): its count keeps no
 * hits and is exact however many (KdQuery.unique). The walk's node decisions are
 * traverse.cl's (the same slack), so it visits every leaf the nearest hit's traversal
 * may.
 *
 * Options (-D): STACK_SIZE (at least the tree's depth + 1), LOCAL_SIZE, RUN (rays a
 * work-item takes: consecutive, or a band of an image's pixels, kd_block_rays), REFINE
 * (list_rays' t, u, v recomputed in double, triangle.cl,
 * kd_refine_hit, from the caller's rays in double), LIST_SLOTS (list_first's program:
 * KdQuery's slots private, LIST_SLOTS of them; count_rays and list_rays are left out).
 * Rays are float32, relative to the tree's origin in its units, or with RAYS_WORLD
 * (ORIGIN_T, DIRECTION_T; SCALE and SCALE_INV where the tree's scale is not 1) the
 * caller's rays in world coordinates, converted to those numbers as they are read
 * (world_rays.h, KdRaySource): kdray/rays.py passes an image's rays so, whose
 * conversion on the host took a sixth of a camera's count. Origins and directions
 * start o_offset and d_offset elements into their buffers. t_min, t_max per ray
 * (t_step 1) or one pair for all (t_step 0), in the tree's units. Outputs are in those
 * units too: the host scales t.
 */
#pragma OPENCL FP_CONTRACT OFF
#include "layout.h"
#include "triangle.cl"
#include "traverse.cl"
#include "world_rays.h"
#ifdef PACKET
/* packet programs walk packets that share their paths as one (packet.cl's node step
 * and cull) and test a lone ray's leaf KD_PACKET triangles at a time (kd_ray_block_all) */
#include "packet.cl"
#ifndef KD_WIDE
#error "packet programs of the queries walk rays that share no path through wide nodes: KD_WIDE"
#endif
/* The fewest rays a work-item's block walks as packets (fewer: all through the wide
 * nodes) */
#define KD_PACKET_WALK_MIN 4u
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

#define KD_SEEN 32u                     /* hits count_rays keeps, per ray (2^k) */
#define KD_COUNT_RAW 0x80000000u         /* count_rays: the count is every hit found */
#define KD_WALK_FAULT 0x40000000u        /* the walk met a corrupt tree (never otherwise) */
#define KD_LIST_MORE 0x20000000u         /* list_rays: the ray has more hits than its slots */
#define KD_WINDING 2u                    /* count_rays' crossing argument for windings */
#define KD_WINDING_RAW 0x7FFFFFFFu       /* count_rays: too many crossings for a winding */

#define KD_COUNT 1u
#define KD_LIST 2u

/* The rays a query reads (KD_QUERY_ARGS): ray k's origin o[k * o_step] and direction
 * d[k], float relative to the tree's origin in its units, or with RAYS_WORLD the
 * caller's rays in world coordinates, converted here as the host converts them
 * (world_rays.h: the same numbers). */
typedef struct {
    __global const KD_ORIGIN_T *o;
    __global const KD_DIRECTION_T *d;
    uint o_step;
#ifdef RAYS_WORLD
    double3 origin;                      /* the tree's origin, world coordinates */
#endif
} KdRaySource;

/* Ray k of rays s: its origin and direction as the walks take them */
KD_INLINE
void kd_source_ray(const KdRaySource *s, uint k, float3 *o, float3 *d)
{
#ifdef RAYS_WORLD
    *o = kd_ray_origin(s->o, (size_t)k * s->o_step, s->origin);
#else
    *o = kd_load3(s->o, (size_t)k * s->o_step);
#endif
    *d = kd_ray_direction(s->d, k);
}

/* What a query keeps of one ray while it walks. */
typedef struct {
    bool crossing;                       /* the count's rule (intersect_triangle) */
    bool fault;                          /* the walk's stack or leaf bound was exceeded */
    bool in_plane;                       /* list: a node's plane held the ray */
    bool nearest_k;                      /* list (set by list_rays): the slots want the
                                          * cap nearest hits only, not whether there are
                                          * more: the walk may end (kd_list_done) */
    bool unique;                         /* the walk meets each triangle once (a wide
                                          * walk: the wide nodes hold each triangle in
                                          * one leaf): a count keeps no hits */
    uint n;                              /* distinct hits */
    uint raw;                            /* count: hits found, copies included; list:
                                          * 1 when a hit found no slot */
    int winding;                         /* count: the crossings' facings summed */
    bool lost;                           /* count: a hit may have been a copy of one
                                          * dropped from seen (kd_count_hit): n is
                                          * lost, raw still counts */
    uint kept, head;                     /* count: the entries of seen in use, the
                                          * least's slot */
    float floor_t;                       /* count: the greatest (t, input id) dropped */
    uint floor_id;                       /* from seen (t -inf: none) */
    float seen_t[KD_SEEN];               /* count: the KD_SEEN greatest hits counted, */
    uint seen[KD_SEEN];                  /* (t, input id), a sorted ring */
    /* list: the ray's slots, cap of them, n used, sorted by (t, input id): in the
     * caller's buffers, or with LIST_SLOTS in private memory (list_first) */
#ifdef LIST_SLOTS
    float t[LIST_SLOTS];
    float uv[2 * LIST_SLOTS];
    uint tri[LIST_SLOTS];                /* the device's triangle copy (layout.h) */
#else
    __global float *t;
    __global float *uv;
    __global uint *tri;
#endif
    uint cap;
} KdQuery;

/* count: whether (t, id) comes before (t2, id2) (or_equal: or is the same) */
KD_INLINE
bool kd_count_before(float t, uint id, float t2, uint id2, bool or_equal)
{
    return t < t2 || (t == t2 && (id < id2 || (or_equal && id == id2)));
}

/* count: one more hit, at t of input id `id` (facing: kd_facing's, for crossings),
 * counted unless counted already. A k-d walk meets a triangle in every leaf that holds
 * a copy of it, and a copy's hit has its twin's (t, id) bit for bit (kd_list_hit).
 * seen keeps the KD_SEEN greatest hits counted, sorted by (t, id) in a ring (entry i
 * at (head + i) % KD_SEEN), floor the greatest dropped from it: a hit after the floor
 * is a copy exactly where its place in seen follows its (t, id) (its twin, as great,
 * was never dropped); one at or before the floor may be a dropped hit's copy, and the
 * count is lost (raw then counts every hit found, which list_rays makes exact). The
 * walks take leaves near first, so hits mostly come in t order, each put in place
 * in a step or two and copies soon after their twins: a ray through thousands of
 * stacked triangles keeps its count. */
#define KD_SEEN_AT(q, i) (((q)->head + (i)) & (KD_SEEN - 1u))

KD_INLINE
void kd_count_hit(KdQuery *q, uint id, float t, int facing)
{
    q->raw++;
    if (q->unique) {                     /* no copies: every hit is a distinct one */
        q->n++;
        q->winding += facing;
        return;
    }
    if (q->lost)
        return;
    if (kd_count_before(t, id, q->floor_t, q->floor_id, true)) {
        q->lost = true;
        return;
    }
    uint j = q->kept;
    while (j > 0u && kd_count_before(t, id, q->seen_t[KD_SEEN_AT(q, j - 1u)],
                                     q->seen[KD_SEEN_AT(q, j - 1u)], false))
        j--;
    uint before = KD_SEEN_AT(q, j - 1u);
    if (j > 0u && q->seen_t[before] == t && q->seen[before] == id)
        return;                          /* a copy of a hit counted */
    q->n++;
    q->winding += facing;
    if (q->kept == KD_SEEN) {
        if (j == 0u) {                   /* the least of them all: dropped at once */
            q->floor_t = t;
            q->floor_id = id;
            return;
        }
        q->floor_t = q->seen_t[q->head]; /* the least kept dropped for it */
        q->floor_id = q->seen[q->head];
        q->head = KD_SEEN_AT(q, 1u);
        q->kept--;
        j--;
    }
    for (uint i = q->kept; i > j; i--) {
        q->seen_t[KD_SEEN_AT(q, i)] = q->seen_t[KD_SEEN_AT(q, i - 1u)];
        q->seen[KD_SEEN_AT(q, i)] = q->seen[KD_SEEN_AT(q, i - 1u)];
    }
    q->seen_t[KD_SEEN_AT(q, j)] = t;
    q->seen[KD_SEEN_AT(q, j)] = id;
    q->kept++;
}

/* The side triangle (p0, p1, p2) turns to the ray where intersect_triangle's crossing
 * rule says the ray crosses it: +1 where the ray leaves through its front (its
 * counter-clockwise side: outward on an outward-oriented mesh), -1 where it enters.
 * The crossing's edge functions, computed as intersect_triangle computes them (the
 * same float shear, then exact products in double: exact signs), are all of one sign
 * or 0, so the first that is not 0 gives it. Summed over a ray's crossings on a closed,
 * consistently oriented mesh: the winding number of the ray's origin. */
KD_INLINE
int kd_facing(const RayShear *s, float3 o, float3 p0, float3 p1, float3 p2)
{
    KD_SHEAR_VERTICES(s, o, p0, p1, p2)
#ifdef cl_khr_fp64
    double U = (double)Cx * (double)By - (double)Cy * (double)Bx;
    double V = (double)Ax * (double)Cy - (double)Ay * (double)Cx;
    double W = (double)Bx * (double)Ay - (double)By * (double)Ax;
#else
    float U = Cx * By - Cy * Bx, V = Ax * Cy - Ay * Cx, W = Bx * Ay - By * Ax;
#endif
    bool positive = U != 0 ? U > 0 : (V != 0 ? V > 0 : W > 0);
    return positive ? -1 : 1;
}

/* list: where the hit (t, copy `tri`) goes among slots 0 .. j - 1, looked for from j
 * back: the first slot that comes after it in (t, input id) order. */
KD_INLINE
uint kd_slot_place(const KdQuery *q, uint j, float t, uint tri, __global const uint *tri_ids)
{
    while (j > 0u && kd_before(t, tri, q->t[j - 1u], q->tri[j - 1u], tri_ids))
        j--;
    return j;
}

/* list: slots j .. end - 1 moved up one (over slot end), and the hit (t, u, v) of copy
 * `tri` put in slot j. */
KD_INLINE
void kd_slot_put(KdQuery *q, uint end, uint j, float t, float u, float v, uint tri)
{
    for (; end > j; end--) {
        q->t[end] = q->t[end - 1u];
        q->uv[2u * end] = q->uv[2u * end - 2u];
        q->uv[2u * end + 1u] = q->uv[2u * end - 1u];
        q->tri[end] = q->tri[end - 1u];
    }
    q->t[j] = t;
    q->uv[2u * j] = u;
    q->uv[2u * j + 1u] = v;
    q->tri[j] = tri;
}

/* list: the hit (t, u, v) of copy `tri` into the ray's slots, kept sorted by (t, input
 * id); with every slot taken (max_hits) it replaces the last one if it comes before it.
 * Its place is found from the end (a few steps: the walks take leaves near first, so a
 * hit mostly comes after those listed). A copy of a triangle listed already (a k-d
 * walk meets a triangle in every leaf that holds it) is the same ray through the same
 * test of the same vertices, so it has its twin's t bit for bit (the rule that makes
 * packets and lone rays agree) and sorts next to it: it is dropped where the slot
 * before its place holds its (t, input id). So a hit costs its steps back to its
 * place, not a scan of the whole list. A hit dropped at the cap, and its copies, never
 * come back: the last slot only moves nearer. */
KD_INLINE
void kd_list_hit(KdQuery *q, uint tri, float t, float u, float v, __global const uint *tri_ids)
{
    uint n = q->n, j = kd_slot_place(q, n, t, tri, tri_ids);
    if (j > 0u && q->t[j - 1u] == t && tri_ids[q->tri[j - 1u]] == tri_ids[tri])
        return;                          /* a copy of a hit listed */
    if (n == q->cap) {
        q->raw = 1u;                     /* a triangle beyond the cap: more hits than slots */
        if (j == n)
            return;                      /* after the last slot */
        n--;                             /* the last slot's hit is dropped */
    } else {
        q->n = n + 1u;
    }
    kd_slot_put(q, n, j, t, u, v, tri);
}

#ifdef PACKET
/* The count's crossing rule on KD_PACKET (ray, triangle) pairs, one a lane: the lanes
 * in `valid` whose triangle the ray may cross. P: the triangles' vertices along each
 * lane's shear axes (kd_lane_vertices' order), okx, oky, okz the ray's origin along
 * them, Sx, Sy its shear. intersect_triangle's sheared edge functions U, V, W,
 * computed alike lane by lane (the same operations in the same order), have the sign
 * of their exact values wherever KD_EDGE_SURE holds; a triangle with one surely
 * positive and one surely negative is crossed under no rule, and every other lane
 * (NaN included) is left to intersect_triangle, which decides it exactly. So the
 * lanes kept hold every crossing, and the count is the scalar loop's. */
KD_INLINE
intP kd_crossing_pairs(const floatP *P, floatP okx, floatP oky, floatP okz, floatP Sx,
                       floatP Sy, intP valid)
{
    floatP Az = P[2] - okz, Bz = P[5] - okz, Cz = P[8] - okz;
    floatP Ax = (P[0] - okx) - Sx * Az, Ay = (P[1] - oky) - Sy * Az;
    floatP Bx = (P[3] - okx) - Sx * Bz, By = (P[4] - oky) - Sy * Bz;
    floatP Cx = (P[6] - okx) - Sx * Cz, Cy = (P[7] - oky) - Sy * Cz;
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

/* kd_crossing_pairs for one ray (shear s, origin o) and a run of KD_PACKET triangles
 * (q: kd_gather_tris' 9 vectors). */
KD_INLINE
intP kd_crossing_lanes(const RayShear *s, float3 o, const KdFP *q, intP valid)
{
    uint kx = s->kx, ky = s->ky, kz = s->kz;
    floatP P[9];
    for (uint i = 0; i < 3u; i++) {
        P[3u * i] = q[3u * i + kx].v;
        P[3u * i + 1u] = q[3u * i + ky].v;
        P[3u * i + 2u] = q[3u * i + kz].v;
    }
    return kd_crossing_pairs(P, (floatP)(kd_comp(o, kx)), (floatP)(kd_comp(o, ky)),
                             (floatP)(kd_comp(o, kz)), (floatP)(s->Sx), (floatP)(s->Sy), valid);
}
#endif

/* list (nearest_k): whether the walk may end at a leaf whose exit is t_exit: every slot
 * taken and the last one's hit final there (kd_hit_final), so that no later leaf holds
 * a nearer hit, unless a node's plane has held the ray (kd_query_leaf). */
KD_INLINE
bool kd_list_done(const KdQuery *q, float t_exit)
{
    return q->nearest_k && q->cap > 0u && q->n == q->cap && !q->in_plane
           && kd_hit_final(q->t[q->cap - 1u], t_exit);
}

/* Test a leaf's triangles for `query` (count or list); true when the walk may stop:
 * a list, when kd_list_done (its nearest hits taken and final at the leaf's exit
 * t_exit). */
KD_INLINE
bool kd_query_leaf(uint query, KdNode leaf, __global const float *tris,
                   __global const uint *tri_ids, const RayShear *shear, float3 o, float t_min,
                   float t_max, float t_exit, KdQuery *q)
{
    uint count = kd_n_prims(leaf);
    uint first = kd_leaf_offset(leaf);
#ifdef PACKET
    if (!q->crossing) {
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
                    kd_count_hit(q, tri_ids[tri], t.s[j], 0);
                else
                    kd_list_hit(q, tri, t.s[j], V.s[j] / det.s[j], W.s[j] / det.s[j], tri_ids);
            }
        }
        return query == KD_LIST && kd_list_done(q, t_exit);
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
            if (!c.s[j] || !intersect_triangle(shear, o, kd_vertex(tris, tri, 0),
                                               kd_vertex(tris, tri, 1), kd_vertex(tris, tri, 2),
                                               tri, t_min, t_max, t_max, KD_NO_HIT, tri_ids,
                                               true, &t, &u, &v))
                continue;
            if (query == KD_COUNT)
                kd_count_hit(q, tri_ids[tri], t,
                             kd_facing(shear, o, kd_vertex(tris, tri, 0),
                                       kd_vertex(tris, tri, 1), kd_vertex(tris, tri, 2)));
            else
                kd_list_hit(q, tri, t, u, v, tri_ids);
        }
    }
    return query == KD_LIST && kd_list_done(q, t_exit);
#endif
    for (uint i = 0; i < count; i++) {
        uint tri = first + i;
        float t, u, v;
        if (!intersect_triangle(shear, o, kd_vertex(tris, tri, 0), kd_vertex(tris, tri, 1),
                                kd_vertex(tris, tri, 2), tri, t_min, t_max, t_max, KD_NO_HIT,
                                tri_ids, q->crossing, &t, &u, &v))
            continue;
        if (query == KD_COUNT)
            kd_count_hit(q, tri_ids[tri], t,
                         q->crossing ? kd_facing(shear, o, kd_vertex(tris, tri, 0),
                                                 kd_vertex(tris, tri, 1), kd_vertex(tris, tri, 2))
                                     : 0);
        else
            kd_list_hit(q, tri, t, u, v, tri_ids);
    }
    return query == KD_LIST && kd_list_done(q, t_exit);
}

/* The walk of one ray carried on from `node` over [t0, t1], with `count` entries on
 * its stack (entry i: stack_node[i * stride], stack_t0[..], stack_t1[..]; room for
 * STACK_SIZE) and `leaves` leaves visited: every leaf left, near child first, each
 * handed to kd_query_leaf until it says stop. kd_walk starts it at the root. */
KD_INLINE
void kd_walk_on(uint query, __global const KdNode *nodes, uint n_nodes,
                __global const float *tris, __global const uint *tri_ids,
                const RayShear *shear, float3 o, float3 d, float t_min, float t_max,
                uint node, float t0, float t1, uint *stack_node, float *stack_t0,
                float *stack_t1, uint stride, uint count, uint leaves, KdQuery *q)
{
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
                stack_node[count * stride] = second;
                stack_t0[count * stride] = step == KD_STEP_IN_PLANE ? t0 : t_mid;
                stack_t1[count * stride] = t1;
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
        if (kd_query_leaf(query, n, tris, tri_ids, shear, o, t_min, t_max, t1, q))
            return;
        if (count == 0u)
            return;
        count--;
        node = stack_node[count * stride];
        t0 = stack_t0[count * stride];
        t1 = stack_t1[count * stride];
    }
}

/* The ray o + t d's range [t_min, t_max] clipped to the scene box (bmin, bmax) as
 * [*t_enter, *t_exit]; false when the ray has nothing to walk (not finite, d 0, or
 * missing the box). */
KD_INLINE
bool kd_walk_range(float3 bmin, float3 bmax, float3 o, float3 d, float t_min, float t_max,
                   float *t_enter, float *t_exit)
{
    if (!(kd_finite3(o) && kd_finite3(d)) || kd_no_direction(d))
        return false;
    *t_enter = t_min;
    *t_exit = t_max;
    if (!(kd_slab(o.x, d.x, bmin.x, bmax.x, t_enter, t_exit)
          && kd_slab(o.y, d.y, bmin.y, bmax.y, t_enter, t_exit)
          && kd_slab(o.z, d.z, bmin.z, bmax.z, t_enter, t_exit)))
        return false;
    *t_enter = KD_BOX_ENTER(*t_enter);
    *t_exit = KD_BOX_EXIT(*t_exit);
    return *t_enter <= *t_exit;
}

/* Walk every leaf of the ray o + t d's range [t_min, t_max] within the scene box
 * (bmin, bmax), near child first, each leaf once, handing each to kd_query_leaf. */
KD_INLINE
void kd_walk(uint query, __global const KdNode *nodes, uint n_nodes, __global const float *tris,
             __global const uint *tri_ids, float3 bmin, float3 bmax, float3 o, float3 d,
             float t_min, float t_max, KdQuery *q)
{
    float t_enter, t_exit;
    if (!kd_walk_range(bmin, bmax, o, d, t_min, t_max, &t_enter, &t_exit))
        return;
    RayShear shear = ray_shear(d);
    uint stack_node[STACK_SIZE];
    float stack_t0[STACK_SIZE];
    float stack_t1[STACK_SIZE];
    kd_walk_on(query, nodes, n_nodes, tris, tri_ids, &shear, o, d, t_min, t_max, 0u, t_enter,
               t_exit, stack_node, stack_t0, stack_t1, 1u, 0u, 0u, q);
}

#ifdef PACKET
/* How far a query's walk must still look: t_max, or once a k-nearest list's slots are
 * full, its last hit's t (an entry beyond it holds no nearer hit; one at it may hold
 * a tie with a lower input id, and is walked). A list's fields only for a list (a
 * count's are not set). */
KD_INLINE
float kd_query_far(uint query, const KdQuery *q, float t_max)
{
    if (query == KD_LIST && q->nearest_k && q->cap > 0u && q->n == q->cap)
        return kd_min(t_max, q->t[q->cap - 1u]);
    return t_max;
}

/* One entry off a query's wide walk (wide.cl): a leaf handed to kd_query_leaf, or a
 * wide node's children that the ray meets before kd_query_far pushed. (No fault
 * check as kd_walk_on's: the wide nodes are made by the Tracer, never read from a
 * file, and children come after their parents, kdray/wide.py.) */
KD_INLINE
void kd_wide_query_step(uint query, KdWideRay *r, KdQuery *q, __global const uint *wide,
                        __global const float *tris, __global const uint *tri_ids)
{
    uint child;
    float far = kd_query_far(query, q, r->t_max);
    if (kd_wide_pop(r, &child) > far)
        return;
    if (child & KD_WIDE_LEAF) {
        /* no exit t: a wide walk ends when its stack does (kd_query_far prunes it) */
        if (kd_query_leaf(query, kd_wide_leaf(child), tris, tri_ids, &r->shear, r->o,
                          r->t_min, r->t_max, -INFINITY, q))
            r->top = 0u;
        return;
    }
    /* a count visits every child its range meets: no order needed */
    kd_wide_push(r, wide + (size_t)child * KD_WIDE_WORDS, far, query != KD_COUNT);
}

/* Start ray k's wide walk into r (its stack st), or leave r->top 0 where the ray has
 * nothing to walk (kd_walk_range). */
KD_INLINE
void kd_wide_query_start(KdWideRay *r, KdWideStack *st, const KdRaySource *src,
                         __global const float *t_mins, __global const float *t_maxs,
                         uint t_step, uint k, float3 bmin, float3 bmax, float reach)
{
    float3 o, d;
    kd_source_ray(src, k, &o, &d);
    float t_min = t_mins[k * t_step], t_max = t_maxs[k * t_step], t_enter, t_exit;
    r->top = 0u;
    if (kd_walk_range(bmin, bmax, o, d, t_min, t_max, &t_enter, &t_exit))
        kd_wide_start(r, st, o, d, t_min, t_max, reach);
}

/* The walks of rays ids[rays[i]] into q[rays[i]] (i < n) through the wide nodes, two at
 * a time taking their steps in turns (wide.cl): every leaf whose triangles' box the
 * ray's range meets, so every hit kd_walk finds, each leaf once; a k-nearest list's
 * walk pruned by its last slot's t. */
KD_INLINE
void kd_wide_walks(uint query, __global const uint *wide, __global const float *tris,
                   __global const uint *tri_ids, float3 bmin, float3 bmax,
                   const KdRaySource *src, __global const float *t_mins,
                   __global const float *t_maxs, uint t_step, const uint *ids,
                   const uchar *rays, uint n, KdQuery *q)
{
    float reach = kd_wide_reach(bmin, bmax);
    KdWideStack sa, sb;
    for (uint i = 0u; i < n; i += 2u) {
        uint ia = rays[i], ib = i + 1u < n ? rays[i + 1u] : rays[i];
        KdWideRay a, b;
        kd_wide_query_start(&a, &sa, src, t_mins, t_maxs, t_step, ids[ia], bmin, bmax,
                            reach);
        b.top = 0u;
        if (i + 1u < n)
            kd_wide_query_start(&b, &sb, src, t_mins, t_maxs, t_step, ids[ib], bmin, bmax,
                                reach);
        q[ia].unique = true;             /* (ib is ia where there is no second ray) */
        q[ib].unique = true;
        while (a.top | b.top) {
            if (a.top)
                kd_wide_query_step(query, &a, &q[ia], wide, tris, tri_ids);
            if (b.top)
                kd_wide_query_step(query, &b, &q[ib], wide, tris, tri_ids);
        }
    }
}

/* A packet's lanes' origins along their shared axes (o[0..2]: kx, ky, kz) and shear
 * constants, least and greatest over its lanes that are on: what kd_walk_culls takes. */
typedef struct {
    float o_lo[3], o_hi[3];
    float Sx_lo, Sx_hi, Sy_lo, Sy_hi;
} KdLaneBounds;

#ifdef KD_CULL
KD_INLINE
void kd_lane_bounds(const KdPacket *r, intP on, uint first, KdLaneBounds *b)
{
    floatP x[5] = {r->okx, r->oky, r->okz, r->Sx, r->Sy};
    float lo[5], hi[5];
    for (uint c = 0; c < 5u; c++) {
        KdFP v;
        v.v = x[c];
        /* the lanes that are off take the first lane's value */
        kd_rangeP(kd_selectP((floatP)(v.s[first]), v.v, on), &lo[c], &hi[c]);
    }
    for (uint c = 0; c < 3u; c++) {
        b->o_lo[c] = lo[c];
        b->o_hi[c] = hi[c];
    }
    b->Sx_lo = lo[3]; b->Sx_hi = hi[3]; b->Sy_lo = lo[4]; b->Sy_hi = hi[4];
}

/* The greatest and least of a * c over a in [a_lo, a_hi] and c in [c_lo, c_hi], as
 * float products: at the corners, rounding being monotone in each factor. */
KD_INLINE
void kd_product_range(float a_lo, float a_hi, floatP c_lo, floatP c_hi, floatP *lo, floatP *hi)
{
    floatP p = a_lo * c_lo, q = a_lo * c_hi, r = a_hi * c_lo, s = a_hi * c_hi;
    *lo = kd_minP(kd_minP(p, q), kd_minP(r, s));
    *hi = kd_maxP(kd_maxP(p, q), kd_maxP(r, s));
}

/* Which of the KD_PACKET triangles in q (kd_gather_tris' 9 vectors) no lane of packet
 * r (r->uniform: one set of shear axes; b: its lanes' bounds) can hit or cross:
 * kd_block_culls' four tests (packet.cl, where the reasoning is) with each lane's
 * origin and shear anywhere in their ranges, so packets of rays from many origins
 * cull too (a query's packets: parallel rays of `contains`, a camera's). A lane's
 * sheared x of a vertex, (P.x - o.x) - S (P.z - o.z) in float, is at least (P.x -
 * o_hi.x) - the greatest of S (P.z - o.z) over the bounds (kd_product_range; a
 * difference's rounding is monotone in each operand), and at most the other way
 * round. A triangle strictly on one side of a line through a lane's ray is crossed
 * under no rule either: the crossing rule moves the ray by an infinitesimal step. */
KD_INLINE
intP kd_walk_culls(const KdPacket *r, const KdLaneBounds *b, const KdFP *q)
{
    intP x_above = (intP)(-1), x_below = (intP)(-1), y_above = (intP)(-1), y_below = (intP)(-1);
#pragma unroll
    for (uint v = 0; v < 3; v++) {
        floatP px = q[3 * v + r->ukx].v, py = q[3 * v + r->uky].v, pz = q[3 * v + r->ukz].v;
        floatP az_lo = pz - b->o_hi[2], az_hi = pz - b->o_lo[2];
        floatP sx_lo, sx_hi, sy_lo, sy_hi;
        kd_product_range(b->Sx_lo, b->Sx_hi, az_lo, az_hi, &sx_lo, &sx_hi);
        kd_product_range(b->Sy_lo, b->Sy_hi, az_lo, az_hi, &sy_lo, &sy_hi);
        x_above &= (px - b->o_hi[0]) - sx_hi > 0.0f;
        x_below &= (px - b->o_lo[0]) - sx_lo < 0.0f;
        y_above &= (py - b->o_hi[1]) - sy_hi > 0.0f;
        y_below &= (py - b->o_lo[1]) - sy_lo < 0.0f;
    }
    return x_above | x_below | y_above | y_below;
}
#endif

/* Triangle `tri`'s hits for count and list, the packet's lanes in `act` at once
 * (kd_packet_leaf's pairs): the crossing rule's candidates (kd_crossing_pairs) each
 * decided by intersect_triangle with its lane's shear, or the nearest hit's rule
 * (kd_test_pairs with no best hit yet), then kd_count_hit or kd_list_hit lane by lane,
 * as kd_query_leaf does with the same pairs. r: the packet (each lane's shear and
 * origin: kd_lane_shear, kd_walk's bit for bit); t_min, t_max: each lane's range; q[l]:
 * lane l's query. */
KD_INLINE
void kd_packet_query_tri(uint query, bool crossing, uint tri, __global const float *tris,
                         __global const uint *tri_ids, const KdPacket *r, intP act,
                         const KdFP *t_min,
                         const KdFP *t_max, KdQuery *q)
{
    __global const float *p = kd_tri_base(tris, tri);
    floatP P[9];
    kd_lane_vertices(r, p, P);
    KdIP c;
    KdFP t, V, W, det;
    if (crossing) {
        c.v = kd_crossing_pairs(P, r->okx, r->oky, r->okz, r->Sx, r->Sy, act);
    } else {
        KdPairs src;
        src.r = r; src.p = p;
        c.v = kd_test_pairs(P[0], P[1], P[2], P[3], P[4], P[5], P[6], P[7], P[8],
                            r->okx, r->oky, r->okz, r->Sx, r->Sy, r->Sz, t_min->v,
                            t_max->v, t_max->v, (uintP)(KD_NO_HIT), (uintP)(tri), tri_ids,
                            act, &src, &t.v, &V.v, &W.v, &det.v);
    }
    uint lanes = kd_bitsP(c.v);
    if (lanes == 0u)
        return;
    uint id = tri_ids[tri];
    float3 p0 = kd_base_vertex(p, 0), p1 = kd_base_vertex(p, 1), p2 = kd_base_vertex(p, 2);
    do {
        uint l = kd_take_lane(&lanes);
        if (!crossing) {
            if (query == KD_LIST)
                kd_list_hit(&q[l], tri, t.s[l], V.s[l] / det.s[l], W.s[l] / det.s[l], tri_ids);
            else
                kd_count_hit(&q[l], id, t.s[l], 0);
        } else {
            RayShear sl;
            float3 ol;
            kd_lane_shear(r, l, &sl, &ol);
            float th, u, v;
            if (!intersect_triangle(&sl, ol, p0, p1, p2, tri, t_min->s[l], t_max->s[l],
                                    t_max->s[l], KD_NO_HIT, tri_ids, true, &th, &u, &v))
                continue;
            if (query == KD_LIST)
                kd_list_hit(&q[l], tri, th, u, v, tri_ids);
            else
                kd_count_hit(&q[l], id, th, kd_facing(&sl, ol, p0, p1, p2));
        }
    } while (lanes);
}

/* A leaf's hits for count and list, for the packet's lanes in `act`: its triangles one
 * by one (kd_packet_query_tri), those no lane can hit left out KD_PACKET at a time
 * where the packet's lanes share their axes (kd_walk_culls, b not NULL). */
KD_INLINE
void kd_packet_query_leaf(uint query, bool crossing, KdNode leaf, __global const float *tris,
                          __global const uint *tri_ids, const KdPacket *r,
                          const KdLaneBounds *b, intP act, const KdFP *t_min,
                          const KdFP *t_max, KdQuery *q)
{
    uint count = kd_n_prims(leaf);
    uint first = kd_leaf_offset(leaf);
#ifdef KD_CULL
    if (b) {
        for (uint i0 = 0; i0 < count; i0 += KD_PACKET) {
            uint m = count - i0 < KD_PACKET ? count - i0 : KD_PACKET;
            KdFP qv[9];
            kd_gather_tris(tris, first + i0, qv);
            /* one origin: packet.cl's cull, which needs no bounds of the origins */
            intP culls = r->cull ? kd_block_culls(r, qv) : kd_walk_culls(r, b, qv);
            uint keep = kd_bitsP((KD_LANE_INDEX < (intP)((int)m)) & ~culls);
            while (keep != 0u)
                kd_packet_query_tri(query, crossing, first + i0 + kd_take_lane(&keep), tris,
                                    tri_ids, r, act, t_min, t_max, q);
        }
        return;
    }
#endif
    for (uint i = 0; i < count; i++)
        kd_packet_query_tri(query, crossing, first + i, tris, tri_ids, r, act, t_min, t_max,
                            q);
}

/* Leaf `leaf` of the walks of the packet's lanes in `act` (r, b: kd_packet_query_leaf's;
 * lo, hi: each lane's range; t_exit: where each leaves the leaf, -inf where a walk's
 * stack alone ends it): with many lanes a triangle against all of them at a time,
 * else lane by lane kd_query_leaf's blocks. Returns the lanes whose walk may stop
 * (kd_list_done). */
KD_INLINE
intP kd_packet_walk_leaf(uint query, bool crossing, KdNode leaf, __global const float *tris,
                         __global const uint *tri_ids, const KdPacket *r,
                         const KdLaneBounds *b, intP act, const KdFP *lo, const KdFP *hi,
                         floatP t_exit, KdQuery *q)
{
    uint at_leaf = kd_bitsP(act), done = 0u;
    uint tests = kd_n_prims(leaf);
    KdFP t_exit_l;
    t_exit_l.v = t_exit;
    if ((float)(popcount(at_leaf) * ((tests + KD_PACKET - 1) / KD_PACKET))
           >= (KD_CULLS(r) ? KD_CULL_LANE_RATIO : KD_LANE_RATIO) * (float)tests) {
        /* many lanes: a triangle against all of them at a time */
        kd_packet_query_leaf(query, crossing, leaf, tris, tri_ids, r, b, act, lo, hi, q);
        for (uint at = query == KD_LIST ? at_leaf : 0u; at;) {
            uint l = kd_take_lane(&at);
            if (kd_list_done(&q[l], t_exit_l.s[l]))
                done |= 1u << l;
        }
        return kd_maskP(done);
    }
    while (at_leaf) {
        uint l = kd_take_lane(&at_leaf);
        RayShear sl;             /* the lane's shear and origin, kd_walk's bit for bit */
        float3 ol;
        kd_lane_shear(r, l, &sl, &ol);
        if (kd_query_leaf(query, leaf, tris, tri_ids, &sl, ol, lo->s[l], hi->s[l],
                          t_exit_l.s[l], &q[l]))
            done |= 1u << l;
    }
    return kd_maskP(done);
}

/* The walks of the packet's lanes in `act` (r, b: kd_packet_query_leaf's; lo, hi: each
 * lane's range), whose directions all lie in `octant`, through the wide nodes as one
 * (wide.cl, kd_packet_wide_node: each lane's slab test kd_wide_push's): every leaf
 * whose box a lane's range meets, for that lane, each once, as kd_wide_walks visits
 * them; a k-nearest list's lane pruned by its last slot's t (kd_query_far). */
KD_INLINE
void kd_packet_wide_walk(uint query, bool crossing, __global const uint *wide,
                         __global const float *tris, __global const uint *tri_ids,
                         const KdPacket *r, const KdLaneBounds *b, intP act, uint octant,
                         float reach, const KdFP *lo, const KdFP *hi, KdQuery *q)
{
    KdPacketWideStack st;
    st.count = 0u;
    KdPacketWide p;
    kd_packet_wide_start(&p, r, octant, reach, lo->v);
    KdFP far;                            /* each lane's kd_query_far */
    far.v = hi->v;
    uint child = 0u;                     /* the root, with the lanes in act */
    for (;;) {
        if (child & KD_WIDE_LEAF) {
            /* no exit t: a walk ends when its stack does (kd_query_far prunes it) */
            kd_packet_walk_leaf(query, crossing, kd_wide_leaf(child), tris, tri_ids, r, b, act,
                                lo, hi, (floatP)(-INFINITY), q);
            if (query == KD_LIST) {
                for (uint at = kd_bitsP(act); at;) {
                    uint l = kd_take_lane(&at);
                    far.s[l] = kd_query_far(query, &q[l], hi->s[l]);
                }
            }
        } else if (kd_packet_wide_step(&p, wide, &child, &act, far.v, &st)) {
            continue;
        }
        /* the next entry that a lane enters at or before its far */
        if (!kd_packet_wide_pop(&st, (intP)(-1), far.v, &child, &act))
            return;
    }
}

/* The walks of the packet of rays ids[0 .. m - 1] (m <= KD_PACKET) into q[0 .. m - 1]
 * on one path, as trace_packet traverses rays that share their paths (packet.cl): where
 * their directions share an octant, through the wide nodes (kd_packet_wide_walk); else
 * through the k-d tree, one node step for all the lanes, each taking the children it
 * needs (kd_packet_step: traverse.cl's rules and slack), and every leaf a lane's range
 * reaches handed to kd_query_leaf for that lane, until it says stop. Returns the lanes to be walked on
 * their own from their start: every lane of rays that share no path (kd_alone), else
 * those that cannot follow the packet (a ray in a node's plane, or needing both
 * children in the other order), and on a stack or leaf bound exceeded (a corrupt
 * tree: kd_walk reports it) every lane not done. A lane's range is kd_walk's
 * (kd_walk_range), every leaf with a hit in it is visited (the slack) and a leaf's
 * hits depend on the ray and the triangles only: each ray's answer is its kd_walk's. */
KD_INLINE
intP kd_packet_walk(uint query, __global const KdNode *nodes, uint n_nodes,
                    __global const uint *wide,
                    __global const float *tris, __global const uint *tri_ids, float3 bmin,
                    float3 bmax, const KdRaySource *src, __global const float *t_mins,
                    __global const float *t_maxs, uint t_step, const uint *ids, uint m,
                    bool crossing, KdQuery *q)
{
    KdFP o[3], dx, dy, dz, enter, exit, lo, hi;
    uint on_bits = 0u;
    for (uint l = 0; l < KD_PACKET; l++) {
        /* lanes past m repeat the first ray (off): kd_alone and the shear see real rays */
        uint k = ids[l < m ? l : 0u];
        float3 p, d;
        kd_source_ray(src, k, &p, &d);
        o[0].s[l] = p.x; o[1].s[l] = p.y; o[2].s[l] = p.z;
        dx.s[l] = d.x; dy.s[l] = d.y; dz.s[l] = d.z;
        lo.s[l] = t_mins[k * t_step];
        hi.s[l] = t_maxs[k * t_step];
        if (l < m && kd_walk_range(bmin, bmax, p, d, lo.s[l], hi.s[l], &enter.s[l],
                                   &exit.s[l]))
            on_bits |= 1u << l;
        else
            enter.s[l] = exit.s[l] = 0.0f;
    }
    if (on_bits == 0u)
        return (intP)(0);                /* no lane has a range to walk: nothing found */
    intP on = kd_maskP(on_bits);
    uint first = kd_take_lane(&on_bits);
    KdPacket r;
    r.uo[0] = o[0].s[first]; r.uo[1] = o[1].s[first]; r.uo[2] = o[2].s[first];
    r.shared_o = !kd_anyP(on & ((o[0].v != (floatP)(r.uo[0])) | (o[1].v != (floatP)(r.uo[1]))
                                | (o[2].v != (floatP)(r.uo[2]))));
    if (kd_alone(&r, on, false, o[0].v, o[1].v, o[2].v, dx.v, dy.v, dz.v, bmin, bmax))
        return on;
    kd_packet_shear(&r, on, first, o[0].v, o[1].v, o[2].v, dx.v, dy.v, dz.v, (floatP)(0.0f),
                    (floatP)(INFINITY));

    const KdLaneBounds *bounds = 0;      /* kd_walk_culls' bounds, where it applies */
#ifdef KD_CULL
    KdLaneBounds lane_bounds;
    if (r.uniform) {
        kd_lane_bounds(&r, on, first, &lane_bounds);
        bounds = &lane_bounds;
    }
#endif
    uint octant;
    if (kd_packet_octant(&r, on, first, &octant)) {
        /* directions in one octant: through the wide nodes as one (no lane leaves) */
        kd_packet_wide_walk(query, crossing, wide, tris, tri_ids, &r, bounds, on, octant,
                            kd_wide_reach(bmin, bmax), &lo, &hi, q);
        return (intP)(0);
    }

    uint stack_node[PACKET_STACK_SIZE];
    floatP stack_t_min[PACKET_STACK_SIZE];
    floatP stack_t_max[PACKET_STACK_SIZE];
    intP stack_act[PACKET_STACK_SIZE];
    uint count = 0u;
    uint leaves = 0u;
    intP act = on;
    intP live = on;                      /* lanes whose walk goes on */
    intP fallback = (intP)(0);
    uint node = 0u;
    floatP t_min_cur = enter.v, t_max_cur = exit.v;
    floatP t_lo = t_min_cur * (1.0f - KD_T_SLACK);
    floatP t_hi = t_max_cur * (1.0f + KD_T_SLACK);
    for (;;) {
        KdNode n = nodes[node];
        while (!kd_is_leaf(n)) {
            /* both children, loaded while the step runs (as kd_packet_traverse) */
            KdNode n_below = nodes[node + 1u], n_above = nodes[kd_above_child(n)];
            KdPacketStep st = kd_packet_step(&r, kd_split_axis(n), kd_split(n), act, t_lo, t_hi);
            if (kd_anyP(st.leave)) {
                fallback |= st.leave;
                live &= ~st.leave;
                act &= ~st.leave;
                if (!kd_anyP(act))
                    break;
            }
            uint below = node + 1u, above = kd_above_child(n);
            uint first_child = st.below_first ? below : above;
            uint second_child = st.below_first ? above : below;
            intP both = st.need_first & st.need_second;
            floatP t_mid = kd_clampP(st.t_split, t_min_cur, t_max_cur);
            if (!kd_anyP(st.need_second)) {
                node = first_child;
            } else if (!kd_anyP(st.need_first)) {
                node = second_child;
            } else if (kd_is_empty_leaf(st.below_first ? n_below : n_above)) {
                /* An empty first child holds no hit: its lanes go on in the second
                 * child (over [t_mid, t_max] where they need both), with no push; a
                 * lane that needs the first only is done here (its stack goes on). */
                if (++leaves > 2u * n_nodes + 2u)
                    return fallback | live;  /* more leaves than a valid tree has */
                node = second_child;
                t_min_cur = kd_selectP(t_min_cur, t_mid, both);
                t_lo = t_min_cur * (1.0f - KD_T_SLACK);
                act = st.need_second;
            } else {
                if (count == PACKET_STACK_SIZE)
                    return fallback | live;  /* deeper than a valid tree: the wide walk takes them */
                stack_node[count] = second_child;
                stack_t_min[count] = kd_selectP(t_min_cur, t_mid, both);
                stack_t_max[count] = t_max_cur;
                stack_act[count] = st.need_second;
                count++;
                node = first_child;
                t_max_cur = kd_selectP(t_max_cur, t_mid, both);
                t_hi = t_max_cur * (1.0f + KD_T_SLACK);
                act = st.need_first;
            }
            n = node == below ? n_below : n_above;
        }

        if (kd_anyP(act)) {
            if (++leaves > 2u * n_nodes + 2u)
                return fallback | live;      /* more leaves than a valid tree has */
            live &= ~kd_packet_walk_leaf(query, crossing, n, tris, tri_ids, &r, bounds, act,
                                         &lo, &hi, t_max_cur, q);
        }

        /* the next entry with a lane whose walk goes on */
        act = (intP)(0);
        while (count > 0u && !kd_anyP(act)) {
            count--;
            node = stack_node[count];
            t_min_cur = stack_t_min[count];
            t_max_cur = stack_t_max[count];
            act = stack_act[count] & live;
        }
        if (!kd_anyP(act))
            return fallback;
        t_lo = t_min_cur * (1.0f - KD_T_SLACK);
        t_hi = t_max_cur * (1.0f + KD_T_SLACK);
    }
}
#endif

/* A query's state before its walk: nothing found, the count's rule when `crossing`. */
KD_INLINE
void kd_query_start(KdQuery *q, bool crossing)
{
    q->crossing = crossing;
    q->fault = false;
    q->in_plane = false;
    q->n = 0u;
    q->raw = 0u;
    q->winding = 0;
    q->unique = false;
    q->lost = false;
    q->kept = 0u;
    q->head = 0u;
    q->floor_t = -INFINITY;
    q->floor_id = 0u;
}

/* packet programs with KD_WIDE take the tree's wide nodes after n_nodes (wide.cl) */
#ifndef KD_WIDE_PARAM
#define KD_WIDE_PARAM
#define KD_WIDE_PASS
#endif

#define KD_QUERY_ARGS                                                                      \
    __global const KdNode *nodes, __global const float *tris, __global const uint *tri_ids, \
    __global const float *bounds, uint n_nodes KD_WIDE_PARAM,                              \
    __global const KD_ORIGIN_T *origins, __global const KD_DIRECTION_T *directions,        \
    uint o_step, uint o_offset, uint d_offset KD_ORIGIN_PARAMS,                            \
    __global const float *t_mins, __global const float *t_maxs, uint t_step, uint n_rays,  \
    uint image_w, __global const uint *order

/* Rays walked together: a packet program's work-item's RUN (as packets and wide
 * walks), else one. */
#ifdef PACKET
#define KD_WALK_BLOCK RUN
#else
#define KD_WALK_BLOCK 1
#endif

/* Packet programs whose work-item takes whole packets can walk an image's rays in
 * blocks of 4 x KD_PACKET / 4 pixels, as render and trace_rays trace them: their
 * footprints are squarer than a row's, so a packet shares more nodes and culls more. */
#if defined(PACKET) && RUN % KD_PACKET == 0
#define KD_IMAGE_BLOCKS
#define KD_BAND_W (4u * (RUN / KD_PACKET))       /* a work-item's columns */
#endif

/* The rays of block b0 / KD_WALK_BLOCK of this work-item into ids[0 .. m - 1]; returns
 * m (0: none left). Rays in rows (image_w 0): RUN consecutive slots from
 * get_global_id(0) * RUN, KD_WALK_BLOCK at a time, slot j holding ray j, or ray
 * order[j] where an order is given (NULL: none; kdray/ray_order.py). An image of
 * image_w columns (n_rays / image_w rows; KD_IMAGE_BLOCKS): a work-item's RUN rays
 * are its band of KD_BAND_W columns by KD_PACKET / 4 rows, packet p (KD_PACKET rays
 * in ids) its columns 4p .. 4p + 3 (lane l: column + l % 4, row + l / 4), the pixels
 * outside the image left out. */
KD_INLINE
uint kd_block_rays(uint b0, uint n_rays, uint image_w, __global const uint *order, uint *ids)
{
#ifdef KD_IMAGE_BLOCKS
    if (image_w) {
        uint bands_x = (image_w + KD_BAND_W - 1u) / KD_BAND_W;
        uint item = (uint)get_global_id(0);
        uint col0 = (item % bands_x) * KD_BAND_W;
        uint row0 = (item / bands_x) * (KD_PACKET / 4u);
        uint n_rows = n_rays / image_w;
        uint m = 0u;
        for (uint j = 0u; j < RUN; j++) {
            uint col = col0 + 4u * (j / KD_PACKET) + j % 4u;
            uint row = row0 + (j % KD_PACKET) / 4u;
            if (col < image_w && row < n_rows)
                ids[m++] = row * image_w + col;
        }
        return b0 == 0u ? m : 0u;
    }
#endif
    uint first = (uint)get_global_id(0) * RUN + b0;
    if (b0 >= RUN || first >= n_rays)
        return 0u;
    uint m = min((uint)KD_WALK_BLOCK, min(n_rays - first, (uint)RUN - b0));
    for (uint l = 0u; l < m; l++)
        ids[l] = order ? order[first + l] : first + l;
    return m;
}

/* A work-item's rays, a block of KD_WALK_BLOCK at a time: its m rays' indices ids[0 ..
 * m - 1] (kd_block_rays). */
#define KD_FOR_ITEM_BLOCKS(ids, m)                                                         \
    uint ids[KD_WALK_BLOCK];                                                               \
    uint m;                                                                                \
    for (uint b0 = 0u; b0 < RUN; b0 += KD_WALK_BLOCK)                                      \
        if ((m = kd_block_rays(b0, n_rays, image_w, order, ids)) == 0u)                    \
            break;                                                                         \
        else

/* Walk rays ids[0 .. n - 1] into q[0 .. n - 1], each started first (kd_query_start,
 * the count's rule when `crossing`; a list's slots, set before, are kept): kd_walk; in
 * packet programs as packets (kd_packet_walk) or through the wide nodes
 * (kd_wide_walks), which give each ray kd_walk's answer. */
KD_INLINE
void kd_walk_block(uint query, bool crossing, KD_QUERY_ARGS, const uint *ids, uint n,
                   KdQuery *q)
{
    for (uint l = 0; l < n; l++)
        kd_query_start(&q[l], crossing);
    float3 bmin = vload3(0, bounds), bmax = vload3(1, bounds);
    KdRaySource src;
    src.o = origins + o_offset;
    src.d = directions + d_offset;
    src.o_step = o_step;
#ifdef RAYS_WORLD
    src.origin = (double3)(origin_x, origin_y, origin_z);
#endif
#ifdef PACKET
    /* packets of rays that share their paths walk as packets, the others (and the
     * lanes that leave a packet, started again; all of a block too small for
     * packets) through the wide nodes */
    uchar alone[KD_WALK_BLOCK];
    uint n_alone = 0u;
    if (n < KD_PACKET_WALK_MIN) {
        for (uint l = 0u; l < n; l++)
            alone[n_alone++] = (uchar)l;
    } else {
        for (uint p0 = 0u; p0 < n; p0 += KD_PACKET) {
            uint m = min((uint)KD_PACKET, n - p0);
            KdIP leave;
            leave.v = kd_packet_walk(query, nodes, n_nodes, wide, tris, tri_ids, bmin, bmax,
                                     &src, t_mins, t_maxs, t_step, ids + p0, m, crossing,
                                     q + p0);
            for (uint l = 0u; l < m; l++) {
                if (!leave.s[l])
                    continue;
                kd_query_start(&q[p0 + l], crossing);
                alone[n_alone++] = (uchar)(p0 + l);
            }
        }
    }
    kd_wide_walks(query, wide, tris, tri_ids, bmin, bmax, &src, t_mins, t_maxs, t_step, ids,
                  alone, n_alone, q);
#else
    for (uint l = 0; l < n; l++) {
        uint k = ids[l];
        float3 o, d;
        kd_source_ray(&src, k, &o, &d);
        kd_walk(query, nodes, n_nodes, tris, tri_ids, bmin, bmax, o, d, t_mins[k * t_step],
                t_maxs[k * t_step], &q[l]);
    }
#endif
}

#define KD_WALK_ARGS nodes, tris, tri_ids, bounds, n_nodes KD_WIDE_PASS, origins,          \
    directions, o_step, o_offset, d_offset KD_ORIGIN_PASS, t_mins, t_maxs, t_step, n_rays, \
    image_w, order

#if !defined(LIST_SLOTS) && !defined(KD_ONLY_LIST_RAYS)
/* out[k]: the number of distinct triangles ray k hits (crossing 1: under the count's
 * rule), or every hit found | KD_COUNT_RAW when the count was lost (kd_count_hit), or
 * KD_WALK_FAULT. crossing 2 (KD_WINDING): the crossings' facings summed (kd_facing), an
 * int, or KD_WINDING_RAW when the count was lost, or KD_WALK_FAULT. */
__kernel __attribute__((reqd_work_group_size(LOCAL_SIZE, 1, 1))) KD_NO_LANES
void count_rays(KD_QUERY_ARGS, uint crossing, __global uint *out)
{
    KD_FOR_ITEM_BLOCKS(ids, m) {
        KdQuery q[KD_WALK_BLOCK];
        kd_walk_block(KD_COUNT, crossing != 0u, KD_WALK_ARGS, ids, m, q);
        for (uint l = 0; l < m; l++)
            out[ids[l]] = q[l].fault ? KD_WALK_FAULT
                        : crossing == KD_WINDING
                            ? (q[l].lost ? KD_WINDING_RAW : as_uint(q[l].winding))
                        : (q[l].lost ? q[l].raw | KD_COUNT_RAW : q[l].n);
    }
}
#endif

#if defined(REFINE) && defined(cl_khr_fp64)
/* the caller's rays in double as given, in world coordinates (origins o_step apart, as
 * `origins`), from element exact_o_offset and exact_d_offset on (the host's arrays,
 * read in place from the start of their page), which the hits are refined from, made
 * relative to the tree's origin in its units here (kd_exact_origin), as trace_rays
 * refines its hit from them (render.cl, kd_exact_ray) */
#define KD_EXACT_RAY_ARGS , __global const double *exact_o, __global const double *exact_d,  \
    uint exact_o_offset, uint exact_d_offset, double exact_origin_x, double exact_origin_y, \
    double exact_origin_z, double exact_scale_inv

/* Ray k's origin as the caller gave it, relative to the tree's origin in its units:
 * (o - origin) / scale, the scale a power of two (its inverse exact), as the host's
 * float64 arithmetic makes it. */
#define kd_exact_origin(k)                                                                 \
    ((vload3((size_t)(k) * o_step, exact_o + exact_o_offset)                              \
      - (double3)(exact_origin_x, exact_origin_y, exact_origin_z)) * exact_scale_inv)
#define kd_exact_direction(k) vload3((k), exact_d + exact_d_offset)
#define KD_EXACT_RAY_PASS , exact_o, exact_d, exact_o_offset, exact_d_offset,               \
    exact_origin_x, exact_origin_y, exact_origin_z, exact_scale_inv
#else
#define KD_EXACT_RAY_ARGS
#define KD_EXACT_RAY_PASS
#endif

/* A list's hits (q, ray k's, walked) made final: each hit's t, u, v from double with
 * REFINE (kd_refine_hit, from the caller's ray as given), then in order again (the
 * refined t moves by its float rounding at most, so this is a few swaps), and each
 * slot's triangle copy made its input id. */
KD_INLINE
void kd_list_finish(KdQuery *q, uint k, __global const float *tris,
                    __global const uint *tri_ids, __global const float *t_mins,
                    __global const float *t_maxs, uint t_step, uint o_step KD_EXACT_RAY_ARGS)
{
#if defined(REFINE) && defined(cl_khr_fp64)
    double3 o = kd_exact_origin(k);
    double3 d = kd_exact_direction(k);
    float t_min = t_mins[k * t_step], t_max = t_maxs[k * t_step];
    for (uint j = 0; j < q->n; j++) {
        uint tri = q->tri[j];
        float t = q->t[j], u = q->uv[2u * j], v = q->uv[2u * j + 1u];
        kd_refine_hit(o, d, kd_vertex(tris, tri, 0), kd_vertex(tris, tri, 1),
                      kd_vertex(tris, tri, 2), t_min, t_max, &t, &u, &v);
        kd_slot_put(q, j, kd_slot_place(q, j, t, tri, tri_ids), t, u, v, tri);
    }
#endif
    for (uint j = 0; j < q->n; j++)
        q->tri[j] = tri_ids[q->tri[j]];
}

#define KD_FINISH_ARGS tris, tri_ids, t_mins, t_maxs, t_step, o_step KD_EXACT_RAY_PASS

#ifndef LIST_SLOTS
#ifndef KD_ONLY_COUNT_RAYS
/* Ray k's hits (crossing: its crossings, the count's rule) into slots offsets[k] ..
 * offsets[k] + caps[k] - 1 (hit_t, hit_uv two floats a slot, hit_id the input id), its
 * count into out_n[k] (KD_WALK_FAULT on a fault): with caps[k] at least its distinct
 * hits, every hit, else the caps[k] first in (t, input id) order, the count then
 * marked KD_LIST_MORE. Sorted by (t, input id), as refined with REFINE. nearest_k:
 * the slots are the nearest hits wanted, not whether there are more (a k-nearest query, or
 * caps[k] the ray's exact count): a walk ends once they are taken and the last is
 * final (kd_list_done), its KD_LIST_MORE then unknown. */
__kernel __attribute__((reqd_work_group_size(LOCAL_SIZE, 1, 1))) KD_NO_LANES
void list_rays(KD_QUERY_ARGS, uint crossing, uint nearest_k, __global const ulong *offsets,
               __global const uint *caps KD_EXACT_RAY_ARGS, __global float *hit_t,
               __global float *hit_uv, __global uint *hit_id, __global uint *out_n)
{
    KD_FOR_ITEM_BLOCKS(ids, m) {
        KdQuery qs[KD_WALK_BLOCK];
        for (uint l = 0; l < m; l++) {
            KdQuery *q = &qs[l];
            uint k = ids[l];
            ulong at = offsets[k];
            q->t = hit_t + at;
            q->uv = hit_uv + 2u * at;
            q->tri = hit_id + at;            /* copies while walking, input ids at the end */
            q->cap = caps[k];
            q->nearest_k = nearest_k != 0u;
        }
        kd_walk_block(KD_LIST, crossing != 0u, KD_WALK_ARGS, ids, m, qs);
        for (uint l = 0; l < m; l++) {
            KdQuery *q = &qs[l];
            uint k = ids[l];
            if (q->fault) {
                out_n[k] = KD_WALK_FAULT;
                continue;
            }
            kd_list_finish(q, k, KD_FINISH_ARGS);
            out_n[k] = q->n | (q->raw ? KD_LIST_MORE : 0u);
        }
    }
}
#endif
#else
/* list_rays' first pass (cap <= LIST_SLOTS slots a ray, in private memory): each
 * work-item's hits, its rays' in the order it took them, each ray's in (t, input id)
 * order, written one after another from where an atomic add on *next puts them
 * (hit_t, hit_uv, hit_id), so that only as many slots are written as there are hits
 * (a first pass's slots are mostly empty: writing them all, fresh memory each call,
 * cost up to a third of the pass); out_n[k] as list_rays', out_at[k] where ray k's
 * hits start. Which work-item takes which place varies from run to run; each ray's
 * hits and count do not. */
__kernel __attribute__((reqd_work_group_size(LOCAL_SIZE, 1, 1))) KD_NO_LANES
void list_first(KD_QUERY_ARGS, uint crossing, uint cap, uint nearest_k,
                volatile __global uint *next KD_EXACT_RAY_ARGS, __global float *hit_t,
                __global float *hit_uv, __global uint *hit_id, __global uint *out_n,
                __global uint *out_at)
{
    KD_FOR_ITEM_BLOCKS(ids, m) {
        KdQuery qs[KD_WALK_BLOCK];
        for (uint l = 0; l < m; l++) {
            qs[l].cap = min(cap, (uint)LIST_SLOTS);
            qs[l].nearest_k = nearest_k != 0u;
        }
        kd_walk_block(KD_LIST, crossing != 0u, KD_WALK_ARGS, ids, m, qs);
        uint total = 0u;
        for (uint l = 0; l < m; l++) {
            KdQuery *q = &qs[l];
            if (q->fault)
                continue;
            kd_list_finish(q, ids[l], KD_FINISH_ARGS);
            total += q->n;
        }
        uint at = total ? atomic_add(next, total) : 0u;
        for (uint l = 0; l < m; l++) {
            KdQuery *q = &qs[l];
            uint k = ids[l];
            out_at[k] = at;
            if (q->fault) {
                out_n[k] = KD_WALK_FAULT;
                continue;
            }
            for (uint j = 0; j < q->n; j++) {
                hit_t[at + j] = q->t[j];
                vstore2((float2)(q->uv[2u * j], q->uv[2u * j + 1u]), at + j, hit_uv);
                hit_id[at + j] = q->tri[j];
            }
            at += q->n;
            out_n[k] = q->n | (q->raw ? KD_LIST_MORE : 0u);
        }
    }
}

#endif
