// FrameRun: one run of a frame: read, accumulate, commit (persist), publish, announce.
#include <catch2/catch.hpp>

#include <OpenImageIO/imageio.h>

#include <fstream>

#include "daemon/files.hpp"
#include "daemon/frame_history.hpp"
#include "daemon/frame_run.hpp"
#include "daemon/versions.hpp"
#include "daemon_support.hpp"

namespace fs = std::filesystem;
using namespace proden;
using namespace proden::daemon;

namespace {

// A FrameRun wired to a real JobStore in a temp dir, recording what it reports.
struct Rig {
  test::TempDir t;
  std::function<void(const std::string&, const fs::path&)> fault;
  JobStore store{t.path() / "state", [this](const std::string& op, const fs::path& p) {
                   if (fault) fault(op, p);
                 }};
  Metrics metrics;
  EventHub hub{100};
  std::shared_ptr<test::EventLog> events = test::listen(hub);
  protocol::JobSpec spec = test::job_spec(t.path(), "j1");
  std::vector<std::pair<PendingPass, Failure>> failed;
  std::vector<FrameRecord> committed;
  std::vector<std::uint64_t> published;
  std::vector<bool> compress_later;  // Hooks::published's flag, per version
  std::function<void(const FrameRecord&)> on_recovered = [](const FrameRecord&) {};

  Rig() { store.create_job(spec); }

  FrameRun::Outcome run(std::vector<PendingPass> batch, FrameRecord rec = {},
                        bool has_state = false, bool republish = false,
                        std::shared_ptr<FrameAccumulator> acc = nullptr) {
    FrameRun::Hooks h;
    h.failed = [this](const PendingPass& p, const Failure& f) { failed.emplace_back(p, f); };
    h.committed = [this](const FrameRecord& r, const std::vector<protocol::PassIdentity>&) {
      committed.push_back(r);
    };
    h.published = [this](std::uint64_t v, const std::vector<std::string>&, bool later) {
      published.push_back(v);
      compress_later.push_back(later);
    };
    h.recovered = [this](const FrameRecord& g) { on_recovered(g); };
    FrameRun fr(store, metrics, hub, h);
    FrameRun::Input in;
    in.spec = spec;
    in.frame = 1;
    in.record = std::move(rec);
    in.has_state = has_state;
    in.republish = republish;
    in.acc = std::move(acc);
    in.batch = std::move(batch);
    return fr.run(std::move(in));
  }
  fs::path watched(const std::string& pass) const { return t.path() / "w" / (pass + ".exr"); }
};

}  // namespace

TEST_CASE("FrameRun: passes are committed with their identities, then published",
          "[daemon][frame_run]") {
  Rig r;
  const auto b = test::write_pass(r.watched("10"), "10", 2);
  const auto a = test::write_pass(r.watched("9"), "9", 1);
  const auto out = r.run({b, a});
  REQUIRE(out.result == FrameRun::Result::done);
  REQUIRE(out.acc);
  CHECK(out.acc->passes() == 2);
  REQUIRE(r.committed.size() == 1);
  const FrameRecord& rec = r.committed[0];
  CHECK(rec.version == 1);
  CHECK(rec.passes == 2);
  CHECK(rec.spp == 8.0);
  REQUIRE(rec.ingested.size() == 2);
  CHECK(rec.ingested[0].pass == "9");  // natural order: 9 before 10
  CHECK(rec.ingested[1].pass == "10");
  CHECK(rec.ingested[0].size == a.size);
  CHECK(rec.ingested[0].content_hash != 0);
  // The commit point: the state on disk holds exactly this.
  CHECK(r.store.load_frame("j1", 1).acc.state_digest() == rec.digest);
  CHECK(r.published == std::vector<std::uint64_t>{1});
  CHECK(fs::exists(output_base(r.spec, 1).string() + ".exr"));
  std::ifstream pub(r.store.published_path("j1", 1));
  std::uint64_t v = 0;
  pub >> v;
  CHECK(v == 1);
  const auto frames = r.events->of_type("frame");
  REQUIRE(frames.size() == 1);
  CHECK(frames[0].data["version"] == 1);
  CHECK(frames[0].data["new_passes"] == 2);
}

TEST_CASE("FrameRun: an accumulated upload is kept aside, a failed pass is reported",
          "[daemon][frame_run]") {
  Rig r;
  const auto up = test::write_pass(r.store.upload_dir("j1", 1) / "a.exr", "a", 1, true);
  const fs::path bad = r.watched("b");
  fs::create_directories(bad.parent_path());
  std::ofstream(bad) << "not an image";
  std::error_code ec;
  const PendingPass bp{"b", bad, fs::file_size(bad), mtime_ns(bad, ec), false};
  const auto out = r.run({up, bp});
  REQUIRE(out.result == FrameRun::Result::done);
  CHECK_FALSE(fs::exists(up.path));
  CHECK(fs::exists(r.store.kept_dir("j1", 1) / "a.exr"));
  REQUIRE(r.failed.size() == 1);
  CHECK(r.failed[0].first.pass == "b");
  CHECK(r.failed[0].second.kind == "unsupported_format");  // not EXR or HDR by its bytes
  CHECK(r.failed[0].second.cls == ErrorClass::bad_input);
  REQUIRE(r.committed.size() == 1);
  CHECK(r.committed[0].passes == 1);
}

