// Shared helpers for proden's unit tests: temporary directories and synthetic passes.
#pragma once

#include <cstdint>
#include <filesystem>
#include <string>

#include "proden/pass.hpp"

namespace proden::test {

// A fresh directory under the system temp dir, removed on destruction.
class TempDir {
 public:
  TempDir();
  ~TempDir();
  TempDir(const TempDir&) = delete;
  TempDir& operator=(const TempDir&) = delete;
  std::string file(const std::string& name) const { return (path_ / name).string(); }
  const std::filesystem::path& path() const { return path_; }

 private:
  std::filesystem::path path_;
};

// A pass of Gaussian noise around a smooth pattern, deterministic in `seed`, with the features
// `layout` asks for (variance = sigma^2 / spp).
Pass make_pass(int width, int height, double spp, std::uint64_t seed, Layout layout = {},
               float sigma = 0.1f);

// Writes `pass` as a generic EXR (R,G,B, Albedo.*, Normal.*, Depth.Z, Variance.*).
void write_generic_exr(const std::string& path, const Pass& pass, bool half = false,
                       const std::string& compression = "zip");

// Copies the first `bytes` bytes of `from` to `to`.
void truncate_copy(const std::string& from, const std::string& to, std::uintmax_t bytes);

}  // namespace proden::test
