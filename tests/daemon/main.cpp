#define CATCH_CONFIG_RUNNER
#include <catch2/catch.hpp>

#include "thread_limit.hpp"

// The daemon's parts in process, under the same library thread caps as `proden serve` (one
// thread in a ThreadSanitizer build, service/thread_limit.hpp).
int main(int argc, char** argv) {
  const auto limit = proden::limit_threads(0);
  return Catch::Session().run(argc, argv);
}
