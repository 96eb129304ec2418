#include "daemon/frame_state.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
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

constexpr char kMagic[8] = {'P', 'R', 'D', 'N', 'F', 'R', 'S', '4'};
constexpr char kMagicV3[8] = {'P', 'R', 'D', 'N', 'F', 'R', 'S', '3'};
constexpr char kMagicV2[8] = {'P', 'R', 'D', 'N', 'F', 'R', 'S', '2'};
constexpr char kMagicV1[8] = {'P', 'R', 'D', 'N', 'F', 'R', 'S', '1'};
// Version 4: magic, u64 m, blob, u64 blob hash | record | u64 n, u64 record hash, the hashes
// checksum_bytes (XXH3). Version 3 (still read) is the same with hash_bytes; versions 1 and 2
// (still read) put the record first. The sizes and names below say V3 for both 3 and 4.
constexpr std::size_t kHeadV3 = sizeof kMagic + 8, kTailV3 = 16;
constexpr std::size_t kMinV3 = kHeadV3 + 8 + kTailV3;  // an empty blob and an empty record
constexpr std::uint64_t kFileSeed = 0x66726d32;

constexpr std::uint64_t kRecordSeed = 0x66726d;

std::uint64_t file_hash(std::span<const std::uint8_t> b, HashKind kind) {
  return hash_with(kind, {b.data(), b.size()}, kFileSeed);
}

std::uint64_t text_hash(const std::string& s, HashKind kind) {
  return hash_with(kind, {reinterpret_cast<const unsigned char*>(s.data()), s.size()}, kRecordSeed);
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

void check_finite(const FrameRecord& record) {
  for (const auto& [name, v] :
       {std::pair{"spp", record.spp}, {"estimated_mse", record.estimated_mse}}) {
    if (!std::isfinite(v)) {
      throw std::invalid_argument(std::string("refusing to persist a non-finite ") + name);
    }
  }
}

std::span<const std::uint8_t> bytes_of(const void* p, std::size_t n) {
  return {static_cast<const std::uint8_t*>(p), n};
}

// The tail of a version 4 file: the record, its size and its hash. Throws std::invalid_argument
// on a non-finite record.
std::vector<std::uint8_t> record_tail(const FrameRecord& record, std::size_t accumulator_bytes) {
  check_finite(record);
  const std::string text = record_text(record, accumulator_bytes);
  const std::uint64_t n = text.size(), h = text_hash(text, HashKind::xxh3);
  std::vector<std::uint8_t> out(text.begin(), text.end());
  for (const std::uint64_t v : {n, h}) {
    const auto b = bytes_of(&v, sizeof v);
    out.insert(out.end(), b.begin(), b.end());
  }
  return out;
}

// The head and blob of a version 4 file, handed to `put` in order, in pieces (the accumulator's
// planes straight from it: a 1080p frame with features holds ~600 MB of statistics, which are
// never copied whole); returns the accumulator's size in the blob.
template <class Put>
std::size_t put_statistics(const FrameAccumulator& frame, std::span<const std::uint8_t> aov,
                           Put&& put) {
  const std::size_t accumulator_bytes = frame.serialized_size();
  const std::uint64_t m = accumulator_bytes + aov.size();
  Checksum h(kFileSeed);
  const auto emit = [&](std::span<const std::uint8_t> b) {
    h.update(b);
    put(b);
  };
  emit(bytes_of(kMagic, sizeof kMagic));
  emit(bytes_of(&m, sizeof m));
  // The accumulator's bytes enter h in the pass that computes their own checksum.
  frame.serialize_to([&put](std::span<const std::uint8_t> b) { put(b); }, &h);
  emit(aov);
  const std::uint64_t blob_hash = h.finish();
  put(bytes_of(&blob_hash, sizeof blob_hash));
  return accumulator_bytes;
}

}  // namespace

