"""kernels/layout.h against kdray/layout.py, on the device: a tiny kernel decodes a
nodes buffer with the header's accessors and reports the struct's size and offsets
(the check pyopencl.tools.match_dtype_to_c_struct makes), and reads triangles from
their blocks. Also: choosing devices and turning kernel build errors into
KernelBuildError."""
import numpy as np
import pytest

from kdray import device as kdevice
from kdray import layout
from kdray.errors import DeviceError, KernelBuildError

cl = pytest.importorskip("pyopencl")

DECODE = r"""
#include "layout.h"

__kernel void layout_sizes(__global uint *out)
{
    __local KdNode dummy;
    out[0] = sizeof(KdNode);
    out[1] = (uint)((__local char *)&dummy.flags - (__local char *)&dummy);
    out[2] = (uint)((__local char *)&dummy.data - (__local char *)&dummy);
    out[3] = __alignof__(KdNode);
    out[4] = KD_LEAF;
    out[5] = KD_NO_HIT;
}

__kernel void decode(__global const KdNode *nodes, __global uint *axis, __global uint *leaf,
                     __global uint *above, __global uint *n_prims, __global float *split,
                     __global uint *offset)
{
    size_t i = get_global_id(0);
    KdNode n = nodes[i];
    axis[i] = kd_split_axis(n);
    leaf[i] = kd_is_leaf(n) ? 1u : 0u;
    above[i] = kd_above_child(n);
    n_prims[i] = kd_n_prims(n);
    split[i] = kd_split(n);
    offset[i] = kd_leaf_offset(n);
}

__kernel void vertices(__global const float *tris, __global float *out)
{
    uint i = get_global_id(0);
    for (uint k = 0; k < 3u; k++) {
        float3 p = kd_vertex(tris, i, k);
        out[9 * i + 3 * k] = p.x;
        out[9 * i + 3 * k + 1] = p.y;
        out[9 * i + 3 * k + 2] = p.z;
    }
    out[9 * get_global_size(0)] = (float)KD_TRI_BLOCK;
}
"""


@pytest.fixture(scope="module")
def ctx():
    context, _ = kdevice.create_context(None)
    program = cl.Program(context, DECODE).build(options=["-I", str(kdevice.KERNEL_DIR)])
    return context, cl.CommandQueue(context), program


def sample_nodes():
    """Interior nodes and leaves with extreme fields: every axis, splits of every sign
    and size (signed zeros, subnormals, huge), children and counts up to 2^30 - 1,
    leaf offsets up to 2^32 - 1."""
    rng = np.random.default_rng(0)
    k = 64
    splits = np.concatenate([np.array([0.0, -0.0, 1e-45, -1e-45, 1.5e-38, 3.4e38, -3.4e38, 1.0],
                                      dtype=np.float32),
                             (rng.normal(size=k - 8) * 10.0 ** rng.integers(-20, 20, k - 8)).astype(np.float32)])
    above = np.concatenate([[1, 2, layout.MAX_NODES - 1], rng.integers(1, layout.MAX_NODES, k - 3)])
    interior = layout.make_interior(np.arange(k) % 3, splits, above)
    counts = np.concatenate([[0, 1, layout.MAX_NODES - 1], rng.integers(0, layout.MAX_NODES, k - 3)])
    offsets = np.concatenate([[0, 2**32 - 1, 2**31], rng.integers(0, 2**32, k - 3)])
    leaves = layout.make_leaf(counts, offsets)
    nodes = np.concatenate([interior, leaves])
    return nodes[rng.permutation(len(nodes))], splits


def test_struct_matches_numpy(ctx):
    context, queue, program = ctx
    out = np.zeros(6, dtype=np.uint32)
    buf = cl.Buffer(context, cl.mem_flags.WRITE_ONLY, out.nbytes)
    program.layout_sizes(queue, (1,), (1,), buf)
    cl.enqueue_copy(queue, out, buf)
    node_dtype = np.dtype([("flags", "<u4"), ("data", "<u4")])
    assert out[0] == node_dtype.itemsize == 8 == layout.NODE_DTYPE.itemsize * 2
    assert out[1] == node_dtype.fields["flags"][1] == 0
    assert out[2] == node_dtype.fields["data"][1] == 4
    assert out[3] == 8                                    # one 8-byte load per node
    assert out[4] == layout.LEAF
    assert out[5] == 0xFFFFFFFF


