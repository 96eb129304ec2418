// Fuzz target: a `.pdnw` weights file's bytes, parsed as proden loads a network
// (io::load_network: network::parse_weights, then the PdNet architecture check). Each input is
// parsed twice: as given (the checksum gate), and with its trailing FNV-1a checksum recomputed so
// the mutations reach every field behind the gate.
//
// Properties: only WeightsError leaves the parser and the network check; an accepted file has
// 1..64 uniquely named tensors of 1..4 dims, finite values, no more value bytes than the file
// holds (no amplification), and serialize_weights -> parse_weights gives the same file back.
#include <cmath>
#include <cstdint>
#include <cstring>
#include <set>
#include <span>
#include <vector>

#include "fuzz_check.hpp"
#include "proden/network/pdnet.hpp"
#include "proden/network/weights.hpp"

using namespace proden::network;

namespace {

bool same(const WeightsFile& a, const WeightsFile& b) {
  if (a.metadata != b.metadata || a.tensors.size() != b.tensors.size()) return false;
  for (std::size_t i = 0; i < a.tensors.size(); ++i) {
    const Tensor& x = a.tensors[i];
    const Tensor& y = b.tensors[i];
    if (x.name != y.name || x.shape != y.shape || x.values.size() != y.values.size()) return false;
    if (!x.values.empty() &&
        std::memcmp(x.values.data(), y.values.data(), x.values.size() * sizeof(float)) != 0) {
      return false;
    }
  }
  return true;
}

void parse_and_check(std::span<const unsigned char> bytes) {
  WeightsFile f;
  try {
    f = parse_weights(bytes, "fuzz.pdnw");
  } catch (const WeightsError& e) {
    (void)e.what();
    return;
  }
  FUZZ_CHECK(!f.tensors.empty() && f.tensors.size() <= 64);
  std::set<std::string> names;
  std::size_t value_bytes = 0;
  for (const Tensor& t : f.tensors) {
    FUZZ_CHECK(names.insert(t.name).second);
    FUZZ_CHECK(!t.shape.empty() && t.shape.size() <= 4);
    FUZZ_CHECK(t.values.size() == t.size());
    for (float v : t.values) FUZZ_CHECK(std::isfinite(v));
    value_bytes += t.values.size() * sizeof(float);
    proden::fuzz::check_json_safe(t.name);
  }
  FUZZ_CHECK(value_bytes <= bytes.size());
  const std::vector<unsigned char> again = serialize_weights(f);
  const WeightsFile g = parse_weights(again, "fuzz.pdnw (re-serialised)");  // must not throw
  FUZZ_CHECK(same(f, g));
  try {
    const PdNet net(f, "fuzz.pdnw");
    FUZZ_CHECK(net.width() >= 1 && net.width() <= 256);
    FUZZ_CHECK(std::isfinite(net.flops_per_pixel()) && net.flops_per_pixel() > 0.0);
  } catch (const WeightsError& e) {
    (void)e.what();
  }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  parse_and_check({data, size});
  if (size >= 24) {
    std::vector<unsigned char> fixed(data, data + size);
    const std::uint64_t h = fnv1a64(std::span<const unsigned char>(fixed).first(size - 8));
    for (int i = 0; i < 8; ++i) fixed[size - 8 + i] = static_cast<unsigned char>(h >> (8 * i));
    parse_and_check(fixed);
  }
  return 0;
}
