// Regression tests of issue 11's daemon defects, each against the in-process Engine (real files,
// real threads; a fake clock for the retry back-off; fault hooks where a disk fault is needed).
#include <catch2/catch.hpp>

#include <condition_variable>
#include <fstream>
#include <new>
#include <system_error>
#include <thread>

#include "daemon/frame_run.hpp"
#include "daemon_support.hpp"
#include "proden/protocol/api.hpp"

namespace fs = std::filesystem;
using namespace proden;
using namespace proden::daemon;
using test::EngineRig;
using test::eventually;
using namespace std::chrono_literals;

namespace {

int api_status(const std::function<void()>& f, std::string* message = nullptr) {
  try {
    f();
  } catch (const protocol::ApiError& e) {
    if (message) *message = e.what();
    return e.status();
  }
  return 0;
}

// The frame's status, or an empty one while the engine does not know the frame yet.
protocol::FrameStatus status_of(EngineRig& rig, const std::string& job, long frame) {
  try {
    return rig.engine->frame(job, frame);
  } catch (const protocol::ApiError&) {
    return {};
  }
}

std::vector<std::string> pass_names(const protocol::FrameStatus& f) {
  std::vector<std::string> out;
  for (const auto& p : f.pass_list) out.push_back(p.pass);
  return out;
}

}  // namespace

// ---- 8. self-ingestion -----------------------------------------------------------------------

TEST_CASE("Regression 8: published frames in the watch directory are not ingested",
          "[daemon][regression]") {
  EngineRig rig;
  SECTION("output dir = watch dir") {
    const fs::path w = rig.allowed() / "w";
    const auto job =
        rig.create("shot", protocol::WatchSpec{w.string(), "{pass}_{frame}.exr"}, w.string());
    test::write_pass(w / "a_0001.exr", "a", 1);
    REQUIRE(eventually([&] { return status_of(rig, job.id, 1).version >= 1; }));
    REQUIRE(fs::exists(w / "shot_0001.exr"));  // the published frame matches the pattern
    std::this_thread::sleep_for(800ms);        // several scans and settle times
    REQUIRE(rig.engine->wait_idle(20000));
    const auto f = rig.engine->frame(job.id, 1);
    CHECK(pass_names(f) == std::vector<std::string>{"a"});
    CHECK(f.quarantined.empty());
    CHECK(f.version == 1);
  }
  SECTION("output dir inside the watch dir") {
    const fs::path w = rig.allowed() / "w2";
    const auto job = rig.create("shot", protocol::WatchSpec{w.string(), "{pass}/shot_{frame}.exr"},
                                (w / "out").string());
    test::write_pass(w / "p1" / "shot_0003.exr", "p1", 1);
    REQUIRE(eventually([&] { return status_of(rig, job.id, 3).version >= 1; }));
    REQUIRE(fs::exists(w / "out" / "shot_0003.exr"));
    std::this_thread::sleep_for(800ms);
    REQUIRE(rig.engine->wait_idle(20000));
    CHECK(pass_names(rig.engine->frame(job.id, 3)) == std::vector<std::string>{"p1"});
  }
}

// ---- 9. absurd numbers -----------------------------------------------------------------------

TEST_CASE("Regression 9: an absurd spp is refused when the job is created",
          "[daemon][regression]") {
  EngineRig rig;
  protocol::JobSpec s;
  s.name = "big";
  s.output.dir = (rig.allowed() / "o").string();
  s.spp = 1e300;
  std::string why;
  CHECK(api_status([&] { rig.engine->create_job(s); }, &why) == 400);
  CHECK_THAT(why, Catch::StartsWith("spp"));
  CHECK(rig.engine->jobs().empty());
}

