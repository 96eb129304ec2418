// huge_pages.hpp: operator new advises large blocks onto transparent huge pages.
#include <catch2/catch.hpp>

#include <cstdint>
#include <cstring>
#include <fstream>
#include <memory>
#include <sstream>
#include <string>

#include "huge_pages.hpp"

using proden::HugePages;

namespace {

// The VmFlags of the mapping that holds `address` (/proc/self/smaps), or "" when none does.
std::string vm_flags(const void* address) {
  const auto a = reinterpret_cast<std::uintptr_t>(address);
  std::ifstream smaps("/proc/self/smaps");
  std::string line;
  bool inside = false;
  while (std::getline(smaps, line)) {
    std::uintptr_t lo = 0, hi = 0;
    char dash = 0;
    std::istringstream head(line);
    if (head >> std::hex >> lo >> dash >> hi && dash == '-') {
      inside = lo <= a && a < hi;
      continue;
    }
    if (inside && line.rfind("VmFlags:", 0) == 0) return line.substr(8) + " ";
  }
  return "";
}

bool advised(const void* address) {
  return vm_flags(address).find(" hg ") != std::string::npos;
}

}  // namespace

TEST_CASE("Huge pages: a large block asks for huge pages where the kernel needs asking",
          "[daemon][memory]") {
  const HugePages mode = proden::huge_pages();
  INFO("mode " << proden::huge_pages_name(mode));
  if (mode == HugePages::sanitizer) {
    // ASan and TSan replace the allocator themselves: nothing of ours runs.
    CHECK(std::strcmp(proden::huge_pages_name(mode), "sanitizer") == 0);
    return;
  }
  // Through operator new (new[] calls it). Whether a smaller block lies in an advised range is
  // not checked: the heap may hand it pages that an earlier large block had advised.
  const std::size_t large_n = std::size_t{64} << 20;
  auto large = std::make_unique<char[]>(large_n);
  // A byte of the large block at least one huge page in, so inside its advised range.
  const char* inner = large.get() + (std::size_t{4} << 20);
  REQUIRE_FALSE(vm_flags(inner).empty());
  // Only the "madvise" mode needs the advice; "always" gives huge pages unasked, and "never"
  // or PRODEN_HUGE_PAGES=off refuse them.
  CHECK(advised(inner) == (mode == HugePages::advised));
}