std::vector<std::uint8_t> frame_state_bytes(const FrameRecord& record,
                                            const FrameAccumulator& frame,
                                            const AovAccumulator& aovs) {
  std::vector<std::uint8_t> out;
  const std::size_t accumulator_bytes = put_statistics(
      frame, aovs.serialize(),
      [&out](std::span<const std::uint8_t> b) { out.insert(out.end(), b.begin(), b.end()); });
  const auto tail = record_tail(record, accumulator_bytes);
  out.insert(out.end(), tail.begin(), tail.end());
  return out;
}

FrameStateWriter::FrameStateWriter(fs::path path, const FrameAccumulator& frame,
                                   const AovAccumulator& aovs)
    : path_(std::move(path)), tmp_(temp_path_for(path_)) {
  fd_ = ::open(tmp_.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd_ < 0) {
    const std::string why = std::strerror(errno);
    tmp_.clear();
    blob_ = std::async(std::launch::deferred, [p = path_, why]() -> Written {
      throw std::runtime_error(p.string() + ": cannot create: " + why);
    });
    return;
  }
  // The renderer AOVs are serialised here (a few planes at most): only `frame` is read by the
  // writing thread.
  auto write = [this, &frame, aov = aovs.serialize()] {
    Written w;
    w.digest = frame.state_digest();
    w.accumulator_bytes = put_statistics(frame, aov, [this](std::span<const std::uint8_t> b) {
      if (!write_all(fd_, b)) {
        throw std::runtime_error(path_.string() + ": write failed: " + std::strerror(errno));
      }
    });
    if (::fdatasync(fd_) != 0) {
      throw std::runtime_error(path_.string() + ": fdatasync failed: " + std::strerror(errno));
    }
    return w;
  };
  try {
    blob_ = std::async(std::launch::async, write);
  } catch (...) {  // no thread to be had: the destructor does not run, so clean up here
    ::close(fd_);
    ::unlink(tmp_.c_str());
    throw;
  }
}

FrameStateWriter::Written FrameStateWriter::wait() {
  if (blob_.valid()) {
    try {
      written_ = blob_.get();
    } catch (...) {
      failed_ = std::current_exception();
    }
  }
  if (failed_) std::rethrow_exception(failed_);  // the writing thread's failure, every time
  return *written_;
}

std::uint64_t FrameStateWriter::digest() {
  return wait().digest;
}

void FrameStateWriter::commit(const FrameRecord& record) {
  const Written w = wait();
  if (fd_ < 0) throw std::logic_error(path_.string() + ": committed twice");
  if (record.digest != w.digest) {
    throw std::logic_error(path_.string() + ": the record's digest is not the statistics'");
  }
  std::vector<std::uint8_t> tail;
  try {
    tail = record_tail(record, w.accumulator_bytes);
  } catch (const std::invalid_argument& e) {
    throw std::invalid_argument(path_.string() + ": " + e.what());
  }
  if (!write_all(fd_, tail)) {
    throw std::runtime_error(path_.string() + ": write failed: " + std::strerror(errno));
  }
  const int fd = fd_;
  fd_ = -1;
  if (::fsync(fd) != 0 || ::close(fd) != 0) {
    throw std::runtime_error(path_.string() + ": fsync failed: " + std::strerror(errno));
  }
  if (::rename(tmp_.c_str(), path_.c_str()) != 0) {
    throw std::runtime_error(path_.string() + ": rename failed: " + std::strerror(errno));
  }
  tmp_.clear();
  fsync_dir(path_.parent_path());
}

FrameStateWriter::~FrameStateWriter() {
  if (blob_.valid()) blob_.wait();  // its failure, if any, is commit()'s to report
  if (fd_ >= 0) ::close(fd_);
  if (!tmp_.empty()) ::unlink(tmp_.c_str());
}

void save_frame_state(const fs::path& path, const FrameRecord& record,
                      const FrameAccumulator& frame, const AovAccumulator& aovs) {
  FrameStateWriter w(path, frame, aovs);
  w.commit(record);
}