TEST_CASE("FrameRun: a watched file that changed since discovery is left for the watcher",
          "[daemon][frame_run]") {
  Rig r;
  auto p = test::write_pass(r.watched("a"), "a", 1);
  p.size += 1;  // as discovered: a different size
  const auto out = r.run({p});
  CHECK(out.result == FrameRun::Result::done);
  CHECK(r.failed.empty());
  CHECK(r.committed.empty());
  CHECK(r.published.empty());
}

TEST_CASE("FrameRun: a failed persist commits nothing and keeps the last state",
          "[daemon][frame_run]") {
  Rig r;
  const auto a = test::write_pass(r.watched("a"), "a", 1);
  REQUIRE(r.run({a}).result == FrameRun::Result::done);
  const FrameRecord first = r.committed.at(0);
  r.fault = [](const std::string& op, const fs::path&) {
    if (op == "state") throw std::runtime_error("no space left on device (simulated)");
  };
  const auto b = test::write_pass(r.watched("b"), "b", 2);
  const auto out = r.run({b}, first, true);
  CHECK(out.result == FrameRun::Result::failed);
  CHECK(r.committed.size() == 1);
  CHECK(r.published.size() == 1);
  CHECK(r.store.load_frame("j1", 1).acc.state_digest() == first.digest);
  const auto errors = r.events->of_type("error");
  REQUIRE(errors.size() == 1);
  CHECK(errors[0].data["kind"] == "publish");
}

TEST_CASE("FrameRun: an unreadable persisted state reads nothing", "[daemon][frame_run]") {
  Rig r;
  const auto a = test::write_pass(r.watched("a"), "a", 1);
  REQUIRE(r.run({a}).result == FrameRun::Result::done);
  const FrameRecord first = r.committed.at(0);
  test::flip_byte(r.store.state_path("j1", 1), 100);  // in the statistics; no earlier state
  const auto b = test::write_pass(r.watched("b"), "b", 2);
  const auto out = r.run({b}, first, true);
  CHECK(out.result == FrameRun::Result::state_unreadable);
  CHECK_THAT(out.error, Catch::Contains("checksum"));
  CHECK(r.committed.size() == 1);
  CHECK(r.failed.empty());
}

TEST_CASE("FrameRun: a damaged state falls back to the last good one, and says so",
          "[daemon][frame_run]") {
  Rig r;
  const auto a = test::write_pass(r.watched("a"), "a", 1);
  REQUIRE(r.run({a}).result == FrameRun::Result::done);
  const auto b = test::write_pass(r.store.upload_dir("j1", 1) / "b.exr", "b", 2, true);
  REQUIRE(r.run({b}, r.committed.at(0), true).result == FrameRun::Result::done);
  const FrameRecord second = r.committed.at(1);
  CHECK_FALSE(fs::exists(b.path));  // kept aside, backing the last good state
  CHECK(fs::exists(r.store.kept_dir("j1", 1) / "b.exr"));
  test::flip_byte(r.store.state_path("j1", 1), -100);
  std::vector<FrameRecord> recovered;
  r.on_recovered = [&](const FrameRecord& g) { recovered.push_back(g); };
  const auto c = test::write_pass(r.watched("c"), "c", 3);
  const auto out = r.run({c}, second, true);
  REQUIRE(out.result == FrameRun::Result::done);
  REQUIRE(recovered.size() == 1);
  CHECK(recovered[0].passes == 1);   // the state before b
  CHECK(recovered[0].version == 2);  // versions never go back
  REQUIRE(r.committed.size() == 3);
  CHECK(r.committed[2].passes == 2);  // a + c; b is for the engine to read again
  CHECK(r.committed[2].version == 3);
  const auto errors = r.events->of_type("error");
  REQUIRE(errors.size() == 1);
  CHECK(errors[0].data["kind"] == "corrupt_state");
  CHECK_THAT(errors[0].data["message"].get<std::string>(), Catch::Contains("last good state"));
  CHECK(fs::exists(r.store.job_dir("j1") / "frames" / "1.corrupt"));  // kept for inspection
}

