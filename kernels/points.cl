/* kernels/points.cl: point queries (kdray/points.py).
 *
 *   closest_points  the nearest point of the surface to each point: its distance, the
 *                   triangle's input id, barycentrics u, v and the point itself
 *   winding_points  the generalized winding number of the surface at each point
 *                   (Jacobson, Kavan & Sorkine-Hornung 2013), tree-accelerated as
 *                   Barill, Dickson, Schmidt, Levin & Jacobson 2018 do it
 *
 * Both run in double: one point a work-item is scalar code (KD_NO_LANES), where a
 * double costs what a float costs on a CPU, and the answers then need no second pass.
 * Points are given in double, relative to the tree's origin in its units; the
 * triangles are the device's float copies (layout.h) converted exactly, or with
 * GEOMETRY64 the input's float64 triangles (tris64, by input id), which the exact
 * tests take in world coordinates, with the points as given (points64): relative to
 * the tree's origin both would carry roundings of their distance from it, a small
 * object's far from the scene's centre (3e-15 of a distance 1e-10 over a triangle
 * 3e-4 across, 1400 away). Their squared distances are then scaled to the tree's
 * units by SCALE_INV2 (the scale's inverse squared: a power of 4, exact).
 *
 * closest_points walks the tree nearest region first (Arya & Mount's incremental
 * distance: a region's lower bound is the squared length of the per-axis offsets
 * from the point to it, and a split changes one of them), skipping a region whose
 * bound exceeds the best squared distance so far. A triangle's part in a leaf lies in
 * the leaf's region (perfect splits), so every triangle's nearest point lies in a
 * region that references it and is not skipped. GEOMETRY64's triangles may leave the
 * regions by their rounding to float: SLACK (a distance, >= 0) widens every bound by
 * it. Equal distances: the lower input id (a triangle in
 * several leaves gives the same distance in each).
 *
 * winding_points sums each triangle's solid angle over 4 pi exactly (Van Oosterom &
 * Strackee) where the point is near, and a node's far-field expansion where the point
 * is more than beta (an argument) times the node's radius from its centre: Barill et
 * al.'s Taylor series to the third order, over the triangles the node owns
 * (kdray/points.py, winding_moments, which says what the node's KD_NODE_VALUES floats
 * hold: each input triangle is owned by one leaf copy, so copies count once).
 *
 * Options (-D): STACK_SIZE (the tree's depth + 1 at least), NEAR_STACK (closest_points'
 * best-first stack, 2 STACK_SIZE unless given), LOCAL_SIZE, GEOMETRY64, SLACK and
 * SCALE_INV2 (double literals), PACKET
 * (leaves in runs of a packet, as packet programs lay them out), KD_PLAIN_VECTOR_OPS,
 * OUT_POINT, OUT_UV, OUT_ID (which outputs closest_points writes).
 */
#pragma OPENCL FP_CONTRACT OFF
#include "layout.h"
#include "ops.h"

#ifndef LOCAL_SIZE
#define LOCAL_SIZE 8
#endif
#ifndef SLACK
#define SLACK 0.0
#endif
#ifndef NEAR_STACK
#define NEAR_STACK (2 * STACK_SIZE)
#endif

#define KD_NO_LANES __attribute__((vec_type_hint(float4)))
#define KD_POINT_FAULT 2u                /* out_fault: the walk met a corrupt tree */
#define KD_NODE_VALUES 32u               /* winding_points: floats a node (points.py) */

KD_INLINE double kd_dot_d(double3 a, double3 b) { return (a.x * b.x + a.y * b.y) + a.z * b.z; }

KD_INLINE
double3 kd_cross_d(double3 a, double3 b)
{
    return (double3)(a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x);
}

/* Vertex k of device copy `tri` in double: its float vertex, or with GEOMETRY64 the
 * input's float64 vertex (tris64: 9 doubles an input id). */
#ifdef GEOMETRY64
#define KD_GEOMETRY_ARG , __global const double *tris64
#define KD_VERTEX_D(tri, k) vload3(3u * tri_ids[tri] + (k), tris64)
#define KD_PASS_GEOMETRY , tris64
#define KD_POINTS64_ARG , __global const double *points64
#else
#define KD_GEOMETRY_ARG
#define KD_VERTEX_D(tri, k) convert_double3(kd_vertex(tris, tri, k))
#define KD_PASS_GEOMETRY
#define KD_POINTS64_ARG
#endif

/* Whether point a comes before point b: by x, then y, then z */
KD_INLINE
bool kd_lower_d(double3 a, double3 b)
{
    return a.x < b.x || (a.x == b.x && (a.y < b.y || (a.y == b.y && a.z < b.z)));
}

