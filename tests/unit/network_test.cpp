// The learned mixer: weights parser bounds, the convolution kernel against a plain double
// reference, tiles == whole image, parity with PyTorch (fixtures written by training/export.py),
// and hard inputs.
#include <catch2/catch.hpp>

#include <cmath>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <random>

#include "../../pipeline/src/network/conv.hpp"
#include "proden/network/builtin.hpp"
#include "proden/network/pdnet.hpp"
#include "proden/network/weights.hpp"

using namespace proden;
using namespace proden::network;

namespace {

struct Inputs {
  Buffer x, y, var, sure;
};

Inputs random_inputs(int w, int h, unsigned seed = 5) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  const Rect r{0, 0, w, h};
  Inputs in{Buffer(r, 3), Buffer(r, 3), Buffer(r, 3), Buffer(r, 3)};
  for (int c = 0; c < 3; ++c)
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x) {
        in.x.at(x, y, c) = 2.0f * u(rng);
        in.y.at(x, y, c) = in.x.at(x, y, c) * (0.8f + 0.4f * u(rng));
        in.var.at(x, y, c) = 0.05f * u(rng);
        in.sure.at(x, y, c) = 0.04f * u(rng) - 0.01f;
      }
  return in;
}

// The network in double precision, straight from the OIHW tensors, zero padding per layer.
std::vector<double> reference_raw(const WeightsFile& wf, const Inputs& in, int w, int h) {
  using Map = std::vector<double>;  // [c][y][x]
  auto conv = [&](const Map& src, int cin, const std::string& name, int k, int cout) {
    const Tensor& W = *wf.find(name + ".weight");
    const Tensor& B = *wf.find(name + ".bias");
    Map out(static_cast<std::size_t>(cout * w * h));
    const int r = k / 2;
    for (int o = 0; o < cout; ++o)
      for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
          double s = B.values[static_cast<std::size_t>(o)];
          for (int i = 0; i < cin; ++i)
            for (int ky = 0; ky < k; ++ky)
              for (int kx = 0; kx < k; ++kx) {
                const int sy = y + ky - r, sx = x + kx - r;
                if (sx < 0 || sy < 0 || sx >= w || sy >= h) continue;
                s += W.values[static_cast<std::size_t>(((o * cin + i) * k + ky) * k + kx)] *
                     src[static_cast<std::size_t>((i * h + sy) * w + sx)];
              }
          out[static_cast<std::size_t>((o * h + y) * w + x)] = s;
        }
    return out;
  };
  auto relu = [](Map m) {
    for (auto& v : m) v = std::max(v, 0.0);
    return m;
  };
  auto add = [](Map a, const Map& b) {
    for (std::size_t i = 0; i < a.size(); ++i) a[i] += b[i];
    return a;
  };
  Map f(static_cast<std::size_t>(18 * w * h));
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x)
      for (int c = 0; c < 3; ++c) {
        float v[6];
        network_features(in.x.at(x, y, c), in.y.at(x, y, c), in.var.at(x, y, c),
                         in.sure.at(x, y, c), v);
        for (int g = 0; g < 6; ++g)
          f[static_cast<std::size_t>(((3 * g + c) * h + y) * w + x)] = v[g];
      }
  const int W = wf.find("conv_in.weight")->shape[0];
  Map a = relu(conv(f, 18, "conv_in", 5, W));
  for (const char* b : {"res1", "res2"}) {
    const Map t = relu(conv(a, W, std::string(b) + ".conv1", 3, W));
    a = relu(add(a, conv(t, W, std::string(b) + ".conv2", 3, W)));
  }
  return conv(a, W, "conv_out", 3, 9);
}

std::vector<unsigned char> read_file(const std::string& path) {
  std::ifstream f(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(f), std::istreambuf_iterator<char>()};
}

// Rewrites the trailing checksum after a deliberate edit, so the check under test is reached.
void reseal(std::vector<unsigned char>& b) {
  const std::uint64_t h = fnv1a64(std::span(b).first(b.size() - 8));
  for (int i = 0; i < 8; ++i) b[b.size() - 8 + static_cast<std::size_t>(i)] = (h >> (8 * i)) & 0xFF;
}

std::string parse_error(const std::vector<unsigned char>& b) {
  try {
    const WeightsFile f = parse_weights(b, "test.pdnw");
    PdNet net(f, "test.pdnw");
  } catch (const WeightsError& e) {
    return e.what();
  }
  return "";
}

}  // namespace

