#include "proden/network/weights.hpp"

#include <cmath>
#include <cstring>
#include <set>

namespace proden::network {
namespace {

constexpr char kMagic[4] = {'P', 'D', 'N', 'W'};
constexpr std::uint32_t kMaxTensors = 64;
constexpr std::uint32_t kMaxMetadata = 1u << 20;
constexpr std::size_t kMaxName = 64;
constexpr std::size_t kMaxElements = std::size_t{1} << 24;

// Reads little-endian fields with a bounds check on every access.
class Reader {
 public:
  Reader(std::span<const unsigned char> bytes, const std::string& source)
      : bytes_(bytes), source_(source) {}

  template <class T>
  T read(const char* field) {
    need(sizeof(T), field);
    T v{};
    for (std::size_t i = 0; i < sizeof(T); ++i) {
      v = static_cast<T>(v | (static_cast<T>(bytes_[pos_ + i]) << (8 * i)));
    }
    pos_ += sizeof(T);
    return v;
  }
  std::string read_string(std::size_t n, const char* field) {
    need(n, field);
    std::string s(reinterpret_cast<const char*>(bytes_.data() + pos_), n);
    pos_ += n;
    return s;
  }
  std::size_t pos() const { return pos_; }
  [[noreturn]] void fail(const std::string& what) const {
    throw WeightsError(source_ + ": " + what);
  }