/* The point q of segment (a, b) nearest p, as p - q, and *s its place from a (0: a,
 * 1: b). The same bits whichever way round the segment is given (it is taken from
 * its lower end, kd_lower_d, first): a point beyond the edge two triangles share is
 * exactly as near to both, so that the lower input id wins (kd_nearest_triangle). At
 * an end, p minus that end: a vertex's own offset in every triangle. */
KD_INLINE
double3 kd_closest_on_segment(double3 p, double3 a, double3 b, double *s)
{
    bool swap = kd_lower_d(b, a);
    double3 lo = swap ? b : a, hi = swap ? a : b;
    double3 e = p - lo, ab = hi - lo;
    double den = kd_dot_d(ab, ab);
    double t = den > 0.0 ? kd_dot_d(e, ab) / den : 0.0;
    if (!(t > 0.0)) {
        t = 0.0;
    } else if (t >= 1.0) {
        t = 1.0;
        e = p - hi;
    } else {
        e = e - t * ab;
    }
    *s = swap ? 1.0 - t : t;
    return e;
}

/* The nearest of triangle (a, b, c)'s edges to p (kd_closest_on_segment): p - q, and
 * q's u, v, *d2 (as kd_closest_on_triangle). */
KD_INLINE
double3 kd_closest_on_edges(double3 p, double3 a, double3 b, double3 c, double *u,
                            double *v, double *d2)
{
    double s, t, r;
    double3 e_ab = kd_closest_on_segment(p, a, b, &s);
    double3 e_ac = kd_closest_on_segment(p, a, c, &t);
    double3 e_bc = kd_closest_on_segment(p, b, c, &r);
    double d_ab = kd_dot_d(e_ab, e_ab), d_ac = kd_dot_d(e_ac, e_ac), d_bc = kd_dot_d(e_bc, e_bc);
    if (d_ab <= d_ac && d_ab <= d_bc) {
        *u = s; *v = 0.0; *d2 = d_ab;
        return e_ab;
    }
    if (d_ac <= d_bc) {
        *u = 0.0; *v = t; *d2 = d_ac;
        return e_ac;
    }
    *u = 1.0 - r; *v = r; *d2 = d_bc;
    return e_bc;
}

/* kd_closest_on_triangle of a triangle whose vertices come in kd_lower_d's order.
 * The point q of triangle (a, b, c) nearest p, q = a + u (b - a) + v (c - a), by the
 * Voronoi region of p (Ericson, Real-Time Collision Detection, 5.1.5). Returns p - q,
 * made from p's offsets to the vertices (not from q), and *d2 its squared length: in
 * the face's region the squared distance to the plane, (n . (p - a))^2 / n . n. So
 * their rounding is relative to the triangle's size, not to the coordinates'. The
 * face's region is told by va, vb, vc, the signed areas of (q, b, c), (a, q, c),
 * (a, b, q) times 2 |n| (so va / n . n is q's weight of a): Ericson's differences of
 * products of dot products (Lagrange's identity) cancel as the triangle's smallest
 * angle squared, which put points of thin triangles in an edge's region while their
 * nearest point lay inside the face (1e-3 of the distance at an angle of 5e-8), so
 * they are n . (edge x offset), whose rounding is the triangle's size times 2^-52 or
 * so whatever its angles. An edge's
 * point is kd_closest_on_segment's (the same bits in both triangles that share the
 * edge). The nearest edge's point is taken instead of the region's (the plane's is
 * never farther than the exact distance, an edge's never nearer):
 * - everywhere in a sliver (its angle at a below 2^-26: n = ab x ac's direction, and
 *   the regions' tests, lost to rounding), which lies within its width of its edges
 *   (off by at most that width, where the point is that near its inside);
 * - where p may lie in an edge's region (va, vb or vc within 2^-44 of the longest
 *   edge squared times p's largest offset squared, far above their rounding, a few
 *   2^-53 of |n| times an edge times an offset) and the edge's distance is the
 *   plane's to 2^-50 of it, or both within 2^-50 of that offset of 0: so that a point
 *   on an edge two triangles share is exactly as near to both, and the lower input
 *   id wins. */
