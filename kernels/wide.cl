/* kernels/wide.cl: rays that share no path through the tree, walked through the wide
 * nodes (kdray/wide.py: an 8-wide BVH over the triangles, each child's box its
 * triangles', each node's slots in an order for each octant of directions, its leaves'
 * triangle copies after the k-d leaves' in tris and tri_ids), two rays a work-item
 * taking their steps in turns.
 *
 * In packet programs, packets of rays that share their paths and an octant walk the
 * same nodes as one (kd_packet_wide_traverse for trace, queries.cl's
 * kd_packet_wide_walk; the section at the end).
 *
 * Why: a k-d walk on its own pays a dependent load and a decision at every node; here
 * one vector step tests a ray against 8 boxes, and a leaf holds up to 16 triangles,
 * each triangle in one leaf. Two rays in turns keep two chains of loads in flight.
 * Each ray's state stays in registers; its stack lives apart (a struct holding the
 * stack arrays would be kept in memory).
 *
 * The hits are trace_ray's bit for bit. A hit does not depend on the tree: it is the
 * nearest in (t, input id) order over t_min < t < t_max of the triangle test, the BVH
 * holds every triangle the k-d tree lists, and every leaf is tested with kd_ray_leaf
 * (the same arithmetic), whatever order the walk takes them in. A child is skipped
 * only when its box, widened by KD_WIDE_PAD of the ray's reach, is missed or entered
 * beyond the best hit so far (strictly: a tie is still visited). The reach, the scene's largest
 * coordinate plus the origin's, bounds |v - o| for every vertex v, and every rounding
 * of the slab test and of the triangle test is far below 2^-16 of it (traverse.cl's
 * KD_T_SLACK reasoning allows 2^-20): so a triangle hit at t lies in a box the ray
 * enters at or before t. A NaN slab (a ray parallel to a face, in its widened plane)
 * loses every compare it is in, which only keeps a child.
 *
 * Options (-D): KD_WIDE (the program takes the wide records after n_nodes),
 * WIDE_STACK (groups a ray's stack: the levels of wide nodes, kdray/wide.py
 * wide_nodes). Not with STATS (such programs trace these rays one by one, trace_ray
 * counting them).
 */
#ifndef KDRAY_WIDE_CL
#define KDRAY_WIDE_CL

/* the wide records follow n_nodes in the tree's arguments of a KD_WIDE program */
#ifdef KD_WIDE
#define KD_WIDE_PARAM , __global const uint *wide
#define KD_WIDE_PASS , wide
#else
#define KD_WIDE_PARAM
#define KD_WIDE_PASS
#endif

#ifdef KD_WIDE
#ifdef STATS
#error "KD_WIDE programs do not count work (STATS)"
#endif
#ifndef WIDE_STACK
#error "KD_WIDE needs WIDE_STACK"
#endif

#pragma OPENCL FP_CONTRACT OFF

/* a record (kdray/wide.py): 6 rows of 8 box planes, 8 children, 8 orders; a child
 * word is a wide node's index, or KD_WIDE_LEAF | (n - 1) << 27 | first / 8 for a leaf
 * of n triangle copies from `first` */
#define KD_WIDE_WORDS 64u
#define KD_WIDE_CHILD 48u
#define KD_WIDE_ORDER 56u
#define KD_WIDE_LEAF 0x80000000u
#define KD_WIDE_PAD 0x1p-16f

/* A ray's stack: a group for each wide node whose children it has still to take (at
 * most one a level, WIDE_STACK levels), group g the node's 8 slots copied as they lie
 * (the child word and where the ray enters the slot's box, t) at 8 g .. 8 g + 7, with
 * its mask (bit k: the slot k-th in the ray's octant's order is still to take) and that
 * order (the node's word for the octant; for walks that need none, slot k's place k and
 * the mask the slots met: kd_wide_push). The top group's mask and order are in the
 * ray (KdWideRay); a group below keeps them at mask[g + 1], order[g + 1] (written by
 * the push above it), and mask[0] is 0 for the pop that ends the walk. A push is two
 * vector copies and a mask, not a store a child. */