 private:
  void need(std::size_t n, const char* field) const {
    if (n > bytes_.size() || pos_ > bytes_.size() - n) {
      fail(std::string(field) + " at byte " + std::to_string(pos_) +
           " runs past the end of the file (" + std::to_string(bytes_.size()) + " bytes)");
    }
  }
  std::span<const unsigned char> bytes_;
  const std::string& source_;
  std::size_t pos_ = 0;
};

bool valid_name(const std::string& s) {
  if (s.empty() || s.size() > kMaxName) return false;
  for (char c : s) {
    const bool ok = (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') ||
                    c == '_' || c == '.';
    if (!ok) return false;
  }
  return true;
}

template <class T>
void put(std::vector<unsigned char>& out, T v) {
  for (std::size_t i = 0; i < sizeof(T); ++i) {
    out.push_back(static_cast<unsigned char>((static_cast<std::uint64_t>(v) >> (8 * i)) & 0xFF));
  }
}

}  // namespace

std::size_t Tensor::size() const {
  std::size_t n = 1;
  for (int d : shape) n *= static_cast<std::size_t>(d);
  return n;
}

std::string Tensor::shape_string() const {
  std::string s = "[";
  for (std::size_t i = 0; i < shape.size(); ++i) {
    if (i) s += ",";
    s += std::to_string(shape[i]);
  }
  return s + "]";
}

const Tensor* WeightsFile::find(const std::string& name) const {
  for (const auto& t : tensors) {
    if (t.name == name) return &t;
  }
  return nullptr;
}

std::uint64_t fnv1a64(std::span<const unsigned char> bytes) {
  std::uint64_t h = 0xcbf29ce484222325ull;
  for (unsigned char b : bytes) {
    h ^= b;
    h *= 0x100000001b3ull;
  }
  return h;
}

WeightsFile parse_weights(std::span<const unsigned char> bytes, const std::string& source) {
  Reader r(bytes, source);
  if (bytes.size() < 24) {
    r.fail("too short for a weights file (" + std::to_string(bytes.size()) + " bytes)");
  }
  if (std::memcmp(bytes.data(), kMagic, 4) != 0) r.fail("magic: not a PDNW weights file");
  r.read_string(4, "magic");
  const auto version = r.read<std::uint16_t>("version");
  if (version != WeightsFile::kVersion) {
    r.fail("version: " + std::to_string(version) + " is not supported (this build reads " +
           std::to_string(WeightsFile::kVersion) + ")");
  }
  r.read<std::uint16_t>("reserved");
  // The checksum first: a truncated or bit-flipped file is refused before its fields are trusted
  // further than their bounds.
  const std::size_t body = bytes.size() - 8;
  std::uint64_t stored = 0;
  for (int i = 0; i < 8; ++i) stored |= static_cast<std::uint64_t>(bytes[body + i]) << (8 * i);
  if (stored != fnv1a64(bytes.first(body))) {
    r.fail("checksum: FNV-1a of the file does not match its last 8 bytes (corrupt or truncated)");
  }
  const auto count = r.read<std::uint32_t>("tensor_count");
  if (count == 0 || count > kMaxTensors) {
    r.fail("tensor_count: " + std::to_string(count) + " is outside 1.." +
           std::to_string(kMaxTensors));
  }
  const auto meta_bytes = r.read<std::uint32_t>("metadata_bytes");
  if (meta_bytes > kMaxMetadata) {
    r.fail("metadata_bytes: " + std::to_string(meta_bytes) + " exceeds " +
           std::to_string(kMaxMetadata));
  }
  WeightsFile file;
  file.metadata = r.read_string(meta_bytes, "metadata");

  struct Span {
    std::uint64_t begin, end;
    std::string name;
  };
  std::vector<Span> spans;
  std::set<std::string> names;
  for (std::uint32_t t = 0; t < count; ++t) {
    const std::string rec = "tensor record " + std::to_string(t);
    const auto name_bytes = r.read<std::uint16_t>("name_bytes");
    if (name_bytes == 0 || name_bytes > kMaxName) {
      r.fail(rec + ": name_bytes " + std::to_string(name_bytes) + " is outside 1.." +
             std::to_string(kMaxName));
    }
    Tensor tensor;
    tensor.name = r.read_string(name_bytes, "name");
    if (!valid_name(tensor.name)) r.fail(rec + ": name has characters outside [A-Za-z0-9_.]");
    if (!names.insert(tensor.name).second) r.fail(tensor.name + ": appears twice");
    const auto ndim = r.read<std::uint8_t>("ndim");
    const auto dtype = r.read<std::uint8_t>("dtype");
    if (ndim < 1 || ndim > 4) {
      r.fail(tensor.name + ": ndim " + std::to_string(ndim) + " is outside 1..4");
    }
    if (dtype != 0) r.fail(tensor.name + ": dtype " + std::to_string(dtype) + " is not float32");
    std::size_t elements = 1;
    for (int d = 0; d < ndim; ++d) {
      const auto dim = r.read<std::uint32_t>("dims");
      if (dim < 1 || dim > kMaxElements) {
        r.fail(tensor.name + ": dimension " + std::to_string(d) + " is " + std::to_string(dim));
      }
      elements *= dim;
      if (elements > kMaxElements) r.fail(tensor.name + ": more than 2^24 elements");
      tensor.shape.push_back(static_cast<int>(dim));
    }
    const auto offset = r.read<std::uint64_t>("offset");
    const std::uint64_t len = elements * sizeof(float);
    if (offset % 4 != 0)
      r.fail(tensor.name + ": data offset " + std::to_string(offset) + " is not a multiple of 4");
    if (offset > body || len > body - offset) {
      r.fail(tensor.name + ": data [" + std::to_string(offset) + ", " +
             std::to_string(offset + len) + ") lies outside the data area (file body is " +
             std::to_string(body) + " bytes)");
    }
    spans.push_back({offset, offset + len, tensor.name});
    tensor.values.resize(elements);
    file.tensors.push_back(std::move(tensor));
  }
  const std::uint64_t header_end = r.pos();
  for (std::size_t i = 0; i < spans.size(); ++i) {
    if (spans[i].begin < header_end) {
      r.fail(spans[i].name + ": data offset " + std::to_string(spans[i].begin) +
             " overlaps the header (ends at " + std::to_string(header_end) + ")");
    }
    for (std::size_t j = 0; j < i; ++j) {
      if (spans[i].begin < spans[j].end && spans[j].begin < spans[i].end) {
        r.fail(spans[i].name + ": data overlaps " + spans[j].name);
      }
    }
  }
  for (std::size_t i = 0; i < spans.size(); ++i) {
    Tensor& t = file.tensors[i];
    std::memcpy(t.values.data(), bytes.data() + spans[i].begin, t.values.size() * sizeof(float));
    for (std::size_t k = 0; k < t.values.size(); ++k) {
      if (!std::isfinite(t.values[k])) {
        r.fail(t.name + ": value " + std::to_string(k) + " is not finite");
      }
    }
  }
  return file;
}

std::vector<unsigned char> serialize_weights(const WeightsFile& file) {
  std::vector<unsigned char> out = {'P', 'D', 'N', 'W'};
  put<std::uint16_t>(out, WeightsFile::kVersion);
  put<std::uint16_t>(out, 0);
  put<std::uint32_t>(out, static_cast<std::uint32_t>(file.tensors.size()));
  put<std::uint32_t>(out, static_cast<std::uint32_t>(file.metadata.size()));
  out.insert(out.end(), file.metadata.begin(), file.metadata.end());
  std::size_t header = out.size();
  for (const auto& t : file.tensors) header += 2 + t.name.size() + 2 + 4 * t.shape.size() + 8;
  std::uint64_t offset = (header + 3) / 4 * 4;
  for (const auto& t : file.tensors) {
    put<std::uint16_t>(out, static_cast<std::uint16_t>(t.name.size()));
    out.insert(out.end(), t.name.begin(), t.name.end());
    put<std::uint8_t>(out, static_cast<std::uint8_t>(t.shape.size()));
    put<std::uint8_t>(out, 0);
    for (int d : t.shape) put<std::uint32_t>(out, static_cast<std::uint32_t>(d));
    put<std::uint64_t>(out, offset);
    offset += t.values.size() * sizeof(float);
  }
  out.resize((out.size() + 3) / 4 * 4, 0);
  for (const auto& t : file.tensors) {
    const auto* p = reinterpret_cast<const unsigned char*>(t.values.data());
    out.insert(out.end(), p, p + t.values.size() * sizeof(float));
  }
  put<std::uint64_t>(out, fnv1a64(out));
  return out;
}

}  // namespace proden::network