KD_INLINE
double3 kd_closest_in_order(double3 p, double3 a, double3 b, double3 c, double *u,
                            double *v, double *d2)
{
    double3 ab = b - a, ac = c - a, ap = p - a;
    double3 n = kd_cross_d(ab, ac);
    double nn = kd_dot_d(n, n);
    if (!(nn > 0x1p-52 * kd_dot_d(ab, ab) * kd_dot_d(ac, ac)))   /* a sliver */
        return kd_closest_on_edges(p, a, b, c, u, v, d2);
    double3 e;
    double d1 = kd_dot_d(ab, ap), d2_ = kd_dot_d(ac, ap);
    if (d1 <= 0.0 && d2_ <= 0.0) {                    /* vertex a */
        *u = 0.0; *v = 0.0;
        e = ap;
    } else {
        double3 bp = p - b;
        double d3 = kd_dot_d(ab, bp), d4 = kd_dot_d(ac, bp);
        double vc = kd_dot_d(n, kd_cross_d(ab, ap));
        if (d3 >= 0.0 && d4 <= d3) {                  /* vertex b */
            *u = 1.0; *v = 0.0;
            e = bp;
        } else if (vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0) {   /* edge ab */
            double s;
            e = kd_closest_on_segment(p, a, b, &s);
            *u = s; *v = 0.0;
        } else {
            double3 cp = p - c;
            double d5 = kd_dot_d(ab, cp), d6 = kd_dot_d(ac, cp);
            double vb = kd_dot_d(n, kd_cross_d(ap, ac));
            double va = kd_dot_d(n, kd_cross_d(c - b, bp));
            if (d6 >= 0.0 && d5 <= d6) {              /* vertex c */
                *u = 0.0; *v = 1.0;
                e = cp;
            } else if (vb <= 0.0 && d2_ >= 0.0 && d6 <= 0.0) {   /* edge ac */
                double s;
                e = kd_closest_on_segment(p, a, c, &s);
                *u = 0.0; *v = s;
            } else if (va <= 0.0 && d4 - d3 >= 0.0 && d5 - d6 >= 0.0) {   /* edge bc */
                double s;
                e = kd_closest_on_segment(p, b, c, &s);
                *u = 1.0 - s; *v = s;
            } else {                                  /* inside the face */
                double3 bc = c - b;
                double l2 = fmax(fmax(kd_dot_d(ab, ab), kd_dot_d(ac, ac)), kd_dot_d(bc, bc));
                double den = 1.0 / (va + vb + vc);
                *u = vb * den; *v = vc * den;
                double h = kd_dot_d(n, ap);
                *d2 = h * h / nn;
                e = n * (h / nn);
                double p2 = fmax(fmax(kd_dot_d(ap, ap), kd_dot_d(bp, bp)), kd_dot_d(cp, cp));
                double near = 0x1p-44 * l2 * p2;
                if (va <= near || vb <= near || vc <= near) {
                    double eu, ev, ed2;
                    double3 ee = kd_closest_on_edges(p, a, b, c, &eu, &ev, &ed2);
                    if (ed2 <= *d2 + 0x1p-50 * *d2 + 0x1p-100 * p2) {
                        *u = eu; *v = ev; *d2 = ed2;
                        return ee;
                    }
                }
                return e;
            }
        }
    }
    *d2 = kd_dot_d(e, e);
    return e;
}

/* Vertices x, y and their given places kx, ky swapped where y comes before x */
#define KD_ORDER_PAIR(x, y, kx, ky)                                                      \
    if (kd_lower_d(y, x)) {                                                                \
        double3 x_ = x;                                                                    \
        uint k_ = kx;                                                                      \
        x = y; y = x_; kx = ky; ky = k_;                                                   \
    }

/* The point q of triangle (a, b, c) nearest p, q = a + u (b - a) + v (c - a): p - q,
 * with *d2 its squared length (kd_closest_in_order). The vertices are taken in
 * kd_lower_d's order, so that a triangle given twice, its vertices in any order, is
 * measured alike, bit for bit, and the lower input id wins (kd_nearest_triangle); u
 * and v are then the weights of b and c. */
KD_INLINE
double3 kd_closest_on_triangle(double3 p, double3 a, double3 b, double3 c, double *u,
                               double *v, double *d2)
{
    uint ka = 0u, kb = 1u, kc = 2u;
    KD_ORDER_PAIR(a, b, ka, kb)
    KD_ORDER_PAIR(b, c, kb, kc)
    KD_ORDER_PAIR(a, b, ka, kb)
    double su, sv;
    double3 e = kd_closest_in_order(p, a, b, c, &su, &sv, d2);
    double sw = 1.0 - su - sv;
    /* the given second and third vertices' weights */
    *u = kb == 1u ? su : (kc == 1u ? sv : sw);
    *v = kb == 2u ? su : (kc == 2u ? sv : sw);
    return e;
}

