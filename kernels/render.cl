/* kernels/render.cl: kdray's kernel entry points.
 *
 *   trace_rays     rays from buffers (origins, directions: 3 floats or doubles each)
 *   render_camera  primary rays of a pinhole camera, generated here
 *
 * Both are persistent: the host launches about enough work-groups to fill the device,
 * and each group pulls batches of BATCH_SIZE rays from one global counter (reset to 0
 * before every launch) until the rays run out. Work-item 0 fetches the batch into
 * __local memory between two barriers that every work-item of the group reaches the
 * same number of times, which OpenCL guarantees on every device (PoCL runs a group's
 * work-items one after another between barriers).
 *
 * Options (-D): LOCAL_SIZE (work-group size, required), BATCH_SIZE (a multiple of it,
 * times PACKET with PACKET), STACK_SIZE (see traverse.cl), TILE_W and TILE_H
 * (render_camera's tiles); PACKET (8 or 16): each work-item traces that many rays as a
 * packet in vector lanes (packet.cl, with PACKET_STACK_SIZE; for CPU devices): as many
 * consecutive rays of trace_rays, a block of 4 x PACKET / 4 pixels of render_camera;
 * else one ray. Outputs, each only when asked: OUT_T (t,
 * +inf on a miss), OUT_UV (u, v; 0 on a miss), OUT_NORMAL (unit geometric normal; 0 on
 * a miss), OUT_ID (input triangle id; 0xFFFFFFFF on a miss), STATS (uint4 per ray).
 * Output buffers that are not compiled in may be passed as NULL. SCALE (a float
 * literal, the tree's scale when it is not 1) multiplies every stored t, and its
 * inverse SCALE_INV (a double literal) the rays trace_rays shifts. RAYS_WORLD:
 * trace_rays reads rays in world coordinates, origins of type ORIGIN_T and directions
 * of DIRECTION_T (float or double), and takes the tree's origin.
 * REFINE: t, u, v of each hit recomputed in double (triangle.cl, kd_refine_hit).
 * ANY_HIT: a ray's traversal ends at the first hit it finds (traverse.cl, kd_hit_done),
 * which trace_rays stores: whether there is any hit (rays.py, occluded), not the nearest.
 */
#pragma OPENCL FP_CONTRACT OFF
#include "layout.h"
#include "triangle.cl"
#include "traverse.cl"

/* t in the tree's units (positions divided by its scale, directions not) times the
 * scale is t; a -D option only where the scale is not 1, so that scenes at scale 1
 * run the kernels as they are (and share their programs). */
#ifdef SCALE
#define KD_T_SCALE (SCALE)
#define KD_SCALE_INV (SCALE_INV)
#else
#define KD_T_SCALE 1.0f
#define KD_SCALE_INV 1.0
#endif
#ifdef PACKET
#include "packet.cl"
#endif

/* A packet kernel is vectorized by hand (floatP): vec_type_hint says so. Without it
 * Intel's CPU runtime vectorizes a work-group across its work-items as soon as the
 * group is as wide as its vector unit (8 work-items with AVX2), and a packet kernel
 * so transposed runs 23-32 times slower (BENCHMARKS.md, "CPU runtimes and packet
 * widths"). PoCL and
 * Oclgrind ignore the hint. */
#ifdef PACKET
#define KD_VEC_HINT __attribute__((vec_type_hint(floatP)))
#else
#define KD_VEC_HINT
#endif
#ifndef LOCAL_SIZE
#define LOCAL_SIZE 64
#endif
#ifndef BATCH_SIZE
#define BATCH_SIZE LOCAL_SIZE
#endif

/* KD_WIDE (packet programs of trace_rays): the tree's wide nodes follow n_nodes
 * (wide.cl) */
#ifndef KD_WIDE_PARAM
#define KD_WIDE_PARAM
#define KD_WIDE_PASS
#endif

#define KD_TREE_ARGS                                                                     \
    __global const KdNode *nodes, __global const float *tris, __global const uint *tri_ids, \
    __global const float *bounds, uint n_nodes KD_WIDE_PARAM

#define KD_OUTPUT_ARGS                                                                   \
    __global float *out_t, __global float *out_uv, __global float *out_normal,           \
    __global uint *out_id, __global uint *out_stats

#define KD_TREE_PARAMS                                                                   \
    __global const KdNode *nodes, __global const float *tris, __global const uint *tri_ids, \
    float3 bmin, float3 bmax, uint n_nodes KD_WIDE_PARAM
#define KD_TREE_PASS nodes, tris, tri_ids, bmin, bmax, n_nodes KD_WIDE_PASS
#define KD_OUTPUT_PASS out_t, out_uv, out_normal, out_id, out_stats

/* The caller's rays in world coordinates, when trace_rays reads them (RAYS_WORLD):
 * what the hits are refined from (refine_hit, kd_refine_packet); render_camera passes
 * NULL. */
#if defined(RAYS_WORLD) && defined(REFINE) && defined(cl_khr_fp64)
#define KD_EXACT_PARAMS , __global const ORIGIN_T *exact_o, __global const DIRECTION_T *exact_d, \
    uint exact_o_step, double3 exact_origin
#define KD_EXACT_PASS , exact_o, exact_d, exact_o_step, exact_origin
#define KD_NO_EXACT , (__global const ORIGIN_T *)0, (__global const DIRECTION_T *)0, 0u, \
    (double3)(0.0)
#else
#define KD_EXACT_PARAMS
#define KD_EXACT_PASS
#define KD_NO_EXACT
#endif

/* With REFINE (and double on the device), and an output that holds t, u or v: hits'
 * t, u, v are recomputed in double (triangle.cl, kd_refine_hit) before they are stored,
 * from the caller's ray when there is one. */
#if defined(REFINE) && defined(cl_khr_fp64) && (defined(OUT_T) || defined(OUT_UV))
#define KD_REFINE_STORED
#endif

#if defined(KD_REFINE_STORED) && defined(RAYS_WORLD)
/* Ray k as the caller gave it (trace_rays with RAYS_WORLD), in double, relative to the
 * tree's origin in its units: what its hit is refined from. */
