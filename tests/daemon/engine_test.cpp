// Engine: the front in process: jobs, uploads through to published frames, restart.
#include <catch2/catch.hpp>

#include <OpenImageIO/imageio.h>

#include <fstream>
#include <thread>

#include "daemon/engine.hpp"
#include "daemon/memory.hpp"
#include "daemon/versions.hpp"
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

TEST_CASE("Engine: resident states are bounded by count and by bytes, least recently updated first",
          "[daemon][engine]") {
  EngineRig rig;
  const auto job = rig.create("resident");
  const auto update = [&](long frame, std::uint64_t seed) {
    rig.engine->upload(job.id, std::to_string(frame), "p" + std::to_string(seed),
                       rig.pass_bytes(seed));
    REQUIRE(rig.engine->wait_idle(20000));
  };
  const auto loads = [&] {
    return rig.metric("proden_stage_duration_seconds_count{stage=\"load\"}");
  };
  // The default budget holds three small frames: every state stays.
  for (long f = 1; f <= 3; ++f) update(f, static_cast<std::uint64_t>(f));
  CHECK(rig.metric("proden_resident_frames") == 3);
  CHECK(rig.metric("proden_resident_budget_bytes") ==
        static_cast<double>(usable_memory_bytes() / 4));  // max_resident_bytes 0: the default
  const double three = rig.metric("proden_resident_bytes");
  REQUIRE(three > 0);
  const auto one = static_cast<std::uint64_t>(three / 3);

  SECTION("a byte budget of two and a half frames keeps the two last updated") {
    rig.config.max_resident_bytes = 2 * one + one / 2;
    rig.restart();  // nothing resident: each frame's next update reloads its state
    const double before = loads();
    const double evicted = rig.metric("proden_evictions_total");
    for (long f = 1; f <= 3; ++f) update(f, static_cast<std::uint64_t>(10 + f));
    CHECK(loads() == before + 3);
    CHECK(rig.metric("proden_resident_frames") == 2);  // 2 and 3; 1 was dropped
    CHECK(rig.metric("proden_resident_bytes") == static_cast<double>(2 * one));
    CHECK(rig.metric("proden_evictions_total") == evicted + 1);
    update(3, 20);  // resident: no reload
    CHECK(loads() == before + 3);
    const auto digest = rig.engine->frame(job.id, 1).state_digest;
    update(1, 21);  // dropped: reloaded from its state file, then 2 is dropped
    CHECK(loads() == before + 4);
    CHECK(rig.metric("proden_evictions_total") == evicted + 2);
    const auto f = rig.engine->frame(job.id, 1);
    CHECK(f.passes == 3);
    CHECK(f.state_digest != digest);
    update(2, 22);
    CHECK(loads() == before + 5);
    CHECK(rig.engine->frame(job.id, 2).passes == 3);
  }
  SECTION("max_resident_frames 1 keeps only the last updated") {
    rig.config.max_resident_frames = 1;
    rig.restart();
    const double before = loads();
    update(1, 11);
    update(2, 12);
    CHECK(rig.metric("proden_resident_frames") == 1);
    CHECK(rig.metric("proden_resident_bytes") == static_cast<double>(one));
    update(2, 13);
    CHECK(loads() == before + 2);
    update(1, 14);
    CHECK(loads() == before + 3);
  }
}

TEST_CASE("Engine: versions published uncompressed (auto) are compressed once it is idle",
          "[daemon][engine]") {
  // The file's compression and every channel's values, as OpenEXR stored them.
  struct Exr {
    std::string compression;
    std::vector<float> values;
  };
  const auto read = [](const fs::path& f) {
    auto in = OIIO::ImageInput::open(f.string());
    REQUIRE(in);
    Exr e;
    e.compression = in->spec().get_string_attribute("compression");
    e.values.resize(in->spec().image_pixels() * in->spec().nchannels);
    REQUIRE(in->read_image(0, 0, 0, in->spec().nchannels, OIIO::TypeDesc::FLOAT, e.values.data()));
    return e;
  };
  EngineRig rig;
  const auto job = rig.create("c");
  REQUIRE(job.output.compression == "auto");
  const fs::path exr = output_base(job, 1).string() + ".exr";
  const auto version = [&](std::uint64_t v) { return version_file(job, 1, v); };
  const auto compression = [&](const fs::path& f) { return read(f).compression; };
  rig.engine->upload(job.id, "1", "a", rig.pass_bytes(1));
  REQUIRE(rig.engine->wait_idle(20000));
  const Exr v1 = read(exr);
  CHECK(v1.compression == "none");
  rig.engine->upload(job.id, "1", "b", rig.pass_bytes(2));
  REQUIRE(rig.engine->wait_idle(20000));
  const Exr v2 = read(exr);
  CHECK(v2.compression == "none");
  CHECK(compression(version(1)) == "none");
  CHECK(rig.metric("proden_publish_compressed_later_total") == 0);
  // Idle for a second (the scheduler's clock): the newest version first, one file per idle time.
  rig.clock.advance(std::chrono::milliseconds(1100));
  REQUIRE(test::eventually([&] { return compression(exr) == "piz"; }));
  CHECK(read(exr).values == v2.values);
  CHECK(fs::equivalent(exr, version(2)));  // the kept copy is the compressed file too
  REQUIRE(rig.engine->wait_idle(20000));
  CHECK(compression(version(1)) == "none");
  rig.clock.advance(std::chrono::milliseconds(1100));
  REQUIRE(test::eventually([&] { return compression(version(1)) == "piz"; }));
  CHECK(read(version(1)).values == v1.values);
  REQUIRE(
      test::eventually([&] { return rig.metric("proden_publish_compressed_later_total") == 2; }));
  // A version left uncompressed by a process that stopped before it was idle: the next one
  // compresses it.
  rig.engine->upload(job.id, "1", "c", rig.pass_bytes(3));
  REQUIRE(rig.engine->wait_idle(20000));
  CHECK(compression(exr) == "none");
  rig.restart();
  CHECK(compression(exr) == "none");
  rig.clock.advance(std::chrono::milliseconds(1100));
  // The restarted scheduler has run nothing yet: its idle hook comes once a run has ended.
  rig.engine->upload(job.id, "2", "a", rig.pass_bytes(4));
  REQUIRE(rig.engine->wait_idle(20000));
  rig.clock.advance(std::chrono::milliseconds(1100));
  REQUIRE(test::eventually([&] {
    rig.clock.advance(std::chrono::milliseconds(1100));
    return compression(exr) == "piz" && compression(output_base(job, 2).string() + ".exr") == "piz";
  }));
  CHECK(fs::equivalent(exr, version(3)));
  CHECK(compression(version(2)) == "piz");
  // A job that asked for `none` keeps it.
  const auto plain = [&] {
    protocol::JobSpec s;
    s.name = "n";
    s.output.dir = (rig.allowed() / "n_out").string();
    s.output.compression = "none";
    s.pipeline = protocol::PipelineSpec::from_json({{"denoiser", "none"}});
    s.spp = 4.0;
    return rig.engine->create_job(s);
  }();
  rig.engine->upload(plain.id, "1", "a", rig.pass_bytes(5));
  REQUIRE(rig.engine->wait_idle(20000));
  for (int i = 0; i < 5; ++i) {
    rig.clock.advance(std::chrono::milliseconds(1100));
    std::this_thread::sleep_for(std::chrono::milliseconds(150));
  }
  REQUIRE(rig.engine->wait_idle(20000));
  CHECK(compression(output_base(plain, 1).string() + ".exr") == "none");
}