TEST_CASE("weights files round-trip and every corruption is refused by name", "[network]") {
  const WeightsFile f = random_weights(16, 3);
  std::vector<unsigned char> bytes = serialize_weights(f);
  const WeightsFile back = parse_weights(bytes, "ok.pdnw");
  REQUIRE(back.tensors.size() == f.tensors.size());
  CHECK(back.metadata == f.metadata);
  for (std::size_t i = 0; i < f.tensors.size(); ++i) {
    CHECK(back.tensors[i].name == f.tensors[i].name);
    CHECK(back.tensors[i].shape == f.tensors[i].shape);
    CHECK(back.tensors[i].values == f.tensors[i].values);
  }
  CHECK(parse_error(bytes).empty());

  SECTION("truncated") {
    bytes.resize(bytes.size() / 2);
    CHECK_THAT(parse_error(bytes), Catch::Contains("checksum"));
  }
  SECTION("too short") {
    bytes.resize(10);
    CHECK_THAT(parse_error(bytes), Catch::Contains("too short"));
  }
  SECTION("bad magic") {
    bytes[0] = 'X';
    CHECK_THAT(parse_error(bytes), Catch::Contains("magic"));
  }
  SECTION("future version") {
    bytes[4] = 2;
    reseal(bytes);
    CHECK_THAT(parse_error(bytes), Catch::Contains("version: 2"));
  }
  SECTION("one flipped bit in the data") {
    bytes[bytes.size() - 100] ^= 0x10;
    CHECK_THAT(parse_error(bytes), Catch::Contains("checksum"));
  }
  SECTION("a NaN weight") {
    WeightsFile g = f;
    g.tensors[3].values[2] = std::nanf("");
    CHECK_THAT(parse_error(serialize_weights(g)), Catch::Contains(g.tensors[3].name + ": value 2"));
  }
  SECTION("wrong shape") {
    WeightsFile g = f;
    g.tensors[4].shape = {16, 16, 9};  // res1.conv2.weight
    CHECK_THAT(parse_error(serialize_weights(g)),
               Catch::Contains("res1.conv2.weight: shape [16,16,9] must be [16,16,3,3]"));
  }
  SECTION("missing tensor") {
    WeightsFile g = f;
    g.tensors.erase(g.tensors.begin() + 7);  // res2.conv1.bias
    CHECK_THAT(parse_error(serialize_weights(g)), Catch::Contains("res2.conv1.bias is missing"));
  }
  SECTION("unknown tensor") {
    WeightsFile g = f;
    g.tensors.push_back({"extra.weight", {2}, {1.0f, 2.0f}});
    CHECK_THAT(parse_error(serialize_weights(g)), Catch::Contains("extra.weight is not a tensor"));
  }
  SECTION("duplicate tensor") {
    WeightsFile g = f;
    g.tensors.push_back(g.tensors[0]);
    CHECK_THAT(parse_error(serialize_weights(g)), Catch::Contains("conv_in.weight: appears twice"));
  }
  SECTION("data offset past the end") {
    // The first record's offset field sits after magic(4)+version(2)+reserved(2)+count(4)+
    // metadata length(4)+metadata+name length(2)+name+ndim(1)+dtype(1)+4 dims.
    const std::size_t at = 16 + f.metadata.size() + 2 + f.tensors[0].name.size() + 2 + 16;
    const std::uint64_t huge = bytes.size() * 4;
    for (int i = 0; i < 8; ++i) bytes[at + static_cast<std::size_t>(i)] = (huge >> (8 * i)) & 0xFF;
    reseal(bytes);
    CHECK_THAT(parse_error(bytes), Catch::Contains("conv_in.weight: data"));
    CHECK_THAT(parse_error(bytes), Catch::Contains("outside the data area"));
  }
  SECTION("tensor count out of range") {
    bytes[8] = 0xFF;
    bytes[9] = 0xFF;
    reseal(bytes);
    CHECK_THAT(parse_error(bytes), Catch::Contains("tensor_count"));
  }
}

