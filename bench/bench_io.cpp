// Reading a pass and writing a published frame, in strips against one whole-image buffer, in one
// run (issue 12): `strip_bytes` = the largest value reproduces the former whole-image decode and
// interleave in the same binary, so the two alternate under the same machine state.
//
//   proden_bench_io --pass PASS.exr [--repeat N] [--tmp DIR]
//
// Read: io::read_pass of PASS (its colour and features), by OpenImageIO in strips and as one whole
// buffer (ReadOptions::exr_decoder `library`), and by the default route (proden's chunk decoder
// where it applies: io/src/exr_chunks.hpp); each with its wall and process CPU time (the CPU is
// what a loaded daemon pays). Write: 27 float channels, the published
// frame's count, filled from PASS's colour, albedo and normal planes (9 layers of 3; noisy render
// data like the frame's render and variance layers), with PIZ and with no compression, through
// io::write_image (temp file, fsync, rename) into DIR (default /tmp). Prints every time and the
// median of each configuration. Run it under the daemon's heap policy (bench/RESULTS.md, the
// glibc tunables line) to time what the daemon does.
#include <algorithm>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <filesystem>
#include <limits>
#include <map>
#include <string>
#include <vector>

#include "bench_common.hpp"
#include "proden/io/image_writer.hpp"
#include "proden/io/pass_reader.hpp"

namespace {

using Clock = std::chrono::steady_clock;
constexpr std::uint64_t kWhole = std::numeric_limits<std::uint64_t>::max();

double since(Clock::time_point t0) {
  return std::chrono::duration<double>(Clock::now() - t0).count();
}

double process_cpu() {
  timespec t{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);
  return static_cast<double>(t.tv_sec) + 1e-9 * static_cast<double>(t.tv_nsec);
}

}  // namespace

int main(int argc, char** argv) {
  std::string pass_path, tmp = "/tmp";
  int repeat = 5;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    const bool more = i + 1 < argc;
    if (a == "--pass" && more) {
      pass_path = argv[++i];
    } else if (a == "--repeat" && more) {
      repeat = std::max(1, std::atoi(argv[++i]));
    } else if (a == "--tmp" && more) {
      tmp = argv[++i];
    } else {
      std::fprintf(stderr, "usage: %s --pass PASS.exr [--repeat N] [--tmp DIR]\n", argv[0]);
      return 2;
    }
  }
  if (pass_path.empty()) {
    std::fprintf(stderr, "--pass is required\n");
    return 2;
  }
  using namespace proden;
  const Pass pass = io::read_pass(pass_path);
  if (pass.albedo.empty() || pass.normal.empty()) {
    std::fprintf(stderr, "%s: needs albedo and normal (a Cycles pass with denoising data)\n",
                 pass_path.c_str());
    return 2;
  }
  const Image* planes[] = {&pass.colour, &pass.albedo, &pass.normal};
  std::vector<io::NamedChannel> channels;
  for (int k = 0; k < 9; ++k)
    io::add_layer(channels, "l" + std::to_string(k) + ".", *planes[k % 3]);
  const std::string out = (std::filesystem::path(tmp) / "proden_bench_io.exr").string();
  const int W = pass.colour.width(), H = pass.colour.height();

  std::map<std::string, std::vector<double>> times;
  for (int r = 0; r < repeat; ++r) {
    for (int route = 0; route < 3; ++route) {
      io::ReadOptions o;
      o.exr_decoder = route == 2 ? io::ExrDecoder::automatic : io::ExrDecoder::library;
      if (route == 0) o.strip_bytes = kWhole;
      const std::string name = route == 0   ? "read, OIIO whole buffer"
                               : route == 1 ? "read, OIIO strips"
                                            : "read, default (chunks)";
      const auto t0 = Clock::now();
      const double c0 = process_cpu();
      const Pass p = io::read_pass(pass_path, o);
      times[name].push_back(since(t0));
      times[name + ", CPU"].push_back(process_cpu() - c0);
    }
    for (const char* compression : {"piz", "none"}) {
      for (const std::uint64_t strip : {kWhole, io::WriteOptions{}.strip_bytes}) {
        io::WriteOptions o;
        o.compression = compression;
        o.strip_bytes = strip;
        const auto t0 = Clock::now();
        io::write_image(out, W, H, channels, o);
        times[std::string("write 27 ch ") + compression +
              (strip == kWhole ? ", whole buffer" : ", strips")]
            .push_back(since(t0));
      }
    }
  }
  std::filesystem::remove(out);
  std::printf("%s: %dx%d; %d rounds, configurations alternating\n", pass_path.c_str(), W, H,
              repeat);
  for (const auto& [name, v] : times) {
    std::printf("%-32s median %.3f s  (", name.c_str(), bench::median(v));
    for (std::size_t i = 0; i < v.size(); ++i) std::printf("%s%.3f", i ? " " : "", v[i]);
    std::printf(")\n");
  }
  return 0;
}
