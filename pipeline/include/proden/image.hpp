// Planar float image: the buffer type every pipeline stage reads and writes.
// Channel c of an image is a contiguous plane of width*height floats (row-major).
#pragma once

#include <cstddef>
#include <memory>
#include <new>
#include <span>
#include <string>
#include <utility>
#include <vector>

namespace proden {

class Image {
 public:
  Image() = default;
  Image(int width, int height, int channels, float fill = 0.0f);
  // The values left unset, for a producer that writes every element itself
  // (FrameAccumulator::estimate): no serial fill, and the pages are first touched by the
  // producer's own threads.
  struct Uninitialized {};
  static constexpr Uninitialized uninitialized{};
  Image(int width, int height, int channels, Uninitialized);

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

  // std::allocator, except that a float made without a value is left unset (default-initialised)
  // instead of zeroed: what Uninitialized needs; the other constructor fills explicitly.
  template <class T>
  struct DefaultInit : std::allocator<T> {
    template <class U>
    struct rebind {
      using other = DefaultInit<U>;
    };
    DefaultInit() = default;
    template <class U>
    DefaultInit(const DefaultInit<U>&) noexcept {}
    template <class U>
    void construct(U* p) noexcept {
      ::new (static_cast<void*>(p)) U;
    }
    template <class U, class... Args>
    void construct(U* p, Args&&... args) {
      ::new (static_cast<void*>(p)) U(std::forward<Args>(args)...);
    }
  };

  int width_ = 0;
  int height_ = 0;
  int channels_ = 0;
  std::vector<float, DefaultInit<float>> data_;
};

}  // namespace proden