typedef struct {
    uint child[8 * WIDE_STACK];
    float t[8 * WIDE_STACK];
    uint mask[WIDE_STACK], order[WIDE_STACK];
} KdWideStack;

/* An octant of directions (bit a: going down axis a) and, in a record, the rows of
 * each slab's near and far planes for it (near: the min going up an axis, the max
 * going down): what a ray's or a packet's box test reads. */
typedef struct {
    uint octant, nx, ny, nz, fx, fy, fz;
} KdWidePlanes;

KD_INLINE
KdWidePlanes kd_wide_planes(uint octant)
{
    KdWidePlanes p;
    p.octant = octant;
    p.nx = (octant & 1u) ? 3u : 0u;
    p.ny = (octant & 2u) ? 4u : 1u;
    p.nz = (octant & 4u) ? 5u : 2u;
    p.fx = 3u - p.nx;
    p.fy = 5u - p.ny;
    p.fz = 7u - p.nz;
    return p;
}

/* A ray's walk: the ray relative to the tree, its range, its best hit, its stack's
 * groups (top; 0: the walk is over) and the top group's mask and order, and for the
 * box test its octant's planes (KdWidePlanes) and each plane's offset c (the pad
 * outwards, minus the origin): the plane's t is (plane + c) / d. */
typedef struct {
    float3 o;
    RayShear shear;
    float t_min, t_max;
    Hit hit;
    uint top, mask, order;
    KdWidePlanes planes;
    float8 ix, iy, iz, cnx, cny, cnz, cfx, cfy, cfz;
    KdWideStack *stack;
} KdWideRay;

/* 1 / d (inv) as the slab test takes it: NaN where d is not 0 but below 2^-128, where
 * 1 / d overflows to +-inf though a plane's t, (plane + c) / d, is finite (a crossing
 * far along the ray would be lost: packet.cl's kd_inverse_far); a NaN slab loses every
 * compare, which only keeps a child. (d = +-0 keeps its +-inf: the ray parallel to
 * the slab's planes never crosses them.) */
KD_INLINE
float kd_wide_inverse(float d, float inv)
{
    return (d != 0.0f && kd_abs(inv) == INFINITY) ? NAN : inv;
}

/* Start ray o + t d over t_min < t < t_max (relative to the tree, finite, d not 0) at
 * the root; reach: the scene box's largest |coordinate|. */
KD_INLINE
void kd_wide_start(KdWideRay *r, KdWideStack *stack, float3 o, float3 d, float t_min,
                   float t_max, float reach)
{
    r->o = o;
    r->shear = ray_shear(d);
    r->t_min = t_min;
    r->t_max = t_max;
    r->hit.t = t_max;
    r->hit.u = 0.0f;
    r->hit.v = 0.0f;
    r->hit.tri = KD_NO_HIT;
    r->stack = stack;
    /* the root, a group of one slot */
    stack->child[0] = 0u;
    stack->t[0] = t_min;
    stack->mask[0] = 0u;
    stack->order[0] = 0u;
    r->top = 1u;
    r->mask = 1u;
    r->order = 0u;
    float3 inv = (float3)(1.0f) / d;
    /* going down an axis: inv < 0 (d = -0 gives -inf) */
    bool down_x = inv.x < 0.0f, down_y = inv.y < 0.0f, down_z = inv.z < 0.0f;
    r->planes = kd_wide_planes((down_x ? 1u : 0u) | (down_y ? 2u : 0u) | (down_z ? 4u : 0u));
    r->ix = (float8)(kd_wide_inverse(d.x, inv.x));
    r->iy = (float8)(kd_wide_inverse(d.y, inv.y));
    r->iz = (float8)(kd_wide_inverse(d.z, inv.z));
    /* the pad: KD_WIDE_PAD of |o| + reach (and a floor for a scene at the origin);
     * the roundings of (pad - o) and of (plane + c) are at most 2^-23 of it */
    float a = kd_max(kd_max(kd_abs(o.x), kd_abs(o.y)), kd_abs(o.z));
    float pad = (a + reach) * KD_WIDE_PAD + 0x1p-120f;
    float px = down_x ? pad : -pad, py = down_y ? pad : -pad, pz = down_z ? pad : -pad;
    r->cnx = (float8)(px - o.x);
    r->cny = (float8)(py - o.y);
    r->cnz = (float8)(pz - o.z);
    r->cfx = (float8)(-px - o.x);
    r->cfy = (float8)(-py - o.y);
    r->cfz = (float8)(-pz - o.z);
}

