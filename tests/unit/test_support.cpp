#include "test_support.hpp"

#include <cmath>
#include <fstream>
#include <iterator>
#include <random>
#include <vector>

#include "proden/io/image_writer.hpp"

namespace proden::test {

namespace fs = std::filesystem;

TempDir::TempDir() {
  static std::mt19937_64 rng(std::random_device{}());
  path_ = fs::temp_directory_path() / ("proden-test-" + std::to_string(rng()));
  fs::create_directories(path_);
}

TempDir::~TempDir() {
  std::error_code ec;
  fs::remove_all(path_, ec);
}

Pass make_pass(int width, int height, double spp, std::uint64_t seed, Layout layout, float sigma) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<float> noise(0.0f, sigma / std::sqrt(static_cast<float>(spp)));
  Pass p;
  p.spp = spp;
  p.colour = Image(width, height, 3);
  for (int c = 0; c < 3; ++c) {
    for (int y = 0; y < height; ++y) {
      for (int x = 0; x < width; ++x) {
        const float base =
            0.2f + 0.1f * static_cast<float>(c) +
            0.3f * std::sin(0.3f * static_cast<float>(x)) * std::cos(0.2f * static_cast<float>(y));
        p.colour.at(x, y, c) = base + noise(rng);
      }
    }
  }
  auto fill = [&](int ch, float v0) {
    Image img(width, height, ch);
    for (int c = 0; c < ch; ++c) {
      for (auto& v : img.plane(c)) v = v0 + 0.05f * static_cast<float>(c) + noise(rng) * 0.1f;
    }
    return img;
  };
  if (layout.albedo) p.albedo = fill(3, 0.5f);
  if (layout.normal) p.normal = fill(3, 0.0f);
  if (layout.depth) p.depth = fill(1, 3.0f);
  if (layout.variance)
    p.variance = Image(width, height, 3, sigma * sigma / static_cast<float>(spp));
  return p;
}

void write_generic_exr(const std::string& path, const Pass& pass, bool half,
                       const std::string& compression) {
  std::vector<io::NamedChannel> ch;
  io::add_layer(ch, "", pass.colour);
  if (!pass.albedo.empty()) io::add_layer(ch, "Albedo.", pass.albedo);
  if (!pass.normal.empty()) io::add_layer(ch, "Normal.", pass.normal, "XYZ");
  if (!pass.depth.empty()) io::add_layer(ch, "Depth.", pass.depth, "Z");
  if (!pass.variance.empty()) io::add_layer(ch, "Variance.", pass.variance);
  io::WriteOptions o;
  o.half = half;
  o.compression = compression;
  io::write_image(path, pass.width(), pass.height(), ch, o);
}

void truncate_copy(const std::string& from, const std::string& to, std::uintmax_t bytes) {
  std::ifstream in(from, std::ios::binary);
  std::vector<char> data((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  data.resize(static_cast<std::size_t>(std::min<std::uintmax_t>(bytes, data.size())));
  std::ofstream out(to, std::ios::binary);
  out.write(data.data(), static_cast<std::streamsize>(data.size()));
}

}  // namespace proden::test
