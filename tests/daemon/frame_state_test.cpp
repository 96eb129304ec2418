// The frame-state file (daemon/frame_state.hpp): the pass identities its record lists (written as
// text one by one) read back as the record's JSON form says, for any strings; format 4's layout,
// its two-step writer, and the states of formats 1 to 3 still loading.
#include <catch2/catch.hpp>

#include <cstring>
#include <filesystem>
#include <fstream>
#include <string>

#include "daemon/files.hpp"
#include "daemon/frame_state.hpp"
#include "daemon_support.hpp"
#include "proden/hash.hpp"

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

// A frame of two passes "a" and "b".
FrameAccumulator two_passes(int width, int height) {
  FrameAccumulator acc;
  acc.add(test::make_pass(width, height, 2.0, 3), "a");
  acc.add(test::make_pass(width, height, 2.0, 4), "b");
  return acc;
}

// The accumulator's blob as daemons before format 4 wrote it: version 3, hash_bytes checksum.
std::vector<std::uint8_t> legacy_blob(const FrameAccumulator& acc) {
  std::vector<std::uint8_t> b = acc.serialize();
  b[7] = 3;
  const std::size_t body = b.size() - 8;
  const std::uint64_t h = hash_bytes({b.data(), body}, 0x61636373746174);
  std::memcpy(b.data() + body, &h, sizeof h);
  return b;
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
  const FrameAccumulator acc = two_passes(16, 8);
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

TEST_CASE("Frame state: version 4 puts the statistics first and covers every byte",
          "[daemon][state]") {
  const FrameAccumulator acc = two_passes(6, 4);
  const FrameRecord r = record_with({{"a", "/r/a.exr", 10, 11, 12}}, acc);
  const auto bytes = frame_state_bytes(r, acc);
  REQUIRE(std::string(bytes.begin(), bytes.begin() + 8) == "PRDNFRS4");
  std::uint64_t m = 0, n = 0;
  std::memcpy(&m, bytes.data() + 8, 8);
  std::memcpy(&n, bytes.data() + bytes.size() - 16, 8);
  CHECK(m == acc.serialize().size());  // no AOVs: the blob is the accumulator
  CHECK(16 + m + 8 + n + 16 == bytes.size());
  const std::string text(bytes.begin() + static_cast<std::ptrdiff_t>(24 + m),
                         bytes.begin() + static_cast<std::ptrdiff_t>(24 + m + n));
  CHECK(json::parse(text).at("frame") == 7);
  FrameRecord back;
  CHECK(parse_frame_state(bytes, "7.state", &back).state_digest() == acc.state_digest());
  // One flipped bit anywhere (head, statistics, their hash, record, sizes, record hash) is
  // refused, never read as another state.
  int refused = 0;
  for (std::size_t i = 0; i < bytes.size(); ++i) {
    auto bad = bytes;
    bad[i] ^= 0x10;
    try {
      parse_frame_state(bad, "7.state", nullptr);
    } catch (const std::exception&) {
      ++refused;
    }
  }
  CHECK(refused == static_cast<int>(bytes.size()));
}

TEST_CASE("Frame state: the record of a version 4 file is read from its end", "[daemon][state]") {
  test::TempDir t;
  FrameAccumulator acc;
  acc.add(test::make_pass(16, 8, 2.0, 3), "a");
  const FrameRecord r = record_with({{"a", "/r/a.exr", 10, 11, 12}}, acc);
  const auto path = t.path() / "7.state";
  save_frame_state(path, r, acc);
  CHECK(load_frame_record(path).ingested.size() == 1);
  test::flip_byte(path, -20);  // inside the record
  CHECK_THROWS(load_frame_record(path));
}

TEST_CASE("Frame state: states written in formats 2 and 3 still load, and are rewritten as 4",
          "[daemon][state]") {
  // Formats 2 and 3 as the daemons before format 4 wrote them (daemon/frame_state.hpp), every
  // hash hash_bytes, the record's digest too. Format 2: "PRDNFRS2", u64 n, the record,
  // u64 hash(record), u64 m, the blob, u64 hash of all before it. Format 3: "PRDNFRS3", u64 m,
  // the blob, u64 hash of all before it, the record, u64 n, u64 hash(record). (The committed
  // format-2 fuzz seeds predate the accumulator's current digest and are refused as damaged.)
  test::TempDir t;
  const FrameAccumulator acc = two_passes(6, 4);
  FrameRecord r = record_with({{"a", "/r/a.exr", 10, 11, 12}, {"b", "/r/b.exr", 1, 2, 3}}, acc);
  r.digest = acc.state_digest(HashKind::legacy);
  const std::vector<std::uint8_t> blob = legacy_blob(acc);
  json head = to_json(r);
  head["accumulator_bytes"] = blob.size();
  const std::string text = head.dump();
  const auto text_hash = [&text] {
    return hash_bytes({reinterpret_cast<const unsigned char*>(text.data()), text.size()}, 0x66726d);
  };
  for (const int format : {2, 3}) {
    INFO("format " << format);
    std::vector<std::uint8_t> old;
    auto put = [&old](const void* p, std::size_t n) {
      old.insert(old.end(), static_cast<const std::uint8_t*>(p),
                 static_cast<const std::uint8_t*>(p) + n);
    };
    auto put64 = [&put](std::uint64_t v) { put(&v, 8); };
    if (format == 2) {
      put("PRDNFRS2", 8);
      put64(text.size());
      put(text.data(), text.size());
      put64(text_hash());
      put64(blob.size());
      put(blob.data(), blob.size());
      put64(hash_bytes({old.data(), old.size()}, 0x66726d32));
    } else {
      put("PRDNFRS3", 8);
      put64(blob.size());
      put(blob.data(), blob.size());
      put64(hash_bytes({old.data(), old.size()}, 0x66726d32));
      put(text.data(), text.size());
      put64(text.size());
      put64(text_hash());
    }
    const auto path = t.path() / ("7." + std::to_string(format) + ".state");
    {
      std::ofstream f(path, std::ios::binary);
      f.write(reinterpret_cast<const char*>(old.data()), static_cast<std::streamsize>(old.size()));
    }
    CHECK(load_frame_record(path).ingested.size() == 2);
    FrameRecord rec;
    const FrameAccumulator back = load_frame_accumulator(path, &rec);
    CHECK(back.serialize() == acc.serialize());
    CHECK(to_json(rec).dump() == to_json(r).dump());
    // Rewritten (the frame's next commit, with the digest of today), it is format 4 and reads
    // back the same.
    rec.digest = back.state_digest();
    save_frame_state(path, rec, back);
    const auto again = read_file(path);
    REQUIRE(again);
    CHECK(std::string(again->begin(), again->begin() + 8) == "PRDNFRS4");
    FrameRecord rec2;
    CHECK(load_frame_accumulator(path, &rec2).serialize() == acc.serialize());
    CHECK(rec2.digest == acc.state_digest());
    CHECK(rec2.ingested.size() == 2);
    // A flipped byte in an old file is still refused.
    auto bad = old;
    bad[bad.size() / 2] ^= 0x10;
    CHECK_THROWS(parse_frame_state(bad, "7.state", nullptr));
  }
}

TEST_CASE("Frame state: the statistics are durable before the commit, the file only after it",
          "[daemon][state]") {
  test::TempDir t;
  FrameAccumulator acc;
  acc.add(test::make_pass(16, 8, 2.0, 3), "a");
  FrameRecord r = record_with({{"a", "/r/a.exr", 10, 11, 12}}, acc);
  const auto path = t.path() / "7.state";
  auto temps = [&t] {
    int n = 0;
    for (const auto& e : std::filesystem::directory_iterator(t.path())) {
      n += e.path().filename().string().find(".tmp") != std::string::npos;
    }
    return n;
  };
  {
    FrameStateWriter w(path, acc, {});
    CHECK(w.digest() == acc.state_digest());  // the statistics are written by now
    CHECK(temps() == 1);
    CHECK_FALSE(std::filesystem::exists(path));
    r.digest = w.digest();
    w.commit(r);
    CHECK(temps() == 0);
  }
  CHECK(load_frame_record(path).version == r.version);
  // Abandoned (the pipeline failed, or the passes were refused): no temp file is left and the
  // committed state is untouched.
  const auto before = read_file(path);
  acc.add(test::make_pass(16, 8, 2.0, 4), "b");
  {
    FrameStateWriter w(path, acc, {});
    CHECK(w.digest() == acc.state_digest());
  }
  CHECK(temps() == 0);
  CHECK(read_file(path) == before);
  // A record that does not describe the statistics written is refused, not committed.
  {
    FrameStateWriter w(path, acc, {});
    CHECK_THROWS(w.commit(r));  // r.digest is the one-pass state's
  }
  CHECK(read_file(path) == before);
  CHECK(temps() == 0);
}

TEST_CASE("Frame state: format-3 files a real daemon wrote load, and rewrite to the same state",
          "[daemon][state]") {
  // The fuzz seeds written by `proden serve` from cropped sample passes (fuzz/README.md), with
  // the accumulator's format v2 inside and every hash hash_bytes: rewritten as format 4, the
  // statistics are the same (digest) and only the accumulator's format byte, its quarters flag
  // (none), the hashes and the record's digest are new.
  for (const char* name : {"v3_cycles_6x4_2passes.state", "v3_povray_5x3_2passes.state"}) {
    INFO(name);
    const auto path =
        std::filesystem::path(PRODEN_SOURCE_DIR) / "fuzz" / "corpus" / "frame_state" / name;
    const auto bytes = read_file(path);
    REQUIRE(bytes);
    FrameRecord rec;
    AovAccumulator aovs;
    const FrameAccumulator acc = parse_frame_state(*bytes, name, &rec, &aovs);
    CHECK(rec.passes == 2);
    CHECK(acc.passes() == 2);
    CHECK(load_frame_record(path).digest == rec.digest);
    CHECK(acc.state_digest(HashKind::legacy) == rec.digest);
    CHECK_FALSE(acc.quarters());
    const std::string old_digest = std::to_string(rec.digest);
    rec.digest = acc.state_digest();
    const std::string new_digest = std::to_string(rec.digest);
    const auto rewritten = frame_state_bytes(rec, acc, aovs);
    // One byte more in the blob (the quarters flag), and the digest's decimal digits.
    CHECK(rewritten.size() == bytes->size() + 1 + new_digest.size() - old_digest.size());
    FrameRecord rec2;
    AovAccumulator aovs2;
    const FrameAccumulator again = parse_frame_state(rewritten, name, &rec2, &aovs2);
    CHECK(again.state_digest() == rec.digest);
    CHECK(again.state_digest(HashKind::legacy) == load_frame_record(path).digest);
    CHECK(frame_state_bytes(rec2, again, aovs2) == rewritten);
  }
}

TEST_CASE("Frame state: a format-4 file a real daemon wrote loads, and rewrites to its own bytes",
          "[daemon][state]") {
  // fuzz/corpus/frame_state/v4_cycles_6x4_2passes.state: `proden serve` (main at 45acc74) fed two
  // 6x4 crops of samples/renders/cornell/pass_00.exr and pass_01.exr (oiiotool --cut 6x4+60+60).
  // Pins format 4 for the daemons after it, as the format-3 seeds pin format 3.
  const auto path = std::filesystem::path(PRODEN_SOURCE_DIR) / "fuzz" / "corpus" / "frame_state" /
                    "v4_cycles_6x4_2passes.state";
  const auto bytes = read_file(path);
  REQUIRE(bytes);
  REQUIRE(std::string(bytes->begin(), bytes->begin() + 8) == "PRDNFRS4");
  FrameRecord rec;
  AovAccumulator aovs;
  const FrameAccumulator acc = parse_frame_state(*bytes, "v4", &rec, &aovs);
  CHECK(rec.passes == 2);
  CHECK(acc.passes() == 2);
  CHECK(rec.renderer == "cycles");
  CHECK(acc.state_digest() == rec.digest);
  CHECK(acc.state_digest(HashKind::legacy) != rec.digest);
  CHECK(load_frame_record(path).digest == rec.digest);
  CHECK(frame_state_bytes(rec, acc, aovs) == *bytes);
}
