"""The k-d tree's binary layout and its file format: the single source of truth.

`kernels/layout.h` mirrors the node encoding below; `tests/test_device_layout.py` checks
that they agree on a device.

Node (8 bytes, pbrt-style, depth-first order)::

    word 0  uint32 flags    bits 0-1: split_axis (0, 1, 2) or 3 = leaf
                            bits 2-31: interior: above_child (node index)
                                       leaf: n_prims (triangles in the leaf)
    word 1  interior: float32 split (the plane's coordinate, relative to `origin`)
            leaf:     uint32 leaf_offset (first index into `leaf_tris`)

The below child of interior node i is i + 1; its above child is `above_child > i`.
A leaf lists `leaf_tris[leaf_offset : leaf_offset + n_prims]`, indices into the
tree's triangle array, whose `tri_ids` map back to the input's triangle order.

Tree file, versions 1, 2 and 3 (all little-endian)::

    offset  size  field
    0       8     magic b"KDRAYTRE"
    8       4     u32 format version (1, 2 or 3)
    12      4     u32 header size (128)
    16      4     u32 n_nodes
    20      4     u32 n_leaf_refs          (length of leaf_tris)
    24      4     u32 n_tris               (triangles stored in the tree)
    28      4     u32 n_input_tris         (triangles in the input; tri_ids < this)
    32      4     u32 depth                (deepest leaf; root is depth 0)
    36      4     u32 max_depth            (build parameter, resolved)
    40      4     u32 leaf_size            (build parameter)
    44      4     versions 1, 2: u32 reserved, 0
                  version 3: u32 n_name_bytes (length of the object names' JSON)
    48      8     f64 K_T
    56      8     f64 K_I
    64      8     f64 empty_bonus
    72      24    f64[3] origin            (world position the float32 data is relative to)
    96      24    f32[6] bounds            (scene box, min xyz then max xyz, relative)
    120     8     version 1: reserved, 0
                  versions 2, 3: f64 scale (a power of two: world = origin + scale * relative)
    128     8 n_nodes       nodes          (u32 flags, u32 split/leaf_offset)
            4 n_leaf_refs   leaf_tris      (u32)
            36 n_tris       triangles      (f32 v0 xyz, v1 xyz, v2 xyz, relative)
            4 n_tris        tri_ids        (u32)
    version 3 only, the object table:
            4 n_input_tris  objects        (u32: each input triangle's object)
            n_name_bytes    object_names   (UTF-8 JSON array of the objects' names,
                                            compact: json.dumps(names, ensure_ascii=False,
                                            separators=(",", ":")))
    end-16  16    checksum: BLAKE2b (16-byte digest) of every byte before it

The version changes only when this layout does. A writer writes the oldest version
that holds the tree: version 3 when it has an object table (more than one object,
KdTree.objects), else version 1 when its scale is 1 and version 2 otherwise, so that
files of the trees the older versions can hold stay readable by every kdray; a reader
reads all three.
"""
import hashlib
import json
import math
import struct

import numpy as np

from .errors import TreeFileError

LEAF = 3
"""`split_axis` value that marks a leaf."""

MAX_NODES = 1 << 30
"""Upper bound of node indices and leaf sizes (30 bits of `flags`)."""

MAX_DEPTH_LIMIT = 64
"""No tree is deeper than this; kernels size their stacks and loops from it."""

MAGIC = b"KDRAYTRE"
VERSION = 3
"""The newest version this kdray writes (and reads, with versions 1 and 2)."""
HEADER = struct.Struct("<8s10I 3d 3d 6f d")
HEADER_SIZE = 128
CHECKSUM_SIZE = 16
assert HEADER.size == HEADER_SIZE

NODE_DTYPE = np.dtype("<u4")
"""Nodes are a (n_nodes, 2) array of this dtype."""


# -- node encoding ------------------------------------------------------------

def make_interior(split_axis, split, above_child):
    """Encode interior nodes.

    split_axis : (k,) int in {0, 1, 2};  split : (k,) float32;  above_child : (k,) int
    Returns (k, 2) uint32.
    """
    split_axis = np.asarray(split_axis, dtype=np.uint32)
    above_child = np.asarray(above_child, dtype=np.uint32)
    out = np.empty(split_axis.shape + (2,), dtype=np.uint32)
    out[..., 0] = split_axis | (above_child << np.uint32(2))
    out[..., 1] = np.asarray(split, dtype=np.float32).view(np.uint32)
    return out


