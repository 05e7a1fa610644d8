/* kernels/inline.h: how kdray's kernel functions are compiled.
 *
 * Rule: every function that is not a __kernel is declared KD_INLINE, so that no call
 * survives into the compiled kernel. Intel's CPU OpenCL compiler (2026.2) runs a
 * work-group's work-items in SIMD lanes and makes SIMD variants of the functions it
 * does not inline; in those, an argument or return value of a 3-element vector type
 * (float3, int3, ...) is packed 12 bytes a lane but read at 16 bytes a lane
 * (sizeof(float3)), so lane k gets lane 4k/3's value or garbage: hits were lost at
 * every local size from 16 up. tests/repros/intel_cpu_vec3_call.py shows it with a
 * 7-line kernel. Inlined, nothing is passed and the compiler is right. GPU compilers
 * inline everything anyway; PoCL gives the same answers either way.
 *
 * The one exception, KD_CALLED, is for a function that is measurably faster as a call
 * and cannot meet the bug: it takes and returns no 3-element vector, and only packet
 * programs (vec_type_hint: not run in SIMD lanes across work-items, so no SIMD
 * variants) call it. tests/test_kernel_source.py checks its parameters.
 */
#ifndef KDRAY_INLINE_H
#define KDRAY_INLINE_H

#define KD_INLINE __attribute__((always_inline))
#define KD_CALLED __attribute__((noinline))

#endif
