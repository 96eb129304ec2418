// Replaces operator new for the executables that link it (CMake: proden_huge_pages): large blocks
// are advised onto transparent huge pages (huge_pages.hpp). The C++ library's array and nothrow
// forms call this one, and its deletes call free(), so they stay a pair. The over-aligned forms
// are left alone: nothing large is over-aligned here.
#include "huge_pages.hpp"

#include <fcntl.h>
#include <sys/mman.h>
#include <unistd.h>

#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <new>

namespace proden {
namespace {

#ifndef PRODEN_SANITIZER_ALLOCATOR
// The first line of a small sysfs file, read with plain system calls (this runs inside operator
// new, so it must not allocate). Empty when unreadable.
struct Line {
  char text[160] = {};
};

Line read_line(const char* path) {
  Line l;
  const int fd = ::open(path, O_RDONLY | O_CLOEXEC);
  if (fd < 0) return l;
  const ssize_t n = ::read(fd, l.text, sizeof l.text - 1);
  ::close(fd);
  l.text[n > 0 ? n : 0] = '\0';
  return l;
}
#endif

struct Policy {
  HugePages mode = HugePages::off;
  std::uintptr_t page = std::uintptr_t{2} << 20;  // the huge page size (x86-64: 2 MiB)
};

Policy detect() {
  Policy p;
#ifdef PRODEN_SANITIZER_ALLOCATOR
  p.mode = HugePages::sanitizer;
  return p;
#else
  const char* env = std::getenv("PRODEN_HUGE_PAGES");
  if (env && (std::strcmp(env, "off") == 0 || std::strcmp(env, "0") == 0)) return p;
  // "always [madvise] never": the bracketed word is the mode.
  const Line mode = read_line("/sys/kernel/mm/transparent_hugepage/enabled");
  if (std::strstr(mode.text, "[madvise]")) {
    p.mode = HugePages::advised;
  } else if (std::strstr(mode.text, "[always]")) {
    p.mode = HugePages::always;
  }
  const Line size = read_line("/sys/kernel/mm/transparent_hugepage/hpage_pmd_size");
  const unsigned long long bytes = std::strtoull(size.text, nullptr, 10);
  // A power of two, or the default stays.
  if (bytes >= 4096 && (bytes & (bytes - 1)) == 0) p.page = static_cast<std::uintptr_t>(bytes);
  return p;
#endif
}

const Policy& policy() {
  static const Policy p = detect();
  return p;
}

#ifndef PRODEN_SANITIZER_ALLOCATOR
// Advises the whole huge pages inside [block, block + n). The advice only marks the range: pages
// already in memory stay as they are, and the kernel falls back to small pages when it has no
// huge one free. Failure (a kernel without THP) is harmless, so it is ignored.
void advise(void* block, std::size_t n) {
  const Policy& p = policy();
  if (p.mode != HugePages::advised) return;
  const std::uintptr_t begin = reinterpret_cast<std::uintptr_t>(block);
  const std::uintptr_t first = (begin + p.page - 1) & ~(p.page - 1);
  const std::uintptr_t last = (begin + n) & ~(p.page - 1);
  if (last > first) {
    ::madvise(reinterpret_cast<void*>(first), last - first, MADV_HUGEPAGE);
  }
}
#endif

}  // namespace

HugePages huge_pages() {
  return policy().mode;
}

const char* huge_pages_name(HugePages mode) {
  switch (mode) {
    case HugePages::advised:
      return "advised";
    case HugePages::always:
      return "always";
    case HugePages::off:
      return "off";
    case HugePages::sanitizer:
      return "sanitizer";
  }
  return "off";
}

}  // namespace proden

#ifndef PRODEN_SANITIZER_ALLOCATOR
void* operator new(std::size_t n) {
  if (n == 0) n = 1;
  for (;;) {
    if (void* p = std::malloc(n)) {
      if (n >= proden::kHugeBlockMin) proden::advise(p, n);
      return p;
    }
    const std::new_handler handler = std::get_new_handler();
    if (!handler) throw std::bad_alloc();
    handler();
  }
}
#endif