def test_device_decodes_like_layout(ctx):
    context, queue, program = ctx
    nodes, splits = sample_nodes()
    n = len(nodes)
    mf = cl.mem_flags
    node_buf = cl.Buffer(context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=np.ascontiguousarray(nodes))
    outs = {name: np.zeros(n, dtype=np.float32 if name == "split" else np.uint32)
            for name in ("axis", "leaf", "above", "n_prims", "split", "offset")}
    bufs = {name: cl.Buffer(context, mf.WRITE_ONLY, a.nbytes) for name, a in outs.items()}
    program.decode(queue, (n,), None, node_buf, *bufs.values())
    for name, a in outs.items():
        cl.enqueue_copy(queue, a, bufs[name])
    queue.finish()
    leaf = layout.is_leaf(nodes)
    assert leaf.sum() == n // 2
    assert np.array_equal(outs["axis"], layout.split_axis(nodes))
    assert np.array_equal(outs["leaf"].astype(bool), leaf)
    assert np.array_equal(outs["above"][~leaf], layout.above_child(nodes[~leaf]))
    assert np.array_equal(outs["n_prims"][leaf], layout.n_prims(nodes[leaf]))
    assert np.array_equal(outs["offset"][leaf], layout.leaf_offset(nodes[leaf]))
    # splits bit for bit (signed zeros and subnormals included)
    assert np.array_equal(outs["split"][~leaf].view(np.uint32), layout.split(nodes[~leaf]).view(np.uint32))
    assert set(splits.view(np.uint32)) == set(layout.split(nodes[~leaf]).view(np.uint32))


def test_device_reads_triangle_blocks_like_layout(ctx):
    """kd_vertex finds every triangle's vertices where layout.triangle_blocks puts them,
    bit for bit, for counts that fill blocks and counts that do not."""
    context, queue, program = ctx
    rng = np.random.default_rng(1)
    mf = cl.mem_flags
    for n in (1, 15, 16, 17, 50):
        tris = rng.normal(size=(n, 3, 3)).astype(np.float32)
        tris[0, 0, 0] = -0.0
        blocks = layout.triangle_blocks(tris)
        assert blocks.dtype == np.float32
        n_blocks = layout.n_triangle_blocks(n)
        assert n_blocks == -(-n // layout.TRI_BLOCK)
        assert len(blocks) == 9 * layout.TRI_BLOCK * n_blocks
        # (block, number, lane): the lanes of the last block past the n-th are zeros
        lanes = blocks.reshape(n_blocks, 9, layout.TRI_BLOCK).transpose(0, 2, 1).reshape(-1, 9)
        assert not lanes[n:].any()
        out = np.zeros(9 * n + 1, dtype=np.float32)
        out_buf = cl.Buffer(context, mf.WRITE_ONLY, out.nbytes)
        program.vertices(queue, (n,), None,
                         cl.Buffer(context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=blocks),
                         out_buf)
        cl.enqueue_copy(queue, out, out_buf)
        assert out[-1] == layout.TRI_BLOCK
        assert np.array_equal(out[:-1].view(np.uint32), tris.reshape(-1).view(np.uint32))


def test_build_error_carries_log(ctx):
    context = ctx[0]
    with pytest.raises(KernelBuildError) as err:
        kdevice.build_program(context, "render.cl", {"STACK_SIZE": "no_such_symbol"})
    assert "render.cl" in str(err.value)
    assert "no_such_symbol" in err.value.log
    with pytest.raises(DeviceError):
        kdevice.build_program(context, "no_such_file.cl", {})


def test_choose_device():
    default = kdevice.choose_device(None)
    assert default is not None
    assert kdevice.choose_device("0").platform == cl.get_platforms()[0]
    assert kdevice.choose_device("0:0") == cl.get_platforms()[0].get_devices()[0]
    name = cl.get_platforms()[0].name
    assert kdevice.choose_device(name[:6].lower()).platform.name == name
    for bad in ("99", "0:99", "no-such-platform", "0:no-such-device"):
        with pytest.raises(DeviceError):
            kdevice.choose_device(bad)
    lines = kdevice.list_devices()
    assert any("--device 0:0" in line for line in lines)


def test_no_platform_says_what_to_install(monkeypatch):
    def none():
        raise cl.LogicError("clGetPlatformIDs failed: PLATFORM_NOT_FOUND_KHR")
    monkeypatch.setattr(cl, "get_platforms", none)
    with pytest.raises(DeviceError, match="pocl-binary-distribution"):
        kdevice.choose_device(None)
    monkeypatch.setattr(cl, "get_platforms", lambda: [])
    with pytest.raises(DeviceError, match="pocl-binary-distribution"):
        kdevice.create_context("0")