/* The 8 lanes of b or-ed together, halves down to one (lane l holding bit l or 0:
 * a mask's lanes as bits) */
KD_INLINE
uint kd_bits8(uint8 b)
{
    uint4 a = b.lo | b.hi;
    uint2 c = a.lo | a.hi;
    return c.x | c.y;
}

/* The order of slots 0 .. 7 as they lie (a record's order word's form) */
#define KD_WIDE_AS_THEY_LIE 0xFAC688u

/* Push the children of wide node w (its record) that the ray meets over [t_min, far],
 * each with where the ray enters its box, as a group taken in the octant's order
 * (KdWideStack), or with `in_order` false as they lie, which saves the mask's
 * permutation: a walk that visits every child it meets whatever it finds (a count's)
 * needs no order, and one that ends at any hit (ANY_HIT) ran faster without it:
 * whichever child holds a hit ends it. */
KD_INLINE
void kd_wide_push(KdWideRay *r, __global const uint *w, float far, bool in_order)
{
    __global const float *rows = (__global const float *)w;
    /* the slabs' entries and exits as selects with the slab's value first: a NaN
     * loses the compare (as fmax and fmin ignore it), one vmaxps or vminps each */
    float8 tn = (float8)(r->t_min), tf = (float8)(far), s;
    s = (vload8(r->planes.nz, rows) + r->cnz) * r->iz; tn = s > tn ? s : tn;
    s = (vload8(r->planes.ny, rows) + r->cny) * r->iy; tn = s > tn ? s : tn;
    s = (vload8(r->planes.nx, rows) + r->cnx) * r->ix; tn = s > tn ? s : tn;
    s = (vload8(r->planes.fz, rows) + r->cfz) * r->iz; tf = s < tf ? s : tf;
    s = (vload8(r->planes.fy, rows) + r->cfy) * r->iy; tf = s < tf ? s : tf;
    s = (vload8(r->planes.fx, rows) + r->cfx) * r->ix; tf = s < tf ? s : tf;
    /* the slots met (an empty slot enters at +inf and leaves at -inf: never met) */
    const uint8 lane = (uint8)(0u, 1u, 2u, 3u, 4u, 5u, 6u, 7u);
    uint met = kd_bits8(as_uint8(tn <= tf) & ((uint8)(1u) << lane));
    if (met == 0u)
        return;
    /* bit k of the mask: whether the k-th slot in the octant's order is met */
    uint order = KD_WIDE_AS_THEY_LIE, mask = met;
    if (in_order) {
        order = w[KD_WIDE_ORDER + r->planes.octant];
        uint8 slot = ((uint8)(order) >> ((uint8)(3u) * lane)) & (uint8)(7u);
        mask = kd_bits8((((uint8)(met) >> slot) & (uint8)(1u)) << lane);
    }
    KdWideStack *st = r->stack;
    uint g = r->top;
    st->mask[g] = r->mask;                /* the group below's (at 0: the 0 of none) */
    st->order[g] = r->order;
    vstore8(tn, g, st->t);
    vstore8(vload8(0, w + KD_WIDE_CHILD), g, st->child);
    r->top = g + 1u;
    r->mask = mask;
    r->order = order;
}

