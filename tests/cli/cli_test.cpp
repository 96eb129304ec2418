// End-to-end tests of the `proden` binary on the committed real renders. Values are checked
// against an independent computation: passes and outputs read with OpenEXR's own API (not OIIO,
// which proden uses) and statistics computed with a plain two-pass formula in double.
#include <ImfChannelList.h>
#include <ImfFrameBuffer.h>
#include <ImfHeader.h>
#include <ImfInputFile.h>
#include <ImfStringAttribute.h>
#include <sys/wait.h>

#include <algorithm>
#include <array>
#include <catch2/catch.hpp>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <nlohmann/json.hpp>
#include <random>
#include <sstream>
#include <string>
#include <vector>

using Catch::Matchers::Contains;
namespace fs = std::filesystem;

namespace {

struct Run {
  int code = -1;
  std::string out, err;
};

struct Scratch {
  fs::path dir;
  Scratch() {
    dir = fs::temp_directory_path() / ("proden-cli-" + std::to_string(std::random_device{}()));
    fs::create_directories(dir);
  }
  ~Scratch() {
    std::error_code ec;
    fs::remove_all(dir, ec);
  }
  std::string file(const std::string& n) const { return (dir / n).string(); }
};

Run proden(const std::string& args, const Scratch& s) {
  const std::string errf = s.file("stderr.txt");
  const std::string cmd = std::string(PRODEN_BINARY) + " " + args + " 2>" + errf;
  Run r;
  FILE* p = ::popen(cmd.c_str(), "r");
  REQUIRE(p);
  std::array<char, 4096> buf{};
  std::size_t n;
  while ((n = std::fread(buf.data(), 1, buf.size(), p)) > 0) r.out.append(buf.data(), n);
  const int status = ::pclose(p);
  r.code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  std::ifstream e(errf);
  std::stringstream ss;
  ss << e.rdbuf();
  r.err = ss.str();
  return r;
}

std::string sample(const std::string& rel) {
  return std::string(PRODEN_SAMPLES_DIR) + "/" + rel;
}

std::vector<std::string> passes(const std::string& set) {
  std::vector<std::string> v;
  for (int k = 0; k < 8; ++k) {
    char name[32];
    std::snprintf(name, sizeof name, "/pass_%02d.exr", k);
    v.push_back(sample("renders/" + set + name));
  }
  return v;
}

std::string join(const std::vector<std::string>& v) {
  std::string s;
  for (const auto& x : v) s += " " + x;
  return s;
}

// Reads named channels with OpenEXR as float planes.
std::vector<std::vector<float>> read_exr(const std::string& path,
                                         const std::vector<std::string>& names, int* w, int* h) {
  Imf::InputFile in(path.c_str());
  const Imath::Box2i dw = in.header().dataWindow();
  *w = dw.max.x - dw.min.x + 1;
  *h = dw.max.y - dw.min.y + 1;
  const std::size_t n = static_cast<std::size_t>(*w) * static_cast<std::size_t>(*h);
  std::vector<std::vector<float>> planes(names.size(), std::vector<float>(n));
  Imf::FrameBuffer fb;
  for (std::size_t c = 0; c < names.size(); ++c) {
    REQUIRE(in.header().channels().findChannel(names[c].c_str()) != nullptr);
    char* base =
        reinterpret_cast<char*>(planes[c].data()) -
        (static_cast<std::ptrdiff_t>(dw.min.x) + static_cast<std::ptrdiff_t>(dw.min.y) * *w) *
            static_cast<std::ptrdiff_t>(sizeof(float));
    fb.insert(names[c].c_str(), Imf::Slice(Imf::FLOAT, base, sizeof(float),
                                           sizeof(float) * static_cast<std::size_t>(*w)));
  }
  in.setFrameBuffer(fb);
  in.readPixels(dw.min.y, dw.max.y);
  return planes;
}

// Every string attribute of an EXR header whose name starts with `prefix`, read with OpenEXR.
std::map<std::string, std::string> string_attributes(const std::string& path,
                                                     const std::string& prefix = "proden:") {
  Imf::InputFile in(path.c_str());
  std::map<std::string, std::string> out;
  for (auto it = in.header().begin(); it != in.header().end(); ++it) {
    const std::string name = it.name();
    if (name.rfind(prefix, 0) != 0) continue;
    if (const auto* a = dynamic_cast<const Imf::StringAttribute*>(&it.attribute())) {
      out[name] = a->value();
    }
  }
  return out;
}

const std::vector<std::string> kCombined = {"ViewLayer.Combined.R", "ViewLayer.Combined.G",
                                            "ViewLayer.Combined.B"};

// Independent mean and variance of the mean over equal-spp passes.
void check_against_independent(const std::string& set, const std::string& out) {
  const auto files = passes(set);
  int w = 0, h = 0;
  std::vector<std::vector<std::vector<float>>> data;
  for (const auto& f : files) data.push_back(read_exr(f, kCombined, &w, &h));
  int ow = 0, oh = 0;
  const auto render = read_exr(out, {"render.R", "render.G", "render.B"}, &ow, &oh);
  const auto var = read_exr(out, {"variance.R", "variance.G", "variance.B"}, &ow, &oh);
  const auto result = read_exr(out, {"R", "G", "B"}, &ow, &oh);
  const auto denoised = read_exr(out, {"denoised.R", "denoised.G", "denoised.B"}, &ow, &oh);
  const auto alpha = read_exr(out, {"alpha.R", "alpha.G", "alpha.B"}, &ow, &oh);
  const auto sure = read_exr(out, {"sure.R", "sure.G", "sure.B"}, &ow, &oh);
  REQUIRE(ow == w);
  REQUIRE(oh == h);
  const double K = static_cast<double>(files.size());
  double worst_mean = 0, worst_var = 0;
  for (int c = 0; c < 3; ++c) {
    for (std::size_t p = 0; p < render[static_cast<std::size_t>(c)].size(); ++p) {
      double m = 0;
      for (const auto& d : data) m += d[static_cast<std::size_t>(c)][p];
      m /= K;
      double s2 = 0;
      for (const auto& d : data) {
        const double e = d[static_cast<std::size_t>(c)][p] - m;
        s2 += e * e;
      }
      const double v = s2 / (K - 1) / K;
      const double got_m = render[static_cast<std::size_t>(c)][p];
      const double got_v = var[static_cast<std::size_t>(c)][p];
      worst_mean = std::max(worst_mean, std::abs(got_m - m) / std::max(std::abs(m), 1e-6));
      worst_var = std::max(worst_var, std::abs(got_v - v) / std::max(v, 1e-12));
      // The result is the blend (1 - alpha) render + alpha denoised.
      const auto cc = static_cast<std::size_t>(c);
      const double a = alpha[cc][p], x = render[cc][p], y = denoised[cc][p];
      REQUIRE(a >= 0.0);
      REQUIRE(a <= 1.0);
      REQUIRE(std::isfinite(sure[cc][p]));
      REQUIRE(result[cc][p] == Approx((1 - a) * x + a * y).margin(1e-6 * std::abs(x) + 1e-7));
    }
  }
  INFO("worst relative error: mean " << worst_mean << ", variance " << worst_var);
  CHECK(worst_mean < 1e-5);
  CHECK(worst_var < 1e-4);
}

}  // namespace

