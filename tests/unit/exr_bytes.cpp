#include "exr_bytes.hpp"

#include <cstring>
#include <fstream>
#include <stdexcept>

namespace proden::test {
namespace {

void put_i32(std::vector<std::uint8_t>& out, std::int64_t v) {
  const auto u = static_cast<std::uint32_t>(v);
  for (int i = 0; i < 4; ++i) out.push_back(static_cast<std::uint8_t>(u >> (8 * i)));
}

void put_u64(std::vector<std::uint8_t>& out, std::uint64_t v) {
  for (int i = 0; i < 8; ++i) out.push_back(static_cast<std::uint8_t>(v >> (8 * i)));
}

void put_f32(std::vector<std::uint8_t>& out, float f) {
  std::uint32_t u;
  std::memcpy(&u, &f, 4);
  put_i32(out, u);
}

void put_str(std::vector<std::uint8_t>& out, const std::string& s) {
  out.insert(out.end(), s.begin(), s.end());
  out.push_back(0);
}

void put_attr(std::vector<std::uint8_t>& out, const ExrAttribute& a) {
  put_str(out, a.name);
  put_str(out, a.type);
  put_i32(out, a.declared_size >= 0 ? a.declared_size : static_cast<std::int64_t>(a.value.size()));
  out.insert(out.end(), a.value.begin(), a.value.end());
}

std::vector<std::uint8_t> box(int w, int h) {
  std::vector<std::uint8_t> v;
  put_i32(v, 0);
  put_i32(v, 0);
  put_i32(v, w - 1);
  put_i32(v, h - 1);
  return v;
}

}  // namespace

ExrAttribute string_attribute(const std::string& name, const std::string& value) {
  return {name, "string", std::vector<std::uint8_t>(value.begin(), value.end()), -1};
}

std::vector<std::uint8_t> exr_bytes(const ExrSpec& spec) {
  std::vector<std::uint8_t> out = {0x76, 0x2f, 0x31, 0x01};
  put_i32(out, 2 | 0x400);  // version 2, long names allowed
  std::vector<std::uint8_t> chlist;
  for (const auto& c : spec.channels) {
    put_str(chlist, c);
    put_i32(chlist, 2);  // FLOAT
    put_i32(chlist, 0);  // pLinear + reserved
    put_i32(chlist, 1);  // x sampling
    put_i32(chlist, 1);  // y sampling
  }
  chlist.push_back(0);
  const int dw = spec.declared_width > 0 ? spec.declared_width : spec.width;
  const int dh = spec.declared_height > 0 ? spec.declared_height : spec.height;
  std::vector<std::uint8_t> f1, center;
  put_f32(f1, 1.0f);
  put_f32(center, 0.0f);
  put_f32(center, 0.0f);
  put_attr(out, {"channels", "chlist", chlist});
  put_attr(out, {"compression", "compression", {0}});
  put_attr(out, {"dataWindow", "box2i", box(dw, dh)});
  put_attr(out, {"displayWindow", "box2i", box(dw, dh)});
  put_attr(out, {"lineOrder", "lineOrder", {0}});
  put_attr(out, {"pixelAspectRatio", "float", f1});
  put_attr(out, {"screenWindowCenter", "v2f", center});
  put_attr(out, {"screenWindowWidth", "float", f1});
  for (const auto& a : spec.extra) put_attr(out, a);
  out.push_back(0);
  if (!spec.pixels) return out;
  const std::size_t line = spec.channels.size() * static_cast<std::size_t>(spec.width) * 4;
  const std::size_t table = out.size();
  const std::size_t first = table + 8 * static_cast<std::size_t>(spec.height);
  for (int y = 0; y < spec.height; ++y) {
    put_u64(out, first + static_cast<std::size_t>(y) * (8 + line));
  }
  for (int y = 0; y < spec.height; ++y) {
    put_i32(out, y);
    put_i32(out, static_cast<std::int64_t>(line));
    for (std::size_t i = 0; i < line / 4; ++i) put_f32(out, spec.value);
  }
  return out;
}

void write_bytes(const std::string& path, const std::vector<std::uint8_t>& bytes) {
  std::ofstream f(path, std::ios::binary);
  f.write(reinterpret_cast<const char*>(bytes.data()), static_cast<std::streamsize>(bytes.size()));
  if (!f) throw std::runtime_error("cannot write " + path);
}

}  // namespace proden::test
