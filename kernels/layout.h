/* kernels/layout.h: the k-d tree's device layout. Mirrors kdray/layout.py, which is
 * the single source of truth; tests/test_device_layout.py checks them against each
 * other on a device.
 *
 * Node, 8 bytes, depth-first order (pbrt):
 *   flags  uint32  bits 0-1: split_axis (0, 1, 2) or KD_LEAF (3)
 *                  bits 2-31: interior: above_child (node index; below child is i + 1)
 *                             leaf: n_prims (triangles listed in the leaf)
 *   data   uint32  interior: float32 bits of the split position (relative to the origin)
 *                  leaf: leaf_offset, its first triangle on the device
 *
 * Triangles on the device: one copy per leaf reference, so that a leaf's triangles
 * are triangles leaf_offset .. leaf_offset + n_prims - 1 (9 float32 each: v0 xyz, v1
 * xyz, v2 xyz, relative to the tree's origin), in the order of its entries of the
 * tree's leaf_tris, with no index list to read first; tri_ids[i] is copy i's
 * triangle's index in the input (kdray/layout.py, device_triangles). A triangle in
 * several leaves has several copies, alike bit for bit, so a hit does not depend on
 * the copy found. With packets a leaf starts on a multiple of PACKET and its last
 * run of PACKET is padded (zero triangles, id KD_NO_HIT), so the device nodes'
 * leaf_offset differs from the tree file's.
 *
 * They lie in blocks of KD_TRI_BLOCK triangles, each of the 9 numbers in a row of the
 * block (kdray/layout.py, triangle_blocks): number c of triangle i is
 * tris[(i / KD_TRI_BLOCK) * 9 * KD_TRI_BLOCK + c * KD_TRI_BLOCK + i % KD_TRI_BLOCK]
 * (kd_tri_base); a packet's run of a leaf lies in one block (packet.cl,
 * kd_gather_tris).
 */
#ifndef KDRAY_LAYOUT_H
#define KDRAY_LAYOUT_H

#include "inline.h"

#define KD_TRI_BLOCK 16u                /* triangles a block (kdray/layout.py, TRI_BLOCK) */
#define KD_LEAF 3u
#define KD_NO_HIT 0xFFFFFFFFu          /* id written on a miss */

typedef struct __attribute__((aligned(8))) {
    uint flags;                          /* 4 bytes: split_axis | above_child/n_prims << 2 */
    uint data;                           /* 4 bytes: split (float bits) or leaf_offset */
} KdNode;                                /* 8 bytes */

KD_INLINE uint kd_split_axis(KdNode n) { return n.flags & 3u; }
KD_INLINE bool kd_is_leaf(KdNode n) { return (n.flags & 3u) == KD_LEAF; }
KD_INLINE bool kd_is_empty_leaf(KdNode n) { return n.flags == KD_LEAF; }  /* a leaf of no triangles */
KD_INLINE uint kd_above_child(KdNode n) { return n.flags >> 2; }
KD_INLINE uint kd_n_prims(KdNode n) { return n.flags >> 2; }
KD_INLINE float kd_split(KdNode n) { return as_float(n.data); }
KD_INLINE uint kd_leaf_offset(KdNode n) { return n.data; }

/* The nearest hit found so far; private to a work-item, never stored as a struct. */
typedef struct {
    float t;                             /* ray parameter, in units of |direction| */
    float u, v;                          /* weights of v1 and v2 */
    uint tri;                            /* index into the device's triangle copies, or KD_NO_HIT */
} Hit;

/* Triangle i's first number; number c (0..8) is at [c * KD_TRI_BLOCK]. */
KD_INLINE
__global const float *kd_tri_base(__global const float *tris, uint i)
{
    return tris + (size_t)(i / KD_TRI_BLOCK) * (9u * KD_TRI_BLOCK) + i % KD_TRI_BLOCK;
}

/* Vertex k (0, 1, 2) of the triangle whose first number is at p (kd_tri_base) */
KD_INLINE
float3 kd_base_vertex(__global const float *p, uint k)
{
    p += 3u * KD_TRI_BLOCK * k;
    return (float3)(p[0], p[KD_TRI_BLOCK], p[2u * KD_TRI_BLOCK]);
}

/* Vertex k (0, 1, 2) of triangle i */
KD_INLINE
float3 kd_vertex(__global const float *tris, uint i, uint k)
{
    return kd_base_vertex(kd_tri_base(tris, i), k);
}

#endif
