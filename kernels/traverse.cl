/* kernels/traverse.cl: nearest-hit k-d tree traversal with a short stack and restart
 * (Horn et al. 2007, "Interactive k-D Tree GPU Raytracing"; the descent and near-child
 * rules of pbrt's KdTreeAggregate).
 *
 * The stack is a ring of STACK_SIZE entries (node, t_min, t_max): when it is full a
 * push drops the OLDEST entry. When it runs empty after dropping entries, traversal
 * restarts at the push-down root (the deepest node all the remaining work lies in).
 *
 * Leaves are visited in one fixed depth-first order (near child first). Horn et al.
 * restart with t_min = the last leaf's t_max; here a restart instead descends again,
 * with the same decisions, to the last leaf visited and carries on after it: of two
 * children, the one before the last leaf in that order is skipped (below child of node
 * i is i + 1, so the last leaf is in the below child iff its index < above_child).
 * The visited leaves, their order and the result therefore do not depend on
 * STACK_SIZE (1 restarts after almost every leaf), with no special case for planes
 * crossed exactly at a restart point, and every restart moves on by at least a leaf.
 *
 * Rays that lie in a split plane (d[axis] = +-0 and o[axis] == split, so t_split is
 * NaN) touch both children over the same t range. Visiting both in one pass would
 * break the early exit (a leaf's hit is final only when nothing left can be nearer),
 * so such a ray is traced in passes instead: each pass takes a fixed side of every
 * in-plane node (below or above, one bit per axis) and is an ordinary restartable
 * front-to-back traversal; more passes run only for the in-plane axes met. A ray can
 * lie in the planes of at most two axes, so there are at most four passes, and a ray
 * in general position runs one.
 *
 * Options: -D STACK_SIZE=n (1..64), -D STATS (count nodes, leaves, tests, restarts).
 */
#ifndef KDRAY_TRAVERSE_CL
#define KDRAY_TRAVERSE_CL

#pragma OPENCL FP_CONTRACT OFF
#include "layout.h"
#include "triangle.cl"

#ifndef STACK_SIZE
#define STACK_SIZE 64
#endif

#ifdef STATS
/* stats: x = interior nodes visited, y = leaves visited, z = triangle tests, w = restarts */
#define KD_STAT(field) ((*stats).field += 1u)
#define KD_STATS_PARAM , uint4 *stats
#define KD_STATS_ARG , stats
#else
#define KD_STAT(field)
#define KD_STATS_PARAM
#define KD_STATS_ARG
#endif

/* Clip [t0, t1] to one slab of a box. A ray parallel to the slab (d = +-0) is inside
 * it or not: it never computes 0 / 0. Divides like the split planes do, so a plane
 * and a box face through one point give the same t. Returns false on a miss. */
KD_INLINE
bool kd_slab(float o, float d, float lo, float hi, float *t0, float *t1)
{
    if (d == 0.0f)
        return o >= lo && o <= hi;
    float ta = (lo - o) / d;
    float tb = (hi - o) / d;
    *t0 = kd_max(*t0, kd_min(ta, tb));   /* no NaN: d != 0, o and the box finite */
    *t1 = kd_min(*t1, kd_max(ta, tb));
    return true;
}

/* Test every triangle of a leaf (the copies tris[leaf_offset ..], layout.h), keeping
 * the first hit with t_min < t < t_max in the order (t, input id). */
KD_INLINE
void kd_intersect_leaf(KdNode leaf, __global const float *tris, __global const uint *tri_ids,
                       const RayShear *shear, float3 o, float t_min, float t_max,
                       Hit *hit KD_STATS_PARAM)
{
    uint count = kd_n_prims(leaf);
    uint first = kd_leaf_offset(leaf);
    for (uint i = 0; i < count; i++) {
        uint tri = first + i;
        float t, u, v;
        KD_STAT(z);
        if (intersect_triangle(shear, o, kd_vertex(tris, tri, 0), kd_vertex(tris, tri, 1),
                               kd_vertex(tris, tri, 2), tri,
                               t_min, t_max, hit->t, hit->tri, tri_ids, false, &t, &u, &v)) {
            hit->t = t;
            hit->u = u;
            hit->v = v;
            hit->tri = tri;
        }
    }
}

