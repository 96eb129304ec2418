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

// The first unsigned number in `path` (a cgroup limit file), or 0 ("max", unreadable, absent).
std::size_t number_in(const char* path) {
  std::FILE* f = std::fopen(path, "r");
  if (!f) return 0;
  unsigned long long v = 0;
  const int n = std::fscanf(f, "%llu", &v);
  std::fclose(f);
  return n == 1 ? static_cast<std::size_t>(v) : 0;
}

std::mutex trim_mu;  // one trim at a time: concurrent ones would only contend for the arenas

}  // namespace

std::size_t usable_memory_bytes() {
  const long pages = ::sysconf(_SC_PHYS_PAGES), page = ::sysconf(_SC_PAGESIZE);
  std::size_t bytes =
      pages > 0 && page > 0 ? static_cast<std::size_t>(pages) * static_cast<std::size_t>(page) : 0;
  // A cgroup without a limit reads "max" (v2) or a huge page-rounded number (v1): both leave the
  // physical size.
  for (const char* limit :
       {"/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory/memory.limit_in_bytes"}) {
    const std::size_t l = number_in(limit);
    if (l > 0 && (bytes == 0 || l < bytes)) bytes = l;
  }
  return bytes;
}

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