/* The best answer so far of one point. */
typedef struct {
    double d2;                           /* squared distance */
    double bound2;                       /* regions farther than this are skipped */
    double pad;                          /* bound2's widening (kd_nearest_pad) */
    double u, v;
    double3 q;                           /* the nearest point (GEOMETRY64: world) */
#ifdef GEOMETRY64
    double3 p64;                         /* the point, world: the exact tests' */
#endif
    uint id;                             /* input id, KD_NO_HIT */
    uint tri;                            /* its device copy (layout.h) */
} KdNearest;

/* Triangle `tri` (device copy) tested exactly against the best so far (p: the point
 * relative to the tree's origin; GEOMETRY64 tests best->p64 against the world
 * triangle, its squared distance then in the tree's units). */
KD_INLINE
void kd_nearest_triangle(__global const float *tris, __global const uint *tri_ids
                         KD_GEOMETRY_ARG, uint tri, double3 p, KdNearest *best)
{
    uint id = tri_ids[tri];
    if (id == KD_NO_HIT)                              /* a packet run's padding */
        return;
#ifdef GEOMETRY64
    double3 at = best->p64;
#else
    double3 at = p;
#endif
    double u, v, d2;
    double3 e = kd_closest_on_triangle(at, KD_VERTEX_D(tri, 0), KD_VERTEX_D(tri, 1),
                                       KD_VERTEX_D(tri, 2), &u, &v, &d2);
#ifdef GEOMETRY64
    d2 *= SCALE_INV2;
#endif
    if (d2 < best->d2 || (d2 == best->d2 && id < best->id)) {
        best->d2 = d2;
        best->u = u;
        best->v = v;
        best->q = at - e;
        best->id = id;
        best->tri = tri;
        double r = sqrt(d2) + SLACK + best->pad;
        best->bound2 = r * r;
    }
}

/* The widening of a point's bound past its best distance: a region's lower bound and
 * a triangle's squared distance in it are rounded apart (by a few roundings of the
 * coordinates, up to the point's or the scene's size: scene, the box's largest
 * |coordinate|), and a region whose bound rounds just above a distance that ties
 * (the lower id) or beats the best must still be walked; else which triangle wins
 * would depend on the order they were tested in (a point's first test is the
 * previous point's triangle). 2^-44 of that size is far above those roundings; it
 * walks a few more regions only where a point is that near a region's side. */
KD_INLINE
double kd_nearest_pad(double3 p, float scene)
{
    double size = fmax(fmax(fabs(p.x), fabs(p.y)), fmax(fabs(p.z), (double)scene));
    return size * 0x1p-44;
}

#ifdef PACKET
/* Packet programs lay a leaf out in runs of KD_PACKET triangles, each run in one
 * block (layout.h): a run's boxes are tested against the best at once, in float, and
 * only the triangles whose box may be near enough are tested exactly. The float test
 * never drops a triangle the exact test could take: the box's offsets are widened by
 * `slack` (the point's and the subtraction's rounding) and the squared distance
 * shrunk by more than its own rounding. */
#define KD_PACKET PACKET
#include "lanes.h"
typedef union { floatP v; float s[KD_PACKET]; } KdPointF;

KD_INLINE floatP kd_run_row(__global const float *base, uint c)
{
#ifdef KD_PLAIN_VECTOR_OPS
    floatP r;
    float *s = (float *)&r;
#pragma unroll
    for (uint j = 0; j < KD_PACKET; j++)
        s[j] = base[c * KD_TRI_BLOCK + j];
    return r;
#else
    return vloadP(0, base + c * KD_TRI_BLOCK);
#endif
}

/* The squared distance from (px, py, pz) to the boxes of the triangles with rows
 * x (c = 0, 3, 6: x of v0, v1, v2), y, z, each offset widened by slack */
KD_INLINE floatP kd_box_offset(floatP a, floatP b, floatP c, float x, float slack)
{
    floatP lo = kd_minP(kd_minP(a, b), c), hi = kd_maxP(kd_maxP(a, b), c);
    return kd_maxP(kd_maxP(lo - x, x - hi) - slack, (floatP)(0.0f));
}

