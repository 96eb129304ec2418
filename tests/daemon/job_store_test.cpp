// JobStore: the state directory's layout, atomic saves and what start-up recovers.
#include <catch2/catch.hpp>

#include <fstream>
#include <set>

#include "daemon/job_store.hpp"
#include "test_support.hpp"

namespace fs = std::filesystem;
using namespace proden;
using namespace proden::daemon;

namespace {

protocol::JobSpec spec_for(const test::TempDir& t, const std::string& id) {
  protocol::JobSpec s;
  s.id = id;
  s.name = "shot_" + id;
  s.output.dir = (t.path() / "out").string();
  s.created = "2026-01-01T00:00:00.000Z";
  return s;
}

void touch(const fs::path& p, const std::string& text = "x") {
  fs::create_directories(p.parent_path());
  std::ofstream(p) << text;
}

FrameAccumulator one_pass_frame(std::uint64_t seed) {
  FrameAccumulator acc;
  acc.add(test::make_pass(8, 6, 4.0, seed), "00");
  return acc;
}

FrameRecord record_of(long frame, const FrameAccumulator& acc, const std::string& pass) {
  FrameRecord r;
  r.frame = frame;
  r.version = 1;
  r.passes = acc.passes();
  r.spp = acc.total_spp();
  r.width = acc.width();
  r.height = acc.height();
  r.digest = acc.state_digest();
  r.ingested.push_back({pass, "/x/" + pass + ".exr", 10, 20, 30});
  return r;
}

auto ignore_corrupt = [](const std::string&) {};

}  // namespace

TEST_CASE("JobStore: a created job loads back with its spec", "[daemon][job_store]") {
  test::TempDir t;
  JobStore store(t.path() / "state");
  const auto spec = spec_for(t, "j1");
  store.create_job(spec);
  CHECK(fs::is_directory(store.job_dir("j1") / "frames"));
  CHECK(fs::is_directory(store.job_dir("j1") / "uploads"));
  const auto loaded = store.load_job(store.job_dir("j1"), ignore_corrupt);
  REQUIRE(loaded);
  CHECK(loaded->spec.id == "j1");
  CHECK(loaded->spec.name == spec.name);
  CHECK(loaded->spec.output.dir == spec.output.dir);
  CHECK(loaded->frames.empty());
  CHECK(loaded->uploads.empty());
}

TEST_CASE("JobStore: frame state and published version round-trip", "[daemon][job_store]") {
  test::TempDir t;
  JobStore store(t.path() / "state");
  store.create_job(spec_for(t, "j1"));
  const FrameAccumulator acc = one_pass_frame(1);
  store.save_frame("j1", record_of(7, acc, "00"), acc);
  store.save_published("j1", 7, 1);
  CHECK(store.load_frame("j1", 7).state_digest() == acc.state_digest());
  const auto loaded = store.load_job(store.job_dir("j1"), ignore_corrupt);
  REQUIRE(loaded);
  REQUIRE(loaded->frames.size() == 1);
  CHECK(loaded->frames[0].record.frame == 7);
  CHECK(loaded->frames[0].record.digest == acc.state_digest());
  CHECK(loaded->frames[0].published_version == 1);
}

TEST_CASE("JobStore: stored uploads are recovered, accumulated ones cleaned up",
          "[daemon][job_store]") {
  test::TempDir t;
  JobStore store(t.path() / "state");
  store.create_job(spec_for(t, "j1"));
  const FrameAccumulator acc = one_pass_frame(2);
  store.save_frame("j1", record_of(3, acc, "00"), acc);
  touch(store.upload_dir("j1", 3) / "00.exr");        // in the state: clean-up was lost
  touch(store.upload_dir("j1", 3) / "01.exr");        // waiting
  touch(store.upload_dir("j1", 4) / "a.exr");         // waiting, other frame
  touch(store.upload_dir("j1", 4) / ".check.b.exr");  // interrupted upload
  const auto loaded = store.load_job(store.job_dir("j1"), ignore_corrupt);
  REQUIRE(loaded);
  std::set<std::pair<long, std::string>> got;
  for (const auto& [frame, p] : loaded->uploads) {
    got.insert({frame, p.pass});
    CHECK(p.upload);
    CHECK(p.size == 1);
  }
  CHECK(got == std::set<std::pair<long, std::string>>{{3, "01"}, {4, "a"}});
  CHECK_FALSE(fs::exists(store.upload_dir("j1", 3) / "00.exr"));
  CHECK_FALSE(fs::exists(store.upload_dir("j1", 4) / ".check.b.exr"));
}