TEST_CASE("the convolution kernel matches a plain double-precision network", "[network]") {
  // Widths 48 / 24 / 8 exercise 3, 2 and 1 output vectors; 23 x 17 leaves remainders for every
  // pixel block size.
  for (int width : {48, 24, 8}) {
    const WeightsFile wf = random_weights(width, 11u + static_cast<unsigned>(width));
    const PdNet net(wf);
    const int w = 23, h = 17;
    const Inputs in = random_inputs(w, h);
    const Rect r{0, 0, w, h};
    Buffer alpha(r, 3), raw(r, 9);
    net.infer(in.x.view(), in.y.view(), in.var.view(), in.sure.view(), r, alpha, &raw);
    const std::vector<double> ref = reference_raw(wf, in, w, h);
    double max_abs = 0, max_diff = 0;
    for (int c = 0; c < 9; ++c)
      for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
          const double e = ref[static_cast<std::size_t>((c * h + y) * w + x)];
          max_abs = std::max(max_abs, std::abs(e));
          max_diff = std::max(max_diff, std::abs(e - raw.at(x, y, c)));
        }
    INFO("width " << width << " max |ref| " << max_abs << " max diff " << max_diff);
    CHECK(max_abs > 0.1);
    CHECK(max_diff <= 1e-5 * std::max(1.0, max_abs));
    for (int c = 0; c < 3; ++c)
      for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
          const double a = ref[static_cast<std::size_t>((c * h + y) * w + x)];
          const double b = ref[static_cast<std::size_t>(((c + 3) * h + y) * w + x)];
          const double cc = ref[static_cast<std::size_t>(((c + 6) * h + y) * w + x)];
          const double want = std::clamp((a - b) / std::max(cc, 1e-6), 0.0, 1.0);
          // Near c = 0 the ratio amplifies float rounding: compare where it is well conditioned.
          if (std::abs(cc) > 1e-2) CHECK(alpha.at(x, y, c) == Approx(want).margin(1e-4));
        }
  }
}

TEST_CASE("the network mixer in tiles equals the whole image, bit for bit", "[network]") {
  const auto net = std::make_shared<const PdNet>(random_weights(24, 7));
  const NetworkMixer mixer(net);
  const int w = 61, h = 45;
  const Inputs in = random_inputs(w, h, 9);
  const MixInputs mi{w, h, in.x.view(), in.y.view(), in.var.view(), in.sure.view(), View{}};
  const Rect image{0, 0, w, h};
  Buffer whole(image, 3);
  net->infer(in.x.view(), in.y.view(), in.var.view(), in.sure.view(), image, whole);
  // 1-pixel tiles: the border rows and columns and a cross through the middle, where the clamped
  // halo takes every shape (all 2745 of them took 42 s under ASan, the unit suite's longest).
  const auto sampled = [&](int tx, int ty) {
    return tx == 0 || ty == 0 || tx == w - 1 || ty == h - 1 || tx == w / 2 || ty == h / 2;
  };
  for (int tile : {1, 7, 16, 33}) {
    int compared = 0, differ = 0;
    for (int ty = 0; ty < h; ty += tile)
      for (int tx = 0; tx < w; tx += tile) {
        if (tile == 1 && !sampled(tx, ty)) continue;
        const Rect out{tx, ty, std::min(tx + tile, w), std::min(ty + tile, h)};
        Buffer part(out, 3);
        mixer.mix(mi, out, part);
        for (int c = 0; c < 3; ++c)
          for (int y = out.y0; y < out.y1; ++y)
            for (int x = out.x0; x < out.x1; ++x) {
              ++compared;
              differ += part.at(x, y, c) != whole.at(x, y, c);
            }
      }
    INFO("tile " << tile);
    // tile 1: the border's 2 (w + h) - 4 pixels and the cross's w + h - 1 less its 4 on the border
    CHECK(compared == 3 * (tile == 1 ? 2 * (w + h) - 4 + (w + h - 1) - 4 : w * h));
    CHECK(differ == 0);
  }
}

