// What the fuzz targets share: a check that survives NDEBUG (a failed property aborts, which
// libFuzzer records as a crash with its input), and the "text that may cross into JSON" property.
#pragma once

#include <cstdio>
#include <cstdlib>
#include <string_view>

#include <nlohmann/json.hpp>

#include "proden/io/text.hpp"

#define FUZZ_CHECK(cond)                                                               \
  do {                                                                                 \
    if (!(cond)) {                                                                     \
      std::fprintf(stderr, "%s:%d: property failed: %s\n", __FILE__, __LINE__, #cond); \
      std::abort();                                                                    \
    }                                                                                  \
  } while (0)

namespace proden::fuzz {

// Text proden may put into an event, an error body or a log line: well-formed UTF-8 (so a strict
// nlohmann dump cannot throw; issue 11, class 1).
inline void check_json_safe(std::string_view text) {
  FUZZ_CHECK(io::is_valid_utf8(text));
  (void)nlohmann::json(std::string(text)).dump();  // strict: throws (-> crash) on bad UTF-8
}

}  // namespace proden::fuzz
