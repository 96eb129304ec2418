// Rectangles and planar views in image coordinates: what per-tile stages read and write.
// A View/Buffer covers a Rect of the full image; at(x, y, c) takes full-image coordinates.
#pragma once

#include <algorithm>
#include <cstddef>
#include <string>
#include <vector>

#include "proden/image.hpp"

namespace proden {

struct Rect {  // half-open [x0, x1) x [y0, y1)
  int x0 = 0, y0 = 0, x1 = 0, y1 = 0;

  int width() const { return x1 - x0; }
  int height() const { return y1 - y0; }
  std::size_t area() const {
    return empty() ? 0 : static_cast<std::size_t>(width()) * static_cast<std::size_t>(height());
  }
  bool empty() const { return x1 <= x0 || y1 <= y0; }
  bool contains(int x, int y) const { return x >= x0 && x < x1 && y >= y0 && y < y1; }
  bool contains(const Rect& r) const {
    return r.x0 >= x0 && r.y0 >= y0 && r.x1 <= x1 && r.y1 <= y1;
  }
  Rect expanded(int r) const { return {x0 - r, y0 - r, x1 + r, y1 + r}; }
  Rect intersect(const Rect& o) const {
    return {std::max(x0, o.x0), std::max(y0, o.y0), std::min(x1, o.x1), std::min(y1, o.y1)};
  }
  bool operator==(const Rect&) const = default;
  std::string to_string() const;
};

// Read-only view of `channels` planes covering `rect` (plane stride = rect.area()).
struct View {
  const float* data = nullptr;
  Rect rect;
  int channels = 0;

  bool valid() const { return data != nullptr && channels > 0; }
  std::size_t index(int x, int y, int c) const {
    return static_cast<std::size_t>(c) * rect.area() +
           static_cast<std::size_t>(y - rect.y0) * static_cast<std::size_t>(rect.width()) +
           static_cast<std::size_t>(x - rect.x0);
  }
  float at(int x, int y, int c) const { return data[index(x, y, c)]; }
  // Pixel (x, y) of plane c and the rest of its row: per-element loops over rows vectorise, where
  // at() recomputes the planar index for every element.
  const float* ptr(int x, int y, int c) const { return data + index(x, y, c); }
};

// A view of a whole image (invalid view for an empty image).
View view_of(const Image& image);

// Owning planar buffer over a rect.
class Buffer {
 public:
  Buffer() = default;
  Buffer(const Rect& rect, int channels, float fill = 0.0f)
      : rect_(rect),
        channels_(channels),
        data_(rect.area() * static_cast<std::size_t>(channels), fill) {}

  // Re-covers `rect` with `channels` planes of `fill`, keeping the allocation when it is large
  // enough: scratch buffers reused from run to run.
  void reset(const Rect& rect, int channels, float fill = 0.0f) {
    rect_ = rect;
    channels_ = channels;
    data_.assign(rect.area() * static_cast<std::size_t>(channels), fill);
  }
  // Floats allocated (reserved) by this buffer.
  std::size_t capacity() const { return data_.capacity(); }

  const Rect& rect() const { return rect_; }
  int channels() const { return channels_; }
  View view() const { return {data_.data(), rect_, channels_}; }
  float& at(int x, int y, int c) { return data_[view().index(x, y, c)]; }
  float at(int x, int y, int c) const { return data_[view().index(x, y, c)]; }
  float* ptr(int x, int y, int c) { return data_.data() + view().index(x, y, c); }
  const float* ptr(int x, int y, int c) const { return data_.data() + view().index(x, y, c); }
  float* row(int y, int c) { return ptr(rect_.x0, y, c); }
  const float* row(int y, int c) const { return ptr(rect_.x0, y, c); }

 private:
  Rect rect_;
  int channels_ = 0;
  std::vector<float> data_;
};

// Copies `region` of a buffer into the same region of a full image.
void store(const Buffer& src, const Rect& region, Image& dst);

}  // namespace proden