KD_INLINE
void kd_nearest_leaf(KdNode leaf, __global const float *tris, __global const uint *tri_ids
                     KD_GEOMETRY_ARG, double3 p, float3 pf, float slack, KdNearest *best)
{
    uint count = kd_n_prims(leaf);
    uint first = kd_leaf_offset(leaf);
    for (uint i0 = 0; i0 < count; i0 += KD_PACKET) {
        __global const float *base = kd_tri_base(tris, first + i0);
        floatP dx = kd_box_offset(kd_run_row(base, 0), kd_run_row(base, 3), kd_run_row(base, 6),
                                  pf.x, slack);
        floatP dy = kd_box_offset(kd_run_row(base, 1), kd_run_row(base, 4), kd_run_row(base, 7),
                                  pf.y, slack);
        floatP dz = kd_box_offset(kd_run_row(base, 2), kd_run_row(base, 5), kd_run_row(base, 8),
                                  pf.z, slack);
        KdPointF box;
        box.v = (dx * dx + dy * dy + dz * dz) * (1.0f - 0x1p-19f);
        if (!kd_anyP(box.v <= (floatP)((float)best->bound2 * (1.0f + 0x1p-19f))))
            continue;
        /* the nearest box first: its triangle's distance mostly rules out the rest */
        uint m = count - i0 < KD_PACKET ? count - i0 : KD_PACKET;
        uint nearest = 0;
        for (uint j = 1; j < m; j++)
            if (box.s[j] < box.s[nearest])
                nearest = j;
        if (box.s[nearest] <= (float)best->bound2 * (1.0f + 0x1p-19f))
            kd_nearest_triangle(tris, tri_ids KD_PASS_GEOMETRY, first + i0 + nearest, p, best);
        for (uint j = 0; j < m; j++)
            if (j != nearest && box.s[j] <= (float)best->bound2 * (1.0f + 0x1p-19f))
                kd_nearest_triangle(tris, tri_ids KD_PASS_GEOMETRY, first + i0 + j, p, best);
    }
}
#else
KD_INLINE
void kd_nearest_leaf(KdNode leaf, __global const float *tris, __global const uint *tri_ids
                     KD_GEOMETRY_ARG, double3 p, float3 pf, float slack, KdNearest *best)
{
    uint count = kd_n_prims(leaf);
    uint first = kd_leaf_offset(leaf);
    for (uint i = 0; i < count; i++)
        kd_nearest_triangle(tris, tri_ids KD_PASS_GEOMETRY, first + i, p, best);
}
#endif

KD_INLINE double kd_get(double3 v, uint axis) { return axis == 0u ? v.x : (axis == 1u ? v.y : v.z); }

KD_INLINE
double3 kd_set(double3 v, uint axis, double x)
{
    if (axis == 0u) v.x = x;
    else if (axis == 1u) v.y = x;
    else v.z = x;
    return v;
}

/* The offset along one axis from x to the interval [lo, hi] (0 inside). */
KD_INLINE double kd_offset(double x, double lo, double hi) { return x < lo ? lo - x : (x > hi ? x - hi : 0.0); }

#define KD_WALK_DONE 0u
#define KD_WALK_CORRUPT 1u
#define KD_WALK_FULL 2u

/* The nearest surface point to p within best->bound2 (the caller's limit).
 *
 * Regions are taken best first, the stacked one nearest the point, which finds a near
 * triangle soon and skips more (about a quarter faster for points near the surface);
 * their stack then has no depth bound, and when its NEAR_STACK entries are full the
 * walk returns KD_WALK_FULL, to be run again `lifo`: last in first out, which stacks
 * at most one region a level (STACK_SIZE <= NEAR_STACK), starting from the best found
 * (a real triangle's distance, so nothing is lost). The answer does not depend on the
 * order: the least squared distance, ties to the lowest input id. KD_WALK_CORRUPT: a
 * tree deeper than its depth or with more leaves than nodes. */
