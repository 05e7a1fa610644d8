/* kernels/inline.h: how kdray's kernel functions are compiled.
 *
 * Rule: every function that is not a __kernel is declared KD_INLINE, so that no call
 * survives into the compiled kernel. Intel's CPU OpenCL compiler (2026.2) runs a
 * work-group's work-items in SIMD lanes, and when a call it did not inline takes a
 * pointer to a private struct (a Hit *, a const RayShear *, or a struct returned by
 * value, which is a hidden pointer), the vectorized call addresses the lanes' copies
 * wrongly: work-items read other work-items' results or garbage, and hits are lost at
 * every local size from 16 up. Inlined, the struct lives in each lane's registers and
 * the compiler is right. GPU compilers inline everything anyway; PoCL gives the same
 * answers either way.
 */
#ifndef KDRAY_INLINE_H
#define KDRAY_INLINE_H

#define KD_INLINE __attribute__((always_inline))

#endif
