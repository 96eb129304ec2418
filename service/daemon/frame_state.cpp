#include "daemon/frame_state.hpp"

#include <cmath>
#include <cstring>
#include <fstream>
#include <stdexcept>

#include "daemon/files.hpp"
#include "proden/hash.hpp"
#include "proden/protocol/json.hpp"

namespace proden::daemon {

using nlohmann::json;
namespace fs = std::filesystem;

namespace {

constexpr char kMagic[8] = {'P', 'R', 'D', 'N', 'F', 'R', 'S', '2'};
constexpr char kMagicV1[8] = {'P', 'R', 'D', 'N', 'F', 'R', 'S', '1'};
constexpr std::uint64_t kFileSeed = 0x66726d32;

std::uint64_t file_hash(std::span<const std::uint8_t> b) {
  return hash_bytes({b.data(), b.size()}, kFileSeed);
}

std::uint64_t text_hash(const std::string& s) {
  return hash_bytes({reinterpret_cast<const unsigned char*>(s.data()), s.size()}, 0x66726d);
}

// The record without its "ingested" list (see record_text).
json record_head(const FrameRecord& r) {
  return {{"frame", r.frame},
          {"estimated_error", r.estimated_error},
          {"renderer", r.renderer},
          {"view_layer", r.view_layer},
          {"view_layers", r.view_layers},
          {"aovs", r.aovs},
          {"convergence", r.convergence.persist()},
          {"versions", r.versions},
          {"version", r.version},
          {"updated", r.updated},
          {"estimated_mse", r.estimated_mse},
          {"estimated_mse_source", r.estimated_mse_source},
          {"passes", r.passes},
          {"spp", r.spp},
          {"width", r.width},
          {"height", r.height},
          {"inputs", r.inputs},
          {"variance_source", r.variance_source},
          {"low_confidence", r.low_confidence},
          {"digest", r.digest}};
}

// Invalid UTF-8 (a message quoting a file) is replaced, never a reason to fail the commit.
std::string dump_text(const json& j) {
  return j.dump(-1, ' ', false, json::error_handler_t::replace);
}

// The record as persisted: one pass identity per element of "ingested", written as text one by
// one rather than built as a JSON tree first. The list grows with every pass a frame has had and
// is written at every commit; a tree of it costs about ten small allocations per pass, which made
// the daemon's heap fragment in step with its passes (bench/results/soak.md).
std::string record_text(const FrameRecord& r, std::size_t accumulator_bytes) {
  json head = record_head(r);
  head["accumulator_bytes"] = accumulator_bytes;
  std::string text = dump_text(head);
  text.pop_back();  // the closing '}'
  text.reserve(text.size() + 24 + r.ingested.size() * 160);
  text += ",\"ingested\":[";
  for (std::size_t i = 0; i < r.ingested.size(); ++i) {
    const protocol::PassIdentity& p = r.ingested[i];
    if (i > 0) text += ',';
    text += "{\"pass\":";
    text += dump_text(json(p.pass));
    text += ",\"source\":";
    text += dump_text(json(p.source));
    text += ",\"size\":" + std::to_string(p.size);
    text += ",\"mtime_ns\":" + std::to_string(p.mtime_ns);
    text += ",\"content_hash\":" + std::to_string(p.content_hash);
    text += '}';
  }
  text += "]}";
  return text;
}

}  // namespace

json to_json(const FrameRecord& r) {
  json j = record_head(r);
  json ingested = json::array();
  for (const auto& p : r.ingested) ingested.push_back(protocol::to_json(p));
  j["ingested"] = std::move(ingested);
  return j;
}

FrameRecord frame_record_from_json(const json& j) {
  // Numbers checked, never cast blindly: a state holds only finite values in range (issue 11,
  // class 9; fuzz/frame_state_fuzz.cpp).
  const auto num = [&j]<class T>(const char* key, T& out) {
    out = protocol::checked_number<T>(j.at(key), std::string("frame state record: ") + key);
  };
  FrameRecord r;
  num("frame", r.frame);
  num("version", r.version);
  r.updated = j.at("updated").get<std::string>();
  num("estimated_mse", r.estimated_mse);
  r.estimated_mse_source = j.at("estimated_mse_source").get<std::string>();
  num("passes", r.passes);
  num("spp", r.spp);
  num("width", r.width);
  num("height", r.height);
  r.inputs = j.at("inputs").get<std::string>();
  r.variance_source = j.at("variance_source").get<std::string>();
  r.low_confidence = j.at("low_confidence").get<bool>();
  num("digest", r.digest);
  for (const auto& p : j.at("ingested")) r.ingested.push_back(protocol::pass_identity_from_json(p));
  // Keys added by issue 13 (absent in older states).
  r.estimated_error = j.value("estimated_error", json());
  r.renderer = j.value("renderer", "");
  r.view_layer = j.value("view_layer", "");
  r.view_layers = j.value("view_layers", std::vector<std::string>{});
  r.aovs = j.value("aovs", json::array());
  r.convergence = Convergence::restore(j.value("convergence", json()));
  r.versions = j.value("versions", std::vector<std::uint64_t>{});
  return r;
}

namespace {

// The file in four pieces, in order (see the header for the layout): the head (magic, the record
// and its hash, the blob's size), the accumulator, the renderer AOVs and the whole-file hash. The
// pieces are written one after the other rather than copied into one buffer first: a 1080p frame
// with features holds a few hundred MB of statistics, and a single buffer of the file would
// double the daemon's peak memory at every commit (bench/results/daemon.md).
struct StatePieces {
  std::vector<std::uint8_t> head, accumulator, aovs;
  std::uint64_t hash = 0;
};

StatePieces state_pieces(const FrameRecord& record, const FrameAccumulator& frame,
                         const AovAccumulator& aovs) {
  for (const auto& [name, v] :
       {std::pair{"spp", record.spp}, {"estimated_mse", record.estimated_mse}}) {
    if (!std::isfinite(v)) {
      throw std::invalid_argument(std::string("refusing to persist a non-finite ") + name);
    }
  }
  StatePieces p;
  // The blob: the accumulator, then the renderer AOVs (issue 13); the record says where it splits.
  p.accumulator = frame.serialize();
  p.aovs = aovs.serialize();
  const std::string text = record_text(record, p.accumulator.size());
  auto put = [&p](const void* data, std::size_t n) {
    const auto* b = static_cast<const std::uint8_t*>(data);
    p.head.insert(p.head.end(), b, b + n);
  };
  auto put64 = [&put](std::uint64_t v) { put(&v, sizeof v); };
  p.head.reserve(sizeof kMagic + 24 + text.size());
  put(kMagic, sizeof kMagic);
  put64(text.size());
  put(text.data(), text.size());
  put64(text_hash(text));
  put64(p.accumulator.size() + p.aovs.size());
  ByteHasher h(p.head.size() + p.accumulator.size() + p.aovs.size(), kFileSeed);
  for (const auto* piece : {&p.head, &p.accumulator, &p.aovs}) h.update(*piece);
  p.hash = h.finish();
  return p;
}

}  // namespace

std::vector<std::uint8_t> frame_state_bytes(const FrameRecord& record,
                                            const FrameAccumulator& frame,
                                            const AovAccumulator& aovs) {
  const StatePieces p = state_pieces(record, frame, aovs);
  std::vector<std::uint8_t> out;
  out.reserve(p.head.size() + p.accumulator.size() + p.aovs.size() + sizeof p.hash);
  for (const auto* piece : {&p.head, &p.accumulator, &p.aovs}) {
    out.insert(out.end(), piece->begin(), piece->end());
  }
  const auto* h = reinterpret_cast<const std::uint8_t*>(&p.hash);
  out.insert(out.end(), h, h + sizeof p.hash);
  return out;
}

void save_frame_state(const fs::path& path, const FrameRecord& record,
                      const FrameAccumulator& frame, const AovAccumulator& aovs) {
  try {
    const StatePieces p = state_pieces(record, frame, aovs);
    const auto* h = reinterpret_cast<const std::uint8_t*>(&p.hash);
    const std::span<const std::uint8_t> pieces[] = {
        p.head, p.accumulator, p.aovs, {h, sizeof p.hash}};
    write_file_atomic(path, pieces);
  } catch (const std::invalid_argument& e) {
    throw std::invalid_argument(path.string() + ": " + e.what());
  }
}

namespace {

FrameRecord parse_record(std::span<const std::uint8_t> b, const std::string& path,
                         std::size_t* blob_offset, std::size_t* accumulator_bytes = nullptr) {
  std::uint64_t n = 0;
  if (b.size() < sizeof kMagic + 8 || (std::memcmp(b.data(), kMagic, sizeof kMagic) != 0 &&
                                       std::memcmp(b.data(), kMagicV1, sizeof kMagic) != 0)) {
    throw std::runtime_error(path + ": not a proden frame state");
  }
  std::memcpy(&n, b.data() + sizeof kMagic, sizeof n);
  if (n > b.size() - sizeof kMagic - 8 || b.size() - sizeof kMagic - 8 - n < 8) {
    throw std::runtime_error(path + ": truncated frame state");
  }
  std::string text(reinterpret_cast<const char*>(b.data() + sizeof kMagic + 8), n);
  std::uint64_t h = 0;
  std::memcpy(&h, b.data() + sizeof kMagic + 8 + n, sizeof h);
  if (h != text_hash(text)) throw std::runtime_error(path + ": corrupt frame state record");
  if (blob_offset) *blob_offset = sizeof kMagic + 16 + n;
  try {
    const json j = json::parse(text);
    if (accumulator_bytes) {
      *accumulator_bytes = j.contains("accumulator_bytes")
                               ? j.at("accumulator_bytes").get<std::size_t>()
                               : b.size() - (sizeof kMagic + 16 + n);
    }
    return frame_record_from_json(j);
  } catch (const std::exception& e) {  // json::exception, or a number out of range
    throw std::runtime_error(path + ": bad frame state record: " + e.what());
  }
}

}  // namespace

FrameRecord load_frame_record(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw std::runtime_error(path.string() + ": cannot open");
  std::vector<std::uint8_t> head(sizeof kMagic + 8);
  if (!in.read(reinterpret_cast<char*>(head.data()), static_cast<std::streamsize>(head.size()))) {
    throw std::runtime_error(path.string() + ": truncated frame state");
  }
  std::uint64_t n = 0;
  std::memcpy(&n, head.data() + sizeof kMagic, sizeof n);
  if (n > (64u << 20)) throw std::runtime_error(path.string() + ": not a proden frame state");
  head.resize(head.size() + n + 8);
  if (!in.read(reinterpret_cast<char*>(head.data() + sizeof kMagic + 8),
               static_cast<std::streamsize>(n + 8))) {
    throw std::runtime_error(path.string() + ": truncated frame state");
  }
  return parse_record(head, path.string(), nullptr);
}

FrameAccumulator parse_frame_state(std::span<const std::uint8_t> all, const std::string& path,
                                   FrameRecord* record, AovAccumulator* aovs) {
  std::span<const std::uint8_t> blob;
  if (all.size() >= sizeof kMagic && std::memcmp(all.data(), kMagic, sizeof kMagic) == 0) {
    // Version 2: the whole file's hash first, then the parts.
    std::uint64_t h = 0;
    if (all.size() < sizeof kMagic + 32) {
      throw std::runtime_error(path + ": truncated frame state");
    }
    std::memcpy(&h, all.data() + all.size() - 8, sizeof h);
    if (h != file_hash(all.first(all.size() - 8))) {
      throw std::runtime_error(path + ": frame state checksum mismatch");
    }
  }
  std::size_t offset = 0, acc_bytes = 0;
  FrameRecord r = parse_record(all, path, &offset, &acc_bytes);
  if (std::memcmp(all.data(), kMagic, sizeof kMagic) == 0) {
    std::uint64_t m = 0;
    if (offset + 16 > all.size()) throw std::runtime_error(path + ": truncated");
    std::memcpy(&m, all.data() + offset, sizeof m);
    if (m != all.size() - offset - 16) {
      throw std::runtime_error(path + ": inconsistent frame state");
    }
    blob = all.subspan(offset + 8, m);
    if (acc_bytes == all.size() - (offset)) acc_bytes = blob.size();  // no accumulator_bytes key
  } else {
    blob = all.subspan(offset);
  }
  if (acc_bytes > blob.size()) throw std::runtime_error(path + ": truncated frame state");
  FrameAccumulator acc = FrameAccumulator::deserialize(blob.first(acc_bytes));
  if (aovs) *aovs = AovAccumulator::deserialize(blob.subspan(acc_bytes));
  if (acc.state_digest() != r.digest) {
    throw std::runtime_error(path + ": accumulator does not match its record");
  }
  if (record) *record = std::move(r);
  return acc;
}

FrameAccumulator load_frame_accumulator(const fs::path& path, FrameRecord* record,
                                        AovAccumulator* aovs) {
  auto bytes = read_file(path);
  if (!bytes) throw std::runtime_error(path.string() + ": cannot read");
  return parse_frame_state(*bytes, path.string(), record, aovs);
}

}  // namespace proden::daemon