KD_INLINE
void kd_exact_ray(uint k, double3 *od, double3 *dd KD_EXACT_PARAMS)
{
    *od = (convert_double3(vload3((size_t)k * exact_o_step, exact_o)) - exact_origin)
          * KD_SCALE_INV;
    *dd = convert_double3(vload3(k, exact_d));
}
#endif

#ifdef KD_REFINE_STORED
/* Ray k's hit, if any, refined (kd_refine_hit) from the caller's ray when there is
 * one, else from the float ray traced (o, d). A packet's hits: kd_refine_packet. */
KD_INLINE
void refine_hit(uint k, Hit *hit, float3 o, float3 d, float t_min, float t_max,
                __global const float *tris KD_EXACT_PARAMS)
{
    if (hit->tri == KD_NO_HIT)
        return;
    double3 od = convert_double3(o), dd = convert_double3(d);
#if defined(RAYS_WORLD)
    if (exact_o)
        kd_exact_ray(k, &od, &dd KD_EXACT_PASS);
#endif
    kd_refine_hit(od, dd, kd_vertex(tris, hit->tri, 0), kd_vertex(tris, hit->tri, 1),
                  kd_vertex(tris, hit->tri, 2), t_min, t_max, &hit->t, &hit->u, &hit->v);
}
#endif

/* Write the outputs of ray k: only those compiled in (its hit refined already). */
KD_INLINE
void store_hit(uint k, const Hit *hit, __global const float *tris, __global const uint *tri_ids,
               KD_OUTPUT_ARGS)
{
    bool found = hit->tri != KD_NO_HIT;
#ifdef OUT_T
    out_t[k] = found ? hit->t * KD_T_SCALE : INFINITY;
#endif
#ifdef OUT_UV
    out_uv[2 * (size_t)k] = found ? hit->u : 0.0f;
    out_uv[2 * (size_t)k + 1] = found ? hit->v : 0.0f;
#endif
#ifdef OUT_NORMAL
    float3 normal = (float3)(0.0f, 0.0f, 0.0f);
    if (found) {
        float3 p0 = kd_vertex(tris, hit->tri, 0);
        normal = kd_normalize(kd_cross(kd_vertex(tris, hit->tri, 1) - p0,
                                       kd_vertex(tris, hit->tri, 2) - p0));
    }
    out_normal[3 * (size_t)k] = normal.x;
    out_normal[3 * (size_t)k + 1] = normal.y;
    out_normal[3 * (size_t)k + 2] = normal.z;
#endif
#ifdef OUT_ID
    out_id[k] = found ? tri_ids[hit->tri] : KD_NO_HIT;
#endif
}

#ifdef PACKET
#if defined(KD_REFINE_STORED) || defined(OUT_NORMAL)
/* P[c].s[l]: number c of lane l's triangle (p0's x, y, z, then p1's, p2's): triangle
 * tri.s[l] where found.s[l], else triangle 0. Only when some lane found a triangle
 * (there is one then). */
KD_INLINE
void kd_gather_triangles(KdIP found, KdUP tri, __global const float *tris, KdFP *P)
{
    for (uint l = 0; l < KD_PACKET; l++) {
        __global const float *p = kd_tri_base(tris, found.s[l] ? tri.s[l] : 0u);
#pragma unroll
        for (uint c = 0; c < 9; c++)
            P[c].s[l] = p[c * KD_TRI_BLOCK];
    }
}
#endif

#ifdef KD_REFINE_STORED
typedef union { doubleP v; double s[KD_PACKET]; } KdDP;

/* kd_refine_hit for the hits of the lanes in `found` (their t, u, v; P: their
 * triangles, kd_gather_triangles), in vectors: the lanes' float rays, or the caller's
 * double rays (kd_exact_ray, ray idx[l]), and their triangles' vertices, converted to
 * doubleP; KD_REFINE_PLANE runs once for all lanes (the scalar's operations: bit for
 * bit its values), and kd_take_refined keeps each lane's values as the scalar would.
 * Lanes without a hit compute their ray against triangle 0, never kept. */
KD_INLINE
void kd_refine_packet(KdFP ox, KdFP oy, KdFP oz, KdFP dx, KdFP dy, KdFP dz, KdIP found,
                      const KdFP *P, KdFP t_min, KdFP t_max, const uint *idx, KdFP *t,
                      KdFP *u, KdFP *v KD_EXACT_PARAMS)
{
    doubleP Ox = convert_doubleP(ox.v), Oy = convert_doubleP(oy.v), Oz = convert_doubleP(oz.v);
    doubleP Dx = convert_doubleP(dx.v), Dy = convert_doubleP(dy.v), Dz = convert_doubleP(dz.v);
#if defined(RAYS_WORLD)
    if (exact_o) {
        KdDP ex, ey, ez, fx, fy, fz;
        ex.v = Ox; ey.v = Oy; ez.v = Oz; fx.v = Dx; fy.v = Dy; fz.v = Dz;
        for (uint l = 0; l < KD_PACKET; l++) {
            if (!found.s[l])
                continue;
            double3 od, dd;
            kd_exact_ray(idx[l], &od, &dd KD_EXACT_PASS);
            ex.s[l] = od.x; ey.s[l] = od.y; ez.s[l] = od.z;
            fx.s[l] = dd.x; fy.s[l] = dd.y; fz.s[l] = dd.z;
        }
        Ox = ex.v; Oy = ey.v; Oz = ez.v; Dx = fx.v; Dy = fy.v; Dz = fz.v;
    }
#endif
    KD_REFINE_PLANE(doubleP, Ox, Oy, Oz, Dx, Dy, Dz,
                    convert_doubleP(P[0].v), convert_doubleP(P[1].v), convert_doubleP(P[2].v),
                    convert_doubleP(P[3].v), convert_doubleP(P[4].v), convert_doubleP(P[5].v),
                    convert_doubleP(P[6].v), convert_doubleP(P[7].v), convert_doubleP(P[8].v),
                    tt, uu, vv)
    KdDP t_d, u_d, v_d;
    t_d.v = tt; u_d.v = uu; v_d.v = vv;
    for (uint l = 0; l < KD_PACKET; l++)
        if (found.s[l])
            kd_take_refined(t_d.s[l], u_d.s[l], v_d.s[l], t_min.s[l], t_max.s[l], &t->s[l],
                            &u->s[l], &v->s[l]);
}
#endif

