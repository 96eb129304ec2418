// A one-line progress display for long CLI runs; silent when stderr is not a terminal.
#pragma once

#include <string>

namespace proden::cli {

class Progress {
 public:
  Progress(std::string what, int total, bool enabled);
  ~Progress();
  void step(const std::string& item);  // "[3/8] denoise: pass_02.exr"
  void done();

 private:
  std::string what_;
  int total_;
  int current_ = 0;
  bool enabled_;
};

}  // namespace proden::cli
