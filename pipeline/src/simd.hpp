// Function multiversioning for hot loops: the compiler emits AVX-512, AVX2 and baseline x86-64
// versions and the loader picks the best for the CPU at run time, so shipped binaries stay
// portable (no -march=native) and still use this machine's AVX-512.
#pragma once

// Not under the sanitizers: their instrumented ifunc resolvers would run before the runtime starts.
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__) && \
    !defined(__SANITIZE_ADDRESS__) && !defined(__SANITIZE_THREAD__)
#define PRODEN_MULTIVERSION __attribute__((target_clones("avx512f", "avx2", "default")))
#else
#define PRODEN_MULTIVERSION
#endif