/* The next slot of the top group (r->top > 0) off the stack: its child word, and
 * where the ray enters its box (returned). */
KD_INLINE
float kd_wide_pop(KdWideRay *r, uint *child)
{
    KdWideStack *st = r->stack;
    uint m = r->mask, g = r->top - 1u;
    uint k = 31u - clz(m & (0u - m));
    uint e = 8u * g + ((r->order >> (3u * k)) & 7u);
    *child = st->child[e];
    m &= m - 1u;
    if (m == 0u) {
        /* the group is done: the one below (index 0: none) is the top now */
        r->top = g;
        m = st->mask[g];
        r->order = st->order[g];
    }
    r->mask = m;
    return st->t[e];
}

/* The leaf a child word (KD_WIDE_LEAF set) names, as a k-d leaf node */
KD_INLINE
KdNode kd_wide_leaf(uint child)
{
    KdNode leaf;
    leaf.flags = ((((child >> 27) & 15u) + 1u) << 2) | KD_LEAF;
    leaf.data = (child & 0x07FFFFFFu) << 3;
    return leaf;
}

/* Whether a ray's walk takes a node's children in order (kd_wide_push): the nearest
 * hit's does, any hit's not */
#ifdef ANY_HIT
#define KD_WIDE_IN_ORDER false
#else
#define KD_WIDE_IN_ORDER true
#endif

/* One entry off the ray's stack: a leaf tested, or a wide node's children that the
 * ray meets before its best hit pushed. */
KD_INLINE
void kd_wide_step(KdWideRay *r, __global const uint *wide, __global const float *tris,
                  __global const uint *tri_ids)
{
    uint child;
    if (kd_wide_pop(r, &child) > r->hit.t)
        return;                           /* entered beyond the best hit */
    if (child & KD_WIDE_LEAF) {
        kd_ray_leaf(kd_wide_leaf(child), tris, tri_ids, &r->shear, r->o, r->t_min,
                    r->t_max, &r->hit);
#ifdef ANY_HIT
        if (r->hit.tri != KD_NO_HIT)
            r->top = 0u;                  /* any hit ends the walk */
#endif
        return;
    }
    kd_wide_push(r, wide + (size_t)child * KD_WIDE_WORDS, r->hit.t, KD_WIDE_IN_ORDER);
}

/* The scene's largest |coordinate| (box bmin, bmax): a wide walk's reach */
KD_INLINE
float kd_wide_reach(float3 bmin, float3 bmax)
{
    return kd_max(kd_max(kd_max(kd_abs(bmin.x), kd_abs(bmin.y)), kd_abs(bmin.z)),
                  kd_max(kd_max(kd_abs(bmax.x), kd_abs(bmax.y)), kd_abs(bmax.z)));
}

/* Nearest hits (with ANY_HIT: any hit) of the lanes in `on`, rays o + t d relative
 * to the tree (each finite, d not 0, as trace_packet's checks leave them) with t_min
 * < t < t_max (each lane's range), as trace_ray's Hit: written to t_l, u_l, v_l, tri_l
 * for every lane in `on`. bmin, bmax: the scene box. Two lanes at a time. */