TEST_CASE("Regression 9: a pass with an absurd spp never poisons the frame's state",
          "[daemon][regression]") {
  test::TempDir t;
  JobStore store(t.path() / "state");
  Metrics metrics;
  EventHub hub(100);
  protocol::JobSpec spec = test::job_spec(t.path(), "j1", "auto");  // the full pipeline
  store.create_job(spec);
  std::vector<Failure> failed;
  std::vector<FrameRecord> committed;
  FrameRun::Hooks h;
  h.failed = [&](const PendingPass&, const Failure& f) { failed.push_back(f); };
  h.committed = [&](const FrameRecord& r, const auto&) { committed.push_back(r); };
  h.published = [](std::uint64_t, const auto&, bool) {};
  FrameRun run(store, metrics, hub, h);
  FrameRun::Input in;
  in.spec = spec;
  in.spec.spp = 1e300;  // as if the file's header claimed it
  in.frame = 1;
  in.batch = {test::write_pass(store.upload_dir("j1", 1) / "a.exr", "a", 1, true),
              test::write_pass(store.upload_dir("j1", 1) / "b.exr", "b", 2, true)};
  run.run(in);
  for (const auto& r : committed) {
    CHECK(std::isfinite(r.spp));
    CHECK(std::isfinite(r.estimated_mse));
  }
  // Whatever was persisted reads back.
  if (fs::exists(store.state_path("j1", 1))) {
    CHECK_NOTHROW(load_frame_record(store.state_path("j1", 1)));
    CHECK_NOTHROW(store.load_frame("j1", 1).acc);
  }
  REQUIRE(failed.size() == 2);
  CHECK(failed[0].kind == "invalid_value");
  CHECK(failed[0].cls == ErrorClass::bad_input);
  // The uploads are not lost: they stay for the quarantine listing.
  CHECK(fs::exists(store.upload_dir("j1", 1) / "a.exr"));
}

TEST_CASE("Regression 9: a non-finite number is never persisted", "[daemon][regression]") {
  test::TempDir t;
  FrameAccumulator acc;
  acc.add(test::make_pass(4, 4, 1.0, 1), "a");
  FrameRecord r;
  r.frame = 1;
  r.digest = acc.state_digest();
  r.estimated_mse = std::numeric_limits<double>::quiet_NaN();
  const fs::path p = t.path() / "1.state";
  CHECK_THROWS(save_frame_state(p, r, acc));
  CHECK_FALSE(fs::exists(p));
  r.estimated_mse = 0.5;
  r.spp = std::numeric_limits<double>::infinity();
  CHECK_THROWS(save_frame_state(p, r, acc));
  r.spp = 1.0;
  save_frame_state(p, r, acc);
  CHECK(load_frame_record(p).estimated_mse == 0.5);
}

// ---- 10. upload race and idempotency ---------------------------------------------------------

TEST_CASE("Regression 10: concurrent uploads of one pass never store the other's body",
          "[daemon][regression]") {
  EngineRig rig;
  const auto job = rig.create("race");
  rig.engine->set_paused(job.id, true);  // keep the stored upload on disk
  const std::string a = rig.pass_bytes(1, 16, 12), b = rig.pass_bytes(2, 20, 10);
  REQUIRE(a != b);
  // Both requests reach the point after spooling before either claims the pass.
  std::mutex mu;
  std::condition_variable cv;
  int spooled = 0;
  rig.fault = [&](const std::string& op, const fs::path&) {
    if (op != "spooled") return;
    std::unique_lock lock(mu);
    ++spooled;
    cv.notify_all();
    cv.wait_for(lock, 2s, [&] { return spooled >= 2; });
  };
  int status[2] = {0, 0};
  std::thread ta(
      [&] { status[0] = api_status([&] { rig.engine->upload(job.id, "1", "07", a); }); });
  std::thread tb(
      [&] { status[1] = api_status([&] { rig.engine->upload(job.id, "1", "07", b); }); });
  ta.join();
  tb.join();
  rig.fault = nullptr;
  INFO("statuses " << status[0] << " " << status[1]);
  REQUIRE(((status[0] == 0) != (status[1] == 0)));  // exactly one accepted
  CHECK((status[0] == 409 || status[1] == 409));
  const std::string& winner = status[0] == 0 ? a : b;
  const fs::path stored = rig.t.path() / "state" / "jobs" / job.id / "uploads" / "1" / "07.exr";
  CHECK(test::read_all(stored) == winner);
}

