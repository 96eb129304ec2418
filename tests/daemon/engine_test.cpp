// Engine: the front in process: jobs, uploads through to published frames, restart.
#include <catch2/catch.hpp>

#include <fstream>

#include "daemon/engine.hpp"
#include "daemon_support.hpp"

namespace fs = std::filesystem;
using namespace proden;
using namespace proden::daemon;

using test::EngineRig;

TEST_CASE("Engine: uploads become a published frame that survives a restart", "[daemon][engine]") {
  EngineRig rig;
  const auto job = rig.create("shot");
  CHECK(job.id.size() == 13);
  rig.engine->upload(job.id, "5", "a", rig.pass_bytes(1));
  rig.engine->upload(job.id, "5", "b", rig.pass_bytes(2));
  REQUIRE(rig.engine->wait_idle(20000));
  const auto f = rig.engine->frame(job.id, 5);
  CHECK(f.passes == 2);
  CHECK(f.spp == 8.0);
  CHECK(f.version >= 1);
  CHECK_FALSE(f.pending);
  CHECK(fs::exists(output_base(job, 5).string() + ".exr"));
  rig.restart();
  const auto g = rig.engine->frame(job.id, 5);
  CHECK(g.passes == 2);
  CHECK(g.state_digest == f.state_digest);
  CHECK(g.version == f.version);
}

TEST_CASE("Engine: job lifecycle and API errors", "[daemon][engine]") {
  EngineRig rig;
  const auto job = rig.create("life");
  CHECK(rig.engine->jobs().size() == 1);
  CHECK(rig.engine->set_paused(job.id, true).paused);
  CHECK(rig.engine->job(job.id).paused);
  CHECK_FALSE(rig.engine->set_paused(job.id, false).paused);
  CHECK_THROWS_AS(rig.create("life"), protocol::ApiError);            // same name: 409
  CHECK_THROWS_AS(rig.engine->frame(job.id, 9), protocol::ApiError);  // no such frame
  CHECK_THROWS_AS(rig.engine->upload(job.id, "x", "a", "b"), protocol::ApiError);
  rig.engine->delete_job(job.id);
  CHECK(rig.engine->jobs().empty());
  CHECK_FALSE(fs::exists(fs::path(rig.config.state_dir) / "jobs" / job.id));
  CHECK_THROWS_AS(rig.engine->job(job.id), protocol::ApiError);
}

TEST_CASE("Engine: a paused job keeps its uploads until resumed", "[daemon][engine]") {
  EngineRig rig;
  const auto job = rig.create("p");
  rig.engine->set_paused(job.id, true);
  rig.engine->upload(job.id, "1", "a", rig.pass_bytes(3));
  REQUIRE(rig.engine->wait_idle(20000));
  CHECK(rig.engine->frame(job.id, 1).passes == 0);
  CHECK(rig.engine->frame(job.id, 1).pending);
  rig.engine->set_paused(job.id, false);
  REQUIRE(rig.engine->wait_idle(20000));
  CHECK(rig.engine->frame(job.id, 1).passes == 1);
}

TEST_CASE("Engine: watched files are ingested once", "[daemon][engine]") {
  EngineRig rig;
  const fs::path watch = rig.t.path() / "allowed" / "w";
  const auto job = rig.create("w", protocol::WatchSpec{watch.string(), "p{pass}_{frame}.exr"});
  test::write_pass(watch / "pa_0002.exr", "a", 4);
  test::write_pass(watch / "pb_0002.exr", "b", 5);
  for (int i = 0;
       i < 200 && rig.metrics.render().find("proden_passes_ingested_total 2") == std::string::npos;
       ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  REQUIRE(rig.engine->wait_idle(20000));
  CHECK(rig.engine->frame(job.id, 2).passes == 2);
  std::this_thread::sleep_for(std::chrono::milliseconds(400));  // more scans: nothing new
  CHECK(rig.engine->frame(job.id, 2).passes == 2);
}