def make_leaf(n_prims, leaf_offset):
    """Encode leaves. n_prims, leaf_offset : (k,) int. Returns (k, 2) uint32."""
    n_prims = np.asarray(n_prims, dtype=np.uint32)
    out = np.empty(n_prims.shape + (2,), dtype=np.uint32)
    out[..., 0] = np.uint32(LEAF) | (n_prims << np.uint32(2))
    out[..., 1] = np.asarray(leaf_offset, dtype=np.uint32)
    return out


def split_axis(nodes):
    """(n,) uint32: 0, 1, 2 for interior nodes, LEAF (3) for leaves."""
    return nodes[..., 0] & np.uint32(3)


def is_leaf(nodes):
    """(n,) bool."""
    return split_axis(nodes) == LEAF


def above_child(nodes):
    """(n,) uint32; meaningful for interior nodes only."""
    return nodes[..., 0] >> np.uint32(2)


n_prims = above_child
"""(n,) uint32 triangle count; meaningful for leaves only (same bits as above_child)."""


def split(nodes):
    """(n,) float32 split position; meaningful for interior nodes only."""
    return np.ascontiguousarray(nodes[..., 1]).view(np.float32)


def leaf_offset(nodes):
    """(n,) uint32 first index into leaf_tris; meaningful for leaves only."""
    return nodes[..., 1]


# -- file format ----------------------------------------------------------------

def file_size(n_nodes, n_leaf_refs, n_tris, n_input_tris=0, n_name_bytes=None):
    """Exact byte size of a tree file with these counts: with n_name_bytes (version 3)
    the object table's 4 n_input_tris + n_name_bytes bytes too."""
    table = 0 if n_name_bytes is None else 4 * n_input_tris + n_name_bytes
    return HEADER_SIZE + 8 * n_nodes + 4 * n_leaf_refs + 40 * n_tris + table + CHECKSUM_SIZE


def header_file_size(header):
    """The byte size a tree file's header (its first HEADER_SIZE bytes, magic already
    checked) says the file has, from its version and counts; None for a version this
    kdray does not read."""
    (_, version, _, n_nodes, n_leaf_refs, n_tris, n_input_tris, _, _, _, n_name_bytes,
     *_) = HEADER.unpack_from(header, 0)
    if version not in (1, 2, 3):
        return None
    return file_size(n_nodes, n_leaf_refs, n_tris, n_input_tris,
                     n_name_bytes if version == 3 else None)


def encode_names(names):
    """The object names as the file holds them: compact UTF-8 JSON."""
    return json.dumps(list(names), ensure_ascii=False, separators=(",", ":")).encode("utf-8")


def is_scale(scale):
    """Whether `scale` may be a tree's scale: a power of two whose float32 is normal
    (depths are scaled by it in float32)."""
    scale = float(scale)
    return (math.isfinite(scale) and 2.0 ** -126 <= scale <= 2.0 ** 127
            and math.frexp(scale)[0] == 0.5)


def encode(tree):
    """KdTree -> bytes of a tree file (deterministic): version 3 when the tree has an
    object table (tree.objects), else version 1 when tree.scale is 1, else version 2."""
    p = tree.params
    scale = float(getattr(tree, "scale", 1.0))
    objects = getattr(tree, "objects", None)
    names = encode_names(tree.object_names) if objects is not None else b""
    version = 3 if objects is not None else 1 if scale == 1.0 else 2
    header = HEADER.pack(
        MAGIC, version, HEADER_SIZE,
        len(tree.nodes), len(tree.leaf_tris), len(tree.triangles), tree.n_input_tris,
        tree.depth, p.max_depth, p.leaf_size, len(names),
        p.K_T, p.K_I, p.empty_bonus,
        *np.asarray(tree.origin, dtype="<f8").tolist(),
        *np.asarray(tree.bounds, dtype="<f4").reshape(6).tolist(),
        0.0 if version == 1 else scale,
    )
    parts = [
        header,
        np.ascontiguousarray(tree.nodes, dtype="<u4").tobytes(),
        np.ascontiguousarray(tree.leaf_tris, dtype="<u4").tobytes(),
        np.ascontiguousarray(tree.triangles, dtype="<f4").tobytes(),
        np.ascontiguousarray(tree.tri_ids, dtype="<u4").tobytes(),
    ]
    if objects is not None:
        parts += [np.ascontiguousarray(objects, dtype="<u4").tobytes(), names]
    body = b"".join(parts)
    return body + hashlib.blake2b(body, digest_size=CHECKSUM_SIZE).digest()