KD_CALLED
void kd_wide_trace(__global const uint *wide, __global const float *tris,
                   __global const uint *tri_ids, intP on, floatP ox, floatP oy, floatP oz,
                   floatP dx, floatP dy, floatP dz, floatP t_min, floatP t_max,
                   float bmin_x, float bmin_y, float bmin_z, float bmax_x, float bmax_y,
                   float bmax_z, KdFP *t_l, KdFP *u_l, KdFP *v_l, KdUP *tri_l)
{
    float reach = kd_wide_reach((float3)(bmin_x, bmin_y, bmin_z),
                                (float3)(bmax_x, bmax_y, bmax_z));
    KdFP oxl, oyl, ozl, dxl, dyl, dzl, lo, hi;
    oxl.v = ox; oyl.v = oy; ozl.v = oz; dxl.v = dx; dyl.v = dy; dzl.v = dz;
    lo.v = t_min; hi.v = t_max;
    KdWideStack sa, sb;
    uint lanes = kd_bitsP(on);
    while (lanes) {
        uint la = kd_take_lane(&lanes);
        bool two = lanes != 0u;
        uint lb = two ? kd_take_lane(&lanes) : la;
        KdWideRay a, b;
        kd_wide_start(&a, &sa, (float3)(oxl.s[la], oyl.s[la], ozl.s[la]),
                      (float3)(dxl.s[la], dyl.s[la], dzl.s[la]), lo.s[la], hi.s[la], reach);
        kd_wide_start(&b, &sb, (float3)(oxl.s[lb], oyl.s[lb], ozl.s[lb]),
                      (float3)(dxl.s[lb], dyl.s[lb], dzl.s[lb]), lo.s[lb], hi.s[lb], reach);
        b.top = two ? 1u : 0u;
        while (a.top | b.top) {
            if (a.top)
                kd_wide_step(&a, wide, tris, tri_ids);
            if (b.top)
                kd_wide_step(&b, wide, tris, tri_ids);
        }
        t_l->s[la] = a.hit.t; u_l->s[la] = a.hit.u; v_l->s[la] = a.hit.v;
        tri_l->s[la] = a.hit.tri;
        if (two) {
            t_l->s[lb] = b.hit.t; u_l->s[lb] = b.hit.u; v_l->s[lb] = b.hit.v;
            tri_l->s[lb] = b.hit.tri;
        }
    }
}


#ifdef KDRAY_PACKET_CL
/* Packets through the wide nodes (packet programs: packet.cl includes this file after
 * its packets' types). A packet of rays that share their paths (a camera's block of
 * pixels) whose lanes' directions share one octant walks the wide nodes as one, as
 * Embree's packets walk its BVH: at a node, each slot's box against all its lanes in
 * one vector step; the slots some lane meets are taken in the octant's order, each
 * with the lanes that meet it and where each enters its box; a lane is carried into
 * a child only while that entry is not beyond its best hit (strictly, as
 * kd_wide_step). A lane's slab test is kd_wide_push's arithmetic for its ray (the same
 * pad, planes and roundings), so it skips a child only where its own walk may, and
 * leaves are kd_packet_leaf's: every lane's hit is the single ray's bit for bit.
 *
 * Why: the k-d packet walk (packet.cl) visits the union of its lanes' cells, one plane
 * a step, a packet's longest path (55 steps of 16 lanes against 22 a ray, bunny) with
 * most lanes idle; here a ray's walk is a few wide nodes deep, each slot tested for
 * all lanes at once, and a triangle lies in one leaf (BENCHMARKS.md, "Incoherent
 * rays": wide nodes). */

/* A packet stack's entries (KdPacketWideStack): at most 7 a level below the root */
#define KD_PACKET_WIDE_STACK (7u * WIDE_STACK + 1u)
#define KD_WIDE_EMPTY 0xFFFFFFFFu

/* The octant of the lanes in `on` of packet r (first: the first of them), in *octant,
 * when they share one (bit a: the direction is negative along axis a, as
 * kd_wide_start's, from 1 / d: -0 is negative). */
KD_INLINE
bool kd_packet_octant(const KdPacket *r, intP on, uint first, uint *octant)
{
    intP down_x = r->d_inv[0] < 0.0f, down_y = r->d_inv[1] < 0.0f, down_z = r->d_inv[2] < 0.0f;
    KdIP x, y, z;
    x.v = down_x; y.v = down_y; z.v = down_z;
    *octant = (x.s[first] ? 1u : 0u) | (y.s[first] ? 2u : 0u) | (z.s[first] ? 4u : 0u);
    return !kd_anyP(on & ((down_x != (intP)(x.s[first])) | (down_y != (intP)(y.s[first]))
                          | (down_z != (intP)(z.s[first]))));
}