/* A block's rows written with plain stores of constant lanes, which LLVM merges into
 * vector stores: PoCL calls vstore and shuffle2 out of line, with their vectors
 * passed through memory (ops.h). KD_ROWS(ROW, ...) applies ROW(r, a, b, c, d, ...) to
 * each row r of the block, a .. d its lanes' components. */
#if KD_PACKET == 16
#define KD_ROWS(ROW, ...)                                                                \
    ROW(0, s0, s1, s2, s3, __VA_ARGS__) ROW(1, s4, s5, s6, s7, __VA_ARGS__)             \
    ROW(2, s8, s9, sa, sb, __VA_ARGS__) ROW(3, sc, sd, se, sf, __VA_ARGS__)
#else
#define KD_ROWS(ROW, ...)                                                                \
    ROW(0, s0, s1, s2, s3, __VA_ARGS__) ROW(1, s4, s5, s6, s7, __VA_ARGS__)
#endif
/* row r of x at p + k0 + r stride */
#define KD_ROW_1(r, a, b, c, d, x, p, k0, stride)                                        \
    {                                                                                    \
        size_t at_ = (k0) + (size_t)(r) * (stride);                                      \
        (p)[at_] = (x).a; (p)[at_ + 1] = (x).b; (p)[at_ + 2] = (x).c; (p)[at_ + 3] = (x).d; \
    }
/* row r of u, v interleaved (u0 v0 u1 v1 ...) at p + 2 (k0 + r stride) */
#define KD_ROW_2(r, a, b, c, d, u, v, p, k0, stride)                                     \
    {                                                                                    \
        __global float *q_ = (p) + 2 * ((k0) + (size_t)(r) * (stride));                  \
        q_[0] = (u).a; q_[1] = (v).a; q_[2] = (u).b; q_[3] = (v).b;                      \
        q_[4] = (u).c; q_[5] = (v).c; q_[6] = (u).d; q_[7] = (v).d;                      \
    }
/* row r of x, y, z interleaved at p + 3 (k0 + r stride) */
#define KD_ROW_3(r, a, b, c, d, x, y, z, p, k0, stride)                                  \
    {                                                                                    \
        __global float *q_ = (p) + 3 * ((k0) + (size_t)(r) * (stride));                  \
        q_[0] = (x).a; q_[1] = (y).a; q_[2] = (z).a; q_[3] = (x).b;                      \
        q_[4] = (y).b; q_[5] = (z).b; q_[6] = (x).c; q_[7] = (y).c;                      \
        q_[8] = (z).c; q_[9] = (x).d; q_[10] = (y).d; q_[11] = (z).d;                    \
    }

/* The outputs of a packet whose lanes are a block of rays, every lane on: lane l is
 * ray k0 + (l / 4) row_stride + l % 4. The values store_hit writes, computed in vectors
 * and written a row of 4 rays at a time (KD_ROWS). `any`: some lane found a triangle;
 * then, with OUT_NORMAL, P holds the lanes' triangles (kd_gather_triangles). */
KD_INLINE
void kd_store_block(size_t k0, size_t row_stride, KdUP tri, KdFP t, KdFP u, KdFP v,
                    const KdFP *P, bool any, __global const uint *tri_ids, KD_OUTPUT_ARGS)
{
    intP found = tri.v != (uintP)(KD_NO_HIT);
#ifdef OUT_T
    floatP t_out = kd_selectP((floatP)(INFINITY), t.v * KD_T_SCALE, found);
    KD_ROWS(KD_ROW_1, t_out, out_t, k0, row_stride)
#endif
#ifdef OUT_UV
    floatP u_out = kd_selectP((floatP)(0.0f), u.v, found);
    floatP v_out = kd_selectP((floatP)(0.0f), v.v, found);
    KD_ROWS(KD_ROW_2, u_out, v_out, out_uv, k0, row_stride)
#endif
#ifdef OUT_ID
    /* a packet with no hit (the sky around a framed object) skips the gather */
    uintP ids = (uintP)(KD_NO_HIT);
    if (any) {
        ids = KD_GATHER(tri_ids, kd_selectPu((uintP)(0u), tri.v, found));
        ids = kd_selectPu((uintP)(KD_NO_HIT), ids, found);
    }
    KD_ROWS(KD_ROW_1, ids, out_id, k0, row_stride)
#endif
#ifdef OUT_NORMAL
    /* kd_normalize(kd_cross(p1 - p0, p2 - p0)) in vectors (its operations in its order) */
    floatP nx = (floatP)(0.0f), ny = (floatP)(0.0f), nz = (floatP)(0.0f);
    if (any) {
        floatP ax = P[3].v - P[0].v, ay = P[4].v - P[1].v, az = P[5].v - P[2].v;
        floatP bx = P[6].v - P[0].v, by = P[7].v - P[1].v, bz = P[8].v - P[2].v;
        floatP cx = ay * bz - az * by, cy = az * bx - ax * bz, cz = ax * by - ay * bx;
        floatP m = kd_maxP(kd_absP(cx), kd_maxP(kd_absP(cy), kd_absP(cz)));
        cx = cx / m;
        cy = cy / m;
        cz = cz / m;
        floatP len = sqrt(cx * cx + cy * cy + cz * cz);
        nx = kd_selectP(nx, cx / len, found);
        ny = kd_selectP(ny, cy / len, found);
        nz = kd_selectP(nz, cz / len, found);
    }
    KD_ROWS(KD_ROW_3, nx, ny, nz, out_normal, k0, row_stride)
#endif
}

/* Trace the packet of rays (ox, oy, oz) + t (dx, dy, dz), each lane over its range
 * t_min < t < t_max, and store the outputs of each lane l in `on` at index idx[l];
 * with row_stride > 0 every lane is on and the lanes are a block (kd_store_block:
 * idx[l] is idx[0] + (l / 4) row_stride + l % 4). */
