// Run-time choice of instruction set for hot loops, so shipped binaries stay portable (no
// -march=native) and still use this machine's AVX-512: function multiversioning (the compiler
// emits AVX-512, AVX2 and baseline x86-64 versions and the loader picks one), and the list of
// builds a kernel compiled once per instruction set may run here.
#pragma once

#include <string>
#include <vector>

// Not under the sanitizers: their instrumented ifunc resolvers would run before the runtime starts.
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__) && \
    !defined(__SANITIZE_ADDRESS__) && !defined(__SANITIZE_THREAD__)
#define PRODEN_MULTIVERSION __attribute__((target_clones("avx512f", "avx2", "default")))
#else
#define PRODEN_MULTIVERSION
#endif

// Kernels compiled once per instruction set (GCC's `#pragma GCC target` sections) have their AVX2
// and AVX-512 builds where this is defined; elsewhere only the baseline one.
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
#define PRODEN_KERNEL_BUILDS_X86 1
#endif

namespace proden {

// The per-instruction-set kernel builds this CPU runs, best last: "baseline", then "avx2" (AVX2
// and FMA), then "avx512" (AVX-512F). Only "baseline" where GCC's per-target builds are not
// compiled (PRODEN_KERNEL_BUILDS_X86 undefined: other compilers, other architectures).
inline std::vector<std::string> cpu_kernel_builds() {
  std::vector<std::string> out = {"baseline"};
#ifdef PRODEN_KERNEL_BUILDS_X86
  __builtin_cpu_init();
  if (__builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma")) out.emplace_back("avx2");
  if (__builtin_cpu_supports("avx512f")) out.emplace_back("avx512");
#endif
  return out;
}

}  // namespace proden
