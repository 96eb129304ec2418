// Cost of persisting and reloading one frame's state (issue 12): a 1920x1080 frame with albedo,
// normal and depth (or --width/--height), its parts timed one by one, then the daemon's whole
// save (write + fsync + rename) and load of the state file, in a directory given by --dir.
#include <sys/resource.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <random>
#include <string>

#include "daemon/frame_state.hpp"
#include "proden/accumulator.hpp"
#include "proden/hash.hpp"

using namespace proden;

namespace {

Pass noisy(int w, int h, std::uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  Pass p;
  p.spp = 4;
  for (Image* img : {&p.colour, &p.albedo, &p.normal}) {
    *img = Image(w, h, 3);
    for (auto& v : img->data()) v = u(rng);
  }
  p.depth = Image(w, h, 1);
  for (auto& v : p.depth.data()) v = u(rng);
  return p;
}

double seconds_since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

double cpu_seconds() {  // of the process: every thread, the state writer's too
  rusage u{};
  ::getrusage(RUSAGE_SELF, &u);
  return static_cast<double>(u.ru_utime.tv_sec + u.ru_stime.tv_sec) +
         1e-6 * static_cast<double>(u.ru_utime.tv_usec + u.ru_stime.tv_usec);
}

struct Best {
  double wall = 1e30, cpu = 1e30;  // each the least over the repetitions
};

template <class F>
Best best_of_both(int repeat, F&& f) {
  Best best;
  for (int i = 0; i < repeat; ++i) {
    const double c0 = cpu_seconds();
    const auto t0 = std::chrono::steady_clock::now();
    f();
    best.wall = std::min(best.wall, seconds_since(t0));
    best.cpu = std::min(best.cpu, cpu_seconds() - c0);
  }
  return best;
}

template <class F>
double best_of(int repeat, F&& f) {
  return best_of_both(repeat, f).wall;
}

}  // namespace

int main(int argc, char** argv) {
  int w = 1920, h = 1080, repeat = 3;
  std::string dir = ".";
  for (int i = 1; i + 1 < argc; i += 2) {
    if (!std::strcmp(argv[i], "--width")) w = std::atoi(argv[i + 1]);
    if (!std::strcmp(argv[i], "--height")) h = std::atoi(argv[i + 1]);
    if (!std::strcmp(argv[i], "--repeat")) repeat = std::atoi(argv[i + 1]);
    if (!std::strcmp(argv[i], "--dir")) dir = argv[i + 1];
  }
  FrameAccumulator acc;
  for (std::uint32_t k = 0; k < 2; ++k) acc.add(noisy(w, h, k + 1), "p" + std::to_string(k));
  daemon::FrameRecord rec;
  rec.frame = 1;
  rec.version = 1;
  rec.passes = acc.passes();
  rec.spp = acc.total_spp();
  rec.width = w;
  rec.height = h;
  rec.digest = acc.state_digest();
  const AovAccumulator aovs;
  const auto bytes = daemon::frame_state_bytes(rec, acc, aovs);
  const double mb = static_cast<double>(bytes.size()) / 1e6;
  std::printf("frame %dx%d, HDR+ALB+NRM+DEP, 2 passes: state file %.1f MB; best of %d\n", w, h, mb,
              repeat);
  std::uint64_t sink = 0;
  const double digest = best_of(repeat, [&] { sink ^= acc.state_digest(); });
  const double serialize = best_of(repeat, [&] { sink ^= acc.serialize().size(); });
  const double hash = best_of(repeat, [&] { sink ^= hash_bytes({bytes.data(), bytes.size()}); });
  const double checksum = best_of(repeat, [&] {
    sink ^= checksum_bytes({bytes.data(), bytes.size()});
  });
  const double file_bytes =
      best_of(repeat, [&] { sink ^= daemon::frame_state_bytes(rec, acc, aovs).size(); });
  const std::filesystem::path path = std::filesystem::path(dir) / "bench_persist.state";
  const Best save = best_of_both(repeat, [&] { daemon::save_frame_state(path, rec, acc, aovs); });
  const double load = best_of(repeat, [&] {
    daemon::FrameRecord r;
    sink ^= daemon::load_frame_accumulator(path, &r).passes();
  });
  std::filesystem::remove(path);
  auto row = [mb](const char* what, double s) {
    std::printf("  %-46s %7.3f s  %7.0f MB/s\n", what, s, mb / s);
  };
  row("state_digest (the record's digest)", digest);
  row("FrameAccumulator::serialize (copy + hash)", serialize);
  row("hash_bytes over the file's bytes", hash);
  row("checksum_bytes over them (XXH3, format 4)", checksum);
  row("frame_state_bytes (the whole file in memory)", file_bytes);
  row("save_frame_state (write + fsync + rename)", save.wall);
  std::printf("  %-46s %7.3f s\n", "save_frame_state, CPU (all threads)", save.cpu);
  row("load_frame_accumulator (read + check + parse)", load);
  std::printf("  (checksum of results %llx)\n", static_cast<unsigned long long>(sink & 0xff));
  return 0;
}