TEST_CASE("hard inputs give alpha in [0, 1], never NaN", "[network][hard]") {
  const PdNet net(random_weights(16, 5));
  const int w = 9, h = 8;
  Inputs in = random_inputs(w, h, 2);
  in.x.at(1, 1, 0) = 1e18f;  // the pipeline's clamp for absurd values
  in.y.at(1, 1, 0) = -1e18f;
  in.x.at(4, 4, 1) = 1e6f;  // 1e6 dynamic range
  in.var.at(2, 5, 2) = 1e36f;
  in.sure.at(6, 2, 1) = -1e30f;
  for (int c = 0; c < 3; ++c) in.var.at(7, 7, c) = 0.0f;  // zero variance
  const Rect r{0, 0, w, h};
  Buffer alpha(r, 3);
  net.infer(in.x.view(), in.y.view(), in.var.view(), in.sure.view(), r, alpha);
  for (int c = 0; c < 3; ++c)
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x) {
        const float a = alpha.at(x, y, c);
        CHECK(std::isfinite(a));
        CHECK(a >= 0.0f);
        CHECK(a <= 1.0f);
      }
}

namespace {

// `net` against a PDNP fixture written by training/export.py (PyTorch's raw output and alpha).
void check_parity(const PdNet& raw_net, const std::string& fixture) {
  const PdNet* net = &raw_net;
  INFO("fixture " << fixture);
  const std::vector<unsigned char> b = read_file(fixture);
  REQUIRE(b.size() > 16);
  REQUIRE(std::memcmp(b.data(), "PDNP", 4) == 0);
  std::uint32_t hdr[3];
  std::memcpy(hdr, b.data() + 4, sizeof hdr);
  const int H = static_cast<int>(hdr[1]), W = static_cast<int>(hdr[2]);
  const std::size_t plane = static_cast<std::size_t>(W) * static_cast<std::size_t>(H);
  REQUIRE(b.size() == 16 + plane * 4 * (12 + 9 + 3));
  auto planes = [&](std::size_t first, int n) {
    Buffer out(Rect{0, 0, W, H}, n);
    for (int c = 0; c < n; ++c)
      std::memcpy(out.row(0, c), b.data() + 16 + (first + static_cast<std::size_t>(c)) * plane * 4,
                  plane * 4);
    return out;
  };
  const Buffer x = planes(0, 3), y = planes(3, 3), var = planes(6, 3), sure = planes(9, 3);
  const Buffer raw_ref = planes(12, 9), alpha_ref = planes(21, 3);
  const Rect r{0, 0, W, H};
  Buffer alpha(r, 3), raw(r, 9);
  net->infer(x.view(), y.view(), var.view(), sure.view(), r, alpha, &raw);
  for (int c = 0; c < 9; ++c) {
    double max_ref = 0, max_diff = 0;
    for (int py = 0; py < H; ++py)
      for (int px = 0; px < W; ++px) {
        max_ref = std::max(max_ref, std::abs(static_cast<double>(raw_ref.at(px, py, c))));
        max_diff = std::max(
            max_diff, std::abs(static_cast<double>(raw_ref.at(px, py, c)) - raw.at(px, py, c)));
      }
    INFO("raw channel " << c << ": max |torch| " << max_ref << ", max diff " << max_diff);
    CHECK(max_diff <= 1e-4 * std::max(1.0, max_ref));
  }
  double max_alpha_diff = 0;
  for (int c = 0; c < 3; ++c)
    for (int py = 0; py < H; ++py)
      for (int px = 0; px < W; ++px)
        max_alpha_diff =
            std::max(max_alpha_diff,
                     std::abs(static_cast<double>(alpha_ref.at(px, py, c)) - alpha.at(px, py, c)));
  INFO("alpha: max diff " << max_alpha_diff);
  CHECK(max_alpha_diff <= 1e-4);
}

std::shared_ptr<const PdNet> load(const std::string& path) {
  return std::make_shared<const PdNet>(parse_weights(read_file(path), path), path);
}

}  // namespace