KD_INLINE
void trace_packet_and_store(KdFP ox, KdFP oy, KdFP oz, KdFP dx, KdFP dy, KdFP dz, KdIP on,
                            bool camera, KdFP t_min, KdFP t_max, KD_TREE_PARAMS,
                            KD_OUTPUT_ARGS,
                            const uint *idx, uint row_stride KD_EXACT_PARAMS)
{
    KdFP t_l, u_l, v_l;
    KdUP tri_l;
#ifdef STATS
    KdUP sx, sy, sz, sw;
    trace_packet(nodes, n_nodes, tris, tri_ids KD_WIDE_PASS, bmin, bmax, on.v, camera,
                 ox.v, oy.v, oz.v,
                 dx.v, dy.v, dz.v, t_min.v, t_max.v, &t_l.v, &u_l.v, &v_l.v, &tri_l.v,
                 &sx, &sy, &sz, &sw);
#else
    trace_packet(nodes, n_nodes, tris, tri_ids KD_WIDE_PASS, bmin, bmax, on.v, camera,
                 ox.v, oy.v, oz.v,
                 dx.v, dy.v, dz.v, t_min.v, t_max.v, &t_l.v, &u_l.v, &v_l.v, &tri_l.v);
#endif
    KdIP found;
    found.v = on.v & (tri_l.v != (uintP)(KD_NO_HIT));
    bool any = kd_anyP(found.v);
#if defined(KD_REFINE_STORED) || defined(OUT_NORMAL)
    /* the lanes' triangles, for the refinement and the normals */
    KdFP P[9];
    if (any)
        kd_gather_triangles(found, tri_l, tris, P);
#else
    const KdFP *P = 0;
#endif
#ifdef KD_REFINE_STORED
    if (any)
        kd_refine_packet(ox, oy, oz, dx, dy, dz, found, P, t_min, t_max, idx, &t_l, &u_l, &v_l
                         KD_EXACT_PASS);
#endif
#ifndef STATS
    if (row_stride) {
        kd_store_block(idx[0], row_stride, tri_l, t_l, u_l, v_l, P, any, tri_ids,
                       KD_OUTPUT_PASS);
        return;
    }
#endif
    for (uint l = 0; l < KD_PACKET; l++) {
        if (!on.s[l])
            continue;
#ifdef STATS
        vstore4((uint4)(sx.s[l], sy.s[l], sz.s[l], sw.s[l]), idx[l], out_stats);
#endif
        Hit hit;
        hit.t = t_l.s[l];
        hit.u = u_l.s[l];
        hit.v = v_l.s[l];
        hit.tri = tri_l.s[l];
        store_hit(idx[l], &hit, tris, tri_ids, KD_OUTPUT_PASS);
    }
}

/* The packet of rays o[l] + t d[l], l < count <= KD_PACKET, in lanes: lanes past count
 * copy ray 0 and are off in `on`. */
KD_INLINE
void kd_gather_packet(uint count, const float3 *o, const float3 *d, KdFP *ox, KdFP *oy,
                      KdFP *oz, KdFP *dx, KdFP *dy, KdFP *dz, KdIP *on)
{
    for (uint l = 0; l < KD_PACKET; l++) {
        uint j = l < count ? l : 0u;
        ox->s[l] = o[j].x; oy->s[l] = o[j].y; oz->s[l] = o[j].z;
        dx->s[l] = d[j].x; dy->s[l] = d[j].y; dz->s[l] = d[j].z;
        on->s[l] = l < count ? -1 : 0;
    }
}
#define KD_RAYS_PER_ITEM KD_PACKET
#else
/* Trace ray o + t d and store its outputs at index idx. */
KD_INLINE
void trace_and_store(float3 o, float3 d, float t_min, float t_max, KD_TREE_PARAMS,
                     KD_OUTPUT_ARGS, uint idx KD_EXACT_PARAMS)
{
    Hit hit;
#ifdef STATS
    uint4 stats = (uint4)(0u);
    trace_ray(nodes, n_nodes, tris, tri_ids, bmin, bmax, o, d, t_min, t_max, &hit,
              &stats);
    vstore4(stats, idx, out_stats);
#else
    trace_ray(nodes, n_nodes, tris, tri_ids, bmin, bmax, o, d, t_min, t_max, &hit);
#endif
#ifdef KD_REFINE_STORED
    refine_hit(idx, &hit, o, d, t_min, t_max, tris KD_EXACT_PASS);
#endif
    store_hit(idx, &hit, tris, tri_ids, KD_OUTPUT_PASS);
}
#define KD_RAYS_PER_ITEM 1
#endif

/* The first ray of the group's next batch. Work-item 0 takes BATCH_SIZE rays from the
 * global counter; every work-item of the group must call this the same number of
 * times (the barriers are in uniform control flow). */
KD_INLINE
uint fetch_batch(__local uint *slot, __global volatile uint *counter)
{
    if (get_local_id(0) == 0)
        *slot = atomic_add(counter, (uint)BATCH_SIZE);
    barrier(CLK_LOCAL_MEM_FENCE);
    uint start = *slot;
    barrier(CLK_LOCAL_MEM_FENCE);        /* all have read it before it is overwritten */
    return start;
}

/* The rays' input type (world_rays.h: float relative to the tree, or with RAYS_WORLD
 * the caller's rays converted here as the host would) */
#include "world_rays.h"
#if defined(RAYS_WORLD) && defined(REFINE) && defined(cl_khr_fp64)
#define KD_TRACE_EXACT , origins, directions, o_step, (double3)(origin_x, origin_y, origin_z)
#else
#define KD_TRACE_EXACT
#endif

