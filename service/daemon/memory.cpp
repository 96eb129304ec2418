#include "daemon/memory.hpp"

#include <algorithm>
#include <climits>
#include <cstdio>
#include <mutex>

#include <unistd.h>
#if defined(__GLIBC__)
#include <malloc.h>
#endif

namespace proden::daemon {
namespace {

std::size_t resident_bytes() {
  std::FILE* f = std::fopen("/proc/self/statm", "r");
  if (!f) return 0;
  unsigned long size = 0, resident = 0;
  const int n = std::fscanf(f, "%lu %lu", &size, &resident);
  std::fclose(f);
  if (n != 2) return 0;
  return static_cast<std::size_t>(resident) * static_cast<std::size_t>(::sysconf(_SC_PAGESIZE));
}

std::mutex trim_mu;  // one trim at a time: concurrent ones would only contend for the arenas

}  // namespace

void configure_allocator(std::size_t mmap_threshold, std::size_t trim_threshold, int arenas) {
#if defined(__GLIBC__)
  const int threshold = static_cast<int>(std::min<std::size_t>(mmap_threshold, 1u << 25));
  const int trim = static_cast<int>(std::min<std::size_t>(trim_threshold, INT_MAX));
  ::mallopt(M_MMAP_THRESHOLD, threshold);
  ::mallopt(M_TRIM_THRESHOLD, trim);
  if (arenas > 0) ::mallopt(M_ARENA_MAX, arenas);
#else
  (void)mmap_threshold;
  (void)trim_threshold;
  (void)arenas;
#endif
}

std::size_t release_free_memory() {
#if defined(__GLIBC__)
  std::lock_guard lock(trim_mu);
  const std::size_t before = resident_bytes();
  ::malloc_trim(0);
  const std::size_t after = resident_bytes();
  return before > after ? before - after : 0;
#else
  return 0;
#endif
}

}  // namespace proden::daemon