TEST_CASE(
    "denoise --aov on real Cycles passes writes render.* and variance.* that match an "
    "independent computation",
    "[cli][real]") {
  Scratch s;
  for (const std::string set : {"cornell", "textured_dof"}) {
    const std::string out = s.file(set + ".exr");
    const Run r = proden("denoise --quiet --aov --json --out " + out + join(passes(set)), s);
    INFO(r.err);
    REQUIRE(r.code == 0);
    const auto j = nlohmann::json::parse(r.out);
    CHECK(j["pass_count"] == 8);
    CHECK(j["spp"] == 32.0);
    CHECK(j["layout"]["name"] == "HDR+ALB+NRM+DEP");
    CHECK(j["variance_source"] == "between_passes");
    CHECK(j["low_confidence"] == false);
    CHECK(j["inputs_used"] == "HDR+ALB+NRM+DEP");
    CHECK(j["pipeline"]["denoiser"] == "nlmeans");
    check_against_independent(set, out);
  }
}

TEST_CASE("denoise --half writes half floats and --no-features reports HDR only", "[cli]") {
  Scratch s;
  const std::string out = s.file("h.exr");
  const Run r =
      proden("denoise -q --half --no-features --json --out " + out + join(passes("cornell")), s);
  REQUIRE(r.code == 0);
  CHECK(nlohmann::json::parse(r.out)["layout"]["name"] == "HDR");
  Imf::InputFile in(out.c_str());
  const Imf::Channel* ch = in.header().channels().findChannel("R");
  REQUIRE(ch);
  CHECK(ch->type == Imf::HALF);
  CHECK(in.header().channels().findChannel("render.R") == nullptr);  // no --aov
}