#ifdef PACKET
/* A packet's KD_PACKET rays as its lanes, in rows of 4 consecutive rays: lanes 4r ..
 * 4r + 3 are rays k0 + r row_stride .. + 3 (row_stride 4: KD_PACKET consecutive rays;
 * the image's width: a block of 4 x KD_PACKET / 4 pixels). Each is converted as
 * KD_RAY_ORIGIN and kd_ray_direction convert it (the same operations on the same
 * values: bit for bit), but in vectors: a row's 12 numbers of the directions, and of
 * the origins unless all rays share one (o_step 0: o_shared, converted), are loaded as
 * vectors of 8 and 4 (KD_LOAD8, KD_LOAD4), shifted and rounded as loaded (a row starts
 * with an x, so the tree's origin repeats x, y, z, x, ... in both: KdDP3), joined in
 * registers (kd_join_rows) and dealt out to the lanes by permutes (kd_deal). Nothing
 * goes through private memory: a read of private memory that spans several stores, or a
 * masked read (as LLVM deals lanes from it), waits until the stores reach the cache,
 * and a trace's profile had its hottest instruction there. */
#ifdef RAYS_WORLD
/* the tree's origin repeated x, y, z, x, ... over a row's 12 numbers: 8, then 4 */
typedef struct { double8 a; double4 b; } KdDP3;
#define KD_ORIGIN_PATTERN_PARAM , const KdDP3 *origin_pattern
#define KD_ORIGIN_PATTERN_ARG , &origin_pattern
#else
#define KD_ORIGIN_PATTERN_PARAM
#define KD_ORIGIN_PATTERN_ARG
#endif
/* The x, y and z of KD_PACKET rays whose numbers follow one another through v[0], v[1],
 * v[2] (lane l takes number 3 l, 3 l + 1, 3 l + 2), and p[0 .. 7], p[0 .. 3] as vectors
 * of p's type T (float or double). KD_PLAIN_VECTOR_OPS (the host sets it for PoCL,
 * which calls vload and shuffle2 out of line, their vectors passed through memory:
 * ops.h): constant lanes and plain loads, which LLVM turns into permutes and vector
 * loads; else shuffle2 and vload, which measured faster on Intel's runtime. */
#define KD_CAT_(a, b) a##b
#define KD_CAT(a, b) KD_CAT_(a, b)
#ifdef KD_PLAIN_VECTOR_OPS
#define KD_LOAD8(T, p)                                                                   \
    ((KD_CAT(T, 8))((p)[0], (p)[1], (p)[2], (p)[3], (p)[4], (p)[5], (p)[6], (p)[7]))
#define KD_LOAD4(T, p) ((KD_CAT(T, 4))((p)[0], (p)[1], (p)[2], (p)[3]))
KD_INLINE
void kd_deal(const floatP *v, floatP *x, floatP *y, floatP *z)
{
    floatP a = v[0], b = v[1], c = v[2];
#if KD_PACKET == 16
    *x = (float16)(a.s0, a.s3, a.s6, a.s9, a.sc, a.sf, b.s2, b.s5, b.s8, b.sb, b.se, c.s1, c.s4,
                   c.s7, c.sa, c.sd);
    *y = (float16)(a.s1, a.s4, a.s7, a.sa, a.sd, b.s0, b.s3, b.s6, b.s9, b.sc, b.sf, c.s2, c.s5,
                   c.s8, c.sb, c.se);
    *z = (float16)(a.s2, a.s5, a.s8, a.sb, a.se, b.s1, b.s4, b.s7, b.sa, b.sd, c.s0, c.s3, c.s6,
                   c.s9, c.sc, c.sf);
#else
    *x = (float8)(a.s0, a.s3, a.s6, b.s1, b.s4, b.s7, c.s2, c.s5);
    *y = (float8)(a.s1, a.s4, a.s7, b.s2, b.s5, c.s0, c.s3, c.s6);
    *z = (float8)(a.s2, a.s5, b.s0, b.s3, b.s6, c.s1, c.s4, c.s7);
#endif
}
#else
#define KD_LOAD8(T, p) vload8(0, p)
#define KD_LOAD4(T, p) vload4(0, p)
/* component c (0: x, 1: y, 2: z), by two permutes */
KD_INLINE
floatP kd_deal_c(const floatP *v, uint c)
{
    uintP at = 3u * KD_LANE_INDEX_U + c;
    uintP end = (uintP)(2u * KD_PACKET);
    uintP first = select((uintP)(0u), at, at < end);          /* from v[0] and v[1] */
    uintP second = select(KD_LANE_INDEX_U, at - (uintP)(KD_PACKET), at >= end);
    return shuffle2(shuffle2(v[0], v[1], first), v[2], second);
}
KD_INLINE
void kd_deal(const floatP *v, floatP *x, floatP *y, floatP *z)
{
    *x = kd_deal_c(v, 0u);
    *y = kd_deal_c(v, 1u);
    *z = kd_deal_c(v, 2u);
}
#endif

/* KD_PACKET / 4 rows of 12 numbers (row r's first 8 in a[r], its last 4 in b[r]) as
 * three vectors holding the numbers in order, joined in registers. */
KD_INLINE
void kd_join_rows(const float8 *a, const float4 *b, floatP *v)
{
#if KD_PACKET == 16
    v[0] = (float16)(a[0], b[0], a[1].s0123);
    v[1] = (float16)(a[1].s4567, b[1], a[2]);
    v[2] = (float16)(b[2], a[3], b[3]);
#else
    v[0] = a[0];
    v[1] = (float8)(b[0], a[1].s0123);
    v[2] = (float8)(a[1].s4567, b[1]);
#endif
}