TEST_CASE("Regression 10: the same bytes again are idempotent, other bytes conflict",
          "[daemon][regression]") {
  EngineRig rig;
  const auto job = rig.create("idem");
  rig.engine->set_paused(job.id, true);
  const std::string a = rig.pass_bytes(1), b = rig.pass_bytes(2);
  auto first = rig.engine->upload(job.id, "1", "07", a);
  CHECK(first["status"] == "queued");
  auto again = rig.engine->upload(job.id, "1", "07", a);  // a retried request
  CHECK(again["status"] == "queued");
  CHECK(api_status([&] { rig.engine->upload(job.id, "1", "07", b); }) == 409);
  rig.engine->set_paused(job.id, false);
  REQUIRE(rig.engine->wait_idle(20000));
  CHECK(rig.engine->frame(job.id, 1).passes == 1);
  auto late = rig.engine->upload(job.id, "1", "07", a);
  CHECK(late["status"] == "ingested");
  CHECK(api_status([&] { rig.engine->upload(job.id, "1", "07", b); }) == 409);
  REQUIRE(rig.engine->wait_idle(20000));
  CHECK(rig.engine->frame(job.id, 1).passes == 1);
  CHECK(rig.metric("proden_uploads_total") == 1);
}

// ---- 11. a damaged frame state ---------------------------------------------------------------

TEST_CASE("Regression 11: a flipped byte in the statistics does not block the frame",
          "[daemon][regression]") {
  EngineRig rig;
  const auto job = rig.create("flip");
  rig.engine->upload(job.id, "1", "a", rig.pass_bytes(1));
  REQUIRE(rig.engine->wait_idle(20000));
  rig.engine->upload(job.id, "1", "b", rig.pass_bytes(2));
  REQUIRE(rig.engine->wait_idle(20000));
  REQUIRE(rig.engine->frame(job.id, 1).passes == 2);
  const auto version = rig.engine->frame(job.id, 1).version;
  const fs::path state = rig.t.path() / "state" / "jobs" / job.id / "frames" / "1.state";
  SECTION("damage in the statistics, found when the frame next runs") {
    rig.restart();                // drop the resident state: the next run reads the file
    test::flip_byte(state, 100);  // inside the accumulated statistics (format 3 starts with them)
  }
  SECTION("damage in the record, found at start-up") {
    rig.engine->stop();
    test::flip_byte(state, -40);  // inside the JSON record (format 3 ends with it)
    rig.restart();
  }
  rig.engine->upload(job.id, "1", "c", rig.pass_bytes(3));
  REQUIRE(eventually([&] {
    const auto f = status_of(rig, job.id, 1);
    return f.passes == 3 && !f.pending;
  }));
  const auto f = rig.engine->frame(job.id, 1);
  auto names = pass_names(f);
  std::sort(names.begin(), names.end());
  CHECK(names == std::vector<std::string>{"a", "b", "c"});
  CHECK(f.version > version);
  bool told = false;
  for (const auto& e : rig.events->of_type("error")) {
    if (e.data["kind"] == "corrupt_state" &&
        e.data["message"].get<std::string>().find("last good state") != std::string::npos) {
      told = true;
    }
  }
  CHECK(told);
  rig.restart();
  CHECK(rig.engine->frame(job.id, 1).passes == 3);
}

// ---- review findings -------------------------------------------------------------------------

