// Planar float image: the buffer type every pipeline stage reads and writes.
// Channel c of an image is a contiguous plane of width*height floats (row-major).
#pragma once

#include <cstddef>
#include <span>
#include <string>
#include <vector>

namespace proden {

class Image {
 public:
  Image() = default;
  Image(int width, int height, int channels, float fill = 0.0f);

  int width() const { return width_; }
  int height() const { return height_; }
  int channels() const { return channels_; }
  std::size_t pixels() const { return static_cast<std::size_t>(width_) * height_; }
  bool empty() const { return channels_ == 0 || pixels() == 0; }
  bool same_size(const Image& other) const {
    return width_ == other.width_ && height_ == other.height_;
  }

  std::span<float> plane(int c);
  std::span<const float> plane(int c) const;
  std::span<float> data() { return data_; }
  std::span<const float> data() const { return data_; }

  float& at(int x, int y, int c) { return data_[index(x, y, c)]; }
  float at(int x, int y, int c) const { return data_[index(x, y, c)]; }

  // "Image(128x128x3)", for logs and assertion messages.
  std::string to_string() const;

 private:
  std::size_t index(int x, int y, int c) const {
    return static_cast<std::size_t>(c) * pixels() + static_cast<std::size_t>(y) * width_ + x;
  }

  int width_ = 0;
  int height_ = 0;
  int channels_ = 0;
  std::vector<float> data_;
};

}  // namespace proden
