/* kernels/lanes_trace.cl: rays that share no path through the tree, one a vector lane,
 * each on its own path (the way ispc's program instances and a GPU's threads trace):
 * packet programs' rays that are not traversed as a packet (kd_alone: origins far
 * apart) or that leave it (packet.cl), when enough of them are left.
 *
 * Why: traced one after the other (trace_ray), a ray's node step waits on its own
 * chain (the node's load, the plane's division, the compares, a branch the CPU
 * predicts badly for such rays): about 30 cycles a node on a Zen 4, most of a ray's
 * time. Here one vector step moves every lane one node down its own path, so KD_PACKET
 * chains advance together and no branch depends on one ray's decision.
 *
 * Each lane makes exactly trace_ray's decisions (traverse.cl, kd_traverse_pass): the
 * same t_split (a division), slack, near child, ranges and early exit, and tests its
 * leaves with kd_ray_leaf, so its hit is trace_ray's bit for bit. Its stack is a plain
 * one of PACKET_STACK_SIZE entries (the tree's depth + 1: never full on a valid tree);
 * a lane hands itself back to trace_ray from its start when it would need what only
 * trace_ray does: a ray lying in a split plane (t_split NaN: trace_ray's passes), a
 * full stack, or more leaves than a correct traversal visits.
 */
#ifndef KDRAY_LANES_TRACE_CL
#define KDRAY_LANES_TRACE_CL
/* (programs that count the work, -D STATS, trace these rays one by one: trace_ray
 * counts it) */
#ifndef STATS

#pragma OPENCL FP_CONTRACT OFF

/* The fewest lanes a packet hands over that start a vector traversal (fewer go one by
 * one: trace_ray), and the fewest it goes on with (the last go on one by one:
 * kd_lane_finish). */
#ifndef KD_LANES_MIN
#define KD_LANES_MIN 4u
#endif
#ifndef KD_LANES_ENTER
#define KD_LANES_ENTER (2u * KD_LANES_MIN < KD_PACKET ? 2u * KD_LANES_MIN : (uint)KD_PACKET)
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

/* One lane's traversal carried on alone from where the vector loop left it (node,
 * range [t0, t1], its stack, leaves visited): kd_lanes_trace's decisions with
 * traverse.cl's scalar node step. Returns false where the lane must be handed back to
 * trace_ray. */
KD_INLINE
bool kd_lane_finish(__global const KdNode *nodes, uint max_leaves, __global const float *tris,
                    __global const uint *tri_ids, const RayShear *shear, float3 o, float3 d,
                    float t_min, float t_max, uint node, float t0, float t1,
                    KdLaneStacks *stacks, uint l, uint leaves, Hit *hit)
{
    for (;;) {
        KdNode n = nodes[node];
        while (!kd_is_leaf(n)) {
            uint first, second;
            bool below_first;
            float t_mid;
            uint step = kd_node_step(n, node, o, d, t0, t1, &first, &second, &below_first,
                                     &t_mid);
            if (step == KD_STEP_IN_PLANE)
                return false;
            if (step == KD_STEP_BOTH) {
                if (!kd_lane_push(stacks, l, second, t_mid, t1))
                    return false;
                t1 = t_mid;
            }
            node = step == KD_STEP_SECOND ? second : first;
            n = nodes[node];
        }
        if (++leaves > max_leaves)
            return false;
        kd_ray_leaf(n, tris, tri_ids, shear, o, t_min, t_max, hit);
        if (kd_hit_done(hit->t, hit->tri, t1) || stacks->top[l] == 0u)
            return true;
        kd_lane_pop(stacks, l, &node, &t0, &t1);
    }
}

/* Nearest hits of the lanes in `on` (rays o + t d relative to the tree's origin, each
 * finite, d not 0, inside the scene box over [t_enter, t_exit], as trace_packet's box
 * clip leaves them), with t_min < t < t_max (each lane's range): lane l's t, u, v, tri as trace_ray's
 * Hit, written to t_l, u_l, v_l, tri_l for the lanes it finishes. Returns the lanes it
 * hands back (see above), which the caller traces with trace_ray.
 *
 * The lanes' state lives in vectors (node, t0, t1) and bit masks (act, handed), and a
 * lane's own changes are merged in by selects: a lane written through memory and read
 * back as a vector would wait for the store (no store-to-load forwarding). */
/* A call, not inlined (KD_CALLED, inline.h): inlined into trace_packet it cost camera
 * traces 2-6 % and incoherent ones 4 % (bench/ab_trace.py). */