def decode(data, name="tree file"):
    """bytes -> dict of the KdTree's fields, or TreeFileError.

    Every count is checked against the byte size before any array is made, so a
    hostile header cannot make us allocate; the checksum is checked before the
    arrays are trusted. Structural checks are `KdTree.validate()`'s job.
    """
    data = memoryview(data)
    if len(data) < HEADER_SIZE + CHECKSUM_SIZE:
        raise TreeFileError(f"{name}: truncated ({len(data)} bytes; a tree file has at least "
                            f"{HEADER_SIZE + CHECKSUM_SIZE})")
    (magic, version, header_size, n_nodes, n_leaf_refs, n_tris, n_input_tris, depth,
     max_depth, leaf_size, n_name_bytes, K_T, K_I, empty_bonus,
     ox, oy, oz, *bounds, scale) = HEADER.unpack_from(data, 0)
    if magic != MAGIC:
        raise TreeFileError(f"{name}: not a kdray tree file (bad magic {bytes(magic)!r})")
    if version not in (1, 2, 3):
        raise TreeFileError(f"{name}: tree file format version {version}; this kdray reads "
                            f"versions 1 to {VERSION} (rebuild it with `kdray build`)")
    if version == 1:
        scale = 1.0
    elif not is_scale(scale):
        raise TreeFileError(f"{name}: scale {scale!r} is not a power of two from 2^-126 to 2^127")
    if header_size != HEADER_SIZE:
        raise TreeFileError(f"{name}: header size {header_size}, expected {HEADER_SIZE}")
    expected = header_file_size(data)
    if len(data) != expected:
        raise TreeFileError(f"{name}: {len(data)} bytes, but its counts need {expected} "
                            f"(truncated or corrupt)")
    body = data[: expected - CHECKSUM_SIZE]
    digest = hashlib.blake2b(body, digest_size=CHECKSUM_SIZE).digest()
    if digest != bytes(data[expected - CHECKSUM_SIZE:]):
        raise TreeFileError(f"{name}: checksum mismatch (the file is corrupt)")
    off = HEADER_SIZE

    def take(dtype, count, shape):
        nonlocal off
        arr = np.frombuffer(data, dtype=dtype, count=count, offset=off).reshape(shape).copy()
        off += arr.nbytes
        return arr

    nodes = take("<u4", 2 * n_nodes, (n_nodes, 2))
    leaf_tris = take("<u4", n_leaf_refs, (n_leaf_refs,))
    triangles = take("<f4", 9 * n_tris, (n_tris, 3, 3))
    tri_ids = take("<u4", n_tris, (n_tris,))
    objects, object_names = None, ()
    if version == 3:
        objects = take("<u4", n_input_tris, (n_input_tris,))
        object_names = decode_names(data[off: off + n_name_bytes], name)
    return dict(
        nodes=nodes, leaf_tris=leaf_tris, triangles=triangles, tri_ids=tri_ids,
        origin=np.array([ox, oy, oz], dtype=np.float64),
        bounds=np.array(bounds, dtype=np.float32).reshape(2, 3),
        n_input_tris=int(n_input_tris), depth=int(depth),
        params=dict(K_T=K_T, K_I=K_I, empty_bonus=empty_bonus,
                    max_depth=int(max_depth), leaf_size=int(leaf_size)),
        scale=float(scale), objects=objects, object_names=object_names,
    )