KD_INLINE
uint kd_nearest_walk(__global const KdNode *nodes, uint n_nodes, __global const float *tris,
                     __global const uint *tri_ids KD_GEOMETRY_ARG, float3 bmin, float3 bmax,
                     double3 p, bool lifo, KdNearest *best)
{
    uint stack_node[NEAR_STACK];
    double3 stack_off[NEAR_STACK];
    double stack_lb[NEAR_STACK];
    uint count = 0;
    uint node = 0;
    double3 off = (double3)(kd_offset(p.x, bmin.x, bmax.x), kd_offset(p.y, bmin.y, bmax.y),
                            kd_offset(p.z, bmin.z, bmax.z));
    double lb = kd_dot_d(off, off);
    uint leaves = 0;
    /* the point in float for kd_nearest_leaf's box test, and that test's slack: the
     * point's rounding and a subtraction's, of coordinates up to its size or the
     * scene's */
    float3 pf = convert_float3(p);
    float size = kd_max(kd_max(kd_abs(pf.x), kd_max(kd_abs(pf.y), kd_abs(pf.z))),
                        kd_max(kd_max(kd_abs(bmin.x), kd_abs(bmax.x)),
                               kd_max(kd_max(kd_abs(bmin.y), kd_abs(bmax.y)),
                                      kd_max(kd_abs(bmin.z), kd_abs(bmax.z)))));
    float slack = size * 0x1p-21f;
    for (;;) {
        if (lb <= best->bound2) {
            KdNode n = nodes[node];
            while (!kd_is_leaf(n)) {
                uint axis = kd_split_axis(n);
                double delta = kd_get(p, axis) - (double)kd_split(n);
                uint below = node + 1u, above = kd_above_child(n);
                uint near = delta <= 0.0 ? below : above;
                uint far = delta <= 0.0 ? above : below;
                double a = kd_get(off, axis);
                double far_lb = (lb - a * a) + delta * delta;
                if (far_lb <= best->bound2) {
                    if (count == (lifo ? STACK_SIZE : NEAR_STACK))
                        return lifo ? KD_WALK_CORRUPT : KD_WALK_FULL;
                    stack_node[count] = far;
                    stack_off[count] = kd_set(off, axis, delta);
                    stack_lb[count] = far_lb;
                    count++;
                }
                node = near;
                n = nodes[node];
            }
            if (++leaves > n_nodes)                    /* more leaves than nodes: corrupt */
                return KD_WALK_CORRUPT;
            kd_nearest_leaf(n, tris, tri_ids KD_PASS_GEOMETRY, p, pf, slack, best);
        }
        if (count == 0u)
            return KD_WALK_DONE;
        uint j = count - 1u;
        if (!lifo)
            for (uint i = 0; i + 1u < count; i++)
                if (stack_lb[i] < stack_lb[j])
                    j = i;
        count--;
        node = stack_node[j];
        off = stack_off[j];
        lb = stack_lb[j];
        stack_node[j] = stack_node[count];
        stack_off[j] = stack_off[count];
        stack_lb[j] = stack_lb[count];
    }
}

/* A work-item's points: `run` consecutive ones (a kernel argument: small launches take
 * fewer a work-item, so that every compute unit gets some; points.py, _run) */
#define KD_FOR_ITEM_POINTS(k)                                                              \
    uint first_point = (uint)get_global_id(0) * run;                                       \
    uint end_point = min(first_point + run, n_points);                                     \
    for (uint k = first_point; k < end_point; k++)

/* Point k's nearest surface point within sqrt(max_d2): out_d its distance (+inf when
 * none is that near, NaN on a corrupt tree), out_point the point (relative to the
 * origin in its units), out_uv its barycentrics (weights of v1, v2), out_id the
 * triangle's input id (KD_NO_HIT when none). A point that is not finite has none. */
__kernel __attribute__((reqd_work_group_size(LOCAL_SIZE, 1, 1))) KD_NO_LANES
void closest_points(__global const KdNode *nodes, __global const float *tris,
                    __global const uint *tri_ids, __global const float *bounds, uint n_nodes
                    KD_GEOMETRY_ARG, __global const double *points KD_POINTS64_ARG,
                    double max_d2, uint n_points, uint run, __global double *out_d,
                    __global double *out_point,
                    __global float *out_uv, __global uint *out_id)
{
    /* Points come in spatial order (points.py): the work-item's previous point's
     * nearest triangle is near this one too, and tested first it bounds the walk from
     * the start, which then skips most regions at once. The answer does not depend on
     * the order triangles are tested in (ties: the lowest input id). */
    uint prev_tri = KD_NO_HIT;
    float3 bmin = vload3(0, bounds), bmax = vload3(1, bounds);
    float scene = fmax(fmax(fmax(fabs(bmin.x), fabs(bmax.x)), fmax(fabs(bmin.y), fabs(bmax.y))),
                       fmax(fabs(bmin.z), fabs(bmax.z)));
    KD_FOR_ITEM_POINTS(k) {
        double3 p = vload3(k, points);
        KdNearest best;
        best.d2 = max_d2;
        best.bound2 = max_d2;
        best.u = 0.0;
        best.v = 0.0;
        best.q = (double3)(0.0);
        best.id = KD_NO_HIT;
        best.tri = KD_NO_HIT;
        best.pad = kd_nearest_pad(p, scene);
#ifdef GEOMETRY64
        best.p64 = vload3(k, points64);
#endif
        uint walk = KD_WALK_DONE;
        if (isfinite(p.x) && isfinite(p.y) && isfinite(p.z)) {
            if (prev_tri != KD_NO_HIT)
                kd_nearest_triangle(tris, tri_ids KD_PASS_GEOMETRY, prev_tri, p, &best);
            walk = kd_nearest_walk(nodes, n_nodes, tris, tri_ids KD_PASS_GEOMETRY,
                                   vload3(0, bounds), vload3(1, bounds), p, false, &best);
            if (walk == KD_WALK_FULL)
                walk = kd_nearest_walk(nodes, n_nodes, tris, tri_ids KD_PASS_GEOMETRY,
                                       vload3(0, bounds), vload3(1, bounds), p, true, &best);
        }
        bool ok = walk == KD_WALK_DONE;
        bool found = ok && best.id != KD_NO_HIT;
        prev_tri = found ? best.tri : KD_NO_HIT;
        out_d[k] = !ok ? NAN : (found ? sqrt(best.d2) : INFINITY);
#ifdef OUT_POINT
        vstore3(found ? best.q : (double3)(0.0), k, out_point);
#endif
#ifdef OUT_UV
        out_uv[2 * (size_t)k] = found ? (float)best.u : 0.0f;
        out_uv[2 * (size_t)k + 1] = found ? (float)best.v : 0.0f;
#endif
#ifdef OUT_ID
        out_id[k] = found ? best.id : KD_NO_HIT;
#endif
    }
}