#ifdef PACKET
/* Packet programs test a single ray's leaf KD_PACKET triangles at a time, in vector
 * lanes (kd_ray_leaf, packet.cl): the same pairs and arithmetic, and the same hit. */
KD_INLINE
void kd_ray_leaf(KdNode leaf, __global const float *tris, __global const uint *tri_ids,
                 const RayShear *shear, float3 o, float t_min, float t_max,
                 Hit *hit KD_STATS_PARAM);
#define KD_RAY_LEAF kd_ray_leaf
#else
#define KD_RAY_LEAF kd_intersect_leaf
#endif

/* Rounding slack of a split plane's t: (split - o) / d is two correctly rounded
 * operations from the exact crossing (four ulps at most with the 2.5-ulp division
 * OpenCL allows by default), and so is the t of the plane it is compared with; a
 * packet's (split - o) * (1 / d) rounds once more, half an ulp, while 1 / d is a
 * normal float (packet.cl, kd_inverse_far); 2^-20 of t is 16 ulps. A child is
 * skipped only when the ray's range misses it by more than that, so a ray through a
 * vertex where several planes meet visits every leaf around the vertex, whichever
 * way each t rounded. */
#define KD_T_SLACK 9.5367431640625e-07f

/* How a ray's range [t0, t1] meets interior node n (index `node`): the one step of
 * every walk of the tree (the nearest hit's here, the queries' in queries.cl).
 * *first is the child on the origin's side (below when the origin is in the plane
 * and d[axis] <= 0), *second the other; *below_first says which is which. Returns
 * KD_STEP_FIRST or KD_STEP_SECOND (the range reaches that child only, by more than
 * the slack), KD_STEP_BOTH (first over [t0, *t_mid], then second over [*t_mid, t1])
 * or KD_STEP_IN_PLANE (the ray lies in the split plane: both, over the same range).
 * A division, not a multiplication by 1/d: planes through one point give the same t
 * when the coordinates are exact (a vertex on two split planes). A packet multiplies
 * (kd_inverse_far): the slack covers both, and every hit is the same. */
#define KD_STEP_FIRST 0u
#define KD_STEP_SECOND 1u
#define KD_STEP_BOTH 2u
#define KD_STEP_IN_PLANE 3u

KD_INLINE
uint kd_node_step(KdNode n, uint node, float3 o, float3 d, float t0, float t1, uint *first,
                  uint *second, bool *below_first, float *t_mid)
{
    uint axis = kd_split_axis(n);
    float split = kd_split(n);
    float o_k = kd_comp(o, axis);
    float d_k = kd_comp(d, axis);
    float t_split = (split - o_k) / d_k;
    uint below = node + 1u;
    uint above = kd_above_child(n);
    *below_first = o_k < split || (o_k == split && d_k <= 0.0f);
    *first = *below_first ? below : above;
    *second = *below_first ? above : below;
    /* the range widened by the slack (computed beside the division) */
    float t_lo = t0 * (1.0f - KD_T_SLACK);
    float t_hi = t1 * (1.0f + KD_T_SLACK);
    *t_mid = kd_clamp(t_split, t0, t1);
    if (kd_isnan(t_split))
        return KD_STEP_IN_PLANE;
    if (t_split > t_hi || t_split <= 0.0f)
        return KD_STEP_FIRST;            /* (the sign of t_split is exact) */
    if (t_split < t_lo)
        return KD_STEP_SECOND;
    return KD_STEP_BOTH;
}

/* The scene box's range of a ray widened by the planes' slack: a ray that grazes the
 * box (through an edge or a corner of it, or to a face lying on it) enters and leaves
 * it at one t, which the clip's roundings (kd_slab) may put either way round, and a
 * hit on the box's face may lie a rounding past its exit. Widening only walks more:
 * the triangle test still holds every hit to t_min < t < t_max. t_enter >= 0 (it is
 * at least t_min). Every clip of the box (trace_ray's, the packets', the queries')
 * takes it, so that a tree's box never decides a hit. */
