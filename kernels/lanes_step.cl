/* kernels/lanes_step.cl: the vector node step and the lanes' own stacks of rays walked
 * side by side, one a vector lane, each on its own path (the way ispc's program
 * instances and a GPU's threads walk): the ray queries' walk of rays that share no
 * path (queries.cl, kd_lanes_walk).
 *
 * Why: walked one after the other, a ray's node step waits on its own chain (the
 * node's load, the plane's division, the compares, a branch the CPU predicts badly for
 * such rays). Here one vector step moves every lane one node down its own path, so
 * KD_PACKET chains advance together and no branch depends on one ray's decision.
 *
 * Each lane makes exactly the single ray's decisions (traverse.cl, kd_node_step): the
 * same t_split (a division), slack, near child and ranges. Its stack is a plain one of
 * PACKET_STACK_SIZE entries (the tree's depth + 1: never full on a valid tree).
 */
#ifndef KDRAY_LANES_STEP_CL
#define KDRAY_LANES_STEP_CL
/* (programs that count the work, -D STATS, walk these rays one by one) */
#ifndef STATS

#pragma OPENCL FP_CONTRACT OFF

/* The fewest lanes a vector walk goes on with (the last go on one by one). */
#ifndef KD_LANES_MIN
#define KD_LANES_MIN 4u
#endif

/* The lanes whose bits are set in `bits` (lane l: bit l), as a mask. */
KD_INLINE
intP kd_maskP(uint bits)
{
    return -as_intP(((uintP)(bits) >> KD_LANE_INDEX_U) & (uintP)(1u));
}

/* kd_node_step (traverse.cl) for every lane: from the lanes' node words (flags, data:
 * split plane), node indices, rays and ranges [t0, t1], each lane's children in its
 * order (first, second), t_mid and decision as masks: go_first, go_second, in_plane
 * (t_split NaN: the ray lies in the plane), and both children where none holds. The
 * same operations in the same order as kd_node_step, so the same decisions. */
typedef struct {
    uintP first, second;
    floatP t_mid;
    intP go_first, go_second, in_plane;
} KdStepP;

KD_INLINE
KdStepP kd_node_stepP(uintP flags, uintP data, uintP node, floatP ox, floatP oy, floatP oz,
                      floatP dx, floatP dy, floatP dz, floatP t0, floatP t1)
{
    KdStepP s;
    intP axis = as_intP(flags & (uintP)(3u));
    floatP split = as_floatP(data);
    floatP o_k = kd_compP(ox, oy, oz, axis);
    floatP d_k = kd_compP(dx, dy, dz, axis);
    floatP t_split = (split - o_k) / d_k;
    uintP below = node + (uintP)(1u);
    uintP above = flags >> 2;
    intP below_first = (o_k < split) | ((o_k == split) & (d_k <= 0.0f));
    s.first = kd_selectPu(above, below, below_first);
    s.second = kd_selectPu(below, above, below_first);
    floatP t_lo = t0 * (1.0f - KD_T_SLACK);
    floatP t_hi = t1 * (1.0f + KD_T_SLACK);
    s.t_mid = kd_clampP(t_split, t0, t1);
    s.in_plane = t_split != t_split;
    s.go_first = (t_split > t_hi) | (t_split <= 0.0f);
    s.go_second = ~s.go_first & (t_split < t_lo);
    return s;
}

/* Every lane's own stack of PACKET_STACK_SIZE entries (node, range [t0, t1]); entry k
 * of lane l at [k * KD_PACKET + l]. */
typedef struct {
    uint node[PACKET_STACK_SIZE * KD_PACKET];
    float t0[PACKET_STACK_SIZE * KD_PACKET];
    float t1[PACKET_STACK_SIZE * KD_PACKET];
    uint top[KD_PACKET];
} KdLaneStacks;

/* Push (node, t0, t1) on lane l's stack; false when it is full. */
KD_INLINE
bool kd_lane_push(KdLaneStacks *s, uint l, uint node, float t0, float t1)
{
    if (s->top[l] == PACKET_STACK_SIZE)
        return false;
    uint k = s->top[l]++ * KD_PACKET + l;
    s->node[k] = node;
    s->t0[k] = t0;
    s->t1[k] = t1;
    return true;
}

/* Pop lane l's most recent entry (its stack not empty). */
KD_INLINE
void kd_lane_pop(KdLaneStacks *s, uint l, uint *node, float *t0, float *t1)
{
    uint k = --s->top[l] * KD_PACKET + l;
    *node = s->node[k];
    *t0 = s->t0[k];
    *t1 = s->t1[k];
}

/* Lane l goes on from its stack's most recent entry: its node and range in the lanes'
 * vectors (node, t0, t1), merged by selects. */
KD_INLINE
void kd_lane_resume(KdLaneStacks *s, uint l, uintP *node, floatP *t0, floatP *t1)
{
    uint next;
    float next_t0, next_t1;
    kd_lane_pop(s, l, &next, &next_t0, &next_t1);
    intP m = KD_LANE_INDEX == (intP)((int)l);
    *node = kd_selectPu(*node, (uintP)(next), m);
    *t0 = kd_selectP(*t0, (floatP)(next_t0), m);
    *t1 = kd_selectP(*t1, (floatP)(next_t1), m);
}

#endif
#endif
