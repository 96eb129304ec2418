#include "cli/progress.hpp"

#include <unistd.h>

#include <cstdio>

namespace proden::cli {

Progress::Progress(std::string what, int total, bool enabled)
    : what_(std::move(what)), total_(total), enabled_(enabled && ::isatty(STDERR_FILENO) == 1) {}

Progress::~Progress() {
  done();
}

void Progress::step(const std::string& item) {
  ++current_;
  if (!enabled_) return;
  std::fprintf(stderr, "\r\033[K[%d/%d] %s: %s", current_, total_, what_.c_str(), item.c_str());
  std::fflush(stderr);
}

void Progress::done() {
  if (!enabled_) return;
  std::fprintf(stderr, "\r\033[K");
  std::fflush(stderr);
  enabled_ = false;
}

}  // namespace proden::cli