TEST_CASE("denoise --compression: PIZ by default (auto), the values the same in every compression",
          "[cli]") {
  Scratch s;
  std::vector<std::vector<std::vector<float>>> values;
  for (const std::string c : {"", "auto", "zip", "rle", "none"}) {
    const std::string out = s.file("c" + c + ".exr");
    const Run r = proden("denoise -q --aov" + (c.empty() ? "" : " --compression " + c) + " --out " +
                             out + join(passes("cornell")),
                         s);
    INFO(r.err);
    REQUIRE(r.code == 0);
    Imf::InputFile in(out.c_str());
    const Imf::Compression want = c.empty() || c == "auto" ? Imf::PIZ_COMPRESSION
                                  : c == "zip"             ? Imf::ZIP_COMPRESSION
                                  : c == "rle"             ? Imf::RLE_COMPRESSION
                                                           : Imf::NO_COMPRESSION;
    CHECK(in.header().compression() == want);
    int w = 0, h = 0;
    values.push_back(read_exr(out, {"R", "G", "B", "denoised.R", "alpha.G", "variance.B"}, &w, &h));
  }
  for (std::size_t i = 1; i < values.size(); ++i) CHECK(values[i] == values[0]);  // lossless
  const Run bad =
      proden("denoise -q --compression dwaa --out " + s.file("x.exr") + join(passes("cornell")), s);
  CHECK(bad.code != 0);
  CHECK_THAT(bad.err, Catch::Contains("one of auto, piz, zip, zips, rle, none"));
}

TEST_CASE("eval agrees with metrics computed independently", "[cli][real]") {
  Scratch s;
  const std::string ref = sample("renders/cornell/reference.exr");
  const std::string img = sample("renders/cornell/pass_03.exr");
  const Run r = proden("eval --json --ref " + ref + " " + img, s);
  INFO(r.err);
  REQUIRE(r.code == 0);
  const auto j = nlohmann::json::parse(r.out);
  REQUIRE(j["results"].size() == 1);
  int w, h;
  const auto a = read_exr(img, kCombined, &w, &h);
  const auto b = read_exr(ref, kCombined, &w, &h);
  double se = 0, rel = 0, sm = 0, n = 0;
  for (std::size_t c = 0; c < 3; ++c) {
    for (std::size_t p = 0; p < a[c].size(); ++p) {
      const double i = a[c][p], t = b[c][p], d = i - t;
      se += d * d;
      rel += d * d / (t * t + 0.01);
      sm += std::abs(d) / (std::abs(i) + std::abs(t) + 0.01);
      ++n;
    }
  }
  const auto& m = j["results"][0];
  CHECK(m["rmse"].get<double>() == Approx(std::sqrt(se / n)).epsilon(1e-9));
  CHECK(m["relmse"].get<double>() == Approx(rel / n).epsilon(1e-9));
  CHECK(m["smape"].get<double>() == Approx(sm / n).epsilon(1e-9));
  // The table form prints the same image and a header.
  const Run t = proden("eval --ref " + ref + " " + img, s);
  CHECK(t.code == 0);
  CHECK_THAT(t.out, Contains("RMSE") && Contains("pass_03.exr"));
}

