"""Miscompilation in Intel's CPU OpenCL runtime (intel-opencl-rt 2026.2.0): a float3
argument passed to a non-inlined function from a vectorized kernel.

Each work-item i calls g(vload3(i, xs)) and should write xs[3*i + 1].
At local size 1 the kernel runs scalar code and is right. At local size 16 it runs
the 16-wide vectorized kernel, which calls the SIMD variant _ZGVeN16v_g. That variant
gets the 16 float3 values packed (12 bytes per lane) but reads lane k at byte 16*k
(sizeof(float3) == 16). Lane k then gets xs[4*k + 1], and lanes 12..15 read past the
192-byte block, so their values are garbage.

usage: python intel_ocl_cpu_vectorizer_bug.py [extra build options, e.g. -cl-opt-disable]
       OCL_PLATFORM=<substring of platform name> (default "Intel(R) OpenCL")
exit status: 1 if local size 1 and local size 16 results differ, else 0.
"""
import os
import sys

# pyopencl would otherwise reuse a cached binary, e.g. one built under different
# CL_CONFIG_* settings; it reads this variable when imported.
os.environ.setdefault("PYOPENCL_NO_CACHE", "1")

import numpy as np
import pyopencl as cl

KERNEL = r"""
__attribute__((noinline)) float g(float3 v) { return v.y; }

__kernel __attribute__((reqd_work_group_size(LS, 1, 1)))
void f(__global const float *xs, __global float *out)
{
    uint i = get_global_id(0);
    out[i] = g(vload3(i, xs));
}
"""

N = 256  # work-items

want = os.environ.get("OCL_PLATFORM", "Intel(R) OpenCL")
plats = [p for p in cl.get_platforms() if want in p.name]
if not plats:
    sys.exit("no OpenCL platform matching %r; have %s"
             % (want, [p.name for p in cl.get_platforms()]))
plat = plats[0]
dev = plat.get_devices()[0]
print("platform:", plat.name, "|", plat.version)
print("device:  ", dev.name, "| driver", dev.driver_version, "|", dev.version)

ctx = cl.Context([dev])
q = cl.CommandQueue(ctx)
mf = cl.mem_flags
xs = np.arange(3 * N, dtype=np.float32)       # xs[k] = k, so results show the addresses read
xb = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=xs)
expected = xs[1::3].copy()                    # v.y of vload3(i, xs) == xs[3*i + 1]


def run(ls):
    prg = cl.Program(ctx, KERNEL).build(options=["-DLS=%d" % ls] + sys.argv[1:])
    out = np.full(N, -1.0, np.float32)
    ob = cl.Buffer(ctx, mf.READ_WRITE | mf.COPY_HOST_PTR, hostbuf=out)
    prg.f(q, (N,), (ls,), xb, ob)
    cl.enqueue_copy(q, out, ob)
    q.finish()
    return out


r1, r16 = run(1), run(16)
bits = lambda a: a.view(np.uint32)
differ = int((bits(r1) != bits(r16)).sum())
print("expected      :", expected[:16].tolist())
print("local size 1  :", r1[:16].tolist())
print("local size 16 :", r16[:16].tolist())
print("wrong vs host: local size 1: %d, local size 16: %d"
      % ((r1 != expected).sum(), (r16 != expected).sum()))
print("work-items that differ between local size 1 and 16: %d of %d" % (differ, N))
sys.exit(1 if differ else 0)