#define KD_BOX_ENTER(t) ((t) * (1.0f - KD_T_SLACK))
#define KD_BOX_EXIT(t) ((t) * (1.0f + KD_T_SLACK))

/* A leaf's hit is final when it is before the leaf's exit by more than the slack:
 * every leaf after it in the order starts at a plane crossed at t_exit or later (as
 * rounded, within the slack), so it cannot hold a nearer hit, nor one as near with a
 * lower index (a hit exactly on the plane is looked for on the other side too). */
KD_INLINE
bool kd_hit_final(float t_hit, float t_exit)
{
    return t_hit < t_exit * (1.0f - KD_T_SLACK);
}

/* Whether a traversal may end at a leaf whose exit is t_exit with the hit (t_hit, tri)
 * found so far: for the nearest hit when it is final; with ANY_HIT (occluded: is there
 * any hit, rays.py), at any hit. */
KD_INLINE
bool kd_hit_done(float t_hit, uint tri, float t_exit)
{
#ifdef ANY_HIT
    return tri != KD_NO_HIT;
#else
    return kd_hit_final(t_hit, t_exit);
#endif
}

/* One front-to-back traversal of [t_enter, t_exit]. `side` picks the child of an
 * in-plane node (bit axis: 0 below, 1 above); the axes met in-plane are or-ed into
 * *in_plane. Returns when the nearest hit is certain or every leaf has been visited.
 * max_leaves: a bound no correct traversal reaches (each leaf once, plus one revisit
 * per restart), so that a corrupt tree cannot hang the device. */
KD_INLINE
void kd_traverse_pass(__global const KdNode *nodes, uint max_leaves, 
                      __global const float *tris, __global const uint *tri_ids, const RayShear *shear,
                      float3 o, float3 d, float t_min, float t_max, float t_enter, float t_exit,
                      uint side, uint *in_plane, Hit *hit KD_STATS_PARAM)
{
    uint stack_node[STACK_SIZE];
    float stack_t_min[STACK_SIZE];
    float stack_t_max[STACK_SIZE];
    uint top = 0;                        /* next free slot of the ring */
    uint count = 0;                      /* entries held, at most STACK_SIZE */
    bool dropped = false;                /* an entry was dropped since the last (re)start */

    uint root = 0;                       /* push-down root and its range */
    float root_t_min = t_enter;
    float root_t_max = t_exit;
    uint last_leaf = 0;                  /* the leaf visited last */
    bool resuming = false;               /* descending to last_leaf after a restart */

    uint node = 0;
    float t_min_cur = t_enter;
    float t_max_cur = t_exit;
    bool pushdown = true;
    uint leaves = 0;

    for (;;) {
        /* Descend to a leaf. When resuming, the same decisions lead back to last_leaf
         * (the ranges on the way are the same as the first time); of two children to
         * visit, one before last_leaf in the visiting order was done: skip it. */
        KdNode n = nodes[node];
        while (!kd_is_leaf(n)) {
            KD_STAT(x);
            uint below = node + 1u;
            uint above = kd_above_child(n);
            /* both children, loaded while the division runs: the next step's node is
             * then at hand */
            KdNode n_below = nodes[below];
            KdNode n_above = nodes[above];
            uint first, second;
            bool below_first;
            float t_mid;
            uint step = kd_node_step(n, node, o, d, t_min_cur, t_max_cur, &first, &second,
                                     &below_first, &t_mid);

            if (step == KD_STEP_IN_PLANE) {
                /* The ray lies in the split plane: this pass's side */
                uint axis = kd_split_axis(n);
                *in_plane |= 1u << axis;
                node = ((side >> axis) & 1u) ? above : below;
            } else if (step == KD_STEP_FIRST) {
                node = first;
            } else if (step == KD_STEP_SECOND) {
                node = second;
            } else {
                bool last_in_below = last_leaf < above;
                if (resuming && last_in_below != below_first) {
                    /* last_leaf is in the second child: the first one is done */
                    node = second;
                    t_min_cur = t_mid;
                } else {
                    /* Push the second child; a full ring drops its OLDEST entry */
                    dropped = dropped || count == STACK_SIZE;
                    stack_node[top] = second;
                    stack_t_min[top] = t_mid;
                    stack_t_max[top] = t_max_cur;
                    top = (top + 1u == STACK_SIZE) ? 0u : top + 1u;
                    count = min(count + 1u, (uint)STACK_SIZE);
                    node = first;
                    t_max_cur = t_mid;
                    pushdown = false;
                }
            }
            if (pushdown) {
                root = node;
                root_t_min = t_min_cur;
                root_t_max = t_max_cur;
            }
            n = node == below ? n_below : n_above;
        }

        if (++leaves > max_leaves)
            break;
        if (resuming) {
            resuming = false;            /* back at last_leaf: tested already */
        } else {
            /* Leaf: test its triangles; a hit at or before the leaf's exit is final */
            KD_STAT(y);
            KD_RAY_LEAF(n, tris, tri_ids, shear, o, t_min, t_max, hit KD_STATS_ARG);
            last_leaf = node;
            if (kd_hit_done(hit->t, hit->tri, t_max_cur))
                break;
        }

        if (count > 0) {
            /* Pop the most recent entry */
            top = (top == 0u) ? STACK_SIZE - 1u : top - 1u;
            count--;
            node = stack_node[top];
            t_min_cur = stack_t_min[top];
            t_max_cur = stack_t_max[top];
            pushdown = false;
        } else if (dropped) {
            /* Stack empty with entries dropped: restart at the push-down root and
             * resume after the last leaf */
            KD_STAT(w);
            dropped = false;
            resuming = true;
            node = root;
            t_min_cur = root_t_min;
            t_max_cur = root_t_max;
            pushdown = true;
        } else {
            break;                       /* every leaf on the ray was visited */
        }
    }
}