TEST_CASE("eval: the accumulated render beats a single pass and a reference made of passes works",
          "[cli][real]") {
  Scratch s;
  const std::string out = s.file("acc.exr");
  REQUIRE(proden("denoise -q --out " + out + join(passes("cornell")), s).code == 0);
  const Run r = proden("eval --json --ref " + sample("renders/cornell/reference.exr") + " " +
                           sample("renders/cornell/pass_00.exr") + " " + out,
                       s);
  REQUIRE(r.code == 0);
  const auto j = nlohmann::json::parse(r.out);
  // 8 passes: the render's MSE falls by ~8x (RMSE is dominated by a few fireflies, so compare
  // relMSE), and the denoised result does better still; require 4x.
  CHECK(j["results"][1]["relmse"].get<double>() * 4 < j["results"][0]["relmse"].get<double>());
  // Reference given as passes: their mean.
  const auto ps = passes("cornell");
  const Run r2 = proden("eval --json --ref " + ps[0] + " --ref " + ps[1] + " " + ps[0], s);
  REQUIRE(r2.code == 0);
  CHECK(nlohmann::json::parse(r2.out)["results"][0]["rmse"].get<double>() > 0);
}

TEST_CASE("the pipeline's result beats the render and matches the better of render and denoised",
          "[cli][real]") {
  Scratch s;
  for (const std::string set : {"cornell", "textured_dof"}) {
    const std::string out = s.file(set + ".exr");
    REQUIRE(proden("denoise -q --aov --out " + out + join(passes(set)), s).code == 0);
    const Run r = proden("eval --json --layer render --layer denoised --layer result --ref " +
                             sample("renders/" + set + "/reference.exr") + " " + out,
                         s);
    REQUIRE(r.code == 0);
    const auto j = nlohmann::json::parse(r.out)["results"];
    REQUIRE(j.size() == 3);
    const double render = j[0]["relmse"], denoised = j[1]["relmse"], result = j[2]["relmse"];
    INFO(set << ": relMSE render " << render << " denoised " << denoised << " result " << result);
    CHECK(result < 0.8 * render);
    CHECK(result <= 1.05 * std::min(render, denoised));
  }
}

TEST_CASE("denoise --mixer network runs the learned mixer on real Cycles passes", "[cli][real]") {
  Scratch s;
  for (const std::string set : {"cornell", "textured_dof"}) {
    const std::string out = s.file(set + "_net.exr");
    const Run d =
        proden("denoise -q --aov --json --mixer network --out " + out + join(passes(set)), s);
    REQUIRE(d.code == 0);
    const auto summary = nlohmann::json::parse(d.out);
    CHECK(summary["pipeline"]["mixer"].get<std::string>().rfind("network-w", 0) == 0);
    CHECK(summary["pipeline"]["weights"] == "built-in pdnet.pdnw");
    check_against_independent(set, out);  // alpha in [0, 1], result = blend, finite SURE
    const Run r = proden("eval --json --layer render --layer denoised --layer result --ref " +
                             sample("renders/" + set + "/reference.exr") + " " + out,
                         s);
    REQUIRE(r.code == 0);
    const auto j = nlohmann::json::parse(r.out)["results"];
    const double render = j[0]["relmse"], denoised = j[1]["relmse"], result = j[2]["relmse"];
    INFO(set << ": relMSE render " << render << " denoised " << denoised << " result " << result);
    CHECK(result < 0.8 * render);
  }
}