TEST_CASE("FrameRun: a persisted but unpublished version is published again",
          "[daemon][frame_run]") {
  Rig r;
  const auto a = test::write_pass(r.watched("a"), "a", 1);
  REQUIRE(r.run({a}).result == FrameRun::Result::done);
  const FrameRecord first = r.committed.at(0);
  fs::remove(output_base(r.spec, 1).string() + ".exr");
  const auto out = r.run({}, first, true, true);
  CHECK(out.result == FrameRun::Result::done);
  CHECK(r.committed.size() == 1);  // nothing new committed
  CHECK(r.published == std::vector<std::uint64_t>{1, 1});
  CHECK(fs::exists(output_base(r.spec, 1).string() + ".exr"));
}

TEST_CASE("FrameRun: an unpublished version is published as itself before new passes",
          "[daemon][frame_run]") {
  // The soak's finding (bench/soak.py): killed between commit and publish, the daemon restarted
  // with new passes waiting merged them into the next version, so the committed version was
  // never published, recorded in the history or announced.
  Rig r;
  r.fault = [](const std::string& op, const fs::path&) {
    if (op == "publish") throw std::runtime_error("killed before the publish (simulated)");
  };
  const auto a = test::write_pass(r.watched("a"), "a", 1);
  const auto first = r.run({a});
  REQUIRE(first.result == FrameRun::Result::failed);
  REQUIRE(first.committed);
  REQUIRE(r.published.empty());
  r.fault = nullptr;
  const auto b = test::write_pass(r.watched("b"), "b", 2);
  const auto out = r.run({b}, r.committed.at(0), true, true);
  REQUIRE(out.result == FrameRun::Result::done);
  CHECK(r.published == std::vector<std::uint64_t>{1, 2});
  REQUIRE(r.committed.size() == 2);
  CHECK(r.committed[1].version == 2);
  CHECK(r.committed[1].passes == 2);
  const auto frames = r.events->of_type("frame");
  REQUIRE(frames.size() == 2);
  CHECK(frames[0].data["version"] == 1);
  CHECK(frames[0].data["passes"] == 1);
  CHECK(frames[0].data["new_passes"] == 0);
  CHECK(frames[1].data["version"] == 2);
  CHECK(frames[1].data["new_passes"] == 1);
  const auto history = FrameHistory::load(r.store.history_path("j1", 1));
  REQUIRE(history.size() == 2);
  CHECK(history[0]["version"] == 1);
  CHECK(history[1]["version"] == 2);
}

TEST_CASE("FrameRun: a version is in the history before it is recorded as published",
          "[daemon][frame_run]") {
  // Killed after the outputs are written but before the version is recorded as published, the
  // version is published again on restart; its history line must not depend on the second try
  // (the soak's clients resume from the history what an event lost with the process missed).
  Rig r;
  r.fault = [](const std::string& op, const fs::path&) {
    if (op == "published") throw std::runtime_error("killed before .pub (simulated)");
  };
  const auto a = test::write_pass(r.watched("a"), "a", 1);
  REQUIRE(r.run({a}).result == FrameRun::Result::failed);
  REQUIRE(r.published.empty());
  auto history = FrameHistory::load(r.store.history_path("j1", 1));
  REQUIRE(history.size() == 1);
  CHECK(history[0]["version"] == 1);
  r.fault = nullptr;
  REQUIRE(r.run({}, r.committed.at(0), true, true).result == FrameRun::Result::done);
  CHECK(r.published == std::vector<std::uint64_t>{1});
  history = FrameHistory::load(r.store.history_path("j1", 1));
  CHECK(history.size() == 1);  // one line per version
  const auto frames = r.events->of_type("frame");
  REQUIRE(frames.size() == 1);
  CHECK(frames[0].data["version"] == 1);
}

TEST_CASE("FrameRun: output.compression auto writes uncompressed and asks for compression later",
          "[daemon][frame_run]") {
  // The published EXR's compression, as OpenEXR stored it.
  const auto compression_of = [](const std::string& exr) {
    auto in = OIIO::ImageInput::open(exr);
    REQUIRE(in);
    return in->spec().get_string_attribute("compression");
  };
  for (const std::string c : {"auto", "piz", "zip", "none"}) {
    CAPTURE(c);
    Rig r;
    r.spec.output.compression = c;
    const auto p = test::write_pass(r.watched("1"), "1", 1);
    REQUIRE(r.run({p}).result == FrameRun::Result::done);
    const std::string exr = output_base(r.spec, 1).string() + ".exr";
    CHECK(compression_of(exr) == (c == "auto" ? "none" : c));
    // The version's kept copy is the same file.
    CHECK(fs::equivalent(exr, version_file(r.spec, 1, 1)));
    REQUIRE(r.compress_later.size() == 1);
    CHECK(r.compress_later[0] == (c == "auto"));
    const std::string text = r.metrics.render();
    CHECK((text.find("proden_publish_uncompressed_total 1") != std::string::npos) == (c == "auto"));
  }
}