TEST_CASE("JobStore: an unreadable frame state is moved aside and reported",
          "[daemon][job_store]") {
  test::TempDir t;
  JobStore store(t.path() / "state");
  store.create_job(spec_for(t, "j1"));
  touch(store.state_path("j1", 5), "not a state file");
  int corrupt = 0;
  const auto loaded = store.load_job(store.job_dir("j1"), [&](const std::string&) { ++corrupt; });
  REQUIRE(loaded);
  CHECK(corrupt == 1);
  CHECK(loaded->frames.empty());
  CHECK(fs::exists(fs::path(store.state_path("j1", 5)).replace_extension(".corrupt")));
}

TEST_CASE("JobStore: temp files of interrupted writes are removed at load", "[daemon][job_store]") {
  test::TempDir t;
  JobStore store(t.path() / "state");
  const auto spec = spec_for(t, "j1");
  store.create_job(spec);
  touch(store.job_dir("j1") / "frames" / ".3.state.tmp123.4");
  touch(fs::path(spec.output.dir) / (".shot_j1_0003.exr.tmp99"));
  touch(fs::path(spec.output.dir) / "shot_j1_0003.exr");
  REQUIRE(store.load_job(store.job_dir("j1"), ignore_corrupt));
  CHECK_FALSE(fs::exists(store.job_dir("j1") / "frames" / ".3.state.tmp123.4"));
  CHECK_FALSE(fs::exists(fs::path(spec.output.dir) / ".shot_j1_0003.exr.tmp99"));
  CHECK(fs::exists(fs::path(spec.output.dir) / "shot_j1_0003.exr"));
}

TEST_CASE("JobStore: the write hook sees each write and can fail it", "[daemon][job_store]") {
  test::TempDir t;
  std::vector<std::string> ops;
  bool fail_state = false;
  JobStore store(t.path() / "state", [&](const std::string& op, const fs::path&) {
    ops.push_back(op);
    if (op == "state" && fail_state) throw std::runtime_error("disk full (simulated)");
  });
  store.create_job(spec_for(t, "j1"));
  const FrameAccumulator acc = one_pass_frame(3);
  store.save_frame("j1", record_of(1, acc, "00"), acc);
  store.save_published("j1", 1, 1);
  CHECK(ops == std::vector<std::string>{"job", "state", "published"});
  fail_state = true;
  const FrameAccumulator acc2 = one_pass_frame(4);
  CHECK_THROWS_WITH(store.save_frame("j1", record_of(1, acc2, "00"), acc2),
                    Catch::Contains("disk full"));
  CHECK(store.load_frame("j1", 1).state_digest() == acc.state_digest());  // old state intact
}

TEST_CASE("JobStore: an upload is spooled, then committed under its pass name",
          "[daemon][job_store]") {
  test::TempDir t;
  JobStore store(t.path() / "state");
  store.create_job(spec_for(t, "j1"));
  const fs::path tmp = store.spool_upload("j1", 2, "07", "body bytes");
  CHECK(fs::exists(tmp));
  CHECK(tmp.filename().string().front() == '.');  // a temp name: never taken for an upload
  const fs::path final_path = store.commit_upload(tmp, "j1", 2, "07");
  CHECK(final_path == store.upload_dir("j1", 2) / "07.exr");
  CHECK_FALSE(fs::exists(tmp));
  std::ifstream in(final_path);
  std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  CHECK(text == "body bytes");
}
