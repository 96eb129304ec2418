// The machine's own sgemm rate, the yardstick the learned mixer's GFLOP/s is reported against
// (OpenBLAS when the build found it, else a plain blocked loop; `how` says which).
#pragma once

#include <tbb/global_control.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <chrono>
#include <random>
#include <string>
#include <vector>

#if defined(PRODEN_BENCH_OPENBLAS)
#include <cblas.h>
#endif

namespace proden::bench {

using Clock = std::chrono::steady_clock;

// sgemm GFLOP/s on n x n matrices with `threads` threads.
inline double sgemm_gflops(int n, int threads, std::string& how) {
  std::vector<float> a(static_cast<std::size_t>(n) * n), b(a.size()), c(a.size(), 0.0f);
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  for (auto& v : a) v = u(rng);
  for (auto& v : b) v = u(rng);
  int reps = 0;
  double secs = 0;
#if defined(PRODEN_BENCH_OPENBLAS)
  how = "OpenBLAS cblas_sgemm (Debian libopenblas0-pthread)";
  openblas_set_num_threads(threads);
  cblas_sgemm(CblasRowMajor, CblasNoTrans, CblasNoTrans, n, n, n, 1.0f, a.data(), n, b.data(), n,
              0.0f, c.data(), n);  // warm-up
  const auto t0 = Clock::now();
  while (secs < 1.0 || reps < 3) {
    cblas_sgemm(CblasRowMajor, CblasNoTrans, CblasNoTrans, n, n, n, 1.0f, a.data(), n, b.data(), n,
                0.0f, c.data(), n);
    ++reps;
    secs = std::chrono::duration<double>(Clock::now() - t0).count();
  }
#else
  how = "plain blocked C++ loop (no OpenBLAS found at configure time)";
  tbb::global_control limit(tbb::global_control::max_allowed_parallelism,
                            static_cast<std::size_t>(threads));
  const int bs = 64;
  const auto t0 = Clock::now();
  while (secs < 1.0 || reps < 1) {
    std::fill(c.begin(), c.end(), 0.0f);
    tbb::parallel_for(0, (n + bs - 1) / bs, [&](int bi) {
      for (int kk = 0; kk < n; kk += bs)
        for (int i = bi * bs; i < std::min(n, (bi + 1) * bs); ++i)
          for (int k = kk; k < std::min(n, kk + bs); ++k) {
            const float aik = a[static_cast<std::size_t>(i) * n + k];
            float* ci = &c[static_cast<std::size_t>(i) * n];
            const float* bk = &b[static_cast<std::size_t>(k) * n];
            for (int j = 0; j < n; ++j) ci[j] += aik * bk[j];
          }
    });
    ++reps;
    secs = std::chrono::duration<double>(Clock::now() - t0).count();
  }
#endif
  return 2.0 * n * n * static_cast<double>(n) * reps / secs / 1e9;
}

}  // namespace proden::bench
