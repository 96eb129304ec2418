#include "proden/network/pdnet.hpp"

#include <algorithm>
#include <cmath>
#include <random>
#include <set>

#include "conv.hpp"

namespace proden::network {
namespace {

using detail::Activation;

// Looks up `name` and checks its shape; repacks OIHW into [ky][kx][cin][cout_pad].
ConvLayer load_conv(const WeightsFile& w, const std::string& source, const std::string& name,
                    int cout, int cin, int k, std::set<std::string>& used) {
  auto shape_str = [](const std::vector<int>& s) {
    std::string out = "[";
    for (std::size_t i = 0; i < s.size(); ++i) out += (i ? "," : "") + std::to_string(s[i]);
    return out + "]";
  };
  const Tensor* wt = w.find(name + ".weight");
  const Tensor* bt = w.find(name + ".bias");
  if (!wt) throw WeightsError(source + ": " + name + ".weight is missing");
  if (!bt) throw WeightsError(source + ": " + name + ".bias is missing");
  const std::vector<int> want_w = {cout, cin, k, k}, want_b = {cout};
  if (wt->shape != want_w) {
    throw WeightsError(source + ": " + name + ".weight: shape " + wt->shape_string() + " must be " +
                       shape_str(want_w));
  }
  if (bt->shape != want_b) {
    throw WeightsError(source + ": " + name + ".bias: shape " + bt->shape_string() + " must be " +
                       shape_str(want_b));
  }
  used.insert(wt->name);
  used.insert(bt->name);
  ConvLayer L;
  L.name = name;
  L.k = k;
  L.cin = cin;
  L.cout = cout;
  L.cout_pad = (cout + 15) / 16 * 16;
  L.weights.assign(static_cast<std::size_t>(k * k * cin) * static_cast<std::size_t>(L.cout_pad),
                   0.0f);
  L.bias.assign(static_cast<std::size_t>(L.cout_pad), 0.0f);
  for (int o = 0; o < cout; ++o) {
    L.bias[static_cast<std::size_t>(o)] = bt->values[static_cast<std::size_t>(o)];
    for (int i = 0; i < cin; ++i) {
      for (int ky = 0; ky < k; ++ky) {
        for (int kx = 0; kx < k; ++kx) {
          const std::size_t src = ((static_cast<std::size_t>(o) * cin + i) * k + ky) * k + kx;
          const std::size_t dst =
              ((static_cast<std::size_t>(ky) * k + kx) * cin + i) * L.cout_pad + o;
          L.weights[dst] = wt->values[src];
        }
      }
    }
  }
  return L;
}

double layer_flops(const ConvLayer& L) {
  return 2.0 * L.k * L.k * L.cin * L.cout;
}

}  // namespace

PdNet::PdNet(const WeightsFile& weights, std::string source) : source_(std::move(source)) {
  const Tensor* first = weights.find("conv_in.weight");
  if (!first) throw WeightsError(source_ + ": conv_in.weight is missing");
  if (first->shape.size() != 4 || first->shape[0] < 1 || first->shape[0] > 256) {
    throw WeightsError(source_ + ": conv_in.weight: shape " + first->shape_string() +
                       " must be [W,18,5,5] with 1 <= W <= 256");
  }
  width_ = first->shape[0];
  std::set<std::string> used;
  conv_in_ = load_conv(weights, source_, "conv_in", width_, kInputs, 5, used);
  for (int b = 0; b < 2; ++b) {
    for (int c = 0; c < 2; ++c) {
      res_[b][c] = load_conv(weights, source_,
                             "res" + std::to_string(b + 1) + ".conv" + std::to_string(c + 1),
                             width_, width_, 3, used);
    }
  }
  conv_out_ = load_conv(weights, source_, "conv_out", kOutputs, width_, 3, used);
  for (const auto& t : weights.tensors) {
    if (!used.count(t.name)) {
      throw WeightsError(source_ + ": " + t.name + " is not a tensor of this network");
    }
  }
}

double PdNet::flops_per_pixel() const {
  double f = layer_flops(conv_in_) + layer_flops(conv_out_);
  for (const auto& b : res_) f += layer_flops(b[0]) + layer_flops(b[1]);
  return f;
}

WeightsFile random_weights(int width, unsigned seed) {
  std::mt19937 rng(seed);
  WeightsFile f;
  f.metadata = R"({"untrained": true})";
  auto conv = [&](const std::string& name, int cout, int cin, int k) {
    std::normal_distribution<float> n(0.0f, std::sqrt(2.0f / static_cast<float>(cin * k * k)));
    Tensor w{name + ".weight", {cout, cin, k, k}, {}};
    w.values.resize(w.size());
    for (auto& v : w.values) v = n(rng);
    Tensor b{name + ".bias", {cout}, std::vector<float>(static_cast<std::size_t>(cout))};
    for (auto& v : b.values) v = 0.1f * n(rng);
    f.tensors.push_back(std::move(w));
    f.tensors.push_back(std::move(b));
  };
  conv("conv_in", width, PdNet::kInputs, 5);
  for (const char* b : {"res1", "res2"}) {
    conv(std::string(b) + ".conv1", width, width, 3);
    conv(std::string(b) + ".conv2", width, width, 3);
  }
  conv("conv_out", PdNet::kOutputs, width, 3);
  return f;
}

void network_features(float x, float y, float var, float sure, float out[6]) {
  const float d2 = (x - y) * (x - y);
  out[0] = x;
  out[1] = y;
  out[2] = std::atan(var);
  out[3] = std::atan(sure);
  out[4] = std::atan(d2);
  out[5] = std::atan(sure + var - d2);
}

void PdNet::infer(const View& x, const View& y, const View& var, const View& sure,
                  const Rect& region, Buffer& alpha, Buffer* raw, InferScratch* scratch) const {
  const int h = region.height(), w = region.width();
  if (h <= 0 || w <= 0) return;
  InferScratch local;
  InferScratch& s = scratch ? *scratch : local;
  const Activation in = Activation::bind(s.buffers[0], h, w, kInputs);
  for (int py = 0; py < h; ++py) {
    for (int px = 0; px < w; ++px) {
      float* p = in.px(py, px);
      const int gx = region.x0 + px, gy = region.y0 + py;
      for (int c = 0; c < 3; ++c) {
        float f[6];
        network_features(x.at(gx, gy, c), y.at(gx, gy, c), var.at(gx, gy, c), sure.at(gx, gy, c),
                         f);
        for (int g = 0; g < 6; ++g) p[3 * g + c] = f[g];
      }
    }
  }
  const int cp = conv_in_.cout_pad;
  Activation a = Activation::bind(s.buffers[1], h, w, cp);
  Activation b = Activation::bind(s.buffers[2], h, w, cp);
  Activation t = Activation::bind(s.buffers[3], h, w, cp);
  detail::conv_forward(conv_in_, in, a, nullptr, true);
  detail::conv_forward(res_[0][0], a, t, nullptr, true);
  detail::conv_forward(res_[0][1], t, b, &a, true);
  detail::conv_forward(res_[1][0], b, t, nullptr, true);
  detail::conv_forward(res_[1][1], t, a, &b, true);
  Activation o = Activation::bind(s.buffers[4], h, w, conv_out_.cout_pad);
  detail::conv_forward(conv_out_, a, o, nullptr, false);

  for (int py = 0; py < h; ++py) {
    for (int px = 0; px < w; ++px) {
      const float* v = o.px(py, px);
      const int gx = region.x0 + px, gy = region.y0 + py;
      for (int c = 0; c < 3; ++c) {
        const float al = (v[c] - v[3 + c]) / std::max(v[6 + c], 1e-6f);
        // NaN (overflowing inputs) falls back to the render: alpha 0 keeps z = x.
        alpha.at(gx, gy, c) = std::isnan(al) ? 0.0f : std::clamp(al, 0.0f, 1.0f);
      }
      if (raw) {
        for (int c = 0; c < kOutputs; ++c) raw->at(gx, gy, c) = v[c];
      }
    }
  }
}

std::string NetworkMixer::name() const {
  return "network-w" + std::to_string(net_->width());
}

void NetworkMixer::mix(const MixInputs& in, const Rect& out, Buffer& alpha) const {
  const Rect image{0, 0, in.width, in.height};
  const Rect region = out.expanded(PdNet::kRadius).intersect(image);
  Buffer full(region, 3);
  net_->infer(in.x, in.y, in.variance, in.sure, region, full, nullptr, &scratch_.local());
  for (int c = 0; c < 3; ++c) {
    for (int py = out.y0; py < out.y1; ++py) {
      for (int px = out.x0; px < out.x1; ++px) alpha.at(px, py, c) = full.at(px, py, c);
    }
  }
}

}  // namespace proden::network