KD_INLINE
void kd_load_packet(__global const KD_ORIGIN_T *origins,
                    __global const KD_DIRECTION_T *directions, size_t k0, size_t row_stride,
                    uint o_step, float3 o_shared, KdFP *ox, KdFP *oy, KdFP *oz, KdFP *dx,
                    KdFP *dy, KdFP *dz KD_ORIGIN_PATTERN_PARAM)
{
    float8 oa[KD_PACKET / 4], da[KD_PACKET / 4];     /* a row's first 8 numbers */
    float4 ob[KD_PACKET / 4], db[KD_PACKET / 4];     /* and its last 4 */
    for (uint r = 0; r < KD_PACKET / 4u; r++) {
        size_t at = 3 * (k0 + r * row_stride);
        if (o_step) {
#ifdef RAYS_WORLD
            /* (float)(((double)o - origin) * (1 / scale)): KD_SCALE_INV is 1.0 at scale 1 */
            oa[r] = convert_float8((convert_double8(KD_LOAD8(KD_ORIGIN_T, origins + at))
                                    - origin_pattern->a) * KD_SCALE_INV);
            ob[r] = convert_float4((convert_double4(KD_LOAD4(KD_ORIGIN_T, origins + at + 8))
                                    - origin_pattern->b) * KD_SCALE_INV);
#else
            oa[r] = KD_LOAD8(float, origins + at);
            ob[r] = KD_LOAD4(float, origins + at + 8);
#endif
        }
        /* (float)d (float directions as they are) */
        da[r] = convert_float8(KD_LOAD8(KD_DIRECTION_T, directions + at));
        db[r] = convert_float4(KD_LOAD4(KD_DIRECTION_T, directions + at + 8));
    }
    floatP o3[3], d3[3];
    if (o_step) {
        kd_join_rows(oa, ob, o3);
        kd_deal(o3, &ox->v, &oy->v, &oz->v);
    } else {
        ox->v = (floatP)(o_shared.x); oy->v = (floatP)(o_shared.y); oz->v = (floatP)(o_shared.z);
    }
    kd_join_rows(da, db, d3);
    kd_deal(d3, &dx->v, &dy->v, &dz->v);
}
#endif

/* Nearest hits of n_rays rays: origin k * o_step (o_step 1, or 0 for one origin shared
 * by all rays) and direction k of each ray k.
 * o_offset, d_offset: where the rays start in their buffers, in elements (a buffer
 * over the host's array from the page it starts in: kdray/device_tree.py, _input_buffer).
 * image_w: 0, or the rays are the rows of an image image_w rays wide (n_rays a
 * multiple of it) and, with PACKET, a packet is a block of 4 x KD_PACKET / 4 of them,
 * as render_camera's (closer together than a row of KD_PACKET); its lanes past the
 * image's right or bottom edge are left out. Without PACKET it changes nothing.
 * order: NULL, or slot k takes ray order[k] (a permutation of the n_rays rays, image_w
 * 0: kdray/ray_order.py), its outputs written at its own index k.
 * t_ranges: ray k's range t_min < t < t_max at 2 k t_step and 2 k t_step + 1 from
 * element t_offset (t_step 0: one range for all rays), in the tree's units.
 *
 * The slots of a batch a work-item takes: with item_runs (CPU devices) one run of
 * BATCH_SIZE / LOCAL_SIZE in a row, so that a group, whose work-items PoCL runs one
 * after another, reads its rays and writes their outputs in order; else every
 * LOCAL_SIZE-th packet, so that neighbouring work-items read neighbouring rays
 * (coalesced on a GPU). A kernel
 * argument, not a -D option, so that one program serves both.
 * A program holds trace_rays or render_camera (KD_ONLY_TRACE_RAYS,
 * KD_ONLY_RENDER_CAMERA; both without either): a call needs one, and each compiles in
 * about half the time of the two. */