TEST_CASE("denoise --denoiser nfor runs NFOR under both mixers and names it in the header",
          "[cli][real]") {
  Scratch s;
  const std::string ref = sample("renders/cornell/reference.exr");
  const std::string nlm = s.file("nlmeans.exr");
  REQUIRE(proden("denoise -q --aov --out " + nlm + join(passes("cornell")), s).code == 0);
  int w = 0, h = 0;
  const auto y_nlm = read_exr(nlm, {"denoised.R", "denoised.G", "denoised.B"}, &w, &h);
  for (const std::string mixer : {"closed-form", "network"}) {
    INFO("mixer " << mixer);
    const std::string out = s.file("nfor_" + mixer + ".exr");
    const Run d = proden("denoise -q --aov --json --timings --denoiser nfor --mixer " + mixer +
                             " --out " + out + join(passes("cornell")),
                         s);
    INFO(d.err);
    REQUIRE(d.code == 0);
    const auto j = nlohmann::json::parse(d.out);
    CHECK(j["pipeline"]["denoiser"] == "nfor");
    CHECK(j["inputs_used"] == "HDR+ALB+NRM+DEP");
    // The sample's passes fill every quarter: NFOR is cross-validated on them.
    CHECK(j["estimated_error"]["source"] == "variance+cross-validation");
    // ... and what that costs is its own stage (NFOR's two half runs).
    CHECK(j["timings"]["cross_validation_cpu"].get<double>() > 0.0);
    const auto hdr = string_attributes(out);
    CHECK(hdr.at("proden:denoiser") == "nfor");
    CHECK(hdr.at("proden:divergence") == "analytic");  // NFOR's hat diagonal (docs/nfor.md)
    CHECK(hdr.at("proden:mixer").rfind(mixer == "network" ? "network-w" : "closed-form-", 0) == 0);
    check_against_independent("cornell", out);  // alpha in [0, 1], result = blend, finite SURE
    // y is NFOR's, not NL-means'.
    const auto y = read_exr(out, {"denoised.R", "denoised.G", "denoised.B"}, &w, &h);
    CHECK(y != y_nlm);
    const Run r = proden(
        "eval --json --layer render --layer denoised --layer result --ref " + ref + " " + out, s);
    REQUIRE(r.code == 0);
    const auto m = nlohmann::json::parse(r.out)["results"];
    REQUIRE(m.size() == 3);
    const double render = m[0]["relmse"], denoised = m[1]["relmse"], result = m[2]["relmse"];
    INFO("relMSE render " << render << " NFOR " << denoised << " result " << result);
    CHECK(denoised < 0.5 * render);
    CHECK(result < 0.5 * render);
    CHECK(result <= 1.05 * std::min(render, denoised));
  }
}

TEST_CASE("denoise --weights: a corrupt or missing file is refused by name, exit 2", "[cli]") {
  Scratch s;
  const std::string bad = s.file("bad.pdnw");
  {
    std::ofstream f(bad, std::ios::binary);
    const char head[] = {'P', 'D', 'N', 'W', 1, 0, 0, 0};  // valid magic and version
    f.write(head, sizeof head);
    f << "not really weights, long enough to reach the checksum";
  }
  const std::string out = s.file("o.exr");
  const Run r = proden(
      "denoise -q --mixer network --weights " + bad + " --out " + out + join(passes("cornell")), s);
  CHECK(r.code == 2);
  CHECK_THAT(r.err, Catch::Contains(bad));
  CHECK_THAT(r.err, Catch::Contains("checksum"));
  CHECK_FALSE(std::filesystem::exists(out));
  const Run m = proden("denoise -q --mixer network --weights " + s.file("none.pdnw") + " --out " +
                           out + join(passes("cornell")),
                       s);
  CHECK(m.code == 2);
  CHECK_THAT(m.err, Catch::Contains("none.pdnw: cannot be opened"));
}

TEST_CASE("info reports renderer, size, channels and spp", "[cli][real]") {
  Scratch s;
  const Run r = proden("info --json " + sample("renders/cornell/pass_00.exr") + " " +
                           sample("renders/povray/pass_00.exr"),
                       s);
  INFO(r.err);
  REQUIRE(r.code == 0);
  const auto j = nlohmann::json::parse(r.out);
  CHECK(j[0]["renderer"] == "cycles");
  CHECK(j[0]["spp"] == 4.0);
  CHECK(j[0]["spp_source"] == "header");
  CHECK(j[0]["width"] == 128);
  CHECK(j[1]["renderer"] == "povray");
  const Run t = proden("info " + sample("renders/cornell/pass_00.exr"), s);
  CHECK_THAT(t.out, Contains("cycles") && Contains("128x128") && Contains("HDR+ALB+NRM+DEP"));
}

