// The daemon's memory: gives the heap's free pages back to the system, so that an idle daemon's
// resident memory follows what it holds rather than the high-water mark of its largest frame run
// (glibc keeps freed memory in per-thread arenas otherwise; bench/results/soak.md measured the
// difference), and says how much memory the process may use (the resident frames' budget).
#pragma once

#include <cstddef>

namespace proden::daemon {

// Fixes glibc's thresholds (call once at start-up, before threads): blocks of at least
// `mmap_threshold` bytes (at most 32 MiB, glibc's ceiling) are mapped and unmapped on free,
// smaller ones come from the arenas; an arena's free top is returned on free only beyond
// `trim_threshold` (else by release_free_memory); at most `arenas` arenas are made (default 8 per
// core). Without it, glibc raises both thresholds to the largest block freed so far (OIIO's
// scanline reads free buffers of about 20 MB per pass), and trims whenever the top allows.
void configure_allocator(std::size_t mmap_threshold, std::size_t trim_threshold, int arenas);

// The memory this process may use: physical memory, or the cgroup's limit (v2 memory.max, v1
// memory.limit_in_bytes) when that is lower (a container's). 0 when neither can be read.
std::size_t usable_memory_bytes();

// Returns free heap pages to the system (malloc_trim): the bytes of resident memory released,
// as measured from /proc/self/statm (0 where that is not available). No-op without glibc.
std::size_t release_free_memory();

}  // namespace proden::daemon