TEST_CASE("Review: out of memory or an I/O error while reading retries, never quarantines",
          "[daemon][regression]") {
  EngineRig rig;
  const auto job = rig.create("oom");
  int faults = 0;
  std::exception_ptr fault;
  SECTION("out of memory") {
    fault = std::make_exception_ptr(std::bad_alloc());
  }
  SECTION("I/O error") {
    fault = std::make_exception_ptr(std::system_error(EIO, std::generic_category(), "read"));
  }
  SECTION("internal error") {
    fault = std::make_exception_ptr(std::logic_error("bug"));
  }
  rig.fault = [&](const std::string& op, const fs::path&) {
    if (op == "read" && faults++ == 0) std::rethrow_exception(fault);
  };
  rig.engine->upload(job.id, "1", "a", rig.pass_bytes(1));
  REQUIRE(rig.engine->wait_idle(20000));
  auto f = rig.engine->frame(job.id, 1);
  CHECK(f.quarantined.empty());
  CHECK(f.passes == 0);
  CHECK(f.pending);  // waiting for its retry
  rig.clock.advance(10min);
  REQUIRE(eventually([&] { return status_of(rig, job.id, 1).passes == 1; }));
  CHECK(rig.engine->frame(job.id, 1).quarantined.empty());
}

TEST_CASE("Review: a stored upload is retried after a failed save", "[daemon][regression]") {
  EngineRig rig;
  const auto job = rig.create("save");
  int faults = 0;
  rig.fault = [&](const std::string& op, const fs::path&) {
    if (op == "state" && faults++ == 0) throw std::runtime_error("no space left (simulated)");
  };
  rig.engine->upload(job.id, "1", "a", rig.pass_bytes(1));
  REQUIRE(rig.engine->wait_idle(20000));
  CHECK(rig.engine->frame(job.id, 1).passes == 0);
  CHECK(rig.engine->frame(job.id, 1).pending);
  rig.clock.advance(10min);
  REQUIRE(eventually([&] { return status_of(rig, job.id, 1).version == 1; }));
  CHECK(rig.engine->frame(job.id, 1).passes == 1);
}

TEST_CASE("Review: a failed publish is retried without a new pass", "[daemon][regression]") {
  EngineRig rig;
  const auto job = rig.create("pub");
  int faults = 0;
  rig.fault = [&](const std::string& op, const fs::path&) {
    if (op == "publish" && faults++ == 0) throw std::runtime_error("EIO (simulated)");
  };
  rig.engine->upload(job.id, "1", "a", rig.pass_bytes(1));
  REQUIRE(rig.engine->wait_idle(20000));
  CHECK(rig.engine->frame(job.id, 1).passes == 1);   // committed
  CHECK(rig.engine->frame(job.id, 1).version == 0);  // not published
  rig.clock.advance(10min);
  REQUIRE(eventually([&] { return status_of(rig, job.id, 1).version == 1; }));
  CHECK(fs::exists(output_base(job, 1).string() + ".exr"));
}

TEST_CASE("Review: pause and resume persist the job spec in order", "[daemon][regression]") {
  EngineRig rig;
  const auto job = rig.create("toggle");
  std::vector<std::thread> threads;
  for (int t = 0; t < 4; ++t) {
    threads.emplace_back([&, t] {
      for (int i = 0; i < 25; ++i) rig.engine->set_paused(job.id, (i + t) % 2 == 0);
    });
  }
  for (auto& th : threads) th.join();
  const bool paused = rig.engine->job(job.id).paused;
  const auto on_disk =
      nlohmann::json::parse(test::read_all(rig.t.path() / "state" / "jobs" / job.id / "job.json"));
  CHECK(on_disk["paused"].get<bool>() == paused);
  rig.restart();
  CHECK(rig.engine->job(job.id).paused == paused);
}

TEST_CASE("Review: a watched job resumes after a restart (engine and watcher locks)",
          "[daemon][regression]") {
  EngineRig rig;
  const fs::path w = rig.allowed() / "w";
  const auto job = rig.create("lock", protocol::WatchSpec{w.string(), "p{pass}_{frame}.exr"});
  test::write_pass(w / "pa_0001.exr", "a", 1);
  REQUIRE(eventually([&] { return status_of(rig, job.id, 1).passes == 1; }));
  rig.restart();
  test::write_pass(w / "pb_0001.exr", "b", 2);
  REQUIRE(eventually([&] { return status_of(rig, job.id, 1).passes == 2; }));
}