TEST_CASE("bad input: named in the error, exit code 3, the rest still processed", "[cli]") {
  Scratch s;
  const std::string placeholder = s.file("placeholder.exr");
  std::ofstream(placeholder).close();
  const auto ps = passes("cornell");
  const std::string out = s.file("o.exr");
  const Run r = proden("denoise -q --json --out " + out + " " + ps[0] + " " + placeholder + " " +
                           ps[1] + " " + ps[1],
                       s);
  CHECK(r.code == 3);
  CHECK_THAT(r.err, Contains(placeholder) && Contains("empty file"));
  CHECK_THAT(r.err, Contains("identical to the already accumulated pass"));
  REQUIRE(fs::exists(out));
  CHECK(nlohmann::json::parse(r.out)["pass_count"] == 2);

  const std::string out2 = s.file("none.exr");
  const Run none = proden("denoise -q --out " + out2 + " " + s.file("missing.exr"), s);
  CHECK(none.code == 3);
  CHECK_THAT(none.err, Contains("missing.exr") && Contains("no such file"));
  CHECK_FALSE(fs::exists(out2));

  const Run usage = proden("denoise " + ps[0], s);  // --out missing
  CHECK(usage.code == 2);
  CHECK(proden("frobnicate", s).code == 2);
}

TEST_CASE(
    "denoise --json reports the estimated error as the daemon does, and the header says how "
    "the frame was made",
    "[cli][real]") {
  Scratch s;
  const std::string out = s.file("e.exr");
  const Run r = proden("denoise -q --aov --json --out " + out + join(passes("cornell")), s);
  INFO(r.err);
  REQUIRE(r.code == 0);
  const auto j = nlohmann::json::parse(r.out);
  // The daemon's frame-status keys (docs/api.md).
  REQUIRE(j.contains("estimated_mse"));
  const double est = j["estimated_mse"];
  // 8 passes: the denoiser's error is cross-validated between the half buffers.
  CHECK(j["estimated_mse_source"] == "variance+cross-validation");
  CHECK(j["estimated_error"]["mse"] == est);
  CHECK(j["estimated_error"]["source"] == "variance+cross-validation");
  CHECK(est > 0);
  // Recomputed independently from the written layers (docs/error_estimate.md): the mean over
  // pixels and RGB of (1-a) var + a m - a (1-a) (y-x)^2 with the denoiser's MSE
  // m = (cvsquare - cvvariance) / sqrt(2), floored at the mean of (1-a)^2 var.
  int w = 0, h = 0;
  const auto x = read_exr(out, {"render.R", "render.G", "render.B"}, &w, &h);
  const auto v = read_exr(out, {"variance.R", "variance.G", "variance.B"}, &w, &h);
  const auto y = read_exr(out, {"denoised.R", "denoised.G", "denoised.B"}, &w, &h);
  const auto a = read_exr(out, {"alpha.R", "alpha.G", "alpha.B"}, &w, &h);
  read_exr(out, {"sure.R", "sure.G", "sure.B"}, &w, &h);                       // present
  read_exr(out, {"mixvariance.R", "mixvariance.G", "mixvariance.B"}, &w, &h);  // present
  const auto cq = read_exr(out, {"cvsquare.R", "cvsquare.G", "cvsquare.B"}, &w, &h);
  const auto cv = read_exr(out, {"cvvariance.R", "cvvariance.G", "cvvariance.B"}, &w, &h);
  double sum = 0, floor = 0, n = 0;
  for (std::size_t c = 0; c < 3; ++c) {
    for (std::size_t p = 0; p < x[c].size(); ++p, ++n) {
      const double al = a[c][p], d = static_cast<double>(y[c][p]) - x[c][p];
      const double m = (static_cast<double>(cq[c][p]) - cv[c][p]) / std::sqrt(2.0);
      sum += (1 - al) * v[c][p] + al * m - al * (1 - al) * d * d;
      floor += (1 - al) * (1 - al) * v[c][p];
    }
  }
  CHECK(est == Approx(std::max(sum, floor) / n).epsilon(1e-9));

  const auto hdr = string_attributes(out);
  const std::map<std::string, std::string> want = {
      {"proden:passes", "8"},
      {"proden:spp", "32.000000"},
      {"proden:inputs", "HDR+ALB+NRM+DEP"},
      {"proden:denoiser", "nlmeans"},
      {"proden:mixer", "closed-form-stein"},
      {"proden:mixer_weights", "none"},
      {"proden:divergence", "analytic"},
      {"proden:t_test", "on"},
      {"proden:variance_source", "between_passes"},
      {"proden:low_confidence", "false"},
      {"proden:estimated_mse_source", "variance+cross-validation"},
  };
  for (const auto& [k, value] : want) {
    INFO(k);
    REQUIRE(hdr.count(k));
    CHECK(hdr.at(k) == value);
  }
  REQUIRE(hdr.count("proden:estimated_mse"));
  CHECK(std::stod(hdr.at("proden:estimated_mse")) == est);  // written to round-trip
  CHECK(string_attributes(out, "Software").at("Software").rfind("proden ", 0) == 0);

  // Other choices show in the header; the options are the daemon's spellings.
  const std::string out2 = s.file("g.exr");
  const Run g = proden("denoise -q --json --denoiser gaussian --mixer network --no-ttest --out " +
                           out2 + join(passes("cornell")),
                       s);
  INFO(g.err);
  REQUIRE(g.code == 0);
  const auto h2 = string_attributes(out2);
  CHECK(h2.at("proden:denoiser") == "gaussian");
  CHECK(h2.at("proden:mixer").rfind("network-w", 0) == 0);
  CHECK(h2.at("proden:mixer_weights") == "built-in pdnet.pdnw");
  CHECK(h2.at("proden:t_test") == "off");
  CHECK(h2.at("proden:inputs") == "HDR");  // the Gaussian reads no features
  const auto jg = nlohmann::json::parse(g.out);
  CHECK(jg["pipeline"]["settings"]["denoiser"] == "gaussian");
  CHECK(jg["estimated_mse"].get<double>() != est);

  // Denoiser none: the render, and its variance as the error.
  const std::string out3 = s.file("n.exr");
  const Run nn =
      proden("denoise -q --aov --json --denoiser none --out " + out3 + join(passes("cornell")), s);
  REQUIRE(nn.code == 0);
  const auto jn = nlohmann::json::parse(nn.out);
  CHECK(jn["estimated_mse_source"] == "variance");
  const auto vn = read_exr(out3, {"variance.R", "variance.G", "variance.B"}, &w, &h);
  const auto rn = read_exr(out3, {"R", "G", "B"}, &w, &h);
  const auto xn = read_exr(out3, {"render.R", "render.G", "render.B"}, &w, &h);
  double mv = 0;
  for (std::size_t c = 0; c < 3; ++c) {
    for (float q : vn[c]) mv += q;
  }
  CHECK(jn["estimated_mse"].get<double>() == Approx(mv / n).epsilon(1e-9));
  CHECK(rn == xn);
  CHECK(string_attributes(out3).at("proden:denoiser") == "none");
  Imf::InputFile in3(out3.c_str());
  CHECK(in3.header().channels().findChannel("denoised.R") == nullptr);
}

TEST_CASE("denoise: contradicting or misplaced pipeline options are refused by their flag, exit 2",
          "[cli]") {
  Scratch s;
  const std::string out = s.file("o.exr");
  const auto ps = passes("cornell");
  const Run c = proden(
      "denoise -q --mixer stein --closed-form-rule inverse-error --out " + out + " " + ps[0], s);
  CHECK(c.code == 2);
  CHECK_THAT(c.err, Contains("--closed-form-rule") && Contains("contradicts mixer stein"));
  const Run w = proden("denoise -q --weights " + sample("../training/weights/pdnet.pdnw") +
                           " --out " + out + " " + ps[0],
                       s);
  CHECK(w.code == 2);
  CHECK_THAT(w.err, Contains("--weights") && Contains("network"));
  CHECK_FALSE(fs::exists(out));
  // The old spellings still work: --mixer closed-form --closed-form-rule inverse-error.
  const Run ok = proden(
      "denoise -q --json --mixer closed-form --closed-form-rule inverse-error "
      "--out " +
          out + " " + ps[0] + " " + ps[1],
      s);
  REQUIRE(ok.code == 0);
  CHECK(nlohmann::json::parse(ok.out)["pipeline"]["mixer"] == "closed-form-inverse-error");
}
