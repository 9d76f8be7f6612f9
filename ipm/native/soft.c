/* The soft silhouette's C kernel: soft_kernel.inc, written once for a type REAL, compiled for float (its exp(-x)
   inlined: expneg) and for double; the exported functions are declared in soft.h. Built by ipm.native. */
#include "soft.h"

#define REAL float
#define NAME(x) x##_f
#define EXP expf
#define EXPM1 expm1f
#define LOG logf
#define TINY 1.0842021724855044e-19f
#define UINT uint32_t
#define EXPBITS 0x7f800000u
#define SIGNBIT 0x80000000u
#define FASTEXP 1
#include "soft_kernel.inc"

#undef REAL
#undef NAME
#undef EXP
#undef EXPM1
#undef LOG
#undef TINY
#undef UINT
#undef EXPBITS
#undef SIGNBIT
#undef FASTEXP
#undef VEC
#undef RUNS
#undef EDGE
#undef PAIR_GEOMETRY
#undef FOR_TRIANGLE_RUNS

#define REAL double
#define NAME(x) x##_d
#define EXP exp
#define EXPM1 expm1
#define LOG log
#define TINY 1.4916681462400413e-154
#define UINT uint64_t
#define EXPBITS 0x7ff0000000000000ull
#define SIGNBIT 0x8000000000000000ull
#define FASTEXP 0
#include "soft_kernel.inc"