/* A packet's walk of the wide nodes: its octant's planes (KdWidePlanes, as a ray's),
 * each lane's 1 / d and plane offsets c (the pad outwards, minus the origin), and each
 * lane's t_min. */
typedef struct {
    KdWidePlanes planes;
    floatP ix, iy, iz, cnx, cny, cnz, cfx, cfy, cfz, t_min;
} KdPacketWide;

KD_INLINE
void kd_packet_wide_start(KdPacketWide *p, const KdPacket *r, uint octant, float reach,
                          floatP t_min)
{
    bool down_x = (octant & 1u) != 0u, down_y = (octant & 2u) != 0u,
         down_z = (octant & 4u) != 0u;
    p->planes = kd_wide_planes(octant);
    /* kd_wide_inverse's NaN, lane by lane */
    floatP inf = (floatP)(INFINITY), nan = (floatP)(NAN);
    p->ix = kd_selectP(r->d_inv[0], nan, (r->d[0] != 0.0f) & (kd_absP(r->d_inv[0]) == inf));
    p->iy = kd_selectP(r->d_inv[1], nan, (r->d[1] != 0.0f) & (kd_absP(r->d_inv[1]) == inf));
    p->iz = kd_selectP(r->d_inv[2], nan, (r->d[2] != 0.0f) & (kd_absP(r->d_inv[2]) == inf));
    floatP a = kd_maxP(kd_maxP(kd_absP(r->o[0]), kd_absP(r->o[1])), kd_absP(r->o[2]));
    floatP pad = (a + reach) * KD_WIDE_PAD + 0x1p-120f;
    floatP px = down_x ? pad : -pad, py = down_y ? pad : -pad, pz = down_z ? pad : -pad;
    p->cnx = px - r->o[0]; p->cny = py - r->o[1]; p->cnz = pz - r->o[2];
    p->cfx = -px - r->o[0]; p->cfy = -py - r->o[1]; p->cfz = -pz - r->o[2];
    p->t_min = t_min;
}

/* Wide node w's slots (its record) against the lanes in `act` over [t_min, far] (each
 * lane's): returns the slots some lane meets, bit j the j-th in the octant's order,
 * with met_child[j] its child word and met_t[j] where each lane enters its box (NaN
 * where the lane does not meet it). kd_wide_push's slab test, a lane each. */
KD_INLINE
uint kd_packet_wide_node(const KdPacketWide *p, __global const uint *w, intP act, floatP far,
                         uint *met_child, floatP *met_t)
{
    __global const float *rows = (__global const float *)w;
    uint order = w[KD_WIDE_ORDER + p->planes.octant];
    /* lane l of acc: bit j where lane l meets the j-th slot in the order */
    uintP acc = (uintP)(0u);
    for (uint j = 0u; j < 8u; j++) {
        uint k = (order >> (3u * j)) & 7u;
        uint c = w[KD_WIDE_CHILD + k];
        if (c == KD_WIDE_EMPTY)
            break;                       /* empty slots come last in every order */
        floatP tn = p->t_min, tf = far, s;
        s = (rows[8u * p->planes.nz + k] + p->cnz) * p->iz; tn = s > tn ? s : tn;
        s = (rows[8u * p->planes.ny + k] + p->cny) * p->iy; tn = s > tn ? s : tn;
        s = (rows[8u * p->planes.nx + k] + p->cnx) * p->ix; tn = s > tn ? s : tn;
        s = (rows[8u * p->planes.fz + k] + p->cfz) * p->iz; tf = s < tf ? s : tf;
        s = (rows[8u * p->planes.fy + k] + p->cfy) * p->iy; tf = s < tf ? s : tf;
        s = (rows[8u * p->planes.fx + k] + p->cfx) * p->ix; tf = s < tf ? s : tf;
        intP m = act & (tn <= tf);
        acc |= as_uintP(m) & (uintP)(1u << j);
        met_child[j] = c;
        met_t[j] = kd_selectP((floatP)(NAN), tn, m);
    }
    return kd_orP(acc);                  /* the lanes or-ed once, not a test a slot */
}

