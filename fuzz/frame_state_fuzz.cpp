// Fuzz target: a frame's state file (service/daemon/frame_state.hpp: "PRDNFRS4", the accumulator
// blob and its hashes, then the JSON record and its hash; versions 1 and 2 put the record first)
// parsed as the daemon loads it after a restart. Each input is parsed twice: as given (the checksum
// gates), and with both checksums recomputed so the mutations reach the record's fields and the
// statistics behind the gates.
//
// Properties: a state either parses or is refused with an exception (never a crash, never UB);
// an accepted state holds only finite numbers (record, pass history, statistics) and its digest
// matches its record (made with the hash of its format); written again (frame_state_bytes, with
// today's digest, as the daemon's next commit does) it reads back to the same record and the same
// statistics (issue 11, classes 9 and 11); its quarters are finite.
#include <cmath>
#include <cstdint>
#include <cstring>
#include <span>
#include <string>
#include <vector>

#include "daemon/frame_state.hpp"
#include "fuzz_check.hpp"
#include "proden/hash.hpp"

using namespace proden;
using namespace proden::daemon;

namespace {

// The checksums of the file format (daemon/frame_state.cpp: version 1 "PRDNFRS1" = magic, u64 n,
// record, u64 record hash, accumulator blob; version 2 "PRDNFRS2" = the same with the blob's
// length before it and a hash of the whole file after it; version 3 "PRDNFRS3" = magic, u64 m,
// blob, u64 hash of all before it, record, u64 n, u64 record hash; version 4 "PRDNFRS4" = version
// 3 with XXH3 for hash_bytes; the blob ends with its own checksum, XXH3 from its version 4 on,
// pipeline/src/accumulator_state.cpp). LLVMFuzzerInitialize proves them against a real state, so
// the harness cannot silently stop reaching past the gates if the format changes.
constexpr std::uint64_t kRecordSeed = 0x66726d;
constexpr std::uint64_t kFileSeed = 0x66726d32;
constexpr std::uint64_t kBlobSeed = 0x61636373746174;

void put64(std::vector<std::uint8_t>& b, std::size_t at, std::uint64_t v) {
  std::memcpy(b.data() + at, &v, sizeof v);
}

// The hash a file (by its magic) or a blob (by its version byte) is checked with.
HashKind file_kind(std::span<const std::uint8_t> b) {
  return b.size() >= 8 && std::memcmp(b.data(), "PRDNFRS4", 8) == 0 ? HashKind::xxh3
                                                                    : HashKind::legacy;
}

void fix_blob(std::vector<std::uint8_t>& b, std::size_t begin, std::size_t end) {
  if (end - begin < 16) return;
  const HashKind kind = b[begin + 7] >= 4 ? HashKind::xxh3 : HashKind::legacy;
  put64(b, end - 8, hash_with(kind, {b.data() + begin, end - 8 - begin}, kBlobSeed));
}

// Recomputes every checksum (and a version 2 blob length) where the layout allows; false if not.
bool fix_checksums(std::vector<std::uint8_t>& b) {
  if (b.size() < 16) return false;
  const bool v1 = std::memcmp(b.data(), "PRDNFRS1", 8) == 0;
  const bool v2 = std::memcmp(b.data(), "PRDNFRS2", 8) == 0;
  const bool v3 =
      std::memcmp(b.data(), "PRDNFRS3", 8) == 0 || std::memcmp(b.data(), "PRDNFRS4", 8) == 0;
  if (!v1 && !v2 && !v3) return false;
  const HashKind kind = file_kind(b);
  std::uint64_t n = 0;
  if (v3) {
    std::uint64_t m = 0;
    std::memcpy(&m, b.data() + 8, sizeof m);
    if (b.size() < 40 || m > b.size() - 40) return false;
    n = b.size() - 40 - m;
    fix_blob(b, 16, 16 + m);
    put64(b, 16 + m, hash_with(kind, {b.data(), 16 + m}, kFileSeed));
    put64(b, b.size() - 16, n);
    put64(b, b.size() - 8, hash_with(kind, {b.data() + 24 + m, n}, kRecordSeed));
    return true;
  }
  std::memcpy(&n, b.data() + 8, sizeof n);
  if (n > b.size() - 16 || b.size() - 16 - n < 8) return false;
  put64(b, 16 + n, hash_bytes({b.data() + 16, n}, kRecordSeed));
  if (v1) {
    fix_blob(b, 24 + n, b.size());
    return true;
  }
  if (b.size() - 24 - n < 16) return false;
  const std::size_t blob = 32 + n, end = b.size() - 8;
  put64(b, 24 + n, end - blob);
  fix_blob(b, blob, end);
  put64(b, end, hash_bytes({b.data(), end}, kFileSeed));
  return true;
}

void check_accepted(const FrameRecord& rec, const FrameAccumulator& acc, HashKind kind) {
  FUZZ_CHECK(std::isfinite(rec.estimated_mse));
  FUZZ_CHECK(std::isfinite(rec.spp));
  FUZZ_CHECK(acc.state_digest(kind) == rec.digest);
  FUZZ_CHECK(std::isfinite(acc.total_spp()));
  for (const auto& p : acc.history()) FUZZ_CHECK(std::isfinite(p.spp) && p.spp > 0.0);
  // Written again with today's digest (the next commit), it reads back the same. What the daemon
  // reports of a frame must be JSON it can write (issue 11, class 9): the record, digest aside.
  FrameRecord now = rec;
  now.digest = acc.state_digest();
  const std::string text = to_json(now).dump();
  const std::vector<std::uint8_t> again = frame_state_bytes(now, acc);
  FrameRecord rec2;
  const FrameAccumulator acc2 = parse_frame_state(again, "fuzz (rewritten)", &rec2);
  FUZZ_CHECK(acc2.state_digest() == acc.state_digest());
  FUZZ_CHECK(to_json(rec2).dump() == text);
  FUZZ_CHECK(acc2.serialize() == acc.serialize());
  // Its quarters (what NFOR's error estimate runs on) hold only finite numbers.
  const FrameEstimate e = acc.estimate({.halves = true, .features = true, .quarters = true});
  for (const auto* qs : {&e.quarter_mean, &e.quarter_variance, &e.quarter_albedo}) {
    for (const Image& q : *qs) {
      for (const float v : q.data()) FUZZ_CHECK(std::isfinite(v));
    }
  }
}

bool parse_and_check(std::span<const std::uint8_t> bytes) {
  FrameRecord rec;
  FrameAccumulator acc;
  try {
    acc = parse_frame_state(bytes, "fuzz", &rec);
  } catch (const std::exception& e) {
    fuzz::check_json_safe(io::printable(e.what()));
    return false;
  }
  check_accepted(rec, acc, file_kind(bytes));
  return true;
}

}  // namespace

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  // A real state of two tiny passes; its checksums spoiled and fixed must read back.
  FrameAccumulator acc;
  for (int k = 0; k < 2; ++k) {
    Pass p;
    p.colour = Image(3, 2, 3);
    for (std::size_t i = 0; i < p.colour.data().size(); ++i) {
      p.colour.data()[i] = 0.25f * static_cast<float>(i + k);
    }
    p.spp = 4.0;
    acc.add(p, "pass" + std::to_string(k));
  }
  FrameRecord rec;
  rec.frame = 1;
  rec.passes = 2;
  rec.spp = acc.total_spp();
  rec.digest = acc.state_digest();
  std::vector<std::uint8_t> bytes = frame_state_bytes(rec, acc);
  FUZZ_CHECK(parse_and_check(bytes));
  bytes[bytes.size() - 1] ^= 0x5a;  // the record's hash
  std::uint64_t m = 0;
  std::memcpy(&m, bytes.data() + 8, sizeof m);
  bytes[16 + m] ^= 0x5a;  // the blob's hash
  FUZZ_CHECK(!parse_and_check(bytes));
  FUZZ_CHECK(fix_checksums(bytes) && parse_and_check(bytes));
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  parse_and_check({data, size});
  std::vector<std::uint8_t> fixed(data, data + size);
  if (fix_checksums(fixed)) parse_and_check(fixed);
  return 0;
}