/* Nearest hit of the ray o + t d with t_min < t < t_max, coordinates relative to the
 * tree's origin; bmin, bmax: the scene box; n_nodes: the tree's node count. Returns whether it hit; *hit holds the hit
 * (tri = KD_NO_HIT and t = t_max on a miss). */
KD_INLINE
bool trace_ray(__global const KdNode *nodes, uint n_nodes, 
               __global const float *tris, __global const uint *tri_ids, float3 bmin, float3 bmax,
               float3 o, float3 d, float t_min, float t_max, Hit *hit KD_STATS_PARAM)
{
    hit->t = t_max;
    hit->u = 0.0f;
    hit->v = 0.0f;
    hit->tri = KD_NO_HIT;
    if (!(kd_finite3(o) && kd_finite3(d)) || kd_no_direction(d))
        return false;

    /* Compute the ray's parametric range inside the scene box, clipped to [t_min, t_max] */
    float t_enter = t_min;
    float t_exit = t_max;
    if (!(kd_slab(o.x, d.x, bmin.x, bmax.x, &t_enter, &t_exit)
          && kd_slab(o.y, d.y, bmin.y, bmax.y, &t_enter, &t_exit)
          && kd_slab(o.z, d.z, bmin.z, bmax.z, &t_enter, &t_exit)))
        return false;
    t_enter = KD_BOX_ENTER(t_enter);
    t_exit = KD_BOX_EXIT(t_exit);
    if (!(t_enter <= t_exit))
        return false;

    RayShear shear = ray_shear(d);
    uint in_plane = 0;                   /* axes met with the ray in the split plane */
    uint done = 1u;                      /* passes run, one bit per side mask */
    uint side = 0;
    for (;;) {
        kd_traverse_pass(nodes, 2u * n_nodes + 2u, tris, tri_ids, &shear, o, d, t_min, t_max,
                         t_enter, t_exit, side, &in_plane, hit KD_STATS_ARG);
        /* Next side mask made only of in-plane axes, not yet run */
        side = 0;
        for (uint m = 1; m < 8u; m++) {
            if ((m & ~in_plane) == 0u && !((done >> m) & 1u)) {
                side = m;
                break;
            }
        }
        if (side == 0u)
            break;
#ifdef ANY_HIT
        if (hit->tri != KD_NO_HIT)
            break;                       /* any hit will do: no other side's pass */
#endif
        done |= 1u << side;
    }
    return hit->tri != KD_NO_HIT;
}

#endif