// tests/training/smoke.sh sets PRODEN_TEST_WEIGHTS / PRODEN_TEST_FIXTURE to a freshly trained and
// exported network; otherwise the committed weights are checked against their fixtures.
TEST_CASE("the network matches its PyTorch parity fixture", "[network][parity]") {
  const char* weights_env = std::getenv("PRODEN_TEST_WEIGHTS");
  const char* fixture_env = std::getenv("PRODEN_TEST_FIXTURE");
  if (weights_env || fixture_env) {
    REQUIRE(weights_env);
    REQUIRE(fixture_env);
    check_parity(*load(weights_env), fixture_env);
    return;
  }
  const std::string dir = PRODEN_SOURCE_DIR;
  SECTION("built-in (training/weights/pdnet.pdnw)") {
    const auto net = builtin_network();
    check_parity(*net, dir + "/tests/data/pdnet_parity_w" + std::to_string(net->width()) + ".bin");
  }
  SECTION("width 24") {
    check_parity(*load(dir + "/training/weights/pdnet_w24.pdnw"),
                 dir + "/tests/data/pdnet_parity_w24.bin");
  }
  SECTION("width 48 trained on NFOR's output (docs/mixer_network.md)") {
    check_parity(*load(dir + "/training/weights/pdnet_nfor_w48.pdnw"),
                 dir + "/tests/data/pdnet_parity_nfor_w48.bin");
  }
  SECTION("untrained width 48 (alpha inside (0, 1): exercises the division)") {
    check_parity(*load(dir + "/training/weights/pdnet_w48_init.pdnw"),
                 dir + "/tests/data/pdnet_parity_init_w48.bin");
  }
}

TEST_CASE("every kernel build this CPU runs (AVX-512, AVX2, baseline) computes the same layer",
          "[network]") {
  std::mt19937 rng(21);
  std::normal_distribution<float> n(0.0f, 0.2f);
  struct Shape {
    int cin, cout, k;
    bool residual, relu;
  };
  // 48 outputs = 3 vectors, 24 -> 2 (padded), 9 -> 1; 5x5 and 3x3; with and without residual.
  for (const Shape sh : {Shape{18, 48, 5, false, true}, Shape{48, 48, 3, true, true},
                         Shape{24, 24, 3, false, true}, Shape{48, 9, 3, false, false}}) {
    network::ConvLayer L;
    L.name = "t";
    L.k = sh.k;
    L.cin = sh.cin;
    L.cout = sh.cout;
    L.cout_pad = (sh.cout + 15) / 16 * 16;
    L.weights.assign(static_cast<std::size_t>(sh.k * sh.k * sh.cin * L.cout_pad), 0.0f);
    L.bias.assign(static_cast<std::size_t>(L.cout_pad), 0.0f);
    for (int t = 0; t < sh.k * sh.k * sh.cin; ++t)
      for (int o = 0; o < sh.cout; ++o)
        L.weights[static_cast<std::size_t>(t * L.cout_pad + o)] = n(rng);
    for (int o = 0; o < sh.cout; ++o) L.bias[static_cast<std::size_t>(o)] = n(rng);
    const int h = 9, w = 19;  // remainders for every pixel block size
    std::vector<float> in_s, res_s;
    const auto in = network::detail::Activation::bind(in_s, h, w, sh.cin);
    const auto res = network::detail::Activation::bind(res_s, h, w, L.cout_pad);
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x) {
        for (int c = 0; c < sh.cin; ++c) in.px(y, x)[c] = n(rng);
        for (int c = 0; c < L.cout_pad; ++c) res.px(y, x)[c] = c < sh.cout ? n(rng) : 0.0f;
      }
    const int r = sh.k / 2;
    for (const std::string& isa : network::detail::conv_isas_available()) {
      std::vector<float> out_s;
      auto out = network::detail::Activation::bind(out_s, h, w, L.cout_pad);
      network::detail::conv_forward_with(isa, L, in, out, sh.residual ? &res : nullptr, sh.relu);
      double worst = 0;
      for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x)
          for (int o = 0; o < sh.cout; ++o) {
            double s = L.bias[static_cast<std::size_t>(o)];
            for (int ky = 0; ky < sh.k; ++ky)
              for (int kx = 0; kx < sh.k; ++kx) {
                const int sy = y + ky - r, sx = x + kx - r;
                if (sy < 0 || sx < 0 || sy >= h || sx >= w) continue;
                for (int i = 0; i < sh.cin; ++i)
                  s += static_cast<double>(L.weights[static_cast<std::size_t>(
                           ((ky * sh.k + kx) * sh.cin + i) * L.cout_pad + o)]) *
                       in.px(sy, sx)[i];
              }
            if (sh.residual) s += res.px(y, x)[o];
            if (sh.relu) s = std::max(s, 0.0);
            worst = std::max(worst, std::abs(s - out.px(y, x)[o]));
          }
      INFO("isa " << isa << ", " << sh.cin << " -> " << sh.cout << ", " << sh.k << "x" << sh.k);
      CHECK(worst < 1e-4);
    }
  }
  CHECK(network::detail::conv_isas_available().front() == "baseline");
}
