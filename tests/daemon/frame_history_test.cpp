// FrameHistory: the versions a frame published, one JSON line each.
#include <catch2/catch.hpp>

#include <fstream>

#include "daemon/frame_history.hpp"
#include "test_support.hpp"

using namespace proden;
using namespace proden::daemon;

TEST_CASE("FrameHistory: versions in order, one per version, torn lines skipped",
          "[daemon][history]") {
  test::TempDir t;
  const auto f = t.path() / "1.history";
  CHECK(FrameHistory::load(f).empty());
  FrameHistory::append(f, {{"version", 2}, {"estimated_mse", 0.5}});
  FrameHistory::append(f, {{"version", 1}, {"estimated_mse", 0.9}});
  FrameHistory::append(f,
                       {{"version", 2}, {"estimated_mse", 0.4}});  // re-published after a restart
  {
    std::ofstream torn(f, std::ios::app);
    torn << R"({"version": 3, "estim)";  // a crash mid-append
  }
  const auto h = FrameHistory::load(f);
  REQUIRE(h.size() == 2);
  CHECK(h[0]["version"] == 1);
  CHECK(h[1]["version"] == 2);
  CHECK(h[1]["estimated_mse"] == 0.4);
  CHECK_THROWS(FrameHistory::append(t.path() / "no" / "such" / "dir", {{"version", 1}}));
}