/* The solid angle of triangle (a, b, c) seen from the origin, over 4 pi (a, b, c
 * relative to the point): positive where the triangle's front (counter-clockwise)
 * faces away from the point (Van Oosterom & Strackee 1983). 0 where the point lies in
 * the triangle's plane (num exactly 0), also inside it, where atan2 would give +-1/2
 * by the sign of num's zero: the triangle is seen edge-on, and a point on a closed
 * surface's face then has winding number 1/2 (the rest of the surface's), not 0 or 1
 * by a zero's sign (reference.winding_number takes the same rule). */
KD_INLINE
double kd_solid_angle(double3 a, double3 b, double3 c)
{
    double la = sqrt(kd_dot_d(a, a)), lb = sqrt(kd_dot_d(b, b)), lc = sqrt(kd_dot_d(c, c));
    double num = kd_dot_d(a, kd_cross_d(b, c));
    double den = la * lb * lc + kd_dot_d(a, b) * lc + kd_dot_d(a, c) * lb + kd_dot_d(b, c) * la;
    return num == 0.0 ? 0.0 : atan2(num, den) * (0.5 / M_PI);   /* 2 atan2 / (4 pi) */
}

#ifdef PACKET
#if KD_PACKET == 16
typedef uchar16 ucharP;
#define vload_ucharP vload16
#else
typedef uchar8 ucharP;
#define vload_ucharP vload8
#endif
typedef union { doubleP v; double s[KD_PACKET]; } KdPointD;

/* The solid angles over 4 pi of a run of KD_PACKET triangles (a leaf starts on a
 * multiple of KD_PACKET: one block), each as kd_solid_angle computes it, lane by
 * lane in double (0 in the triangle's plane), summed over the lanes whose copy is
 * owned (padding never is). */
KD_INLINE
double kd_run_solid_angles(__global const float *tris, __global const uchar *owned,
                           uint first, double3 p)
{
    __global const float *base = kd_tri_base(tris, first);
    doubleP ax = convert_doubleP(kd_run_row(base, 0)) - p.x;
    doubleP ay = convert_doubleP(kd_run_row(base, 1)) - p.y;
    doubleP az = convert_doubleP(kd_run_row(base, 2)) - p.z;
    doubleP bx = convert_doubleP(kd_run_row(base, 3)) - p.x;
    doubleP by = convert_doubleP(kd_run_row(base, 4)) - p.y;
    doubleP bz = convert_doubleP(kd_run_row(base, 5)) - p.z;
    doubleP cx = convert_doubleP(kd_run_row(base, 6)) - p.x;
    doubleP cy = convert_doubleP(kd_run_row(base, 7)) - p.y;
    doubleP cz = convert_doubleP(kd_run_row(base, 8)) - p.z;
    doubleP la = sqrt((ax * ax + ay * ay) + az * az);
    doubleP lb = sqrt((bx * bx + by * by) + bz * bz);
    doubleP lc = sqrt((cx * cx + cy * cy) + cz * cz);
    doubleP num = (ax * (by * cz - bz * cy) + ay * (bz * cx - bx * cz)) + az * (bx * cy - by * cx);
    doubleP ab = (ax * bx + ay * by) + az * bz;
    doubleP ac = (ax * cx + ay * cy) + az * cz;
    doubleP bc = (bx * cx + by * cy) + bz * cz;
    doubleP den = ((la * lb * lc + ab * lc) + ac * lb) + bc * la;
    KdPointD angle;
    /* 0 in the triangle's plane, as kd_solid_angle */
    angle.v = select(atan2(num, den), (doubleP)(0.0), num == (doubleP)(0.0))
              * convert_doubleP(vload_ucharP(0, owned + first));
    double sum = 0.0;
    for (uint j = 0; j < KD_PACKET; j++)
        sum += angle.s[j];
    return sum * (0.5 / M_PI);
}
#endif