namespace {

FrameRecord parse_record_text(const std::string& text, const std::string& path,
                              std::optional<std::size_t>* accumulator_bytes) {
  try {
    const json j = json::parse(text);
    if (accumulator_bytes && j.contains("accumulator_bytes")) {
      *accumulator_bytes = j.at("accumulator_bytes").get<std::size_t>();
    }
    return frame_record_from_json(j);
  } catch (const std::exception& e) {  // json::exception, or a number out of range
    throw std::runtime_error(path + ": bad frame state record: " + e.what());
  }
}

std::uint64_t get64(std::span<const std::uint8_t> b, std::size_t at) {
  std::uint64_t v = 0;
  std::memcpy(&v, b.data() + at, sizeof v);
  return v;
}

bool has_magic(std::span<const std::uint8_t> b, const char (&magic)[8]) {
  return b.size() >= sizeof magic && std::memcmp(b.data(), magic, sizeof magic) == 0;
}

// For a file of the statistics-first layout (versions 3 and 4), the hash it was written with;
// nothing for another layout.
std::optional<HashKind> v3_layout(std::span<const std::uint8_t> b) {
  if (has_magic(b, kMagic)) return HashKind::xxh3;
  if (has_magic(b, kMagicV3)) return HashKind::legacy;
  return std::nullopt;
}

// Version 3's sizes: m (the head's), n (the tail's) and the file's (at least kMinV3, checked
// before m and n are read) must add up.
void check_v3_sizes(std::uint64_t size, std::uint64_t m, std::uint64_t n, const std::string& path) {
  if (m > size - kMinV3 || n != size - kMinV3 - m) {
    throw std::runtime_error(path + ": inconsistent frame state");
  }
}

// Version 3's record from the file's last n + kTailV3 bytes (sizes checked), for a blob of m.
FrameRecord v3_record(std::span<const std::uint8_t> end, std::uint64_t m, const std::string& path,
                      std::size_t* accumulator_bytes, HashKind kind) {
  const std::size_t n = end.size() - kTailV3;
  std::string text(reinterpret_cast<const char*>(end.data()), n);
  if (get64(end, end.size() - 8) != text_hash(text, kind)) {
    throw std::runtime_error(path + ": corrupt frame state record");
  }
  std::optional<std::size_t> acc_bytes;
  FrameRecord r = parse_record_text(text, path, &acc_bytes);
  if (!acc_bytes || *acc_bytes > m) throw std::runtime_error(path + ": inconsistent frame state");
  if (accumulator_bytes) *accumulator_bytes = *acc_bytes;
  return r;
}

// Version 3, the whole file: the record, and the blob checked against its hash.
FrameRecord parse_v3(std::span<const std::uint8_t> all, const std::string& path,
                     std::span<const std::uint8_t>* blob, std::size_t* accumulator_bytes,
                     HashKind kind) {
  if (all.size() < kMinV3) throw std::runtime_error(path + ": truncated frame state");
  const std::uint64_t m = get64(all, sizeof kMagic), n = get64(all, all.size() - kTailV3);
  check_v3_sizes(all.size(), m, n, path);
  FrameRecord r = v3_record(all.last(n + kTailV3), m, path, accumulator_bytes, kind);
  if (get64(all, kHeadV3 + m) != file_hash(all.first(kHeadV3 + m), kind)) {
    throw std::runtime_error(path + ": frame state checksum mismatch");
  }
  *blob = all.subspan(kHeadV3, m);
  return r;
}

// Versions 1 and 2: the record comes first.
FrameRecord parse_record(std::span<const std::uint8_t> b, const std::string& path,
                         std::size_t* blob_offset, std::optional<std::size_t>* accumulator_bytes) {
  if (!has_magic(b, kMagicV2) && !has_magic(b, kMagicV1)) {
    throw std::runtime_error(path + ": not a proden frame state");
  }
  if (b.size() < sizeof kMagic + 8) throw std::runtime_error(path + ": truncated frame state");
  const std::uint64_t n = get64(b, sizeof kMagic);
  if (n > b.size() - sizeof kMagic - 8 || b.size() - sizeof kMagic - 8 - n < 8) {
    throw std::runtime_error(path + ": truncated frame state");
  }
  std::string text(reinterpret_cast<const char*>(b.data() + sizeof kMagic + 8), n);
  if (get64(b, sizeof kMagic + 8 + n) != text_hash(text, HashKind::legacy)) {
    throw std::runtime_error(path + ": corrupt frame state record");
  }
  if (blob_offset) *blob_offset = sizeof kMagic + 16 + n;
  return parse_record_text(text, path, accumulator_bytes);
}

void read_at(std::ifstream& in, std::uint64_t at, std::span<std::uint8_t> out,
             const std::string& path) {
  if (!in.seekg(static_cast<std::streamoff>(at)) ||
      !in.read(reinterpret_cast<char*>(out.data()), static_cast<std::streamsize>(out.size()))) {
    throw std::runtime_error(path + ": truncated frame state");
  }
}

}  // namespace