#ifndef KD_ONLY_RENDER_CAMERA
__kernel __attribute__((reqd_work_group_size(LOCAL_SIZE, 1, 1))) KD_VEC_HINT
void trace_rays(KD_TREE_ARGS,
                __global const KD_ORIGIN_T *origins, __global const KD_DIRECTION_T *directions,
                uint o_offset, uint d_offset,
                uint o_step, uint n_rays, uint image_w, __global const uint *order,
                __global const float *t_ranges, uint t_offset, uint t_step,
                uint item_runs KD_ORIGIN_PARAMS, __global volatile uint *counter, KD_OUTPUT_ARGS)
{
    origins += o_offset;
    directions += d_offset;
    t_ranges += t_offset;
    float3 bmin = vload3(0, bounds);
    float3 bmax = vload3(1, bounds);
    uint run = BATCH_SIZE / LOCAL_SIZE;
    uint first = get_local_id(0) * (item_runs ? run : KD_RAYS_PER_ITEM);
    uint end = item_runs ? first + run : BATCH_SIZE;
    uint step = item_runs ? KD_RAYS_PER_ITEM : LOCAL_SIZE * KD_RAYS_PER_ITEM;
#ifdef PACKET
    float3 o_shared = o_step ? (float3)(0.0f) : KD_RAY_ORIGIN(origins, 0);
#ifdef RAYS_WORLD
    KdDP3 origin_pattern;
    origin_pattern.a = (double8)(origin_x, origin_y, origin_z, origin_x, origin_y, origin_z,
                                 origin_x, origin_y);
    origin_pattern.b = (double4)(origin_z, origin_x, origin_y, origin_z);
#endif
#endif
    /* the work slots: the rays, or with image blocks KD_PACKET slots a block (those
     * past the image's edges empty lanes) */
    uint n_slots = n_rays;
#ifdef PACKET
    uint blocks_x = (image_w + 3u) / 4u;
    uint n_rows = image_w ? n_rays / image_w : 0u;
    if (image_w)
        n_slots = blocks_x * ((n_rows + KD_PACKET / 4u - 1u) / (KD_PACKET / 4u)) * KD_PACKET;
#endif
    __local uint batch;
    for (;;) {
        uint start = fetch_batch(&batch, counter);
        if (start >= n_slots)            /* the same for the whole group */
            break;
        for (uint j = first; j < end; j += step) {
            uint k0 = start + j;
            if (k0 >= n_slots)
                break;
#ifdef PACKET
            /* A whole packet in rows of 4 rays, row_stride apart, loaded as vectors: a
             * block inside the image (rows a row of the image apart), or KD_PACKET
             * consecutive rays (rows 4 apart). Else the rays there are, one by one: of a
             * block at the image's edge (lane l is ray (col0 + l % 4, row0 + l / 4), the
             * lanes inside the image first), or the last rays. One call traces either:
             * PoCL keeps each inlined copy's private data apart, for every work-item of
             * a group, on one thread's stack (kdray/work_sizes.py, POCL_ITEM_BYTES). */
            KdFP ox, oy, oz, dx, dy, dz;
            KdIP on;
            KdUP idx;
            uint col0 = 0u, row0 = 0u, row_stride = 0u, first_ray = k0;
            if (image_w) {
                uint q = k0 / KD_PACKET;
                col0 = (q % blocks_x) * 4u;
                row0 = (q / blocks_x) * (KD_PACKET / 4u);
                if (col0 + 4u <= image_w && row0 + KD_PACKET / 4u <= n_rows) {
                    first_ray = row0 * image_w + col0;
                    row_stride = image_w;
                }
            } else if (n_rays - k0 >= KD_PACKET && !order) {
                row_stride = 4u;
            }
            if (row_stride) {
                idx.v = (uintP)(first_ray) + (KD_LANE_INDEX_U >> 2) * row_stride
                        + (KD_LANE_INDEX_U & 3u);
                /* every lane is on, but computed: with a constant mask Oclgrind 21.10 gets
                 * other hits than PoCL and Intel's runtime (the soup scene of
                 * tests/test_runtimes.py), as with its constant selects (lanes.h) */
                on.v = idx.v < (uintP)(n_rays);
                kd_load_packet(origins, directions, first_ray, row_stride, o_step, o_shared,
                               &ox, &oy, &oz, &dx, &dy, &dz KD_ORIGIN_PATTERN_ARG);
            } else {
                float3 o[KD_PACKET], d[KD_PACKET];
                uint count = 0;
                for (uint l = 0; l < KD_PACKET; l++) {
                    uint k = k0 + l;
                    bool inside = k < n_rays;
                    if (image_w) {
                        uint col = col0 + l % 4u, row = row0 + l / 4u;
                        k = row * image_w + col;
                        inside = col < image_w && row < n_rows;
                    }
                    if (inside && order)
                        k = order[k];
                    if (inside) {
                        o[count] = KD_RAY_ORIGIN(origins, (size_t)k * o_step);
                        d[count] = kd_ray_direction(directions, k);
                        idx.s[count++] = k;
                    }
                }
                for (uint l = count; l < KD_PACKET; l++)
                    idx.s[l] = idx.s[0];          /* off lanes */
                kd_gather_packet(count, o, d, &ox, &oy, &oz, &dx, &dy, &dz, &on);
            }
            /* each lane's range (off lanes: a ray's that is on, or the first) */
            KdFP t_lo, t_hi;
            if (t_step) {
                for (uint l = 0; l < KD_PACKET; l++) {
                    size_t at = 2 * (size_t)(idx.s[l] < n_rays ? idx.s[l] : 0u);
                    t_lo.s[l] = t_ranges[at];
                    t_hi.s[l] = t_ranges[at + 1];
                }
            } else {
                t_lo.v = (floatP)(t_ranges[0]);
                t_hi.v = (floatP)(t_ranges[1]);
            }
            trace_packet_and_store(ox, oy, oz, dx, dy, dz, on, false, t_lo, t_hi, KD_TREE_PASS,
                                   KD_OUTPUT_PASS, idx.s, row_stride KD_TRACE_EXACT);
#else
            uint k = order ? order[k0] : k0;
            float3 o = KD_RAY_ORIGIN(origins, (size_t)k * o_step);
            float3 d = kd_ray_direction(directions, k);
            size_t at = 2 * (size_t)k * t_step;
            trace_and_store(o, d, t_ranges[at], t_ranges[at + 1], KD_TREE_PASS, KD_OUTPUT_PASS, k
                            KD_TRACE_EXACT);
#endif
        }
    }
}
#endif

/* Primary rays of the pixels in rows row0 .. row0 + n_rows - 1 (row length `width`),
 * written to outputs 0 .. n_rows * width - 1 (row-major, from row0).
 * camera: 12 floats, M = R K^-1 row-major (9), then the eye relative to the tree's
 * origin in its units (3). Pixel (i, j) (column, row): direction M [i + 0.5, j + 0.5,
 * 1], not normalized, so t (times t_scale) is the z-depth.
 * RAY_MAP (a central camera model: kdray.lens): M = R, and pixel p's direction is
 * M ray_map[p], ray_map holding 3 floats a pixel of the whole image (camera axes);
 * a pixel whose map entry is NaN has no ray and is not traced nor written (the host
 * writes its miss). ray_map is NULL without RAY_MAP.
 * ORTHOGRAPHIC: camera holds 15 floats, M = R K'^-1 / scale (K^-1 with its last row
 * 0), then the eye relative to the origin in the tree's units, then the unit forward
 * axis: pixel (i, j)'s ray leaves eye + M [i + 0.5, j + 0.5, 1] along the forward
 * axis (its origin on the plane through the camera's eye).
 *
 * Pixels are taken in tiles of TILE_W x TILE_H (tiles row-major, rows within a tile;
 * a batch is best one tile), so the rays a group traces one after another are
 * neighbours in both directions and find the tree's nodes in the cache. Slots of the
 * tiling past the image's right or bottom edge are skipped. With PACKET a packet is a
 * block of 4 x PACKET / 4 pixels of a tile (TILE_W a multiple of 4, TILE_H of PACKET / 4). */
