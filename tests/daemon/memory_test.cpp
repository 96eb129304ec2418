// daemon/memory.hpp: freed heap pages go back to the system.
#include <catch2/catch.hpp>

#include <cstring>
#include <vector>

#include "daemon/memory.hpp"
#include "huge_pages.hpp"

using namespace proden::daemon;

// Under the sanitizers' own allocator glibc's trim has nothing to do.
#if defined(__GLIBC__) && !defined(PRODEN_SANITIZER_ALLOCATOR)
TEST_CASE("Memory: free pages between live blocks go back to the system", "[daemon][memory]") {
  // 64 MiB of small blocks, then all but one in 64 freed: the heap cannot shrink from its top
  // (live blocks are spread through it), yet most of its pages hold nothing.
  constexpr std::size_t kBlock = 1024, kCount = 64 * 1024;
  std::vector<char*> blocks(kCount);
  for (auto& b : blocks) {
    b = new char[kBlock];
    std::memset(b, 1, kBlock);
  }
  for (std::size_t i = 0; i < kCount; ++i) {
    if (i % 64 != 0) {
      delete[] blocks[i];
      blocks[i] = nullptr;
    }
  }
  const std::size_t released = release_free_memory();
  CHECK(released > 32u * 1024 * 1024);
  for (auto* b : blocks) delete[] b;
}
#endif