def decode_names(data, name="tree file"):
    """The object names from the file's JSON (`encode_names`): a tuple of str, or
    TreeFileError. That they are unique and match the objects is
    `KdTree.validate()`'s job."""
    from .validate import parse_json
    try:
        text = bytes(data).decode("utf-8")
        names = parse_json(text, "they", TreeFileError)   # nesting, huge numbers: refused
    except (ValueError, TreeFileError) as e:       # UnicodeDecodeError is a ValueError
        raise TreeFileError(f"{name}: the object names are not UTF-8 JSON ({e})") from None
    if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
        raise TreeFileError(f"{name}: the object names are not a JSON array of strings")
    try:
        for n in names:
            n.encode("utf-8")                   # JSON may hold lone surrogates
    except UnicodeEncodeError:
        raise TreeFileError(f"{name}: an object name is not valid Unicode") from None
    return tuple(names)


# -- on the device (kernels/layout.h, kernels/render.cl) ------------------------------

MISS = np.uint32(0xFFFFFFFF)
"""Triangle id of a ray that hits nothing (KD_NO_HIT in kernels/layout.h)."""

KERNEL_OUTPUTS = ("T", "UV", "NORMAL", "ID")
"""What a kernel can compute and store per ray (kernels/render.cl, -D OUT_<name>)."""

OUTPUT_WIDTH = {"T": (1, np.float32), "UV": (2, np.float32), "NORMAL": (3, np.float32),
                "ID": (1, np.uint32), "STATS": (4, np.uint32)}
"""(values per ray, dtype) of each kernel output and of the STATS counters."""


TRI_BLOCK = 16
"""Triangles a block of the device's triangle buffer holds (KD_TRI_BLOCK in
kernels/layout.h; `triangle_blocks`)."""


def device_sizes(tree, run=1):
    """Bytes of each of the tree's device buffers for leaves read in runs of `run`
    triangles: {"nodes", "triangles", "triangle ids": int}, the last two with a copy
    per leaf reference and each leaf padded to whole runs (`device_triangles`), the
    triangles in blocks (`triangle_blocks`)."""
    refs = n_device_triangles(tree.nodes, run)
    return {"nodes": int(tree.nodes.nbytes), "triangles": 36 * TRI_BLOCK * n_triangle_blocks(refs),
            "triangle ids": 4 * refs}


def n_device_triangles(nodes, run=1):
    """Triangle copies on the device (`device_triangles`) of a tree with these nodes,
    each leaf's n_prims rounded up to a multiple of `run`."""
    return int(_leaf_runs(np.asarray(nodes, dtype=np.uint32).reshape(-1, 2), run)[2].sum())