#ifndef TILE_W
#define TILE_W 64
#endif
#ifndef TILE_H
#define TILE_H 8
#endif
#ifndef KD_ONLY_TRACE_RAYS
__kernel __attribute__((reqd_work_group_size(LOCAL_SIZE, 1, 1))) KD_VEC_HINT
void render_camera(KD_TREE_ARGS, __global const float *camera, __global const float *ray_map,
                   uint width, uint row0, uint n_rows,
                   __global volatile uint *counter, KD_OUTPUT_ARGS)
{
    float3 bmin = vload3(0, bounds);
    float3 bmax = vload3(1, bounds);
    float3 m0 = vload3(0, camera);       /* rows of M */
    float3 m1 = vload3(1, camera);
    float3 m2 = vload3(2, camera);
    float3 eye = vload3(3, camera);
#ifdef ORTHOGRAPHIC
    float3 fwd = vload3(4, camera);      /* every ray's direction */
#endif
    uint tiles_x = (width + TILE_W - 1u) / TILE_W;
    uint tiles_y = (n_rows + TILE_H - 1u) / TILE_H;
    uint n_slots = tiles_x * tiles_y * (TILE_W * TILE_H);   /* < 2^32: checked on the host */
    __local uint batch;
    for (;;) {
        uint start = fetch_batch(&batch, counter);
        if (start >= n_slots)            /* the same for the whole group */
            break;
        for (uint j = get_local_id(0) * KD_RAYS_PER_ITEM; j < BATCH_SIZE;
             j += LOCAL_SIZE * KD_RAYS_PER_ITEM) {
            uint slot = start + j;
            if (slot >= n_slots)
                break;
            uint tile = slot / (TILE_W * TILE_H);
            uint in_tile = slot % (TILE_W * TILE_H);
            uint tile_col = (tile % tiles_x) * TILE_W;
            uint tile_row = (tile / tiles_x) * TILE_H;           /* from row0 */
#ifdef PACKET
            /* a packet is a block of 4 x KD_PACKET / 4 pixels (closer together than a
             * row), its rays made in vectors with the arithmetic of the one-ray case
             * below: lane l is pixel (col0 + l % 4, row0_b + l / 4) */
            uint block = in_tile / KD_PACKET;
            uint col0 = tile_col + (block % (TILE_W / 4u)) * 4u;
            uint row0_b = tile_row + (block / (TILE_W / 4u)) * (KD_PACKET / 4u);
            if (col0 >= width || row0_b >= n_rows)
                continue;
#ifndef RAY_MAP
            /* exact: pixel indices are below 2^24 */
            floatP x = convert_floatP((uintP)(col0) + (KD_LANE_INDEX_U & 3u)) + 0.5f;
            floatP y = convert_floatP((uintP)(row0 + row0_b) + (KD_LANE_INDEX_U >> 2)) + 0.5f;
#endif
            KdFP ox, oy, oz, dx, dy, dz;
            ox.v = (floatP)(eye.x); oy.v = (floatP)(eye.y); oz.v = (floatP)(eye.z);
            KdIP on;
            uint idx[KD_PACKET];
            for (uint l = 0; l < KD_PACKET; l++) {
                uint col = col0 + l % 4u, row = row0_b + l / 4u;
                on.s[l] = col < width && row < n_rows ? -1 : 0;
                idx[l] = row * width + col;
            }
#ifdef RAY_MAP
            /* each pixel's camera-axis direction from the map (NaN: no ray, not traced) */
            KdFP x, y, z;
            for (uint l = 0; l < KD_PACKET; l++) {
                float3 v = on.s[l] ? vload3((size_t)row0 * width + idx[l], ray_map)
                                   : (float3)(0.0f, 0.0f, 1.0f);
                if (kd_isnan(v.x))
                    on.s[l] = 0;
                x.s[l] = v.x; y.s[l] = v.y; z.s[l] = on.s[l] ? v.z : 1.0f;
            }
            dx.v = m0.x * x.v + m0.y * y.v + m0.z * z.v;
            dy.v = m1.x * x.v + m1.y * y.v + m1.z * z.v;
            dz.v = m2.x * x.v + m2.y * y.v + m2.z * z.v;
#elif defined(ORTHOGRAPHIC)
            ox.v = eye.x + (m0.x * x + m0.y * y + m0.z);
            oy.v = eye.y + (m1.x * x + m1.y * y + m1.z);
            oz.v = eye.z + (m2.x * x + m2.y * y + m2.z);
            dx.v = (floatP)(fwd.x); dy.v = (floatP)(fwd.y); dz.v = (floatP)(fwd.z);
#else
            dx.v = m0.x * x + m0.y * y + m0.z;
            dy.v = m1.x * x + m1.y * y + m1.z;
            dz.v = m2.x * x + m2.y * y + m2.z;
#endif
            /* every lane on (a block inside the image, each pixel with a ray): its
             * outputs stored a row at a time */
            uint row_stride = kd_countP(on.v) == KD_PACKET ? width : 0u;
            KdFP t_lo, t_hi;
            t_lo.v = (floatP)(0.0f);
            t_hi.v = (floatP)(INFINITY);
            trace_packet_and_store(ox, oy, oz, dx, dy, dz, on, true, t_lo, t_hi, KD_TREE_PASS,
                                   KD_OUTPUT_PASS, idx, row_stride KD_NO_EXACT);
#else
            uint col = tile_col + in_tile % TILE_W;
            uint row = tile_row + in_tile / TILE_W;
            if (col >= width || row >= n_rows)
                continue;
            uint idx = row * width + col;
            float3 o = eye;
#ifdef RAY_MAP
            float3 v = vload3((size_t)row0 * width + idx, ray_map);
            if (kd_isnan(v.x))       /* no ray: the host writes the miss */
                continue;
            float3 d = (float3)(m0.x * v.x + m0.y * v.y + m0.z * v.z,
                                m1.x * v.x + m1.y * v.y + m1.z * v.z,
                                m2.x * v.x + m2.y * v.y + m2.z * v.z);
#elif defined(ORTHOGRAPHIC)
            float x = (float)col + 0.5f;
            float y = (float)(row0 + row) + 0.5f;
            o = (float3)(eye.x + (m0.x * x + m0.y * y + m0.z),
                         eye.y + (m1.x * x + m1.y * y + m1.z),
                         eye.z + (m2.x * x + m2.y * y + m2.z));
            float3 d = fwd;
#else
            float x = (float)col + 0.5f;
            float y = (float)(row0 + row) + 0.5f;
            float3 d = (float3)(m0.x * x + m0.y * y + m0.z,
                                m1.x * x + m1.y * y + m1.z,
                                m2.x * x + m2.y * y + m2.z);
#endif
            trace_and_store(o, d, 0.0f, INFINITY, KD_TREE_PASS, KD_OUTPUT_PASS, idx
                            KD_NO_EXACT);
#endif
        }
    }
}
#endif