/* A packet's stack: a child word and each lane's entry t an entry (NaN: the lane does
 * not meet the child's box; KD_PACKET_WIDE_STACK of them), count in use. */
typedef struct {
    uint child[KD_PACKET_WIDE_STACK];
    floatP t[KD_PACKET_WIDE_STACK];
    uint count;
} KdPacketWideStack;

/* Wide node *child's step for the lanes in *act over [t_min, far]
 * (kd_packet_wide_node): the slots some lane meets but the first pushed onto st, the
 * last first so that the next pop is the next in the order, and the first taken now
 * (*child, *act: the lanes that meet it). False where no lane meets any slot. */
KD_INLINE
bool kd_packet_wide_step(const KdPacketWide *p, __global const uint *wide, uint *child,
                         intP *act, floatP far, KdPacketWideStack *st)
{
    uint met_child[8];
    floatP met_t[8];
    uint bits = kd_packet_wide_node(p, wide + (size_t)*child * KD_WIDE_WORDS, *act, far,
                                    met_child, met_t);
    if (bits == 0u)
        return false;
    uint j0 = 31u - clz(bits & (0u - bits));
    bits &= bits - 1u;
    while (bits != 0u) {
        uint j = 31u - clz(bits);
        bits &= ~(1u << j);
        st->child[st->count] = met_child[j];
        st->t[st->count] = met_t[j];
        st->count++;
    }
    *child = met_child[j0];
    *act = met_t[j0] <= far;
    return true;
}

/* The next entry off st that a lane in `live` enters at or before its far, into
 * *child and *act (the lanes that go on there); false when none is left. */
KD_INLINE
bool kd_packet_wide_pop(KdPacketWideStack *st, intP live, floatP far, uint *child, intP *act)
{
    while (st->count > 0u) {
        st->count--;
        *child = st->child[st->count];
        *act = live & (st->t[st->count] <= far);
        if (kd_anyP(*act))
            return true;
    }
    return false;
}

/* Nearest hits (with ANY_HIT: any hit) into h of the lanes in `act` of packet r, whose
 * directions all lie in `octant` (kd_packet_octant), through the wide nodes; reach: the
 * scene box's largest |coordinate| (kd_wide_reach). */
KD_INLINE
void kd_packet_wide_traverse(__global const uint *wide, __global const float *tris,
                             __global const uint *tri_ids, const KdPacket *r, intP act,
                             uint octant, float reach, KdPacketHit *h)
{
    KdPacketWideStack st;
    st.count = 0u;
    KdPacketWide p;
    kd_packet_wide_start(&p, r, octant, reach, r->t_min);
    intP live = act;                     /* with ANY_HIT: lanes with no hit yet */
    uint child = 0u;                     /* the root, with the lanes in act */
    for (;;) {
        if (child & KD_WIDE_LEAF) {
            kd_packet_leaf(kd_wide_leaf(child), tris, tri_ids, r, act, h);
#ifdef ANY_HIT
            live &= ~(act & as_intP(h->tri != (uintP)(KD_NO_HIT)));
#endif
        } else if (kd_packet_wide_step(&p, wide, &child, &act, h->t, &st)) {
            continue;
        }
        /* the next entry that a live lane enters at or before its best hit */
        if (!kd_packet_wide_pop(&st, live, h->t, &child, &act))
            return;
    }
}
#endif

#endif
#endif
