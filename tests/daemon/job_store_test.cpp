// JobStore: the state directory's layout, atomic saves and what start-up recovers.
#include <catch2/catch.hpp>

#include <fstream>
#include <set>
#include <system_error>

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

auto ignore_corrupt = [](long, const std::string&) {};

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
  CHECK(store.load_frame("j1", 7).acc.state_digest() == acc.state_digest());
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
    got.insert(std::make_pair(frame, p.pass));
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
  const auto loaded =
      store.load_job(store.job_dir("j1"), [&](long, const std::string&) { ++corrupt; });
  REQUIRE(loaded);
  CHECK(corrupt == 1);
  CHECK(loaded->frames.empty());
  CHECK(fs::exists(store.state_path("j1", 5).string() + ".corrupt"));
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
  CHECK(ops == std::vector<std::string>{"job", "fsync_dir", "state", "published"});
  fail_state = true;
  const FrameAccumulator acc2 = one_pass_frame(4);
  CHECK_THROWS_WITH(store.save_frame("j1", record_of(1, acc2, "00"), acc2),
                    Catch::Contains("disk full"));
  CHECK(store.load_frame("j1", 1).acc.state_digest() == acc.state_digest());  // old state intact
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

TEST_CASE("JobStore: a job whose job.json is missing but which holds state is kept",
          "[daemon][job_store][regression]") {
  test::TempDir t;
  JobStore store(t.path() / "state");
  store.create_job(spec_for(t, "j1"));
  const FrameAccumulator acc = one_pass_frame(5);
  store.save_frame("j1", record_of(1, acc, "00"), acc);
  touch(store.upload_dir("j1", 2) / "a.exr");
  fs::remove(store.job_dir("j1") / "job.json");
  CHECK_THROWS(store.load_job(store.job_dir("j1"), ignore_corrupt));
  CHECK(fs::exists(store.state_path("j1", 1)));
  CHECK(fs::exists(store.upload_dir("j1", 2) / "a.exr"));
}

TEST_CASE("JobStore: a job.json that cannot be opened leaves the job alone",
          "[daemon][job_store][regression]") {
  test::TempDir t;
  JobStore store(t.path() / "state", [](const std::string& op, const fs::path&) {
    if (op == "open_job") throw std::system_error(EMFILE, std::generic_category(), "open");
  });
  store.create_job(spec_for(t, "j1"));
  CHECK_THROWS(store.load_job(store.job_dir("j1"), ignore_corrupt));
  CHECK(fs::exists(store.job_dir("j1") / "job.json"));
}

TEST_CASE("JobStore: an interrupted job creation (nothing but empty directories) is removed",
          "[daemon][job_store]") {
  test::TempDir t;
  JobStore store(t.path() / "state");
  fs::create_directories(store.job_dir("j2") / "frames");
  fs::create_directories(store.job_dir("j2") / "uploads");
  CHECK_FALSE(store.load_job(store.job_dir("j2"), ignore_corrupt));
  CHECK_FALSE(fs::exists(store.job_dir("j2")));
}

TEST_CASE("JobStore: an upload's directory entries are durable before it is acknowledged",
          "[daemon][job_store][regression]") {
  test::TempDir t;
  std::vector<std::pair<std::string, fs::path>> ops;
  JobStore store(t.path() / "state",
                 [&](const std::string& op, const fs::path& p) { ops.emplace_back(op, p); });
  store.create_job(spec_for(t, "j1"));
  ops.clear();
  const fs::path tmp = store.spool_upload("j1", 2, "07", "body");
  const fs::path final_path = store.commit_upload(tmp, "j1", 2, "07");
  // The new frame directory's entry in uploads/ is synced, and the final name's entry after the
  // rename.
  auto at = [&](const std::string& op, const fs::path& p) {
    for (std::size_t i = 0; i < ops.size(); ++i) {
      if (ops[i].first == op && ops[i].second == p) return static_cast<long>(i);
    }
    return -1L;
  };
  CHECK(at("fsync_dir", store.job_dir("j1") / "uploads") >= 0);
  const long renamed = at("upload", final_path);
  const long synced = at("fsync_dir", store.upload_dir("j1", 2));
  REQUIRE(renamed >= 0);
  CHECK(synced > renamed);
}

TEST_CASE("JobStore: a record quoting invalid UTF-8 is still saved and read back",
          "[daemon][job_store]") {
  test::TempDir t;
  JobStore store(t.path() / "state");
  store.create_job(spec_for(t, "j1"));
  const FrameAccumulator acc = one_pass_frame(6);
  FrameRecord r = record_of(1, acc, "00");
  r.ingested[0].source = std::string("/w/\xff\xfe/00.exr");  // bytes from a file system
  REQUIRE_NOTHROW(store.save_frame("j1", r, acc));
  const auto back = store.load_frame("j1", 1);
  CHECK(back.acc.state_digest() == acc.state_digest());
  CHECK(back.record.ingested.at(0).pass == "00");
}

TEST_CASE("JobStore: a damaged quarantine.json costs its records, not the job",
          "[daemon][job_store]") {
  test::TempDir t;
  JobStore store(t.path() / "state");
  store.create_job(spec_for(t, "j1"));
  touch(store.job_dir("j1") / "quarantine.json", "[{\"frame\": 3, \"pass\": \"a\"");  // cut off
  const auto loaded = store.load_job(store.job_dir("j1"), ignore_corrupt);
  REQUIRE(loaded);
  CHECK(loaded->spec.id == "j1");
  CHECK(loaded->quarantine == nlohmann::json::array());
}