KD_CALLED
intP kd_lanes_trace(__global const KdNode *nodes, uint max_leaves,
                    __global const float *tris, __global const uint *tri_ids, intP on,
                    floatP ox, floatP oy, floatP oz, floatP dx, floatP dy, floatP dz,
                    floatP t_min, floatP t_max, floatP t_enter, floatP t_exit,
                    KdFP *t_l, KdFP *u_l, KdFP *v_l, KdUP *tri_l)
{
    KdFP oxl, oyl, ozl, dxl, dyl, dzl, lo, hi;
    oxl.v = ox; oyl.v = oy; ozl.v = oz; dxl.v = dx; dyl.v = dy; dzl.v = dz;
    lo.v = t_min; hi.v = t_max;
    RayShear shear[KD_PACKET];
    Hit hit[KD_PACKET];
    KdLaneStacks stacks;
    uint leaves[KD_PACKET];
    uint act = kd_bitsP(on);
    for (uint l = 0; l < KD_PACKET; l++) {
        shear[l] = ray_shear((float3)(dxl.s[l], dyl.s[l], dzl.s[l]));
        hit[l].t = hi.s[l];
        hit[l].u = 0.0f;
        hit[l].v = 0.0f;
        hit[l].tri = KD_NO_HIT;
        stacks.top[l] = 0u;
        leaves[l] = 0u;
    }

    uint handed = 0u;
    uintP node = (uintP)(0u);
    floatP t0 = t_enter, t1 = t_exit;
    while (popcount(act) >= KD_LANES_MIN) {
        /* every lane's node as one 8-byte word, flags in its low half (lanes that are
         * done read their last node again: no branch per lane) */
        ulongP word = KD_GATHER_AS(ulongP, (__global const ulong *)nodes, node);
        uintP flags = convert_uintP(word & (ulongP)(0xFFFFFFFFul));
        uintP data = convert_uintP(word >> 32);
        intP leaf = as_intP((flags & (uintP)(3u)) == (uintP)(KD_LEAF));
        intP active = kd_maskP(act);
        uint inner = kd_bitsP(active & ~leaf);

        if (inner) {
            KdStepP st = kd_node_stepP(flags, data, node, ox, oy, oz, dx, dy, dz, t0, t1);
            uint in_plane = inner & kd_bitsP(st.in_plane);
            uint both = inner & ~in_plane & ~kd_bitsP(st.go_first | st.go_second);
            /* both: push the second child over [t_mid, t1], go on in the first (lane
             * by lane, plain stores: a scatter costs more on the CPUs measured) */
            if (both) {
                KdUP second_l;
                KdFP mid_l, t1_l;
                second_l.v = st.second;
                mid_l.v = st.t_mid;
                t1_l.v = t1;
                uint push = both;
                do {
                    uint l = kd_take_lane(&push);
                    if (!kd_lane_push(&stacks, l, second_l.s[l], mid_l.s[l], t1_l.s[l]))
                        handed |= 1u << l;      /* full: trace_ray's ring and restart */
                } while (push);
            }
            handed |= in_plane;
            act &= ~handed;
            intP step = kd_maskP(inner & act);
            node = kd_selectPu(node, kd_selectPu(st.first, st.second, st.go_second), step);
            t1 = kd_selectP(t1, st.t_mid, step & kd_maskP(both));
        }

        /* leaves: each lane's triangles, KD_PACKET at a time (kd_ray_leaf); a hit
         * before the leaf's exit is final, else the lane's next entry */
        uint at_leaf = act & kd_bitsP(leaf);
        if (at_leaf) {
            KdUP flags_l, data_l;
            KdFP t1_l;
            flags_l.v = flags;
            data_l.v = data;
            t1_l.v = t1;
            do {
                uint l = kd_take_lane(&at_leaf);
                if (++leaves[l] > max_leaves) {
                    handed |= 1u << l;          /* a corrupt tree: trace_ray's bound */
                    act &= ~(1u << l);
                    continue;
                }
                KdNode n;
                n.flags = flags_l.s[l];
                n.data = data_l.s[l];
                kd_ray_leaf(n, tris, tri_ids, &shear[l],
                            (float3)(oxl.s[l], oyl.s[l], ozl.s[l]), lo.s[l], hi.s[l], &hit[l]);
                if (kd_hit_done(hit[l].t, hit[l].tri, t1_l.s[l]) || stacks.top[l] == 0u) {
                    act &= ~(1u << l);
                } else {
                    kd_lane_resume(&stacks, l, &node, &t0, &t1);
                }
            } while (at_leaf);
        }
    }

    /* the last few lanes one by one: a vector step costs more than their scalar steps */
    if (act) {
        KdUP node_l;
        KdFP t0_l, t1_l;
        node_l.v = node;
        t0_l.v = t0;
        t1_l.v = t1;
        do {
            uint l = kd_take_lane(&act);
            if (!kd_lane_finish(nodes, max_leaves, tris, tri_ids, &shear[l],
                                (float3)(oxl.s[l], oyl.s[l], ozl.s[l]),
                                (float3)(dxl.s[l], dyl.s[l], dzl.s[l]), lo.s[l], hi.s[l],
                                node_l.s[l], t0_l.s[l], t1_l.s[l], &stacks, l, leaves[l],
                                &hit[l]))
                handed |= 1u << l;
        } while (act);
    }

    uint done = kd_bitsP(on) & ~handed;
    while (done) {
        uint l = kd_take_lane(&done);
        t_l->s[l] = hit[l].t;
        u_l->s[l] = hit[l].u;
        v_l->s[l] = hit[l].v;
        tri_l->s[l] = hit[l].tri;
    }
    return kd_maskP(handed);
}

#endif
#endif
