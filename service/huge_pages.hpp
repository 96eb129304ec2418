// Large blocks on transparent huge pages: the executables that link service/huge_pages.cpp
// replace `operator new` so that a block of at least kHugeBlockMin bytes asks the kernel for
// 2 MiB pages (madvise MADV_HUGEPAGE) where the kernel gives them only on request. The CLI's
// 1080p run touches ~1.9 GB of fresh memory; faulting it in 4 KiB pages took about a third of its
// time (bench/RESULTS.md, "Huge pages"; docs/api.md, "Memory").
#pragma once

#include <cstddef>

// Defined in ASan and TSan builds, whose allocators replace malloc and operator new.
#if defined(__SANITIZE_ADDRESS__) || defined(__SANITIZE_THREAD__)
#define PRODEN_SANITIZER_ALLOCATOR 1
#elif defined(__has_feature)
#if __has_feature(address_sanitizer) || __has_feature(thread_sanitizer)
#define PRODEN_SANITIZER_ALLOCATOR 1
#endif
#endif

namespace proden {

// Smallest block that is advised: it always holds at least one whole 2 MiB page.
inline constexpr std::size_t kHugeBlockMin = std::size_t{4} << 20;

enum class HugePages {
  advised,    // the kernel's THP mode is "madvise": large blocks are advised
  always,     // mode "always": the kernel backs large blocks with huge pages unasked
  off,        // mode "never", no THP in the kernel, or PRODEN_HUGE_PAGES=off
  sanitizer,  // an ASan or TSan build: the sanitizer's allocator is in charge, nothing is replaced
};

// What this process does with large blocks (decided once, from the environment and
// /sys/kernel/mm/transparent_hugepage/enabled).
HugePages huge_pages();

// "advised", "always", "off" or "sanitizer", for logs.
const char* huge_pages_name(HugePages mode);

}  // namespace proden