def _leaf_runs(nodes, run):
    """(leaf (L,) node indices, count (L,) their n_prims, padded (L,) count rounded up
    to a multiple of run), intp, for nodes (n, 2) uint32."""
    leaf = np.flatnonzero(is_leaf(nodes))
    count = n_prims(nodes)[leaf].astype(np.intp)
    return leaf, count, -(-count // run) * run


def n_triangle_blocks(n):
    """Blocks of TRI_BLOCK triangles `triangle_blocks` makes of n triangles."""
    return -(-n // TRI_BLOCK)


def triangle_blocks(tris, out=None):
    """The device's triangle buffer: tris (n, 3, 3) float32 in blocks of TRI_BLOCK,
    each number of its triangles in a row, (n_triangle_blocks(n) * 9 * TRI_BLOCK,)
    float32 (written into `out`, such an array, when given). Number c (0..8: v0 x y z,
    v1 x y z, v2 x y z) of triangle i is at (i // TRI_BLOCK) * 9 * TRI_BLOCK + c *
    TRI_BLOCK + i % TRI_BLOCK; past the last triangle, zeros.

    Why: a leaf's next run of triangles (kernels/packet.cl, kd_gather_tris) is then 9
    vector loads, a number of each, where 9-float rows took a float at a time."""
    tris = np.asarray(tris, dtype=np.float32).reshape(-1, 9)
    n, blocks = len(tris), n_triangle_blocks(len(tris))
    if out is None:
        out = np.empty(blocks * 9 * TRI_BLOCK, np.float32)
    rows = out.reshape(blocks, 9, TRI_BLOCK)
    full = n // TRI_BLOCK
    rows[:full] = tris[:full * TRI_BLOCK].reshape(full, TRI_BLOCK, 9).transpose(0, 2, 1)
    if full < blocks:
        last = np.zeros((TRI_BLOCK, 9), np.float32)
        last[:n - full * TRI_BLOCK] = tris[full * TRI_BLOCK:]
        rows[full] = last.T
    return out


def _device_leaves(tree, run):
    """(nodes, first, count, padded, start): tree.nodes (n_nodes, 2) uint32 with each
    leaf's leaf_offset its first copy as the kernels read them (`device_triangles`),
    and per leaf (L,) intp its first entry of tree.leaf_tris, n_prims, n_prims padded
    to runs of `run`, and first copy."""
    nodes = np.array(tree.nodes, dtype=np.uint32).reshape(-1, 2)
    leaf, count, padded = _leaf_runs(nodes, run)
    first = leaf_offset(nodes)[leaf].astype(np.intp)
    start = np.cumsum(padded) - padded               # each leaf's first copy, in node order
    nodes[leaf, 1] = start
    return nodes, first, count, padded, start


def device_nodes(tree, run=1):
    """The nodes of `device_triangles` alone, (n_nodes, 2) uint32: tree.nodes with each
    leaf's offset its first triangle as the kernels read them, without making the
    triangle copies."""
    return _device_leaves(tree, run)[0]


def device_triangles(tree, run=1):
    """The tree as the kernels read it, its leaves read in runs of `run` triangles (1;
    with packets, the packet's width, a divisor of TRI_BLOCK): (nodes (n_nodes, 2)
    uint32, tris (n, 3, 3) float32, tri_ids (n,) uint32), n = n_device_triangles.

    The nodes are tree.nodes with each leaf's leaf_offset its first triangle here
    (kernels/layout.h): leaf i's triangles are tris[leaf_offset : leaf_offset +
    n_prims], copies of its entries of tree.leaf_tris in that order, with their input
    ids. A leaf starts on a multiple of `run` and takes whole runs: the rest of its
    last run is padding (zero triangles, id MISS), which no kernel tests (lanes past a
    leaf's end are masked off).

    Why: a leaf is read in runs, with no index list to read first, for 40 bytes a
    reference instead of 4 a reference and 40 a triangle (BENCHMARKS.md measures
    both); a run that starts on a multiple of its length lies in one block
    (`triangle_blocks`), 9 aligned vector loads, where a run across two blocks took
    their rows joined by shuffles (kernels/packet.cl, kd_gather_tris). The copies of a
    triangle are alike and keep its input id, so ties still go to the lowest input id
    (kd_before) and a hit does not depend on the copy found."""
    if run < 1 or TRI_BLOCK % run:
        raise ValueError(f"run must divide {TRI_BLOCK}, got {run}")
    nodes, first, count, padded, _ = _device_leaves(tree, run)
    return (nodes, *triangle_copies(tree, padded_entries(tree.leaf_tris, first, count, padded)))


def padded_entries(refs, first, count, padded):
    """(padded.sum(),) intp: leaf after leaf, refs[first[i]:first[i] + count[i]] then
    -1 up to padded[i] entries (first, count, padded (L,) integers): the triangles
    `triangle_copies` copies for leaves of padded runs, leaf i's from
    (cumsum(padded) - padded)[i]."""
    padded = np.asarray(padded, dtype=np.intp)
    start = np.cumsum(padded) - padded
    # each copy's place k in its leaf: entry first + k of refs, or padding from k = count
    k = np.arange(int(padded.sum())) - np.repeat(start, padded)
    pad = k >= np.repeat(count, padded)
    entry = np.where(pad, 0, np.repeat(first, padded) + k)
    return np.where(pad, -1, np.asarray(refs, dtype=np.intp)[entry])


def triangle_copies(tree, tri):
    """(tris (k, 3, 3) float32, tri_ids (k,) uint32): copies of tree.triangles[tri]
    with their input ids, for tri (k,) integers, -1 where a copy is padding (zero
    triangles, id MISS): the copies the kernels read (`device_triangles`, and the wide
    nodes' leaves, kdray/wide.py)."""
    tri = np.asarray(tri, dtype=np.intp)
    pad = tri < 0
    safe = np.where(pad, 0, tri)
    tris = np.asarray(tree.triangles, dtype=np.float32).reshape(-1, 3, 3)[safe]
    tris[pad] = 0.0
    tri_ids = np.asarray(tree.tri_ids, dtype=np.uint32)[safe]
    tri_ids[pad] = MISS
    return tris, tri_ids