FrameRecord load_frame_record(const fs::path& path) {
  const std::string name = path.string();
  std::ifstream in(path, std::ios::binary);
  if (!in) throw std::runtime_error(name + ": cannot open");
  std::error_code ec;
  const std::uint64_t size = fs::file_size(path, ec);
  if (ec) throw std::runtime_error(name + ": cannot open");
  std::vector<std::uint8_t> head(kHeadV3);
  read_at(in, 0, head, name);
  constexpr std::uint64_t kMaxRecord = 64u << 20;
  if (const auto kind = v3_layout(head)) {  // the record is read from the end
    if (size < kMinV3) throw std::runtime_error(name + ": truncated frame state");
    std::uint8_t tail[kTailV3];
    read_at(in, size - kTailV3, tail, name);
    const std::uint64_t n = get64(tail, 0), m = get64(head, sizeof kMagic);
    if (n > kMaxRecord) throw std::runtime_error(name + ": not a proden frame state");
    check_v3_sizes(size, m, n, name);
    std::vector<std::uint8_t> end(n + kTailV3);
    read_at(in, size - end.size(), end, name);
    return v3_record(end, m, name, nullptr, *kind);
  }
  const std::uint64_t n = get64(head, sizeof kMagic);
  if (n > kMaxRecord) throw std::runtime_error(name + ": not a proden frame state");
  head.resize(head.size() + n + 8);
  read_at(in, kHeadV3, std::span(head).subspan(kHeadV3), name);
  return parse_record(head, name, nullptr, nullptr);
}

FrameAccumulator parse_frame_state(std::span<const std::uint8_t> all, const std::string& path,
                                   FrameRecord* record, AovAccumulator* aovs) {
  std::span<const std::uint8_t> blob;
  std::size_t acc_bytes = 0;
  FrameRecord r;
  // The hash the file and its record's digest were made with (legacy before version 4).
  const std::optional<HashKind> layout = v3_layout(all);
  const HashKind kind = layout.value_or(HashKind::legacy);
  if (layout) {
    r = parse_v3(all, path, &blob, &acc_bytes, kind);
  } else {
    const bool v2 = has_magic(all, kMagicV2);
    if (v2) {
      // Version 2: the whole file's hash first, then the parts.
      if (all.size() < sizeof kMagic + 32)
        throw std::runtime_error(path + ": truncated frame state");
      if (get64(all, all.size() - 8) != file_hash(all.first(all.size() - 8), kind)) {
        throw std::runtime_error(path + ": frame state checksum mismatch");
      }
    }
    std::size_t offset = 0;
    std::optional<std::size_t> acc_key;
    r = parse_record(all, path, &offset, &acc_key);
    if (v2) {
      if (offset + 16 > all.size()) throw std::runtime_error(path + ": truncated");
      const std::uint64_t m = get64(all, offset);
      if (m != all.size() - offset - 16)
        throw std::runtime_error(path + ": inconsistent frame state");
      blob = all.subspan(offset + 8, m);
    } else {
      blob = all.subspan(offset);
    }
    acc_bytes = acc_key.value_or(blob.size());  // no accumulator_bytes key: no AOVs
  }
  if (acc_bytes > blob.size()) throw std::runtime_error(path + ": truncated frame state");
  FrameAccumulator acc = FrameAccumulator::deserialize(blob.first(acc_bytes));
  if (aovs) *aovs = AovAccumulator::deserialize(blob.subspan(acc_bytes));
  if (acc.state_digest(kind) != r.digest) {
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