/* Point k's generalized winding number into out_w (NaN on a corrupt tree); 0 for a
 * point that is not finite. */
__kernel __attribute__((reqd_work_group_size(LOCAL_SIZE, 1, 1))) KD_NO_LANES
void winding_points(__global const KdNode *nodes, __global const float *tris,
                    __global const uint *tri_ids, __global const float *bounds, uint n_nodes
                    KD_GEOMETRY_ARG, __global const double *points KD_POINTS64_ARG,
                    __global const float *moments,
                    __global const uchar *owned, double beta2, uint n_points, uint run,
                    __global double *out_w)
{
    KD_FOR_ITEM_POINTS(k) {
        double3 p = vload3(k, points);
        if (!(isfinite(p.x) && isfinite(p.y) && isfinite(p.z))) {
            out_w[k] = 0.0;
            continue;
        }
#ifdef GEOMETRY64
        double3 at = vload3(k, points64);        /* world, as tris64: the exact angles' */
#else
        double3 at = p;
#endif
        uint stack[STACK_SIZE];
        uint count = 0;
        uint node = 0;
        uint visits = 0;
        double w = 0.0;
        bool ok = true;
        for (;;) {
            __global const float *m = moments + (size_t)node * KD_NODE_VALUES;
            double r = (double)m[3];
            bool pop = true;
            if (++visits > n_nodes) {                  /* a node twice: corrupt */
                ok = false;
                break;
            }
            if (r >= 0.0) {                            /* it owns triangles */
                double3 c = (double3)((double)m[0], (double)m[1], (double)m[2]);
                double3 d = c - p;                     /* r0 = centre - point */
                double dd = kd_dot_d(d, d);
                KdNode n = nodes[node];
                if (dd > beta2 * (r * r)) {
                    /* far (d = centre - point): 1/4pi times
                     *   d.N / |d|^3                                        (dipole)
                     * + tr C / |d|^3 - 3 d^T C d / |d|^5                   (2nd order)
                     * + 1/2 (-3 (2a + b).d / |d|^5 + 15 T(d, d, d) / |d|^7)  (3rd) */
                    double3 N = (double3)((double)m[4], (double)m[5], (double)m[6]);
                    double3 ab = (double3)((double)m[15], (double)m[16], (double)m[17]);
                    double inv = 1.0 / dd;
                    double inv3 = inv * sqrt(inv);
                    double inv5 = inv3 * inv;
                    double x = d.x, y = d.y, z = d.z;
                    double dCd = (double)m[9] * x * x + (double)m[10] * y * y
                                 + (double)m[11] * z * z + (double)m[12] * x * y
                                 + (double)m[13] * x * z + (double)m[14] * y * z;
                    double T3 = (double)m[18] * x * x * x + (double)m[19] * y * y * y
                                + (double)m[20] * z * z * z + (double)m[21] * x * x * y
                                + (double)m[22] * x * x * z + (double)m[23] * x * y * y
                                + (double)m[24] * y * y * z + (double)m[25] * x * z * z
                                + (double)m[26] * y * z * z + (double)m[27] * x * y * z;
                    w += (kd_dot_d(d, N) * inv3 + ((double)m[8] * inv3 - 3.0 * dCd * inv5)
                          + 0.5 * (-3.0 * kd_dot_d(ab, d) * inv5 + 15.0 * T3 * inv5 * inv))
                         * (0.25 / M_PI);
                } else if (kd_is_leaf(n)) {
                    uint first = kd_leaf_offset(n);
#if defined(PACKET) && !defined(GEOMETRY64)
                    for (uint i = 0; i < kd_n_prims(n); i += KD_PACKET)
                        w += kd_run_solid_angles(tris, owned, first + i, p);
#else
                    for (uint i = 0; i < kd_n_prims(n); i++) {
                        uint tri = first + i;
                        if (!owned[tri])
                            continue;
                        w += kd_solid_angle(KD_VERTEX_D(tri, 0) - at, KD_VERTEX_D(tri, 1) - at,
                                            KD_VERTEX_D(tri, 2) - at);
                    }
#endif
                } else {
                    if (count == STACK_SIZE) {
                        ok = false;
                        break;
                    }
                    stack[count++] = kd_above_child(n);
                    node = node + 1u;
                    pop = false;
                }
            }
            if (pop) {
                if (count == 0u)
                    break;
                node = stack[--count];
            }
        }
        out_w[k] = ok ? w : NAN;
    }
}
