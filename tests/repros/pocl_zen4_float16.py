"""PoCL 3.0 (pocl-binary-distribution, LLVM 14) on an AMD Zen 4 with AVX-512 visible:
its LLVM names the CPU "znver3" (a CPU without AVX-512) while the device reports
16-lane floats (native_vector_width_float 16), and compiling vector code then kills
the process. Seen on the project's 2-core AMD EPYC (family 25, model 17), 2026-12-04:

    plain   a float16 load, multiply-add and store      SIGSEGV
    sqrt    sqrt(float16)                               SIGSEGV (in kdray's render.cl:
                                                        "LLVM ERROR: Cannot select ...
                                                        fsqrt", in _cl_sqrtDv16_f)
    priv    a private array of float16                  "LLVM ERROR: Do not know how to
                                                        scalarize this operator's
                                                        operand!" (SIGABRT)

float8 runs all three correctly, but kdray's packet kernel of 8 lanes with its STATS
counters aborts too ("Cannot select: store ... trunc to v8f32"). kdray therefore fails
PoCL's probe on such a CPU without building anything (kdray.device.compiler_fault).

usage: python tests/repros/pocl_zen4_float16.py [plain|sqrt|priv] [lanes: 16 or 8]
       Run each case in its own process: a crash cannot be caught.
exit status: 0 when the kernel ran and gave the right answer, 1 when the answer was
wrong, 2 when no PoCL device is present; a crash ends the process by its signal.
"""
import os
import sys
import tempfile

# a fresh compiler cache, so that the kernel is compiled here and not read back
os.environ["POCL_CACHE_DIR"] = tempfile.mkdtemp(prefix="pocl-zen4-")

import numpy as np
import pyopencl as cl

KERNELS = {
    "plain": "__kernel void k(__global const float *a, __global float *o) {"
             " int i = get_global_id(0); floatW v = vloadW(i, a); vstoreW(v * v + 1.0f, i, o); }",
    "sqrt": "__kernel void k(__global const float *a, __global float *o) {"
            " int i = get_global_id(0); vstoreW(sqrt(vloadW(i, a)), i, o); }",
    "priv": "__kernel void k(__global const float *a, __global float *o) {"
            " int i = get_global_id(0); floatW s[8];"
            " for (int j = 0; j < 8; j++) s[j] = vloadW(i, a) * (float)j;"
            " vstoreW(s[(int)a[0] & 7], i, o); }",
}


def expected(case, a):
    if case == "plain":
        return a * a + np.float32(1)
    if case == "sqrt":
        return np.sqrt(a)
    return a * np.float32(int(a[0]) & 7)


def main():
    case = sys.argv[1] if len(sys.argv) > 1 else "plain"
    lanes = int(sys.argv[2]) if len(sys.argv) > 2 else 16
    platforms = [p for p in cl.get_platforms() if "Portable Computing Language" in p.name]
    if not platforms:
        print("no PoCL platform")
        return 2
    device = platforms[0].get_devices()[0]
    print(f"{device.name.strip()}: {device.version.strip()}, native float width "
          f"{device.native_vector_width_float}; {case} with float{lanes}", flush=True)
    ctx = cl.Context([device])
    queue = cl.CommandQueue(ctx)
    source = KERNELS[case].replace("floatW", f"float{lanes}").replace(
        "vloadW", f"vload{lanes}").replace("vstoreW", f"vstore{lanes}")
    program = cl.Program(ctx, source).build()
    a = np.random.default_rng(0).uniform(0.5, 7.5, lanes * 64).astype(np.float32)
    out = np.empty_like(a)
    mf = cl.mem_flags
    a_buf = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=a)
    out_buf = cl.Buffer(ctx, mf.WRITE_ONLY, out.nbytes)
    program.k(queue, (64,), (4,), a_buf, out_buf)
    cl.enqueue_copy(queue, out, out_buf)
    queue.finish()
    right = np.allclose(out, expected(case, a), rtol=1e-6)
    print("right" if right else "wrong")
    return 0 if right else 1


if __name__ == "__main__":
    sys.exit(main())
