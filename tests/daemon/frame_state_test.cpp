// The frame-state file's record: the pass identities it lists (written as text one by one, see
// daemon/frame_state.cpp) read back as the JSON form of the record says, for any strings.
#include <catch2/catch.hpp>

#include <string>

#include "daemon/files.hpp"
#include "daemon/frame_state.hpp"
#include "daemon_support.hpp"

using namespace proden;
using namespace proden::daemon;
using nlohmann::json;

namespace {

FrameRecord record_with(const std::vector<protocol::PassIdentity>& ids,
                        const FrameAccumulator& acc) {
  FrameRecord r;
  r.frame = 7;
  r.version = 3;
  r.passes = acc.passes();
  r.spp = acc.total_spp();
  r.digest = acc.state_digest();
  r.ingested = ids;
  return r;
}

}  // namespace

TEST_CASE("Frame state: every pass identity reads back as the record's JSON form says",
          "[daemon][state]") {
  FrameAccumulator acc;
  acc.add(test::make_pass(4, 4, 1.0, 1), "a");
  std::vector<protocol::PassIdentity> ids;
  const std::vector<std::string> awkward = {
      "plain",
      "quote\" and backslash\\",
      std::string("control \x01\x1f\n\t", 12),
      "unicode \xc3\xa9\xe2\x82\xac",
      "invalid \xff\xfe utf-8",
      "",
  };
  for (std::size_t i = 0; i < awkward.size(); ++i) {
    ids.push_back({"p" + std::to_string(i), "/renders/" + awkward[i] + ".exr", 1000 + i,
                   -5 - static_cast<std::int64_t>(i), 0xffffffffffffffffull - i});
  }
  for (int i = 0; i < 3000; ++i) {  // a long list: one text, no tree of it
    ids.push_back({"pass_" + std::to_string(i), "/renders/f7/pass_" + std::to_string(i) + ".exr",
                   static_cast<std::uint64_t>(i) * 4096, 1700000000000000000 + i,
                   static_cast<std::uint64_t>(i) * 0x9e3779b97f4a7c15ull});
  }
  const FrameRecord r = record_with(ids, acc);
  const auto bytes = frame_state_bytes(r, acc);
  FrameRecord back;
  parse_frame_state(bytes, "7.state", &back);

  // What the JSON form of the record (invalid UTF-8 replaced) reads back as.
  const FrameRecord expected = frame_record_from_json(
      json::parse(to_json(r).dump(-1, ' ', false, json::error_handler_t::replace)));
  REQUIRE(back.ingested.size() == ids.size());
  for (std::size_t i = 0; i < ids.size(); ++i) {
    INFO("identity " << i);
    CHECK(back.ingested[i].pass == expected.ingested[i].pass);
    CHECK(back.ingested[i].source == expected.ingested[i].source);
    CHECK(back.ingested[i].size == ids[i].size);
    CHECK(back.ingested[i].mtime_ns == ids[i].mtime_ns);
    CHECK(back.ingested[i].content_hash == ids[i].content_hash);
  }
  CHECK(back.ingested[1].source == ids[1].source);  // valid strings exactly as given
  CHECK(back.ingested[2].source == ids[2].source);
  CHECK(back.ingested[3].source == ids[3].source);
  CHECK(back.ingested[4].source != ids[4].source);  // invalid UTF-8: replaced, as before
  CHECK(back.version == 3);
  CHECK(back.digest == r.digest);

  // Written again, the same bytes: the text is a function of the record.
  CHECK(frame_state_bytes(back, acc) == frame_state_bytes(expected, acc));
}

TEST_CASE("Frame state: a record without passes still reads back", "[daemon][state]") {
  FrameAccumulator acc;
  acc.add(test::make_pass(4, 4, 1.0, 1), "a");
  const FrameRecord r = record_with({}, acc);
  FrameRecord back;
  parse_frame_state(frame_state_bytes(r, acc), "7.state", &back);
  CHECK(back.ingested.empty());
  CHECK(back.frame == 7);
}

TEST_CASE("Frame state: the file written in pieces holds exactly frame_state_bytes",
          "[daemon][state]") {
  test::TempDir t;
  FrameAccumulator acc;
  acc.add(test::make_pass(16, 8, 2.0, 3), "a");
  acc.add(test::make_pass(16, 8, 2.0, 4), "b");
  const FrameRecord r =
      record_with({{"a", "/r/a.exr", 10, 11, 12}, {"b", "/r/b.exr", 20, 21, 22}}, acc);
  const auto path = t.path() / "7.state";
  save_frame_state(path, r, acc);
  const auto on_disk = read_file(path, 1u << 30);
  REQUIRE(on_disk);
  CHECK(*on_disk == frame_state_bytes(r, acc));
  FrameRecord back;
  load_frame_accumulator(path, &back);
  CHECK(back.ingested.size() == 2);
}
